"""Does a continued rest state stand for a drop? Hidden effects scored on fresh drops and by continuation.

``diagnose`` refits each candidate effect by continuation: it starts from the baseline's rest
state and follows it, by warm-started static solves, as the effect grows from null. That keeps
the fold pattern, so a gain is the effect's and not a luckier drop's. This study asks whether
the continued state is the state a drop with the effect would reach. For each hidden effect
(``common.STRENGTHS``) the virtual lab drops ``--captures`` captures of "mid" on the
default fit mesh, and with the true parameters known it scores the library misfit
(``refine.Misfit``: ½χ² in noise units, mean over the captures and over fit drop seeds 100, 101, ...):

* ``none_fresh``: fresh drops at the true k1 without the effect (what the baseline model can do
  at the true k1);
* ``effect_fresh``: fresh drops at the true parameters, effect included (the truth);
* ``effect_continued``: the ``none_fresh`` rest states continued to the true effect (what a
  nested refit sees at the truth);
* ``grid``: fresh drops (first fit seed) at 0, ½, 1 and 1.5 times the true effect.

If ``effect_continued`` scores far worse than ``effect_fresh``, a refit by continuation cannot
find the effect even at the true parameters. ``--joint`` adds what a search that does not know
the truth would face: the baseline fit (``refine.fit``, no effect, from the true parameters,
drop seed 100), then fresh drops (seed 100) over its k1 times an overall factor (``K_SCALES``)
and the effect at ``GRID`` times its true strength. ``clean`` (nothing hidden) shows whether
the baseline fit drifts from the truth on its own. ``--search NAMES`` tries a search that uses
no truth: every named candidate at each of its ``Effect.probes`` (``PROBE_STEPS``; and null)
times each overall k1 factor around the baseline fit, on fresh drops (seed 100); per candidate
the grid point with the lowest misfit on the first capture is kept, and its misfit on the other
captures (held out) is reported next to the best null point's. One JSON line per effect.
About 2–3 minutes per effect on two CPU cores.

    python -m experiments.redrop_vs_continuation --only heavy_hem,bias_asymmetry --seeds 2
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

from drapejax import refine  # noqa: E402
from drapejax.diagnose.select import combine  # noqa: E402
from drapejax.effects import REGISTRY  # noqa: E402
from drapejax.io import load_measurement  # noqa: E402
from drapejax.material import example_params  # noqa: E402
from drapejax.mesh import cusick_mesh  # noqa: E402
from drapejax.virtual_lab import make_measurement  # noqa: E402

if __package__:  # python -m experiments.redrop_vs_continuation
    from .common import STRENGTHS as CASES
else:  # python experiments/redrop_vs_continuation.py
    from common import STRENGTHS as CASES

GRID = (0.0, 0.5, 1.0, 1.5)
K_SCALES = (1.0, 1.4, 2.0)


PROBE_STEPS = ((-2.0, -1.0, 1.0, 2.0), (-1.5, 1.5))
"""``Effect.probes`` offsets, prior stds, of a one-parameter and of a vector candidate: the
ladder behind this study's numbers in experiments/README.md, pinned so that a change of
``select.Screen``'s defaults does not change them."""


def search(names: str, base: refine.FitResult, misfits, mesh, init, spacing_m: float) -> dict:
    """Truth-free grid per candidate around ``base`` on fresh drops (module docstring)."""
    kb = np.asarray(base.theta[:3])
    out = {}
    for cname in [c.strip() for c in names.split(",") if c.strip()]:
        cand = REGISTRY[cname]
        prob = refine.Problem(mesh, misfits[0].targets, init, [combine([cand])], np.zeros(3 + cand.n_params()),
                              np.r_[refine.K_PRIOR_STD, cand.prior_std()], spacing_m)
        rows = []
        for k in K_SCALES:
            for th in [cand.theta0(), *cand.probes(*PROBE_STEPS)]:
                x = prob.drop(np.r_[kb + np.log(k), th], 100)
                rows.append({"k": k, "theta": np.asarray(th).tolist(), "fitted": misfits[0].loss(x),
                             "heldout": float(np.mean([mf.loss(x) for mf in misfits[1:]]))})
        null = [r for r in rows if np.array_equal(r["theta"], cand.theta0())]
        best = min(rows, key=lambda r: r["fitted"])
        out[cname] = {"best": best, "best_null": min(null, key=lambda r: r["fitted"])}
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default="heavy_hem,bias_asymmetry,heterogeneity,bending_saturation,off_centre")
    ap.add_argument("--captures", type=int, default=3)
    ap.add_argument("--seeds", type=int, default=2, help="fit drop seeds 100, 101, ...")
    ap.add_argument("--spacing", type=float, default=refine.FIT_SPACING_M)
    ap.add_argument("--rim", type=float, default=refine.FIT_RIM_SPACING_M)
    ap.add_argument("--joint", action="store_true", help="also the grid around the baseline fit's k1")
    ap.add_argument("--search", default="", help="comma-separated candidates for the truth-free grid search")
    ap.add_argument("--workdir", type=Path, default=None)
    args = ap.parse_args(argv)
    work = args.workdir or Path(tempfile.mkdtemp(prefix="redrop_"))
    mesh = cusick_mesh(args.spacing, rim_spacing_m=args.rim)
    truth = example_params("mid")
    for name in [s.strip() for s in args.only.split(",") if s.strip()]:
        t0 = time.perf_counter()
        # "clean" hides nothing: its effect rows are the heavy hem at null, so only k1 varies
        theta_e = np.asarray(CASES[name].get(name, [0.0]), float)
        eff = REGISTRY.get(name, REGISTRY["heavy_hem"])
        ms = [load_measurement(make_measurement(work / name / f"capture_{i}", params=truth, effects=CASES[name],
                                                spacing_m=args.spacing, rim_spacing_m=args.rim, seed=i))
              for i in range(args.captures)]
        misfits = [refine.Misfit(mesh, refine.measured_targets(m)) for m in ms]
        prob = refine.Problem(mesh, misfits[0].targets, truth, [combine([eff])], np.zeros(3 + eff.n_params()),
                              np.r_[refine.K_PRIOR_STD, eff.prior_std()], args.spacing)
        at = lambda s: np.r_[np.zeros(3), s * theta_e]
        score = lambda x: float(np.mean([mf.loss(x) for mf in misfits]))

        rows = {"none_fresh": [], "effect_fresh": [], "effect_continued": []}
        for seed in range(100, 100 + args.seeds):
            x0 = prob.drop(at(0.0), seed)
            rows["none_fresh"].append(score(x0))
            rows["effect_fresh"].append(score(prob.drop(at(1.0), seed)))
            prob.x = x0
            rows["effect_continued"].append(score(prob.rest(at(1.0), seed)))
        out = {"grid_seed100": {str(s): score(prob.drop(at(s), 100)) for s in GRID}}
        if args.joint or args.search:
            base = refine.fit(ms[0], init=truth, spacing_m=args.spacing, mesh=mesh, max_steps=6, seed=100)
        if args.joint:
            kb = np.asarray(base.theta[:3])
            out["baseline"] = {"theta_k": kb.tolist(), "loss_fitted": base.loss, "misfit": score(base.x)}
            out["joint_seed100"] = {f"k×{k}, effect×{s}": score(prob.drop(np.r_[kb + np.log(k), s * theta_e], 100))
                                    for k in K_SCALES for s in GRID}
        if args.search:
            out["search"] = search(args.search, base, misfits, mesh, truth, args.spacing)
        print(json.dumps({"effect": name, "theta": theta_e.tolist(), "n_rows": misfits[0].n_rows,
                          **{k: {"mean": float(np.mean(v)), "per_seed": v} for k, v in rows.items()},
                          **out, "seconds": time.perf_counter() - t0}), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
