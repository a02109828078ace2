"""Does an effect look like a stiffer fabric? Drape coefficient and folds, effect against k1 scale.

A fit without an effect takes whatever change of k1 best mimics it. This drapes one fabric with a
registered effect at several strengths, and the same fabric without it at several overall k1
scales (every direction multiplied alike), over several drop seeds, and prints one JSON line per
drape: status, Newton iterations, drape coefficient and fold count (256 px silhouette). Pairs
with the same drape coefficient show what the k1 stand-in cannot reproduce (here: the folds).

    python -m experiments.effect_lookalike --effect bending_friction --strengths 20 --k1-scales 1.5 --seeds 0,1,2,3
    python -m experiments.effect_lookalike --effect bending_saturation --strengths 1 --k1-scales 0.7,0.85 --seeds 0,1

The mesh is the fit mesh (20 mm graded from 3 mm at the disc edge) unless ``--spacing-mm`` and
``--rim-mm`` say otherwise; the drop is ``drapejax.solve.drape`` with the default ``SolverConfig``
and the base model's terms (uncapped membrane), the effect's terms added.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp

jax.config.update("jax_enable_x64", True)

from drapejax.effects import REGISTRY  # noqa: E402
from drapejax.energy import default_energies  # noqa: E402
from drapejax.material import example_params  # noqa: E402
from drapejax.mesh import cusick_mesh  # noqa: E402
from drapejax.solve import SolverConfig, drape  # noqa: E402

if __package__:  # python -m experiments.effect_lookalike
    from .common import dc_and_folds, emit
else:  # python experiments/effect_lookalike.py
    from common import dc_and_folds, emit


def floats(text: str) -> list[float]:
    return [float(v) for v in text.split(",") if v]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--effect", required=True, help=f"a registered effect: {', '.join(REGISTRY)}")
    ap.add_argument("--strengths", type=floats, default=[], help="comma list of the effect's θ (one-parameter "
                    "effects) to drape; 0 is always draped")
    ap.add_argument("--k1-scales", type=floats, default=[], help="comma list of overall k1 factors to drape "
                    "without the effect")
    ap.add_argument("--fabric", default="mid", help="an example fabric")
    ap.add_argument("--seeds", default="0", help="comma list of drop seeds")
    ap.add_argument("--spacing-mm", type=float, default=20.0)
    ap.add_argument("--rim-mm", type=float, default=3.0, help="disc-edge spacing (0: uniform mesh)")
    ap.add_argument("--out", type=Path, default=None, help="append the JSON lines here too")
    a = ap.parse_args()
    if a.effect not in REGISTRY:
        ap.error(f"--effect: unknown effect {a.effect!r}; known: {', '.join(REGISTRY)}")
    effect = REGISTRY[a.effect]
    if effect.n_params() != 1:
        ap.error(f"--effect: {a.effect} has {effect.n_params()} parameters; this study takes one-parameter effects")
    mesh = cusick_mesh(a.spacing_mm / 1e3, rim_spacing_m=a.rim_mm / 1e3 if a.rim_mm > 0 else None)
    p = example_params(a.fabric)
    terms = default_energies("cusick")
    run = jax.jit(lambda th, q, seed: drape(mesh, q, seed, terms=terms + effect.terms(mesh, th), config=SolverConfig()))

    def scaled(s):
        return eqx.tree_at(lambda q: (q.bend_k1_warp, q.bend_k1_weft, q.bend_k1_bias), p,
                           (p.bend_k1_warp * s, p.bend_k1_weft * s, p.bend_k1_bias * s))

    cases = [(0.0, 1.0)] + [(th, 1.0) for th in a.strengths if th != 0.0] + [(0.0, s) for s in a.k1_scales]
    for seed in [int(s) for s in a.seeds.split(",")]:
        for theta, scale in cases:
            start = time.perf_counter()
            r = jax.block_until_ready(run(jnp.array([theta]), scaled(scale), seed))
            dc, folds = dc_and_folds(r.x, mesh)
            emit({"effect": a.effect, "fabric": a.fabric, "spacing_mm": a.spacing_mm, "rim_mm": a.rim_mm,
                  "verts": int(mesh.n_verts), "seed": seed, "theta": theta, "k1_scale": scale,
                  "status": int(r.status), "newton_iters": int(r.newton_iters), "dc": dc, "folds": folds,
                  "seconds": round(time.perf_counter() - start, 1)}, a.out)


if __name__ == "__main__":
    main()
