"""Do the virtual lab's drops and the fit's drops agree? Truth and null dropped by both solvers.

The virtual lab drops with exact Newton steps (``refine.EXACT_CONFIG``); ``refine.fit``'s
default drops with projected ones (``refine.CONTINUATION_CONFIG``, "problem" below). For each
case of ``common.STRENGTHS`` this makes the same 3 captures as ``effect_recovery.py`` (25 mm,
seeds 0–2), drops the hidden generator ("truth") and "mid" without the effect ("null") with
each solver at seeds 100–102, and prints each model's mean ½χ² over every drop and capture, by
the selection rows (``select.selection_misfits``) and by the fit's rows. If the solvers landed
on different fold branches, the truth would score much better with the lab's solver.

Usage: python -m experiments.solver_match [--only bending_saturation,bias_asymmetry] [--workdir DIR]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import jax
import numpy as np

from drapejax import refine
from drapejax.diagnose.select import fresh_drop, effect_problem, selection_misfits
from drapejax.io import load_measurement
from drapejax.material import example_params
from drapejax.mesh import cusick_mesh
from drapejax.virtual_lab import make_measurement, simulate_with_effects

jax.config.update("jax_enable_x64", True)

if __package__:  # python -m experiments.solver_match
    from .common import STRENGTHS, generator
else:  # python experiments/solver_match.py
    from common import STRENGTHS, generator

SPACING_M = 0.025
SEEDS = (100, 101, 102)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default="bending_saturation")
    ap.add_argument("--workdir", type=Path, default=None)
    args = ap.parse_args()
    work = args.workdir or Path(tempfile.mkdtemp(prefix="solver_match_"))
    mesh, mid = cusick_mesh(SPACING_M, warp_angle_deg=0.0), example_params("mid")
    for case in [s.strip() for s in args.only.split(",") if s.strip()]:
        t0, eff = time.perf_counter(), STRENGTHS[case]
        ms = [load_measurement(make_measurement(work / case / f"capture_{i}", params=mid, effects=eff,
                                                spacing_m=SPACING_M, seed=i)) for i in range(3)]
        sel = selection_misfits(ms, mesh)
        fit_rows = [refine.Misfit(mesh, refine.measured_targets(m)) for m in ms]
        truth_effects, theta = generator(eff)
        out = {"case": case}
        for label, effs, th, hidden in (("truth", truth_effects, theta, eff), ("null", [], np.zeros(3), {})):
            prob = effect_problem(sel[0].targets, effs, mid, mesh, SPACING_M, config=refine.CONTINUATION_CONFIG)
            for solver in ("problem", "lab"):
                xs = [fresh_drop(prob, th, s) if solver == "problem" else
                      simulate_with_effects(mid, hidden, spacing_m=SPACING_M, seed=s)[0] for s in SEEDS]
                per_drop = [float(np.mean([m.loss(x) for m in sel])) for x in xs]
                out[f"{label}_{solver}"] = {"selection_rows": float(np.mean(per_drop)),
                                            "fit_rows": float(np.mean([m.loss(x) for x in xs for m in fit_rows])),
                                            "per_drop": np.round(per_drop, 2).tolist()}
        out["seconds"] = time.perf_counter() - t0
        print(json.dumps(out), flush=True)


if __name__ == "__main__":
    main()
