"""How tight must the static force tolerance be? Drape coefficient, folds and implicit gradients
against the residual force of the fine-level equilibrium.

A cascadic drape (``solve.drape_multilevel``) drops on a coarse nested Cusick mesh and solves the
static equilibrium on the finer levels. The finest static solve is where the time goes, and most
of its Newton iterations only push the residual force from about 1e-2 to 1e-5 of a vertex's
weight. This experiment starts the finest solve from the same prolonged coarse shape for each
``force_tol`` in a ladder (``SolverConfig.force_tol``: the solve stops when every residual force
is below ``0.1 * force_tol`` of the mean vertex weight) and records, per tolerance, the Newton
iterations, seconds, drape coefficient, fold count, the largest residual over the mean vertex
weight, and the implicit gradient (``solve.equilibrium``) of a smooth observable (the mean hem
radius) with respect to log k1 of each direction, compared with the tightest tolerance's.
An implicit gradient at a point that is not an equilibrium carries an error of order
``H^-1 r`` (the residual ``r`` propagated through the inverse Hessian), so its agreement with the
tight one measures how far the loose state is from the equilibrium in the directions that matter.

One JSON line per (seed, tolerance):

    python -m experiments.force_tolerance --spacing-mm 10 --rim-mm 2 --levels 2 --seeds 0,1,2

With ``--trajectory K`` it instead follows one tight finest-level solve in chunks of K Newton
iterations (the same Newton method restarted from where the last chunk stopped) and prints, after
each chunk, the drape coefficient, fold count, the phase of the rim's fold harmonic (a rotation
of the fold pattern shows as a drifting phase), the largest and the root-mean-square residual
over the mean vertex weight, the energy, and the largest vertex move over the chunk: where the
iterations go.

    python -m experiments.force_tolerance --seeds 0 --trajectory 10
"""

from __future__ import annotations

import argparse
import json
import time

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)

from drapejax.energy import default_energies, total_energy  # noqa: E402
from drapejax.material import G, example_params  # noqa: E402
from drapejax.mesh import nested_cusick_meshes  # noqa: E402
from drapejax import observe  # noqa: E402
from drapejax.solve import NewtonConfig, SolverConfig, drape, equilibrium, static_solve  # noqa: E402

if __package__:  # python -m experiments.force_tolerance
    from .common import dc_and_folds
else:  # python experiments/force_tolerance.py
    from common import dc_and_folds

TOLERANCES = (1e-1, 3e-2, 1e-2, 3e-3, 1e-3, 1e-4)


def hem_radius_gradient(mesh, params, x, terms):
    """d(mean hem radius, m)/d(log k1) for warp, weft and bias, through the implicit function theorem."""
    r0 = np.linalg.norm(np.asarray(mesh.rest)[:, :2], axis=1)
    hem = jnp.asarray(np.nonzero(r0 > r0.max() - 1e-6)[0])

    def radius(logk):
        p = eqx_replace(params, jnp.exp(logk))
        xr = equilibrium(mesh, p, x, terms=terms)
        return jnp.mean(jnp.linalg.norm(xr[hem, :2], axis=1))

    logk = jnp.log(jnp.stack([params.bend_k1_warp, params.bend_k1_weft, params.bend_k1_bias]))
    return np.asarray(jax.grad(radius)(logk))


def fold_phase_deg(x, mesh, folds: int) -> float:
    """Phase (degrees of rotation) of the rim profile's harmonic at the fold count."""
    sil = observe.silhouette(np.asarray(x), np.asarray(mesh.faces), n=256, extent_m=0.16)
    prof = np.asarray(observe.rim_profile(sil, 0.16))
    c = np.fft.rfft(prof - prof.mean())[max(folds, 1)]
    return float(np.degrees(-np.angle(c)) / max(folds, 1))


def trajectory(mesh, params, terms, x0, chunk: int, weight: float, grad_e, seed: int) -> None:
    """Print the state after each ``chunk`` Newton iterations of a tight static solve from ``x0``."""
    cfg = SolverConfig(static=NewtonConfig(max_iters=chunk, step_tol_m=1e-9))
    solve = jax.jit(lambda x: static_solve(mesh, params, x, terms=terms, config=cfg))
    x, total, elapsed = x0, 0, 0.0
    for _ in range(400 // chunk):
        t0 = time.perf_counter()
        r = jax.block_until_ready(solve(x))
        elapsed += time.perf_counter() - t0
        move = float(jnp.max(jnp.linalg.norm(r.x - x, axis=1)))
        x, total = r.x, total + int(r.newton_iters)
        g = np.asarray(grad_e(x))
        dc, folds = dc_and_folds(x, mesh)
        print(json.dumps({"seed": seed, "newton_iters": total, "seconds": round(elapsed, 1), "status": int(r.status),
                          "dc": round(dc, 4), "folds": folds,
                          "fold_phase_deg": round(fold_phase_deg(x, mesh, folds), 2),
                          "max_residual_over_weight": float(np.abs(g).max()) / weight,
                          "rms_residual_over_weight": float(np.sqrt(np.mean(g ** 2))) / weight,
                          "energy_j": float(r.energy_j), "max_move_mm": round(1e3 * move, 4)}), flush=True)
        if int(r.status) == 0:
            break


def eqx_replace(params, k1):
    """``params`` with its three linear bending rigidities replaced by ``k1`` (warp, weft, bias)."""
    import equinox as eqx
    return eqx.tree_at(lambda p: (p.bend_k1_warp, p.bend_k1_weft, p.bend_k1_bias), params, (k1[0], k1[1], k1[2]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--fabric", default="mid", help="an example_params name")
    ap.add_argument("--spacing-mm", type=float, default=10.0, help="coarsest level's spacing")
    ap.add_argument("--rim-mm", type=float, default=2.0, help="coarsest level's spacing at the disc edge")
    ap.add_argument("--levels", type=int, default=2, help="levels (each halves the spacing)")
    ap.add_argument("--seeds", default="0,1,2", help="comma list of drop seeds")
    ap.add_argument("--trajectory", type=int, default=0, help="follow one tight solve in chunks of this many "
                    "Newton iterations instead of the tolerance ladder")
    ap.add_argument("--tolerances", default=",".join(f"{t:g}" for t in TOLERANCES), help="force_tol ladder")
    a = ap.parse_args()
    meshes, prolongs = nested_cusick_meshes(a.spacing_mm / 1e3, a.levels, rim_spacing_m=a.rim_mm / 1e3)
    p = example_params(a.fabric)
    terms = default_energies("cusick")
    tols = [float(t) for t in a.tolerances.split(",")]
    fine = meshes[-1]
    weight = float(G * np.mean(np.asarray(p.density * fine.vertex_area)))
    grad_e = jax.jit(jax.grad(lambda x: total_energy(terms, x, fine, p)))
    coarse = jax.jit(lambda s: drape(meshes[0], p, s, terms=terms, config=SolverConfig()))
    solvers = {t: jax.jit(lambda x0, t=t: static_solve(fine, p, x0, terms=terms, config=SolverConfig(force_tol=t)))
               for t in tols}
    for s in [int(v) for v in a.seeds.split(",")]:
        r = coarse(s)
        x = r.x
        for mesh, prolong in zip(meshes[1:-1], prolongs[:-1]):
            x = static_solve(mesh, p, prolong(x, mesh), terms=terms).x
        x0 = prolongs[-1](x, fine)
        if a.trajectory:
            trajectory(fine, p, terms, x0, a.trajectory, weight, grad_e, s)
            continue
        rows = []
        for t in sorted(tols):
            jax.block_until_ready(solvers[t](x0))  # compile (first seed) / warm
            t0 = time.perf_counter()
            rf = jax.block_until_ready(solvers[t](x0))
            sec = time.perf_counter() - t0
            resid = float(jnp.max(jnp.abs(grad_e(rf.x)))) / weight
            rows.append(dict(seed=s, force_tol=t, status=int(rf.status), newton_iters=int(rf.newton_iters),
                             seconds=round(sec, 2), max_residual_over_weight=resid,
                             dc_folds=dc_and_folds(rf.x, fine),
                             dradius_dlogk1_mm=(1e3 * hem_radius_gradient(fine, p, rf.x, terms)).round(4).tolist()))
        ref = np.asarray(rows[0]["dradius_dlogk1_mm"])
        for row in rows:
            g = np.asarray(row["dradius_dlogk1_mm"])
            row["gradient_rel_error"] = float(np.linalg.norm(g - ref) / max(np.linalg.norm(ref), 1e-30))
            row["dc_minus_tightest"] = round(row["dc_folds"][0] - rows[0]["dc_folds"][0], 4)
            print(json.dumps({"fabric": a.fabric, "spacing_mm": a.spacing_mm, "rim_mm": a.rim_mm,
                              "verts": [m.n_verts for m in meshes], **row}), flush=True)


if __name__ == "__main__":
    main()
