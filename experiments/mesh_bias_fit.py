"""Calibrate the estimators' stiffness bias against converged drapes (``drapejax.mesh_bias``).

The fit mesh and the packaged networks' training drapes are coarser than a converged drape, so
each estimator reads k1 too stiff where a fabric folds finely. Given converged captures of known
fabrics (``experiments/converged_fit.py --converged-mm 0 --workdir DIR``: ``drapejax simulate``'s
drape of table fabrics, each fitted on the fit mesh), this regresses, per estimator, the log ratio
of the estimated to the true overall rigidity (geometric mean of k1 over warp, weft and bias) on
the log of the estimated overall bending length, x = log(ℓ_est / ℓ_ref), by a polynomial of the
degree (0, 1 or 2) whose leave-one-out predictions are closest:

    log(k1_est / k1_true) = c0 + c1 x + c2 x²

Estimators: ``fit_mesh`` (the refined fit, from the converged_fit rows) and, with ``--captures
DIR``, each packaged network that ``drapejax estimate --no-refine`` may pick, run on the captures
there (``inverse_2ds`` on the silhouette, ``inverse_3dh_oriented`` on the scan with its warp
angle, ``inverse_3dh`` on the scan without it, and the two 3DH models ``--buckling`` picks); their
rows are appended to ``--network-rows``.

It prints, per estimator and fabric, the error before correction, after it with the regression of
all rows, and with the regression made without that fabric (leave-one-out: what a fabric outside
the calibration can expect), and the medians. ``--write`` stores every estimator's coefficients,
residual std, calibrated range and leave-one-out median in the JSON file that ``drapejax
estimate`` reads (default ``drapejax/data/mesh_bias.json``). For the refined fit, whose rows
carry each direction's k1 and Laplace std, it also stores the per-direction scatter
(``direction_scatter``) that ``drapejax estimate`` adds to each direction's std.

    python -m experiments.mesh_bias_fit fit_rows.jsonl [--captures DIR --network-rows net.jsonl] [--write [PATH]]
    python -m experiments.mesh_bias_fit fit_rows.jsonl net.jsonl --write     # again, from the rows alone
    python -m experiments.mesh_bias_fit new_rows.jsonl new_net.jsonl --check # the packaged one on other fabrics
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
from pathlib import Path

import numpy as np

from drapejax.material import DIRECTIONS

REF_MM = 20.0  # ℓ_ref: a typical overall bending length, mm
DEGREES = (0, 1, 2)  # polynomial degrees tried
DEFAULT_OUT = Path(__file__).resolve().parents[1] / "drapejax" / "data" / "mesh_bias.json"
FIT_MESH = (0.02, 0.003)  # the default fit mesh: spacing, rim spacing, m


def load_rows(paths: list[str]) -> dict[str, dict[str, dict]]:
    """estimator -> fabric -> row (``k1_overall_est``, ``k1_overall_true``, ``bending_length_est_mm``);
    converged_fit rows become ``fit_mesh`` rows; the last row of an estimator and fabric wins."""
    out: dict[str, dict[str, dict]] = {}
    for p in paths:
        for line in Path(p).read_text().splitlines():
            if not line.strip():
                continue
            r = json.loads(line)
            if "bending_length_coarse_mm" in r:  # a converged_fit row
                if r.get("truth_status") != "at_rest":
                    continue
                mesh = (r.get("spacing_m", FIT_MESH[0]), r.get("rim_spacing_m", FIT_MESH[1]))
                if not np.allclose(mesh, FIT_MESH):
                    raise SystemExit(f"{p}: {r['fabric']} was fitted on {mesh}, not the default fit mesh {FIT_MESH}")
                directions = {"log_ratio_direction": [float(np.log1p(r[f"rel_err_{d}_coarse"])) for d in DIRECTIONS],
                              "std_log_laplace": [float(r["std_log_coarse"][d]) for d in DIRECTIONS]} \
                    if isinstance(r.get("std_log_coarse"), dict) else {}
                r = {"estimator": "fit_mesh", "fabric": r["fabric"], "capped_start": bool(r.get("capped_start", False)),
                     "k1_overall_est": r["k1_overall_coarse"],
                     "k1_overall_true": r["k1_overall_true"], "bending_length_est_mm": r["bending_length_coarse_mm"],
                     "bending_length_true_mm": r["bending_length_true_mm"], **directions}
            if "estimator" in r:
                out.setdefault(r["estimator"], {})[r["fabric"]] = r
    return out


def network_rows(captures: Path) -> list[dict]:
    """Each packaged network's uncorrected estimate of every capture folder under ``captures``."""
    from drapejax.inverse.estimate import DEFAULT_CHECKPOINT, InverseModel
    from drapejax.io import load_measurement, load_truth
    from drapejax.mesh_bias import bending_length_mm, overall_k1

    rows, models = [], {}
    for folder in sorted(p for p in captures.iterdir() if (p / "truth.json").exists()):
        m = load_measurement(folder)
        truth = load_truth(folder)["params"]
        # each view read by the checkpoint drapejax estimate --no-refine [--buckling] picks for it
        readings = [(m, DEFAULT_CHECKPOINT)] + [
            (view, InverseModel.checkpoint_for(view, buckling))
            for view in (m, dataclasses.replace(m, warp_angle_deg=None)) for buckling in (False, True)]
        for view, checkpoint in readings:
            if checkpoint not in models:
                models[checkpoint] = InverseModel.load(checkpoint)
            est = models[checkpoint].estimate_no_refine(view, mesh_bias=False)["params"]
            rows.append({"estimator": checkpoint.stem, "fabric": folder.name, "k1_overall_est": overall_k1(est),
                         "k1_overall_true": overall_k1(truth), "bending_length_est_mm": bending_length_mm(est),
                         "bending_length_true_mm": bending_length_mm(truth)})
    return rows


def regress(x: np.ndarray, y: np.ndarray, degree: int) -> np.ndarray:
    """Least-squares coefficients (c0, c1, ...) of y = Σ cᵢ xⁱ."""
    A = np.stack([x**i for i in range(degree + 1)], 1)
    return np.linalg.lstsq(A, y, rcond=None)[0]


def predict(coef: np.ndarray, x: np.ndarray) -> np.ndarray:
    return sum(c * x**i for i, c in enumerate(coef))


def leave_one_out(x: np.ndarray, y: np.ndarray, degree: int) -> np.ndarray:
    """Residual of each row under the regression made without it."""
    out = np.empty_like(y)
    for i in range(len(y)):
        keep = np.arange(len(y)) != i
        out[i] = y[i] - predict(regress(x[keep], y[keep], degree), x[i])
    return out


def direction_scatter(rows: list[dict], loo_log_factor: np.ndarray, std_log: float) -> tuple[float, dict]:
    """The per-direction scatter σ of a refined fit, and the 2σ coverage with and without it.

    For each fabric i and direction d, r_id = log(k1_d,est / k1_d,true) minus ``loo_log_factor[i]``,
    the log factor of the regression made without fabric i. σ is the maximum-likelihood value under
    r_id ~ N(0, s_id² + σ²), s_id the fit's Laplace std: it solves mean(r² / (s² + σ²)) = 1. It holds
    what neither the Laplace std nor the overall regression's scatter (``std_log``) covers: how a drape
    splits one overall rigidity between warp, weft and bias."""
    r = np.concatenate([np.asarray(row["log_ratio_direction"]) - lf for row, lf in zip(rows, loo_log_factor)])
    s = np.concatenate([row["std_log_laplace"] for row in rows])
    lo, hi = 0.0, float(np.sqrt(np.mean(r**2))) + 1.0
    if np.mean(r**2 / s**2) <= 1.0:
        hi = 0.0
    for _ in range(80):  # mean(r²/(s²+σ²)) falls with σ
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if np.mean(r**2 / (s**2 + mid**2)) > 1.0 else (lo, mid)
    sigma = 0.5 * (lo + hi)
    coverage = {name: float(np.mean(np.abs(r) <= 2.0 * np.sqrt(s**2 + e**2)))
                for name, e in (("laplace_only", 0.0), ("laplace_and_overall_std", std_log),
                                ("laplace_and_direction_std", sigma))}
    return float(sigma), coverage


def calibrate(key: str, rows: list[dict]) -> dict:
    """One estimator's regression (the degree with the smallest leave-one-out rms), printed per
    fabric, with its leave-one-out errors."""
    ell = np.array([r["bending_length_est_mm"] for r in rows])
    x = np.log(ell / REF_MM)
    y = np.log([r["k1_overall_est"] / r["k1_overall_true"] for r in rows])
    loos = {d: leave_one_out(x, y, d) for d in DEGREES if len(y) > d + 2}
    rms = {d: float(np.sqrt(np.mean(v**2))) for d, v in loos.items()}
    degree = min(rms, key=rms.get)
    coef = regress(x, y, degree)
    resid = y - predict(coef, x)
    std_log = float(np.sqrt(np.sum(resid**2) / max(len(y) - degree - 1, 1)))
    loo = loos[degree]
    print(f"\n{key}: degree {degree} (leave-one-out rms of log k1 by degree: "
          f"{', '.join(f'{d}: {v:.3f}' for d, v in rms.items())})")
    print(f"{'fabric':<10}{'ℓ true':>8}{'ℓ est':>8}{'error':>9}{'corrected':>11}{'LOO':>8}")
    for r, yi, ri, li in sorted(zip(rows, y, resid, loo), key=lambda t: t[0]["bending_length_true_mm"]):
        print(f"{r['fabric']:<10}{r['bending_length_true_mm']:8.1f}{r['bending_length_est_mm']:8.1f}"
              f"{np.expm1(yi):+9.1%}{np.expm1(ri):+11.1%}{np.expm1(li):+8.1%}")
    med = {k: float(np.median(np.abs(np.expm1(v)))) for k, v in (("uncorrected", y), ("corrected", resid),
                                                                   ("leave_one_out", loo))}
    print(f"coefficients {', '.join(f'{c:+.3f}' for c in coef)}; residual std (log) {std_log:.3f}; median "
          f"|error|: uncorrected {med['uncorrected']:.1%}, corrected {med['corrected']:.1%}, leave-one-out "
          f"{med['leave_one_out']:.1%}")
    rec = {"coef": [float(c) for c in coef], "ref_mm": REF_MM, "std_log": std_log,
           "range_mm": [float(ell.min()), float(ell.max())], "n": len(rows),
           "fabrics": sorted(r["fabric"] for r in rows), "leave_one_out_rms_log": rms, "median_abs_error": med}
    if key == "fit_mesh":
        starts = {r["capped_start"] for r in rows}
        if len(starts) > 1:
            raise SystemExit("mesh_bias_fit: fit_mesh rows fitted from both starts (converged_fit --capped-start "
                             "and not); calibrate each start apart")
        rec.update(spacing_m=FIT_MESH[0], rim_spacing_m=FIT_MESH[1], capped_start=starts.pop())
    if all("log_ratio_direction" in r for r in rows):
        sigma, coverage = direction_scatter(rows, y - loo, std_log)
        rec.update(std_log_direction=sigma, coverage_2sigma_leave_one_out=coverage)
        print(f"per-direction scatter (log) {sigma:.3f}; per-direction k1 inside 2σ, factor left one out: "
              + ", ".join(f"{k.replace('_', ' ')} {v:.0%}" for k, v in coverage.items()))
    return rec


def check(key: str, rows: list[dict], record: dict) -> dict:
    """The calibration ``record`` of ``key`` (``--write``'s, read as ``drapejax estimate`` reads it)
    scored on rows it was not made from: each fabric's error before and after its correction, the
    medians, and for the refined fit the share of per-direction k1 inside the widened 2σ."""
    from drapejax.mesh_bias import MeshBias

    bias = MeshBias.from_record(record)
    if any(r.get("capped_start", False) != bias.capped_start for r in rows):
        raise SystemExit(f"mesh_bias_fit: {key}: rows fitted from another start than the calibration's")
    print(f"\n{key}, calibration of {record['n']} fabrics checked on {len(rows)} others:")
    print(f"{'fabric':<10}{'ℓ true':>8}{'ℓ est':>8}{'error':>9}{'corrected':>11}  inside range")
    y, corrected, z = [], [], []
    for r in sorted(rows, key=lambda r: r["bending_length_true_mm"]):
        log_f, inside = bias.log_factor(r["bending_length_est_mm"])
        yi = float(np.log(r["k1_overall_est"] / r["k1_overall_true"]))
        y.append(yi)
        corrected.append(yi - log_f)
        if "log_ratio_direction" in r:
            z += [abs(v - log_f) / np.hypot(s, bias.widen_log)
                  for v, s in zip(r["log_ratio_direction"], r["std_log_laplace"])]
        print(f"{r['fabric']:<10}{r['bending_length_true_mm']:8.1f}{r['bending_length_est_mm']:8.1f}"
              f"{np.expm1(yi):+9.1%}{np.expm1(yi - log_f):+11.1%}  {inside}")
    out = {"n": len(rows), "fabrics": sorted(r["fabric"] for r in rows),
           "median_abs_error": {"uncorrected": float(np.median(np.abs(np.expm1(y)))),
                                "corrected": float(np.median(np.abs(np.expm1(corrected))))}}
    if z:
        out["per_direction_inside_2sigma"] = float(np.mean(np.asarray(z) <= 2.0))
    print(f"median |error|: uncorrected {out['median_abs_error']['uncorrected']:.1%}, corrected "
          f"{out['median_abs_error']['corrected']:.1%}"
          + (f"; per-direction k1 inside 2σ {out['per_direction_inside_2sigma']:.0%} of {len(z)}" if z else ""))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("rows", nargs="+", help="JSON lines: converged_fit.py --converged-mm 0 rows, network rows")
    ap.add_argument("--captures", default=None, help="converged_fit.py's --workdir: run the packaged networks on "
                    "its captures")
    ap.add_argument("--network-rows", default=None, help="with --captures: append the networks' rows here")
    ap.add_argument("--write", nargs="?", const=str(DEFAULT_OUT), default=None, metavar="PATH",
                    help="store the calibration (default drapejax/data/mesh_bias.json)")
    ap.add_argument("--check", nargs="?", const=str(DEFAULT_OUT), default=None, metavar="PATH",
                    help="instead of calibrating, score the stored calibration (default the packaged one) on these "
                    "rows, fabrics it was not made from")
    a = ap.parse_args()
    if a.check and a.write:
        raise SystemExit("mesh_bias_fit: --check scores a stored calibration; it writes none")
    paths = list(a.rows)
    if a.captures:
        if not a.network_rows:
            raise SystemExit("mesh_bias_fit: --captures needs --network-rows (where the networks' rows go)")
        with open(a.network_rows, "a") as f:
            for r in network_rows(Path(a.captures)):
                f.write(json.dumps(r) + "\n")
        paths.append(a.network_rows)
    by_estimator = load_rows(paths)
    if a.check:
        stored = json.loads(Path(a.check).read_text())
        for key, rows in sorted(by_estimator.items()):
            if isinstance(stored.get(key), dict):
                seen = set(stored[key].get("fabrics", ())) & set(rows)
                if seen:
                    raise SystemExit(f"mesh_bias_fit: {key}: {sorted(seen)} are in the calibration; --check scores "
                                     "fabrics it was not made from")
                check(key, list(rows.values()), stored[key])
        return
    record = {}
    for key, rows in sorted(by_estimator.items()):
        if len(rows) < 4:
            raise SystemExit(f"mesh_bias_fit: {key}: {len(rows)} usable rows; need at least 4")
        record[key] = calibrate(key, list(rows.values()))
    if a.write:
        record["made"] = datetime.date.today().isoformat()
        record["commands"] = ["python -m experiments.converged_fit --converged-mm 0 --fabrics ... --workdir W "
                              "--out fit_rows.jsonl",
                              "python -m experiments.mesh_bias_fit fit_rows.jsonl --captures W --network-rows "
                              "net.jsonl --write"]
        Path(a.write).write_text(json.dumps(record, indent=1) + "\n")
        print(f"wrote {a.write}")


if __name__ == "__main__":
    main()
