"""Which hidden effects can the fit's residual rows see at all, even without fold noise?

``effect_recovery.py`` finds few effects, and each refusal can have two causes: the effect's
change of the observables is within the drop-to-drop noise, or the baseline's three k1 scales
reproduce that change, so nothing is left for the effect to explain. This study separates them
without any fit. On one rest state of the "mid" fabric (drop seed 0) it computes, by warm-started
static solves on the same fold branch (continuation, no new drop):

* the k1 secants: the change of the features when k1 along warp, weft or bias grows by 10 %;
* each effect's secant: the change when the effect is switched on at its ``effect_recovery``
  strength (the nonlinear response, not a derivative at zero, so inert-at-zero effects count).

Each change is whitened by the per-drop noise of every feature, measured here over
``--seeds`` drops. "signal" = ½‖Δr‖² and "unexplained" = ½‖P⊥Δr‖², with P⊥ the projection
orthogonal to the three k1 secants: the most any fit can gain by adding the effect, on
noise-free data, against the BIC penalty ½·k·log(n) of ``diagnose``. Reported for the library's
rows (``refine.Misfit``: DC, fold depth, first harmonic, hem and ring heights, warp/bias
second harmonic) and for an extended set (all twelve harmonic amplitudes and the mean height on
eleven rings from 95 to 145 mm), to show which observables would make an effect visible.

    python -m experiments.effect_detectability                 # 20 mm graded from 3 mm, 6 noise drops
    python -m experiments.effect_detectability --only heavy_hem,edge_curl --seeds 4
    python -m experiments.effect_detectability --real ../shared/data/real_cusick   # capture spread only

``--real DIR`` instead prints the capture-to-capture spread of the same observables over the
captures of each real fabric in DIR (``common.groups``) and its median and rms over the
fabrics: with the drop-to-drop spread above, what ``refine.SIGMA_*`` are made of.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)

from drapejax import refine  # noqa: E402
from drapejax.effects import REGISTRY  # noqa: E402
from drapejax.energy import default_energies  # noqa: E402
from drapejax.material import FabricParams, example_params  # noqa: E402
from drapejax.io import load_measurement  # noqa: E402
from drapejax.mesh import cusick_mesh  # noqa: E402
from drapejax.solve import drape, quick_config, static_solve  # noqa: E402

if __package__:  # python -m experiments.effect_detectability
    from .common import EXTRA_RINGS_M, LIBRARY_SIGMA, features, groups
    from .common import STRENGTHS as CASES
else:  # python experiments/effect_detectability.py
    from common import EXTRA_RINGS_M, LIBRARY_SIGMA, features, groups
    from common import STRENGTHS as CASES

STRENGTHS = {name: effects[name] for name, effects in CASES.items() if name in effects}
"""Each effect's θ at its ``effect_recovery.py`` strength."""


def scores(delta: np.ndarray, k_secants: np.ndarray, n_params: int) -> dict:
    """Signal ½‖Δ‖², what the k1 secants cannot absorb ½‖P⊥Δ‖², and the BIC penalty."""
    q, _ = np.linalg.qr(k_secants)
    perp = delta - q @ (q.T @ delta)
    penalty = 0.5 * n_params * math.log(len(delta))
    return {"signal": 0.5 * float(delta @ delta), "unexplained": 0.5 * float(perp @ perp), "penalty": penalty,
            "top_rows": [int(i) for i in np.argsort(-np.abs(perp))[:3]]}


def real_spread(data) -> int:
    """Capture-to-capture std of every observable, per real fabric, then median and rms over fabrics."""
    sds = []
    for name, folders in groups(Path(data)).items():
        rows = []
        for f in folders:
            m = load_measurement(f)
            rows.append(features(np.asarray(m.scan_vertices, float), np.asarray(m.scan_faces))["extended"])
        sd = np.std(np.array(rows), axis=0, ddof=1)
        sds.append(sd)
        print(json.dumps({"fabric": name, "captures": len(folders), "std": sd.tolist()}), flush=True)
    sds = np.array(sds)
    print(json.dumps({"layout": "dc, harmonic amplitudes 1-12, c1 (x, y), hem, rings at rings_m, aniso, shear",
                      "rings_m": list(EXTRA_RINGS_M), "median": np.median(sds, 0).tolist(),
                      "rms": np.sqrt(np.mean(sds**2, 0)).tolist()}), flush=True)
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spacing", type=float, default=refine.FIT_SPACING_M)
    ap.add_argument("--rim", type=float, default=refine.FIT_RIM_SPACING_M)
    ap.add_argument("--seeds", type=int, default=6, help="drops for the per-feature noise")
    ap.add_argument("--only", default="", help="comma list of effects (default all)")
    ap.add_argument("--real", default=None, help="print the capture spread of the real scans in this folder instead")
    args = ap.parse_args(argv)
    if args.real:
        return real_spread(args.real)
    t0 = time.perf_counter()
    mesh = cusick_mesh(args.spacing, rim_spacing_m=args.rim or None)
    faces = np.asarray(mesh.faces)
    base = default_energies("cusick")
    cfg = quick_config(exact_step_hessian=False, exact_static_hessian=False)
    mid = example_params("mid")
    drop = jax.jit(lambda p, s: drape(mesh, p, s, terms=base, config=cfg))

    feats = [features(np.asarray(drop(mid, s).x), faces) for s in range(args.seeds)]
    noise = {k: np.std([f[k] for f in feats], axis=0, ddof=1) for k in feats[0]}
    sigma = {"library": LIBRARY_SIGMA, "extended": np.maximum(noise["extended"], 1e-5)}
    print(json.dumps({"noise_per_drop": {k: v.tolist() for k, v in noise.items()},
                      "library_sigma": LIBRARY_SIGMA.tolist(), "rings_m": list(EXTRA_RINGS_M)}), flush=True)

    x0 = np.asarray(drop(mid, 0).x)
    f0 = features(x0, faces)

    solve_jit = eqx.filter_jit(lambda p, terms: static_solve(mesh, p, jnp.asarray(x0), terms=terms, config=cfg).x)

    def solve(params: FabricParams, terms) -> np.ndarray:
        return np.asarray(solve_jit(params, terms))

    k_sec = {k: [] for k in f0}
    for d in refine.DIRECTIONS:
        kw = mid.to_dict()
        kw[f"bend_k1_{d}"] *= 1.1
        kw[f"bend_k2_{d}"] *= 1.1
        f = features(solve(FabricParams.from_dict(kw), base), faces)
        for k in f0:
            k_sec[k].append((f[k] - f0[k]) / sigma[k])
    k_sec = {k: np.stack(v, 1) for k, v in k_sec.items()}

    only = [s for s in args.only.split(",") if s] or list(STRENGTHS)
    for name in only:
        eff = REGISTRY[name]
        terms = base + tuple(eff.terms(mesh, jnp.asarray(STRENGTHS[name], float)))
        x = solve(mid, terms)
        f = features(x, faces)
        row = {"effect": name, "strength": STRENGTHS[name],
               "max_move_mm": 1e3 * float(np.max(np.linalg.norm(x - x0, axis=1)))}
        for k in f0:
            row[k] = scores((f[k] - f0[k]) / sigma[k], k_sec[k], eff.n_params())
        print(json.dumps(row), flush=True)
    print(json.dumps({"seconds": time.perf_counter() - t0, "mesh_verts": mesh.n_verts}), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
