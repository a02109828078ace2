"""Where one Newton step of a fine static solve goes: element Hessians per term, the triplets
sent to the host, one shifted sparse solve, one Cholesky factorisation; then the whole fine
static solve.

The state is that of ``drapejax simulate``'s default hierarchy for the "mid" fabric: the coarse
level's rest state (drop seed ``--seed``) prolonged onto the finest level. Times are medians of
``--repeats`` calls after compiling. One JSON object on stdout.

    python benchmarks/newton_step.py --spacing-mm 5 --repeats 5
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import jax
import numpy as np

from drapejax.energy import default_energies, total_energy
from drapejax.material import example_params
from drapejax.mesh import cusick_hierarchy
from drapejax.solve import SolverConfig, coarsest_spacing_m, drape, static_solve
from drapejax.solve._sparse import _pattern, element_hessians, hessian_coo, sparse_solve_shifted


def median_ms(fn, arg, repeats: int) -> float:
    """Median wall milliseconds of ``fn(arg)`` after one compiling call."""
    fn = jax.jit(fn)
    jax.block_until_ready(fn(arg))
    runs = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(fn(arg))
        runs.append(time.perf_counter() - start)
    return round(1e3 * statistics.median(runs), 1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--spacing-mm", type=float, default=5.0, help="finest level's interior spacing")
    ap.add_argument("--fabric", default="mid", help="example fabric")
    ap.add_argument("--seed", type=int, default=0, help="the coarse drop's seed")
    ap.add_argument("--repeats", type=int, default=5, help="timed calls per figure (median)")
    ap.add_argument("--no-solve", action="store_true", help="skip the whole fine static solve")
    a = ap.parse_args()
    jax.config.update("jax_enable_x64", True)
    p = example_params(a.fabric)
    meshes, prolongs = cusick_hierarchy(a.spacing_mm / 1e3, coarsest_spacing_m=coarsest_spacing_m(p))
    terms = default_energies("cusick")
    coarse = jax.jit(lambda q: drape(meshes[0], q, a.seed, terms=terms, config=SolverConfig()))(p)
    fine = meshes[-1]
    x = coarse.x
    for m, pr in zip(meshes[1:], prolongs):
        x = pr(x, m)
    diag = 1e-6 * p.density * fine.vertex_area
    out = {"fabric": a.fabric, "levels": [{"spacing_mm": 1e3 * m.info.spacing_m, "verts": int(m.n_verts)}
                                          for m in meshes], "seed": a.seed, "repeats": a.repeats,
           "element_hessian_ms": {}}
    entries = 0
    for t in terms:
        out["element_hessian_ms"][type(t).__name__] = median_ms(
            lambda y, t=t: element_hessians(t, y, fine, p, False, True)[1], x, a.repeats)
        entries += int(jax.eval_shape(lambda y, t=t: element_hessians(t, y, fine, p, False, True)[1], x).size)
    rows, cols, vals = hessian_coo(terms, x, fine, p, diag, project=False, exact=True)
    out["element_entries"] = entries
    out["triplets_to_host"] = int(vals.shape[0])
    out["assembly_ms"] = median_ms(lambda y: hessian_coo(terms, y, fine, p, diag, project=False, exact=True)[2],
                                   x, a.repeats)
    g = jax.grad(lambda y: total_energy(terms, y, fine, p))(x).reshape(-1)
    out["shifted_solve_ms"] = median_ms(
        lambda y: sparse_solve_shifted(*hessian_coo(terms, y, fine, p, diag, project=False, exact=True), -g, 0.0,
                                       True)[0], x, a.repeats)
    pat = _pattern(np.asarray(rows), np.asarray(cols), g.shape[0])
    data = pat.upper_data(np.asarray(vals, np.float64))
    data[pat.diag] += 1e3 * np.mean(np.abs(data[pat.diag]))  # certainly positive definite
    runs = []
    for _ in range(a.repeats):
        start = time.perf_counter()
        pat.cholesky_solve(data, np.asarray(g))
        runs.append(time.perf_counter() - start)
    out["cholesky_ms"] = round(1e3 * statistics.median(runs), 1)
    out["upper_entries"] = int(data.size)
    if not a.no_solve:
        solve = jax.jit(lambda y: static_solve(fine, p, y, terms=terms, config=SolverConfig()))
        jax.block_until_ready(solve(x))
        start = time.perf_counter()
        r = jax.block_until_ready(solve(x))
        sec = time.perf_counter() - start
        out["fine_static"] = {"seconds": round(sec, 2), "newton_iters": int(r.newton_iters),
                              "ms_per_iteration": round(1e3 * sec / max(int(r.newton_iters), 1), 1),
                              "energy_j": float(r.energy_j), "status": int(r.status)}
    print(json.dumps(out))


if __name__ == "__main__":
    main()
