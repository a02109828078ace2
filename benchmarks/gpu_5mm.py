"""GPU timings of the issue's benchmark drape: "mid" Cusick at 5 mm, full ``SolverConfig``.

Prints JSON lines: compile and rest seconds of single drapes (seeds 0 and 1), the implicit
gradient of ``drapejax.bench.rest_scalar`` w.r.t. all parameters (first call and a repeat), and a
``vmap`` batch of 16 members (densities 0.8-1.2x, seeds 0-15; compile timed apart). On a GPU
"auto" means the device-resident CG solver. The CPU's numbers come from ``bench_drape.py``.
Run on a machine with a GPU: ``python benchmarks/gpu_5mm.py``.
"""

import json
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)

from drapejax.bench import density_batch, rest_scalar, timed  # noqa: E402
from drapejax.material import example_params  # noqa: E402
from drapejax.mesh import cusick_mesh  # noqa: E402
from drapejax.solve import SolverConfig, drape, drape_batch, equilibrium  # noqa: E402


def main(batch: int = 16) -> None:
    mesh, p, cfg = cusick_mesh(0.005), example_params("mid"), SolverConfig()
    run = jax.jit(lambda p, s: drape(mesh, p, s, config=cfg))
    t0 = time.perf_counter()
    compiled = run.lower(p, 0).compile()
    print(json.dumps({"backend": jax.default_backend(), "device": str(jax.devices()[0]), "verts": int(mesh.n_verts),
                      "compile_s": time.perf_counter() - t0}), flush=True)
    for seed in (0, 1):
        t, r = timed(compiled, p, seed)
        print(json.dumps({"seed": seed, "rest_s": t, "status": int(r.status), "steps": int(r.steps),
                          "newton_iters": int(r.newton_iters), "cg_iters": int(r.cg_iters)}), flush=True)
        if seed == 0:
            x0 = r.x
    grad = jax.jit(jax.grad(lambda p: rest_scalar(equilibrium(mesh, p, x0))))
    first, _ = timed(grad, p)
    again, g = timed(grad, p)
    print(json.dumps({"grad_first_s": first, "grad_s": again,
                      "finite": all(bool(np.isfinite(np.asarray(v)).all()) for v in jax.tree.leaves(g))}), flush=True)
    pb = density_batch(p, batch)
    seeds = jnp.arange(batch)
    f = jax.jit(lambda a, b: drape_batch(mesh, a, b, config=cfg, strategy="vmap"))
    t0 = time.perf_counter()
    compiled = f.lower(pb, seeds).compile()
    c = time.perf_counter() - t0
    t, rb = timed(compiled, pb, seeds)
    print(json.dumps({"batch": batch, "compile_s": c, "batch_s": t, "drapes_per_min": 60 * batch / t,
                      "status": np.asarray(rb.status).tolist(), "steps": np.asarray(rb.steps).tolist(),
                      "newton_iters": np.asarray(rb.newton_iters).tolist()}), flush=True)


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 16)
