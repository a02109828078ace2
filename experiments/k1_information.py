"""How precisely can one drape capture pin k1? A Cramér–Rao bound from the simulator's own re-drop spread.

For N truths from the 618-fabric prior (the same draws, seed 12345, as ``refine_synthetic.py``)
each truth is dropped from flat with K seeds on the fit mesh. At every rest state the fit's
whitened residual rows (``refine.Problem``: fold depth, DC, world first harmonic, hem and ring
heights, warp anisotropy, bias shear) and their Jacobian in log k1 (warp, weft, bias; k2 scaled
with k1, as the fit does) are taken, the Jacobian by implicit differentiation of the rest state.

With J̄ the mean Jacobian over the K drops and C the drop-to-drop covariance of the rows
(diagonal, from the same K drops), no unbiased estimator from ONE capture has a smaller
covariance of log k1 than (J̄ᵀ C⁻¹ J̄)⁻¹ (Cramér–Rao for Gaussian rows). Reported from it:
the std per direction and of the overall scale (geometric mean); the stds along the information
matrix's eigenvectors, best to worst, and the worst one (unit length, the free direction); and
the best-determined combination (``refine.best_combination``) with its std. With n captures a
std falls as 1/√n, so (std / 0.05)² captures reach a 5 % standard error. Next to it: the same
bound with C = I, i.e. with the fixed noise floors ``refine.SIGMA_*`` the fit whitens by (its
Laplace std without the prior).

``--four-fold`` adds one candidate row the fit does not have: the rim profile's warp-aligned
fourth harmonic 2·mean(r cos 4(φ − ψ)) (m; Jacobian of its soft counterpart; whitened by
``refine.SIGMA_H2_M`` in the fixed-floor bound). It is the one phase-dependent trace of how the
axes' rigidity compares with the bias's, so it asks whether such a row would pin the
combination the other rows leave free.

Caveats, stated with the numbers: J̄ is the derivative along each drop's own fold pattern (what
the fit follows), not of the expectation over fold patterns; C is estimated from K drops and
its off-diagonal terms are left out.

Usage: python -m experiments.k1_information [--n 20] [--drops 6] [--spacing 0.02] [--rim 0.003]
       [--only 0,5] [--four-fold] [--out OUT.jsonl]
Drop seeds 100000 + 100 i + s, s < K: none is one ``refine_synthetic.py`` drapes with (1000 + i).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)

from drapejax import observe, refine  # noqa: E402
from drapejax.inverse.prior import default_prior  # noqa: E402
from drapejax.material import unstack  # noqa: E402
from drapejax.mesh import cusick_mesh  # noqa: E402
from drapejax.solve import equilibrium  # noqa: E402

if __package__:  # python -m experiments.k1_information
    from .common import emit
else:  # python experiments/k1_information.py
    from common import emit

KEYS = [f"bend_k1_{d}" for d in refine.DIRECTIONS]
SCALE = np.full(3, 1.0 / 3.0)
"""Row of the overall k1 scale (geometric mean of the three) in log k1."""


def _targets() -> refine.Targets:
    """Placeholder targets: neither the Jacobian nor the spread of the rows depends on them."""
    return refine.Targets(dc=0.0, harmonics=np.zeros(refine.N_HARMONICS), hem_m=0.0, silhouette=None, aniso_m=0.0,
                          c1_m=np.zeros(2), shear_m=0.0, rings_m=np.zeros(len(refine.RING_RADII_M)))


def bound(j: np.ndarray, var: np.ndarray) -> dict:
    """Cramér–Rao stds of log k1 (per direction and overall scale) for rows of variance ``var``."""
    info = j.T @ (j / var[:, None])
    cov = np.linalg.pinv(info)
    w, v = np.linalg.eigh(info)
    best, std = refine.best_combination(info)
    return {"std_log_k1": dict(zip(KEYS, np.sqrt(np.clip(np.diag(cov), 0, None)).tolist())),
            "std_log_scale": float(np.sqrt(max(SCALE @ cov @ SCALE, 0.0))),
            "eigen_std": (1.0 / np.sqrt(np.maximum(w[::-1], 1e-300))).tolist(),
            "free_direction": dict(zip(KEYS, (v[:, 0] * np.sign(v[np.argmax(np.abs(v[:, 0])), 0])).tolist())),
            "best_combination": {"weights": dict(zip(KEYS, best.tolist())), "std": std},
            "condition": float(np.linalg.cond(info))}


def _four_fold(r):
    """2·mean(r cos 4φ) of a rim profile r(φ), m: the fit mesh has its warp along +x."""
    phi = 2 * np.pi * np.arange(r.shape[0]) / r.shape[0]
    return 2.0 * jnp.mean(r * jnp.cos(4.0 * phi))


def four_fold_row(prob: refine.Problem):
    """(hard value, Jacobian in log k1) of the warp-aligned fourth harmonic at a rest state, m."""
    def soft(theta, x_rest):
        p, terms = prob.split(theta)
        x = equilibrium(prob.mesh, p, x_rest, terms=terms)
        return _four_fold(observe.soft_rim_profile(x, sharpness=20.0 / prob.spacing_m, n_angles=refine.N_ANGLES,
                                                   vertex_radius_m=prob.spacing_m))

    jac = jax.jit(jax.jacfwd(soft))
    faces = np.asarray(prob.mesh.faces)

    def row(x):
        sil = observe.silhouette(x, faces, n=256, extent_m=refine.EXTENT_M)
        r = observe.rim_profile(sil, refine.EXTENT_M, n_angles=refine.N_ANGLES)
        return float(_four_fold(jnp.asarray(r))), np.asarray(jac(jnp.zeros(3), jnp.asarray(x)))

    return row


def case(prob: refine.Problem, drops: int, i: int, four_fold: bool = False) -> dict:
    rows, jacs = [], []
    n = prob.n_rows
    extra = four_fold_row(prob) if four_fold else None
    for s in range(drops):
        x = prob.drop(np.zeros(3), 100_000 + 100 * i + s)
        r, j = prob.evaluate(np.zeros(3), x, jacobian=True)
        rows.append(r[:n])
        jacs.append(j[:n])
        if extra is not None:
            v, jv = extra(x)
            rows[-1] = np.append(rows[-1], v / refine.SIGMA_H2_M)
            jacs[-1] = np.vstack([jacs[-1], jv / refine.SIGMA_H2_M])
    rows, jbar = np.array(rows), np.mean(jacs, axis=0)
    var = np.var(rows, axis=0, ddof=1)
    return {"row_std_in_noise_floors": np.sqrt(var).tolist(),
            "jacobian_mean": jbar.tolist(),
            "jacobian_spread": np.std(jacs, axis=0, ddof=1).tolist(),
            "redrop": bound(jbar, np.maximum(var, 1e-12)),
            "fixed_floors": bound(jbar, np.ones(len(var)))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=20)
    ap.add_argument("--drops", type=int, default=6)
    ap.add_argument("--spacing", type=float, default=refine.FIT_SPACING_M)
    ap.add_argument("--rim", type=float, default=refine.FIT_RIM_SPACING_M)
    ap.add_argument("--only", default="", help="comma-separated truth indices (default: all N)")
    ap.add_argument("--four-fold", action="store_true", help="add the warp-aligned 4th-harmonic row (module doc)")
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args()
    only = {int(v) for v in a.only.split(",") if v}
    mesh = cusick_mesh(a.spacing, warp_angle_deg=0.0, rim_spacing_m=a.rim)
    stds, eig = [], []
    for i, truth in enumerate(unstack(default_prior().sample(a.n, seed=12345))):
        if only and i not in only:
            continue
        t0 = time.perf_counter()
        prob = refine.Problem(mesh, _targets(), truth, (), np.zeros(3), np.array(refine.K_PRIOR_STD), a.spacing,
                              config=refine.EXACT_CONFIG)
        row = {"i": i, "truth": {k: float(v) for k, v in truth.to_dict().items() if k in KEYS},
               "bending_length_mm": 1e3 * refine.bending_length_m(truth), "drops": a.drops, "four_fold": a.four_fold,
               **case(prob, a.drops, i, a.four_fold), "seconds": time.perf_counter() - t0}
        emit(row, a.out)
        stds.append([*row["redrop"]["std_log_k1"].values(), row["redrop"]["std_log_scale"]])
        eig.append(row["redrop"]["eigen_std"])
    s = np.array(stds)
    med = np.median(s, axis=0)
    print(json.dumps({"summary": {
        "cases": len(s), "drops": a.drops, "four_fold": a.four_fold, "n_verts": mesh.n_verts,
        "median_std_log_k1": dict(zip(KEYS, med[:3].tolist())), "median_std_log_scale": float(med[3]),
        "median_eigen_std": np.median(eig, axis=0).tolist(),
        "captures_for_5pct": dict(zip(KEYS + ["scale"], np.ceil((med / 0.05) ** 2).astype(int).tolist()))}}),
        flush=True)


if __name__ == "__main__":
    main()
