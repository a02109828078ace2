"""Mesh convergence of the Cusick drape: drape coefficient and its drop-to-drop spread vs spacing.

The fits (``drapejax estimate``/``diagnose``, 20 mm by default) and the network's training set
(15 mm) run on coarse meshes. This study drops one example fabric with several drop seeds at
each spacing and prints, per (spacing, solver config), the mean and standard deviation of the
drape coefficient over the seeds at rest, the fold counts and the wall time: whether the
simulated drape has converged, and whether its fold noise is a property of the fabric or of
the mesh. One JSON line per case, then a summary line.

    python -m experiments.cusick_convergence                                  # 20,15,10,7.5 mm
    python -m experiments.cusick_convergence --spacings-mm 20,10 --configs quick,full --fabric light
    python -m experiments.cusick_convergence --spacings-mm 20,10 --rim-mm 3 --seeds 3   # rim-graded meshes
    python -m experiments.cusick_convergence --spacings-mm 20 --rim-mm 3 --no-hourglass  # no hourglass control
    python -m experiments.cusick_convergence --fabric light --spacings-mm 20,10 --rim-mm 3 --buckling  # compression cap
    python -m experiments.cusick_convergence --spacings-mm 10,7,5 --configs full --seeds 2 --bending shape_operator_bare
"""

from __future__ import annotations

import argparse
import json
import time

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

from drapejax import observe  # noqa: E402
from drapejax.refine import EXTENT_M  # noqa: E402
from drapejax.material import FabricParams, bending_length, example_params  # noqa: E402
from drapejax.energy import HourglassControl, default_energies, shape_operator_energies  # noqa: E402
from drapejax.mesh import cusick_mesh  # noqa: E402
from drapejax.solve import SolverConfig, drape, quick_config  # noqa: E402

CONFIGS = {"quick": quick_config, "full": SolverConfig}


def case(fabric: str, spacing_m: float, config: str, seeds: int, rim_m: float | None = None,
         k_scale: float = 1.0, hourglass: bool = True, buckling: bool = False, bending: str = "fit") -> dict:
    """Drops ``fabric`` (bending rigidities × ``k_scale``) with seeds 0..seeds-1 at one spacing; DC
    and fold count of each rest shape, and the bending length (k1/ρg)^(1/3) of the geometric-mean k1.
    ``hourglass=False`` drops the base model without its hourglass control; ``buckling`` caps the
    membrane's compression at the element scale (``energy.Membrane``); ``bending="shape_operator"``
    drapes the model with per-triangle hinge shape operators and their curvature-jump control,
    ``"shape_operator_bare"`` without that control (``energy.shape_operator_energies``)."""
    mesh = cusick_mesh(spacing_m, rim_spacing_m=rim_m)
    if bending == "fit":
        model = default_energies("cusick", buckling=buckling)
    else:
        model = shape_operator_energies("cusick", buckling=buckling, jump=bending == "shape_operator")
    terms = tuple(t for t in model if hourglass or not isinstance(t, HourglassControl))
    run = jax.jit(lambda p, s: drape(mesh, p, s, terms=terms, config=CONFIGS[config]()))
    kw = example_params(fabric).to_dict()
    for k in kw:
        if k.startswith("bend_k"):
            kw[k] *= k_scale
    p, faces, info = FabricParams.from_dict(kw), np.asarray(mesh.faces), mesh.info
    dcs, folds, status = [], [], []
    t = time.perf_counter()
    for seed in range(seeds):
        r = run(p, seed)
        status.append(int(r.status))
        if status[-1] != 0:
            continue
        sil = observe.silhouette(np.asarray(r.x), faces, n=256, extent_m=EXTENT_M)
        dcs.append(float(observe.drape_coefficient(sil, EXTENT_M, specimen_radius_m=info.specimen_radius_m,
                                                   disk_radius_m=info.disk_radius_m)))
        folds.append(int(observe.fold_count(observe.rim_profile(sil, EXTENT_M))))
    return {"fabric": fabric, "k_scale": k_scale, "bending_length_mm": 1e3 * float(bending_length(p, "mean")),
            "spacing_mm": spacing_m * 1000,
            "rim_mm": None if rim_m is None else rim_m * 1000, "config": config,
            "hourglass": hourglass, "buckling": buckling, "bending": bending, "verts": mesh.n_verts,
            "status": status, "dc_mean": float(np.mean(dcs)) if dcs else None,
            "dc_std": float(np.std(dcs, ddof=1)) if len(dcs) > 1 else None, "dc": np.round(dcs, 4).tolist(),
            "folds": folds, "seconds": round(time.perf_counter() - t, 1)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--spacings-mm", default="20,15,10,7.5")
    ap.add_argument("--configs", default="quick", help="comma list of: " + ", ".join(CONFIGS))
    ap.add_argument("--fabric", default="mid", help="an example_params name")
    ap.add_argument("--k-scale", type=float, default=1.0, help="multiply the fabric's bending rigidities")
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--rim-mm", type=float, default=None, help="graded mesh: spacing on the disc edge")
    ap.add_argument("--no-hourglass", action="store_true", help="leave the hourglass control out of the model")
    ap.add_argument("--buckling", action="store_true", help="cap the membrane's compression at the element scale")
    ap.add_argument("--bending", default="fit", choices=["fit", "shape_operator", "shape_operator_bare"],
                    help="bending discretisation: vertex fit with hourglass control, per-triangle hinge shape "
                         "operators with their curvature-jump control, or without it")
    a = ap.parse_args()
    rows = []
    for config in a.configs.split(","):
        for sp in (float(s) / 1000 for s in a.spacings_mm.split(",")):
            rows.append(case(a.fabric, sp, config, a.seeds, a.rim_mm and a.rim_mm / 1000, a.k_scale,
                              not a.no_hourglass, a.buckling, a.bending))
            print(json.dumps(rows[-1]), flush=True)
    keys = ("spacing_mm", "rim_mm", "config", "hourglass", "buckling", "bending", "dc_mean", "dc_std", "seconds")
    print(json.dumps({"summary": [{k: r[k] for k in keys} for r in rows]}))


if __name__ == "__main__":
    main()
