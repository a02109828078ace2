"""Refinement on held-out simulated drapes: median relative k1 error, network alone vs refined.

Truths are drawn from the 618-fabric prior, draped with a held-out seed, observed (silhouette,
height map, scan) and estimated by the packaged network, then refined (``drapejax.refine``)
with a different drop seed. Usage: python experiments/refine_synthetic.py [N] [SPACING_M] [OUT.json]
"""

import json
import sys
import tempfile
import time
from pathlib import Path

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

from drapejax import observe, refine  # noqa: E402
from drapejax.inverse.estimate import InverseModel  # noqa: E402
from drapejax.inverse.prior import default_prior  # noqa: E402
from drapejax.io import load_measurement, write_measurement  # noqa: E402
from drapejax.material import unstack  # noqa: E402
from drapejax.mesh import cusick_mesh  # noqa: E402
from drapejax.solve import drape, quick_config  # noqa: E402

KEYS = [f"bend_k1_{d}" for d in refine.DIRECTIONS]


def main(n: int, spacing_m: float, out: Path) -> None:
    out.parent.mkdir(parents=True, exist_ok=True)
    mesh = cusick_mesh(spacing_m)
    faces = np.asarray(mesh.faces)
    model = InverseModel.load_default()
    run = jax.jit(lambda p, s: drape(mesh, p, s, config=quick_config()))
    rows = []
    for i, truth in enumerate(unstack(default_prior().sample(n, seed=12345))):
        t0 = time.perf_counter()
        x = np.asarray(run(truth, 1000 + i).x)
        folder = Path(tempfile.mkdtemp()) / "m"
        write_measurement(folder, test="cusick", specimen_radius_m=0.15, disk_radius_m=0.09,
                          areal_density_kg_m2=float(truth.density), warp_angle_deg=0.0,
                          silhouette=observe.silhouette(x, faces, n=256, extent_m=0.16),
                          height=observe.height_map(x, faces, n=256, extent_m=0.16), scan=(x, faces))
        m = load_measurement(folder)
        init = refine._to_fabric(model.estimate_no_refine(m)["params"], m.areal_density_kg_m2, 0.2)
        res = refine.fit(m, init=init, spacing_m=spacing_m, seed=i, mesh=mesh, max_steps=8)
        t, a, b = truth.to_dict(), init.to_dict(), res.params.to_dict()
        row = {"i": i, "truth": {k: t[k] for k in KEYS}, "network": {k: a[k] for k in KEYS},
               "refined": {k: float(b[k]) for k in KEYS}, "loss_network": res.loss_start, "loss_refined": res.loss,
               "status": res.status, "seconds": time.perf_counter() - t0}
        row["err_network"] = {k: abs(a[k] / t[k] - 1) for k in KEYS}
        row["err_refined"] = {k: abs(float(b[k]) / t[k] - 1) for k in KEYS}
        rows.append(row)
        print(json.dumps(row), flush=True)
        summary = {"n": len(rows), "spacing_m": spacing_m, "n_verts": mesh.n_verts,
                   "median_rel_err_network": {k: float(np.median([r["err_network"][k] for r in rows])) for k in KEYS},
                   "median_rel_err_refined": {k: float(np.median([r["err_refined"][k] for r in rows])) for k in KEYS},
                   "never_worse_on_loss": all(r["loss_refined"] <= r["loss_network"] for r in rows),
                   "rows": rows}
        out.write_text(json.dumps(summary, indent=1))
    print(json.dumps({k: v for k, v in summary.items() if k != "rows"}, indent=1))


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 20, float(sys.argv[2]) if len(sys.argv) > 2 else 0.025,
         Path(sys.argv[3]) if len(sys.argv) > 3 else Path("experiments/results/refine_synthetic.json"))
