"""Where the exact Hessian is indefinite: the shift ladder against absolute-eigenvalue membrane
Hessians, on the finest static solve of ``drapejax simulate``'s default hierarchy.

For each fabric and drop seed the coarsest level drops once; its rest shape, carried to the
finest level by the hierarchy's prolongations, starts one finest-level static solve per Newton
rule:

- ``shift``: ``solve.Direct()``, the default: the exact Hessian where it is positive definite,
  else the least diagonal shift of a tenfold ladder (a multiple of the mean diagonal) that
  makes it so;
- ``absolute``: ``solve.Direct(absolute=True)``: where the exact Hessian is indefinite, first the
  element Hessians of the terms with ``element_instability`` (the membrane) by their
  eigenvalues' magnitudes, every other term exact (Longva et al. 2023), then the ladder;
- ``absolute-above-T``: ``solve.Direct(absolute=True, absolute_above=T)``: the shift ladder on
  the exact Hessian up to a shift of T times the mean diagonal, the absolute rule beyond it.

With ``--coarse capped`` (``drape_multilevel``'s default) the coarsest level drops with each
term's ``coarse_level()``, the membrane's compression cap (``energy.Membrane(buckling=True)``,
whose Euler load grows as the spacing's inverse square), and the finest level solves the uncapped
model: a coarse level that does not lock in compression hands light fabrics a start near their
fine rest state. ``--coarse uncapped``: the coarsest level drops the finest level's model.

One JSON line per (fabric, seed, rule): Newton iterations, status, seconds (after compiling),
energy, drape coefficient and fold count. A lower energy at the same iteration budget is a
solve that got further; the fold count shows when the rule led to another fold state.

    python -m experiments.indefinite_steps --fabrics mid,lightest --seeds 0 --max-iters 200 --coarse uncapped
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

from drapejax.energy import coarse_level, default_energies  # noqa: E402
from drapejax.mesh import cusick_hierarchy  # noqa: E402
from drapejax.solve import STATUS_NAMES, Direct, NewtonConfig, SolverConfig, coarsest_spacing_m, drape  # noqa: E402
from drapejax.solve import static_solve  # noqa: E402

if __package__:  # python -m experiments.indefinite_steps
    from .common import TABLE, dc_and_folds, emit, pick_fabrics
else:  # python experiments/indefinite_steps.py
    from common import TABLE, dc_and_folds, emit, pick_fabrics

RULES = {"shift": Direct(), "absolute": Direct(absolute=True),
         **{f"absolute-above-{t:g}": Direct(absolute=True, absolute_above=t) for t in (1e-6, 1e-5, 1e-4, 1e-3)}}


def fabric(name: str, table: Path):
    """An example fabric ("light", "mid", "heavy") or a pick of the 618-fabric table."""
    return pick_fabrics(table, (name,))[name][1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--fabrics", default="mid,lightest", help="example names or table picks (softest, lightest, ...)")
    ap.add_argument("--seeds", default="0", help="comma list of drop seeds")
    ap.add_argument("--spacing-mm", type=float, default=5.0, help="finest level's spacing (simulate's default)")
    ap.add_argument("--rules", default=",".join(RULES), help="comma list of: " + ", ".join(RULES))
    ap.add_argument("--max-iters", type=int, default=200, help="finest static solve's Newton iterations")
    ap.add_argument("--coarse", choices=("capped", "uncapped"), default="capped",
                    help="the coarsest level's membrane: with the compression cap (drape_multilevel's default) or not")
    ap.add_argument("--table", default=str(TABLE), help="the 618-fabric CSV")
    ap.add_argument("--out", default=None, help="append the JSON lines to this file")
    a = ap.parse_args()
    out = Path(a.out) if a.out else None
    terms = default_energies("cusick")
    for name in a.fabrics.split(","):
        p = fabric(name, Path(a.table))
        meshes, prolongs = cusick_hierarchy(a.spacing_mm / 1e3, coarsest_spacing_m=coarsest_spacing_m(p))
        fine = meshes[-1]
        solvers = {}
        for rule in a.rules.split(","):
            static = NewtonConfig(max_iters=a.max_iters, step_tol_m=1e-9)
            cfg = SolverConfig(linear_solver=RULES[rule], static=static)
            solvers[rule] = jax.jit(lambda x0, cfg=cfg, p=p, m=fine: static_solve(m, p, x0, terms=terms, config=cfg))
        for seed in [int(s) for s in a.seeds.split(",")]:
            coarse_terms = coarse_level(terms) if a.coarse == "capped" else terms
            x = drape(meshes[0], p, seed, terms=coarse_terms).x
            for mesh, prolong in zip(meshes[1:], prolongs):
                x = prolong(x, mesh)
            for rule, solve in solvers.items():
                solve.lower(x).compile()
                t0 = time.perf_counter()
                r = jax.block_until_ready(solve(x))
                dc, folds = dc_and_folds(r.x, fine)
                emit(dict(fabric=name, seed=seed, rule=rule, coarse_cap=a.coarse == "capped",
                          levels=[m.n_verts for m in meshes],
                          newton_iters=int(r.newton_iters), status=STATUS_NAMES[int(r.status)],
                          seconds=round(time.perf_counter() - t0, 1), energy_j=float(r.energy_j), dc=dc,
                          folds=folds), out)


if __name__ == "__main__":
    main()
