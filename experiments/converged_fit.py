"""Does the fit recover a fabric from a converged drape? The coarse fit against the converged refit.

For each chosen fabric (rows of the 618-fabric table picked by bending length, or the embedded
examples), a capture is made by ``drapejax simulate``'s drape (nested meshes, finest level 5 mm:
``cli.simulate_to_folder``) with drop seed ``--truth-seed``, and estimated twice in one run of
``refine.estimate(..., converged_spacing_m=...)``: the fit on the fit mesh (20 mm graded from 3 mm,
what ``drapejax estimate`` does by default) and its continuation on the nested meshes down to the
converged spacing (``refine.converged_refit``). One JSON line per fabric: the true and estimated
overall rigidity (geometric mean of k1 over warp, weft and bias) and per-direction k1, their
relative errors, the losses (the coarse fit's parameters scored on the finest level, then the
refit's), statuses and seconds. The capture's seed differs from the fit's drop seed, so the fit
sees a fold pattern of its own, as with a real specimen.

    python -m experiments.converged_fit --fabrics q25,median,q90,lightest,mid --out /tmp/conv_fit.jsonl
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

from drapejax.cli import simulate_to_folder  # noqa: E402
from drapejax.inverse.estimate import InverseModel  # noqa: E402
from drapejax.io import load_measurement  # noqa: E402
from drapejax.material import DIRECTIONS, bending_length, check  # noqa: E402
from drapejax.mesh_bias import bending_length_mm  # noqa: E402
from drapejax.mesh_bias import overall_k1 as overall  # noqa: E402
from drapejax.refine import estimate  # noqa: E402

if __package__:  # python -m experiments.converged_fit
    from .common import TABLE, emit, pick_fabrics
else:  # python experiments/converged_fit.py
    from common import TABLE, emit, pick_fabrics


def run_one(name: str, p, a, tmp: Path) -> dict:
    folder = tmp / name
    t0 = time.perf_counter()
    if a.reuse and (folder / "made.json").exists():
        made = json.loads((folder / "made.json").read_text())
    else:
        made = simulate_to_folder(p, test="cusick", spacing_m=a.truth_mm / 1e3, seed=a.truth_seed, out=folder)
        (folder / "made.json").write_text(json.dumps({k: made[k] for k in ("status", "dc", "folds")}))
    truth_s = time.perf_counter() - t0
    truth = p.to_dict()
    t0 = time.perf_counter()
    m = load_measurement(folder)  # the start the fit below refines, uncorrected: the network's own reading
    network = {"params": InverseModel.for_measurement(m, buckling=a.capped_start).estimate_no_refine(
        m, mesh_bias=False)["params"],
               "seconds": time.perf_counter() - t0}
    conv_m = a.converged_mm / 1e3 if a.converged_mm > 0 else None
    # the fit mesh's own values, uncorrected: what experiments/mesh_bias_fit.py calibrates
    out = estimate(folder, seed=a.fit_seed, converged_spacing_m=conv_m, max_steps=a.max_steps, mesh_bias=False,
                   capped_start=a.capped_start)
    coarse = out["converged"]["params_coarse"] if conv_m else out["params"]
    row = {"fabric": name, "capped_start": a.capped_start, "density_kg_m2": float(p.density),
           "truth_status": made["status"],
           "truth_dc": made["dc"], "truth_folds": made["folds"], "truth_s": round(truth_s, 1),
           "bending_length_true_mm": float(bending_length(p, "mean")) * 1e3,
           "k1_overall_true": overall(truth), "k1_overall_network": overall(network["params"]),
           "bending_length_network_mm": bending_length_mm(network["params"]),
           "k1_overall_coarse": overall(coarse), "bending_length_coarse_mm": bending_length_mm(coarse)}
    for method in ("network", "coarse"):
        row[f"rel_err_overall_{method}"] = row[f"k1_overall_{method}"] / row["k1_overall_true"] - 1.0
    for d in DIRECTIONS:
        k = f"bend_k1_{d}"
        row[f"rel_err_{d}_network"] = network["params"][k] / truth[k] - 1.0
        row[f"rel_err_{d}_coarse"] = coarse[k] / truth[k] - 1.0
    row["network_s"] = network["seconds"]
    if conv_m:
        fine = out["params"]
        row["k1_overall_converged"] = overall(fine)
        row["rel_err_overall_converged"] = row["k1_overall_converged"] / row["k1_overall_true"] - 1.0
        for d in DIRECTIONS:
            k = f"bend_k1_{d}"
            row[f"rel_err_{d}_converged"] = fine[k] / truth[k] - 1.0
            row[f"std_{d}_converged"] = out["std"][k]
        c = out["converged"]
        row.update({"loss_coarse_model": c["loss_coarse_model"], "loss_converged": c["loss"], "status": c["status"],
                    "drape_status": c["drape_status"], "levels": c["levels"]})
    else:
        std_log = {d: out["std"][f"bend_k1_{d}"] / out["params"][f"bend_k1_{d}"] for d in DIRECTIONS}
        row.update({"status": out["status"], "spacing_m": out["spacing_m"], "rim_spacing_m": out["rim_spacing_m"],
                    "std_log_coarse": std_log})
    row.update({"dc_simulated": out["fit"]["dc_simulated"], "dc_measured": out["fit"]["dc_measured"],
                "warnings": out["warnings"], "estimate_s": out["seconds"]})
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--table", default=str(TABLE), help="the 618-fabric CSV")
    ap.add_argument("--fabrics", default="q25,median,q90,lightest,mid", help="comma list of table picks (softest, "
                    "lightest, stiffest, q10, q25, median, q75, q90) or embedded examples (light, mid, heavy)")
    ap.add_argument("--truth-mm", type=float, default=5.0, help="finest spacing of the captures' drapes, mm")
    ap.add_argument("--converged-mm", type=float, default=5.0, help="finest spacing of the converged refit, mm "
                    "(0: the fit on the fit mesh alone)")
    ap.add_argument("--truth-seed", type=int, default=1, help="drop seed of the captures")
    ap.add_argument("--fit-seed", type=int, default=0, help="drop seed of the fits")
    ap.add_argument("--max-steps", type=int, default=8, help="Levenberg-Marquardt steps of the coarse fit")
    ap.add_argument("--capped-start", action="store_true", help="start the fits from the 3DH models trained on "
                    "capped-membrane drapes (refine.estimate's capped_start)")
    ap.add_argument("--out", default=None, help="append the JSON lines to this file as they come")
    ap.add_argument("--workdir", default=None, help="keep the capture folders here (default: a temporary folder)")
    ap.add_argument("--reuse", action="store_true", help="with --workdir: estimate the captures already there "
                    "instead of draping them again")
    a = ap.parse_args()
    out = Path(a.out) if a.out else None
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(a.workdir) if a.workdir else Path(tmp)
        for name, (_, p, _) in pick_fabrics(Path(a.table), a.fabrics.split(",")).items():
            try:
                check(p)
            except ValueError as e:  # a table row outside the model (a bending moment that turns back)
                emit({"fabric": name, "skipped": str(e)}, out)
                continue
            emit(run_one(name, p, a, work), out)


if __name__ == "__main__":
    main()
