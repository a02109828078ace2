"""Nested-mesh (cascadic) drapes against a direct drop on the finest mesh: iterations per level.

Builds a Cusick hierarchy (``mesh.nested_cusick_meshes``: a coarse mesh, optionally graded at
the disc edge, and its uniform subdivisions), drapes one example fabric with
``solve.drape_multilevel`` (the dynamic drop on the coarsest level, a static solve on each finer
one from the prolongated shape) and, with ``--direct``, drops the same fabric directly on the
finest level. One JSON line per (mode, seed): per level its vertex count, status, Newton
iterations, seconds (after a compile run), drape coefficient and fold count.

    python -m experiments.multilevel_drape --spacing-mm 10 --levels 2 --seeds 0,1
    python -m experiments.multilevel_drape --spacing-mm 10 --rim-mm 2 --levels 2 --seeds 0,1 --direct
    python -m experiments.multilevel_drape --spacing-mm 10 --levels 2 --buckling     # compression cap on every level
"""

from __future__ import annotations

import argparse
import json
import time

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

from drapejax.energy import default_energies  # noqa: E402
from drapejax.material import example_params  # noqa: E402
from drapejax.mesh import nested_cusick_meshes  # noqa: E402
from drapejax.solve import SolverConfig, drape, drape_multilevel  # noqa: E402

if __package__:  # python -m experiments.multilevel_drape
    from .common import dc_and_folds
else:  # python experiments/multilevel_drape.py
    from common import dc_and_folds


def timed(fn, *args):
    """(result, seconds) of one call, blocking on the result."""
    t = time.perf_counter()
    out = jax.block_until_ready(fn(*args))
    return out, round(time.perf_counter() - t, 2)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--fabric", default="mid", help="an example_params name")
    ap.add_argument("--spacing-mm", type=float, default=10.0, help="coarsest level's spacing")
    ap.add_argument("--rim-mm", type=float, default=None, help="coarsest level's spacing at the disc edge (graded)")
    ap.add_argument("--levels", type=int, default=2, help="number of levels (each halves the spacing)")
    ap.add_argument("--seeds", default="0,1", help="comma list of drop seeds")
    ap.add_argument("--buckling", action="store_true", help="cap the membrane's compression on every level")
    ap.add_argument("--direct", action="store_true", help="also drop directly on the finest level")
    a = ap.parse_args()
    meshes, prolongs = nested_cusick_meshes(a.spacing_mm / 1e3, a.levels,
                                            rim_spacing_m=None if a.rim_mm is None else a.rim_mm / 1e3)
    p = example_params(a.fabric)
    terms = default_energies("cusick", buckling=a.buckling)
    config = SolverConfig()
    multi = jax.jit(lambda s: drape_multilevel(meshes, prolongs, p, s, terms=terms, config=config))
    direct = jax.jit(lambda s: drape(meshes[-1], p, s, terms=terms, config=config))
    seeds = [int(s) for s in a.seeds.split(",")]
    common = {"fabric": a.fabric, "spacing_mm": a.spacing_mm, "rim_mm": a.rim_mm, "buckling": a.buckling,
              "verts": [m.n_verts for m in meshes]}
    jax.block_until_ready(multi(seeds[0]))  # compile
    for s in seeds:
        r, sec = timed(multi, s)
        print(json.dumps({**common, "mode": "multilevel", "seed": s, "status": int(r.finest.status),
                          "level_status": np.asarray(r.level_status).tolist(),
                          "level_newton_iters": np.asarray(r.level_newton_iters).tolist(), "seconds": sec,
                          "coarse_dc_folds": dc_and_folds(r.coarse_x, meshes[0]),
                          "dc_folds": dc_and_folds(r.finest.x, meshes[-1])}), flush=True)
    if a.direct:
        jax.block_until_ready(direct(seeds[0]))
        for s in seeds:
            r, sec = timed(direct, s)
            print(json.dumps({**common, "mode": "direct", "seed": s, "status": int(r.status), "steps": int(r.steps),
                              "newton_iters": int(r.newton_iters), "seconds": sec,
                              "dc_folds": dc_and_folds(r.x, meshes[-1])}), flush=True)


if __name__ == "__main__":
    main()
