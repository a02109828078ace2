"""The loop on one hidden effect: virtual-lab captures → ``diagnose`` over the candidates given.

Makes ``--captures`` virtual-lab captures (drop seeds ``--first-seed``, +1, ...) of an example fabric with the
effects of ``--hidden`` (``name=θ``, repeatable; none: clean captures), runs
``drapejax.diagnose.diagnose`` on them with the candidate effects of ``--candidates`` (one
effect at most, no k1 rescale; ``--membrane-scan`` adds the membrane scan) and prints one JSON line: what was
selected and why, the baseline's k1 over the truth's, each candidate's screen and confirmation
figures, and the identifiability stage's verdicts (std with k1 known and free, the measurement
that would separate the effect). The HTML report and its JSON go to ``--workdir``.

    python -m experiments.effect_loop --hidden bending_friction=20 \
        --candidates bending_friction,bending_saturation,heavy_hem

``--bench TEST:DIRECTION`` (repeatable; ``cantilever``, ``pure_bending`` or ``tensile``, ``warp``,
``weft``, ``bias`` or ``counter_bias``, the other bias) adds bench readings on strips of the same
fabric, hidden effects included (``virtual_lab.virtual_bench``), to the captures' folders, and the
line then carries the bench stage's verdict on each candidate (bending readings) and the membrane
the tensile readings set:

    python -m experiments.effect_loop --hidden bending_friction=20 \
        --candidates bending_friction,bending_saturation,heavy_hem --bench pure_bending:weft
    python -m experiments.effect_loop --fabric light --first-seed 4 \
        --candidates bending_friction,bending_saturation,heavy_hem \
        --bench tensile:warp --bench tensile:weft --bench tensile:bias

The captures and the fits use the same mesh (``--spacing-mm``, ``--rim-mm``: the fit mesh, 20 mm
graded from 3 mm, by default) and the base model (uncapped membrane).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

from drapejax.diagnose import MembraneScan, Screen, diagnose, recovery  # noqa: E402
from drapejax.effects import REGISTRY  # noqa: E402
from drapejax.material import DIRECTIONS, example_params  # noqa: E402
from drapejax.virtual_lab import make_measurements, virtual_bench  # noqa: E402

if __package__:  # python -m experiments.effect_loop
    from .common import emit, parse_bench_tests, parse_candidates, parse_hidden
else:  # python experiments/effect_loop.py
    from common import emit, parse_bench_tests, parse_candidates, parse_hidden


TESTED_FIELDS = ("name", "signature", "values", "confirm_misfit", "confirm_null_misfit", "gain_noise_units", "accepted",
                 "reason")
"""What the JSON line keeps of each candidate the search tried."""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--hidden", action="append", default=[], help="NAME=THETA of a hidden effect (repeatable)")
    ap.add_argument("--candidates", required=True, help=f"comma list of candidate effects: {', '.join(REGISTRY)}")
    ap.add_argument("--fabric", default="mid", help="an example fabric")
    ap.add_argument("--captures", type=int, default=3)
    ap.add_argument("--first-seed", type=int, default=1, help="drop seed of the first capture (the others follow); "
                    "distinct seeds give independent cases of one fabric")
    ap.add_argument("--spacing-mm", type=float, default=20.0)
    ap.add_argument("--rim-mm", type=float, default=3.0, help="disc-edge spacing (0: uniform mesh)")
    ap.add_argument("--workdir", type=Path, default=None, help="where the captures and the report go (default: a "
                    "temporary folder)")
    ap.add_argument("--out", type=Path, default=None, help="append the JSON line here too")
    ap.add_argument("--membrane-scan", action="store_true", help="scan the baseline's membrane stiffness "
                    "(diagnose's membrane=MembraneScan())")
    ap.add_argument("--k-widen", type=int, default=Screen().k_widen, help="times the screen may widen a candidate's "
                    "k1 grid beyond its softest or stiffest factor (diagnose's Screen.k_widen, default 3)")
    ap.add_argument("--bench", action="append", default=[], help="TEST:DIRECTION of bench readings to add "
                    "(cantilever, pure_bending or tensile; warp, weft, bias or counter_bias), repeatable")
    a = ap.parse_args()
    tests = parse_bench_tests("--bench", a.bench, ap)
    hidden = parse_hidden(a.hidden, ap)
    names = parse_candidates(a.candidates, ap)
    spacing, rim = a.spacing_mm / 1e3, (a.rim_mm / 1e3 if a.rim_mm > 0 else None)
    params = example_params(a.fabric)
    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        root = a.workdir or Path(tmp)
        bench = virtual_bench(params, hidden, tests) if tests else []
        folders = make_measurements([root / f"capture_{i}" for i in range(a.captures)],
                                    [a.first_seed + i for i in range(a.captures)], params=params, effects=hidden,
                                    spacing_m=spacing, rim_spacing_m=rim, bench=bench)
        lab_s = time.perf_counter() - start
        res = diagnose(folders, report=root / "report.html", spacing_m=spacing, rim_spacing_m=rim,
                       candidates=[REGISTRY[n] for n in names], max_effects=1, rescale=None,
                       membrane=MembraneScan() if a.membrane_scan else None, screen=Screen(k_widen=a.k_widen))
    base, final = res["baseline"]["params"], res["final"]["params"]
    row = {"fabric": a.fabric, "hidden": hidden, "candidates": names, "spacing_mm": a.spacing_mm, "rim_mm": a.rim_mm,
           "captures": a.captures, "first_seed": a.first_seed,
           "selected": res["selected"], "reason": res.get("reason"),
           **recovery(res, hidden),
           "baseline_k1_over_truth": [round(base[f"bend_k1_{d}"] / float(getattr(params, f"bend_k1_{d}")), 3)
                                      for d in DIRECTIONS],
           "baseline_heldout_misfit": res["baseline"]["heldout_misfit"],
           "baseline_within_noise": res["baseline"]["misfit_within_noise"],
           "baseline_expected": res["baseline"]["expected"],
           "final_k1_over_truth": [round(final[f"bend_k1_{d}"] / float(getattr(params, f"bend_k1_{d}")), 3)
                                   for d in DIRECTIONS],
           "final_heldout_misfit": res["final"]["heldout_misfit"], "final_expected": res["final"]["expected"],
           "tested": [{k: e.get(k) for k in TESTED_FIELDS} for e in res["effects_tested"]],
           "identifiability": {n: {k: v.get(k) for k in ("std_conditional", "std_marginal", "k1_confounding",
                                                         "identifiable", "separated_by", "with_measurement")}
                               for n, v in (res.get("identifiability") or {}).items()},
           "bench_tests": a.bench, "k_widen": a.k_widen,
           "bench": None if res.get("bench") is None else {
               "selected": res["bench"]["selected"], "error_before": res["bench"]["error_before"],
               "readings": res["bench"]["readings"], "effects": res["bench"]["effects"]},
           "selected_by": res.get("selected_by"),
           "membrane_scan": res.get("membrane_scan"),
           "tensile": res.get("tensile"),
           "lab_seconds": round(lab_s, 1), "diagnose_seconds": round(res["seconds"], 1),
           "stage_seconds": {k: round(v, 1) for k, v in res["stage_seconds"].items()},
           "seconds": round(time.perf_counter() - start, 1)}
    emit(row, a.out)


if __name__ == "__main__":
    main()
