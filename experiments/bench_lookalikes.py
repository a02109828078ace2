"""Which effect do bench readings name? The bench stage of ``diagnose`` on virtual strips alone.

Virtual bench readings of an example fabric with a hidden effect that a strip feels
(``drapejax.virtual_lab.virtual_bench``: seeded reading noise of ``io.READING_STD``), tested by
``drapejax.diagnose.bench.bench_evidence`` against the candidates at a fabric whose k1 are all
``--k1-factor`` times the truth (what a drape's baseline fit absorbs), without any capture's
information. Each row is one seed and one set of readings: which candidate is named, which are
ambiguous (within the bench stage's margin of the best), and each candidate's fall of the
objective against the χ² it needs. ``--upper-only`` repeats each set without the pure bending
rows below 50 1/m (the rows a KES-FB2 reading of B alone would give); ``--loading-only`` repeats
it without the unloading branch (``pure_bending_unloading``), as a tester read on loading alone.

    python -m experiments.bench_lookalikes --hidden bending_saturation=1 --k1-factor 0.8 \
        --candidates bending_friction,bending_saturation,bias_asymmetry \
        --readings pure_bending:weft --readings pure_bending:warp,pure_bending:weft,pure_bending:bias --seeds 3,4,5
    python -m experiments.bench_lookalikes --hidden bias_asymmetry=1 --k1-factor 1.3 \
        --candidates bending_friction,bending_saturation,bias_asymmetry \
        --readings pure_bending:warp,pure_bending:weft,pure_bending:bias \
        --readings pure_bending:warp,pure_bending:weft,pure_bending:bias,pure_bending:counter_bias
    python -m experiments.bench_lookalikes --hidden bending_saturation=1 --k1-factor 0.8 \
        --candidates bending_friction,bending_saturation --readings pure_bending:warp --loading-only
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

from drapejax.diagnose.bench import bench_evidence  # noqa: E402
from drapejax.diagnose.strip import UNLOADING_TEST  # noqa: E402
from drapejax.effects import REGISTRY  # noqa: E402
from drapejax.material import DIRECTIONS, example_params  # noqa: E402
from drapejax.virtual_lab import virtual_bench  # noqa: E402

if __package__:  # python -m experiments.bench_lookalikes
    from .common import emit, parse_bench_tests, parse_candidates, parse_hidden
else:  # python experiments/bench_lookalikes.py
    from common import emit, parse_bench_tests, parse_candidates, parse_hidden

LOW_CURVATURE_PER_M = 50.0
"""Pure bending rows below this curvature are dropped by ``--upper-only``."""


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fabric", default="mid", help="example fabric (drapejax.material.example_params)")
    ap.add_argument("--hidden", required=True, help="NAME=THETA[,THETA...] of the hidden effect")
    ap.add_argument("--candidates", required=True, help="comma list of candidate effects")
    ap.add_argument("--k1-factor", type=float, default=1.0, help="the tested fabric's k1 over the truth's")
    ap.add_argument("--readings", action="append", required=True,
                    help="a set of readings, TEST:DIRECTION[,TEST:DIRECTION...] (repeatable)")
    ap.add_argument("--seeds", default="3,4,5", help="reading-noise seeds")
    ap.add_argument("--upper-only", action="store_true", help="also each set without the rows below 50 1/m")
    ap.add_argument("--loading-only", action="store_true", help="also each set without the unloading branch")
    ap.add_argument("--results", type=Path, default=None, help="append the JSON lines to this file")
    a = ap.parse_args(argv)
    hidden = parse_hidden([a.hidden], ap)
    candidates = [REGISTRY[n] for n in parse_candidates(a.candidates, ap)]
    truth = example_params(a.fabric)
    fitted = dataclasses.replace(truth, **{f"bend_k1_{d}": getattr(truth, f"bend_k1_{d}") * a.k1_factor
                                           for d in DIRECTIONS})
    for item in a.readings:
        tests = parse_bench_tests("--readings", [t for t in item.split(",") if t], ap)
        if not tests:
            ap.error(f"--readings {item!r}: expected TEST:DIRECTION[,TEST:DIRECTION...]")
        for seed in (int(s) for s in a.seeds.split(",")):
            records = virtual_bench(truth, hidden, tests, seed=seed)
            subsets = {"all": records}
            if a.upper_only:
                subsets["upper"] = [r for r in records if r.test != "pure_bending"
                                    or r.values["curvature_per_m"] >= LOW_CURVATURE_PER_M]
            if a.loading_only:
                subsets["loading"] = [r for r in records if r.test != UNLOADING_TEST]
            for rows, recs in subsets.items():
                t0 = time.time()
                ev = bench_evidence(recs, fitted, candidates)
                emit({"fabric": a.fabric, "hidden": hidden, "k1_factor": a.k1_factor, "readings": item, "rows": rows,
                      "n_readings": len(recs), "seed": seed, "selected": ev["selected"],
                      "ambiguous": ev.get("ambiguous"), "error_before": ev["error_before"],
                      "effects": {n: {k: e.get(k) for k in ("found", "chi2_drop", "chi2_needed", "theta",
                                                            "theta_std_prior_stds", "error_after")}
                                  for n, e in ev["effects"].items() if e.get("felt")},
                      "seconds": round(time.time() - t0, 1)}, a.results)


if __name__ == "__main__":
    main()
