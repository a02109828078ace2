"""Speed and memory benchmark of a Cusick drape (mid-weight fabric), with the Newton peer.

The command line of ``drapejax.bench.run_bench`` (its docstring and benchmarks/README.md say
what each field measures); ``drapejax bench`` runs the same. Run
``python benchmarks/bench_drape.py --spacing-mm 5 --json``. On a CPU, ``--strategies=`` times
"map" alone.
"""

from __future__ import annotations

import argparse
import json

from drapejax.bench import parse_strategies, run_bench


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spacing-mm", type=float, default=5.0, help="mesh edge length, mm")
    ap.add_argument("--repeats", type=int, default=3, help="timed runs (median reported)")
    ap.add_argument("--batch", type=int, default=16, help="members of the batched runs")
    ap.add_argument("--no-newton", action="store_true", help="skip the Newton peer")
    ap.add_argument("--no-process", action="store_true", help="skip timing whole `drapejax simulate` processes")
    ap.add_argument("--strategies", default="vmap,map",
                    help="comma-separated batch strategies to time besides the device's default")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    a = ap.parse_args(argv)
    res = run_bench(a.spacing_mm / 1000.0, a.repeats, batch=a.batch, newton=not a.no_newton,
                    strategies=parse_strategies(a.strategies), process=not a.no_process)
    print(json.dumps(res) if a.json else json.dumps(res, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
