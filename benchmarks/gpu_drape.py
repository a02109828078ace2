"""GPU check and timings: single and batched Cusick drapes with the matrix-free (CG) solver.

Prints JSON: per-spacing single-drape seconds (median of repeats, after compile), batched
throughput, agreement of vmap with a loop, and the drape coefficient of each member; with
``--prior N``, a dataset-like batch of N members drawn from the shipped 618-fabric prior
(``quick_config``, as ``drapejax.inverse.dataset`` runs it): status counts and drapes/s.
Run on a machine with a GPU: ``python benchmarks/gpu_drape.py --json``.
"""

import argparse
import dataclasses
import json
import time

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)

from drapejax.material import example_params, stack  # noqa: E402
from drapejax.mesh import cusick_mesh  # noqa: E402
from drapejax.solve import SolverConfig, drape, drape_batch, quick_config  # noqa: E402


def projected_dc(x, r_disk=0.09, r_spec=0.15, nbins=180):
    r = np.linalg.norm(x[:, :2], axis=1)
    ph = np.arctan2(x[:, 1], x[:, 0])
    b = np.clip(((ph + np.pi) / (2 * np.pi) * nbins).astype(int), 0, nbins - 1)
    rmax = np.zeros(nbins)
    np.maximum.at(rmax, b, r)
    area = 0.5 * np.sum(rmax**2) * 2 * np.pi / nbins
    return (area - np.pi * r_disk**2) / (np.pi * (r_spec**2 - r_disk**2))


def prior_batch(n: int, spacing_m: float, repeats: int) -> dict:
    """Members 0..n-1 of the default prior (seed 0), drop seeds 0..n-1, one batched call."""
    from drapejax.inverse.prior import default_prior

    mesh = cusick_mesh(spacing_m)
    params, seeds = default_prior().sample(n, 0), jnp.arange(n)
    cfg = quick_config(linear_solver="cg")
    r, first_s, batch_s = timed(lambda p, s: drape_batch(mesh, p, s, config=cfg), params, seeds, repeats=repeats)
    status = np.asarray(r.status)
    return {"spacing_mm": spacing_m * 1000, "config": "prior_batch", "batch": n, "verts": mesh.n_verts,
            "first_call_s": first_s, "batch_s": batch_s, "drapes_per_s": n / batch_s if batch_s else None,
            "status_counts": {int(k): int(v) for k, v in zip(*np.unique(status, return_counts=True))},
            "median_newton_iters": float(np.median(np.asarray(r.newton_iters))),
            "median_cg_iters": float(np.median(np.asarray(r.cg_iters)))}


def timed(f, *a, repeats=3):
    t = time.perf_counter()
    out = jax.block_until_ready(f(*a))
    compile_s = time.perf_counter() - t
    ts = []
    for _ in range(repeats):
        t = time.perf_counter()
        out = jax.block_until_ready(f(*a))
        ts.append(time.perf_counter() - t)
    return out, compile_s, float(np.median(ts)) if ts else None


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--spacings-mm", default="10,5")
    ap.add_argument("--batch", type=int, default=32)
    ap.add_argument("--repeats", type=int, default=3, help="timed repeats after the compiling call")
    ap.add_argument("--prior", type=int, default=0, help="size of a batch drawn from the prior (0: none)")
    ap.add_argument("--prior-spacing-mm", type=float, default=15.0)
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    out = {"backend": jax.default_backend(), "devices": [str(d) for d in jax.devices()], "runs": []}
    if a.prior:
        out["runs"].append(prior_batch(a.prior, a.prior_spacing_mm / 1000, a.repeats))
        print(json.dumps(out["runs"][-1]), flush=True)
    p = example_params("mid")
    for sp in [float(s) / 1000 for s in a.spacings_mm.split(",") if s]:
        mesh = cusick_mesh(sp)
        for name, cfg in (("full", SolverConfig(linear_solver="cg")), ("quick", quick_config(linear_solver="cg"))):
            f = jax.jit(lambda p, s, cfg=cfg: drape(mesh, p, s, config=cfg))
            r, c, t = timed(f, p, 0, repeats=a.repeats)
            out["runs"].append({"spacing_mm": sp * 1000, "config": name, "verts": mesh.n_verts, "compile_s": c,
                                "rest_s": t, "status": int(r.status), "steps": int(r.steps),
                                "newton_iters": int(r.newton_iters), "cg_iters": int(r.cg_iters),
                                "dc": projected_dc(np.asarray(r.x))})
            print(json.dumps(out["runs"][-1]), flush=True)
        b = a.batch
        if not b:
            continue
        scale = jnp.exp(jnp.linspace(-1.5, 1.5, b))
        pb = stack([p] * b)
        pb = dataclasses.replace(pb, bend_k1_warp=pb.bend_k1_warp * scale, bend_k1_weft=pb.bend_k1_weft * scale,
                                 bend_k1_bias=pb.bend_k1_bias * scale)
        seeds = jnp.arange(b)
        cfg = quick_config(linear_solver="cg")
        rb, c, t = timed(lambda pb, s: drape_batch(mesh, pb, s, config=cfg), pb, seeds, repeats=1)
        loop = [jax.jit(lambda p, s: drape(mesh, p, s, config=cfg))(jax.tree.map(lambda v: v[i], pb), seeds[i])
                for i in (0, b // 2, b - 1)]
        diff = max(float(jnp.max(jnp.abs(rb.x[i] - one.x))) for i, one in zip((0, b // 2, b - 1), loop))
        out["runs"].append({"spacing_mm": sp * 1000, "config": "quick_batch", "batch": b, "compile_s": c,
                            "batch_s": t, "drapes_per_min": 60 * b / t, "status": np.asarray(rb.status).tolist(),
                            "vmap_vs_loop_max_diff_m": diff,
                            "dc": [round(projected_dc(np.asarray(x)), 3) for x in rb.x]})
        print(json.dumps(out["runs"][-1]), flush=True)
    if a.json:
        print(json.dumps(out))


if __name__ == "__main__":
    main()
