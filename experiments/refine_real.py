"""Real scans: fit one capture per fabric, evaluate the refined drape on the fabric's other captures.

For every fabric in ../shared/data/real_cusick: network estimate + refinement on its first
capture, then DC error, fold-count error, rotation/mirror-aligned IoU and scan distance of the
refined simulated drape against each other capture (and of the network-only drape), next to the
re-drop noise floor, and of the fitted capture itself (what a fit that reproduced it exactly would
score: the bound this protocol sets). For fabrics with known density, k1 per direction in µN·m ± std vs the
618-fabric range at similar density (±20 %).
Usage: python -m experiments.refine_real [SPACING_M] [OUT.json] [MAX_FABRICS] [RIM_SPACING_M] [SOLVER]
[--converged-mm MM]
(RIM_SPACING_M: a rim-graded mesh, see ``drapejax.mesh.cusick_mesh``; SOLVER: "continuation",
``refine.fit``'s default, or "exact", ``drapejax estimate``'s; ``--converged-mm``: the fit then goes
on on nested meshes down to MM, ``refine.converged_refit``, and the refined drape evaluated on the
other captures is that finest level's, the network's drape a drop on the fit mesh as before)
"""

import argparse
import json
import re
import time
from collections import defaultdict
from pathlib import Path

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

from drapejax import refine  # noqa: E402
from drapejax.inverse.estimate import InverseModel  # noqa: E402
from drapejax.inverse.prior import read_fabric_table  # noqa: E402
from drapejax.io import Measurement, load_measurement  # noqa: E402
from drapejax.mesh import cusick_mesh  # noqa: E402
from drapejax.observe import aligned_iou  # noqa: E402
from drapejax.solve import drape, quick_config  # noqa: E402

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"
NOISE_FLOOR = {"iou_same_fabric": 0.908, "dc_same_fabric": 0.029, "folds_same_fabric": 1, "scan_mm_same_fabric": 2.9}


def capture_bound(fitted: Measurement, other: Measurement) -> dict:
    """The fitted capture itself as the prediction of another: what a perfect fit of it scores."""
    a, b = refine.measured_targets(fitted), refine.measured_targets(other)
    return {"abs_dc_err": abs(a.dc - b.dc), "iou": float(aligned_iou(a.silhouette, b.silhouette, mirror=True)[0])}


def main(spacing_m: float, out: Path, max_fabrics: int, rim_m: float | None = None,
         solver: str = "continuation", converged_mm: float | None = None, only: set[int] | None = None) -> None:
    out.parent.mkdir(parents=True, exist_ok=True)
    groups = defaultdict(list)
    for d in sorted((DATA / "real_cusick").iterdir()):
        groups[int(re.match(r"bdp_f(\d+)_", d.name).group(1))].append(d)
    rho618, k1_618, _ = read_fabric_table(DATA / "reference" / "fabrics_618_bending.csv")
    model = InverseModel.load_default()
    results = []
    for fabric in [f for f in sorted(groups) if only is None or f in only][:max_fabrics]:
        t0 = time.perf_counter()
        fit_dir, others = groups[fabric][0], groups[fabric][1:]
        m = load_measurement(fit_dir)
        mesh = cusick_mesh(spacing_m, warp_angle_deg=m.warp_angle_deg or 0.0, rim_spacing_m=rim_m)
        faces = np.asarray(mesh.faces)
        init = refine.to_fabric(model.estimate_no_refine(m, mesh_bias=False)["params"], m.areal_density_kg_m2, 0.2)
        res = refine.fit(m, init=init, spacing_m=spacing_m, mesh=mesh, config=refine.SOLVERS[solver])
        x_net = np.asarray(jax.jit(lambda p: drape(mesh, p, 0, config=quick_config()))(init).x)
        fine_faces, conv, x_coarse = faces, None, res.x
        if converged_mm is not None:
            coarse_loss, coarse_k1 = res.loss, res.params.to_dict()
            res, fine_mesh, conv = refine.converged_refit(m, res, init, spacing_m=converged_mm / 1e3)
            fine_faces = np.asarray(fine_mesh.faces)
            conv = {**conv, "loss_coarse_mesh": coarse_loss, "loss": res.loss,
                    "k1_coarse_uNm": {d: coarse_k1[f"bend_k1_{d}"] * 1e6 for d in refine.DIRECTIONS}}
        evals = []
        for o in others:
            mo = load_measurement(o)
            evals.append({"capture": o.name, "refined": refine.compare(res.x, fine_faces, mo),
                          "network": refine.compare(x_net, faces, mo), "fitted_capture": capture_bound(m, mo),
                          **({"coarse_fit": refine.compare(x_coarse, faces, mo)} if conv else {})})
        sd = np.sqrt(np.diag(res.cov))[:3]
        row = {"fabric": fabric, "fit_capture": fit_dir.name, "status": res.status, "loss_start": res.loss_start,
               "loss": res.loss, "density": m.areal_density_kg_m2, "converged": conv,
               "fit_itself": refine.compare(res.x, fine_faces, m), "evaluations": evals,
               "seconds": time.perf_counter() - t0}
        for which in ("refined", "network") + (("coarse_fit",) if conv else ()):
            e = [v[which] for v in evals]
            row[which] = {"abs_dc_err": float(np.median([abs(v["dc_simulated"] - v["dc_measured"]) for v in e])),
                          "fold_err": float(np.median([abs(v["folds_simulated"] - v["folds_measured"]) for v in e])),
                          "iou": float(np.median([v["iou"] for v in e])),
                          "scan_mm": float(np.median([v["scan_mm"] for v in e]))}
        row["fitted_capture"] = {k: float(np.median([v["fitted_capture"][k] for v in evals]))
                                 for k in ("abs_dc_err", "iou")}
        if m.areal_density_kg_m2 is not None:
            rho = m.areal_density_kg_m2
            near = np.abs(np.log(rho618 / rho)) < np.log(1.2)
            pd = res.params.to_dict()
            row["k1_uNm"] = {d: {"value": float(pd[f"bend_k1_{d}"]) * 1e6,
                                 "std": float(pd[f"bend_k1_{d}"]) * 1e6 * float(sd[i]),
                                 "618_similar_density_p5_p50_p95": (np.percentile(k1_618[near, i], [5, 50, 95]) * 1e6
                                                                    ).tolist(),
                                 "n_similar": int(near.sum())} for i, d in enumerate(refine.DIRECTIONS)}
        results.append(row)
        print(json.dumps({k: v for k, v in row.items() if k != "evaluations"}), flush=True)
        out.write_text(json.dumps({"spacing_m": spacing_m, "rim_spacing_m": rim_m, "n_verts": mesh.n_verts,
                                   "noise_floor": NOISE_FLOOR, "fabrics": results}, indent=1))
    print("fabric  status                         |dDC| ref/net/cap     folds ref/net  "
          "IoU ref/net/cap      scan mm ref/net")
    for r in results:
        a, b, c = r["refined"], r["network"], r["fitted_capture"]
        print(f"{r['fabric']:6d}  {r['status']:30s} "
              f"{a['abs_dc_err']:.3f}/{b['abs_dc_err']:.3f}/{c['abs_dc_err']:.3f}   "
              f"{a['fold_err']:.0f}/{b['fold_err']:.0f}          {a['iou']:.3f}/{b['iou']:.3f}/{c['iou']:.3f}    "
              f"{a['scan_mm']:.1f}/{b['scan_mm']:.1f}")
    print("noise floor (same fabric):", NOISE_FLOOR)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("spacing_m", nargs="?", type=float, default=0.025, help="fit mesh spacing, m")
    ap.add_argument("out", nargs="?", type=Path, default=Path("experiments/results/refine_real.json"),
                    help="result JSON, rewritten after each fabric")
    ap.add_argument("max_fabrics", nargs="?", type=int, default=1000, help="fit at most this many fabrics")
    ap.add_argument("rim_spacing_m", nargs="?", type=float, default=None, help="rim spacing of a graded mesh, m")
    ap.add_argument("solver", nargs="?", default="continuation",
                    help='a key of refine.SOLVERS: "continuation" or "exact"')
    ap.add_argument("--converged-mm", type=float, default=None, metavar="MM",
                    help="continue each fit on nested meshes down to MM (refine.converged_refit)")
    ap.add_argument("--only", default=None, metavar="N,N", help="only these fabric numbers (e.g. 13,14)")
    a = ap.parse_args()
    main(a.spacing_m, a.out, a.max_fabrics, a.rim_spacing_m, a.solver, a.converged_mm,
         None if a.only is None else {int(f) for f in a.only.split(",")})
