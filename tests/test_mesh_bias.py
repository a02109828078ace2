"""The fit mesh's calibrated stiffness bias (``drapejax.mesh_bias``): what the correction does
to an estimate, where it applies, and that the packaged coefficients are the regression of the
recorded calibration rows."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from drapejax.mesh_bias import CALIBRATION, MeshBias, correct, default_bias

ROOT = Path(__file__).resolve().parents[1]
ROWS = ROOT / "docs" / "results" / "2026-12-07-mesh-bias.jsonl"
CHECK_ROWS = ROOT / "docs" / "results" / "2026-12-07-mesh-bias-check.jsonl"  # fabrics outside the calibration


def _bias(**kw):
    d = dict(coef=(0.2, -0.5), ref_mm=20.0, range_mm=(10.0, 30.0), std_log=0.1, spacing_m=0.02, rim_spacing_m=0.003)
    return MeshBias(**{**d, **kw})


def test_correction_divides_k1_and_k2_alike_and_widens_the_std():
    """k1 and k2 of every direction are divided by one factor (so each k2/k1 ratio, the shape of the
    moment curve, is kept), other parameters are untouched, and each k1's relative std becomes the
    Laplace std and the calibration's scatter added in quadrature."""
    bias = _bias()
    params = {"density": 0.2, "bend_k1_warp": 2e-6, "bend_k1_weft": 1e-6, "bend_k1_bias": 1.5e-6,
              "bend_k2_warp": -1e-8, "bend_k2_weft": -5e-9, "bend_k2_bias": 0.0, "stretch_alpha_warp": 10.0}
    std = {k: None for k in params} | {"bend_k1_warp": 0.3 * 2e-6, "bend_k1_weft": 0.2e-6, "bend_k1_bias": 0.3e-6}
    out, out_std, rec = correct(params, std, 15.0, bias)
    f = np.exp(0.2 - 0.5 * np.log(15.0 / 20.0))
    assert rec["factor"] == pytest.approx(f) and rec["inside_calibration"]
    for d in ("warp", "weft", "bias"):
        assert out[f"bend_k1_{d}"] == pytest.approx(params[f"bend_k1_{d}"] / f)
        assert out[f"bend_k2_{d}"] == pytest.approx(params[f"bend_k2_{d}"] / f)
        rel = std[f"bend_k1_{d}"] / params[f"bend_k1_{d}"]
        assert out_std[f"bend_k1_{d}"] / out[f"bend_k1_{d}"] == pytest.approx(np.hypot(rel, 0.1))
    assert out["density"] == params["density"] and out["stretch_alpha_warp"] == params["stretch_alpha_warp"]
    assert out_std["bend_k2_warp"] is None
    # a calibrated per-direction scatter (a refined fit's) widens each direction instead of the overall std
    _, wide, rec = correct(params, std, 15.0, _bias(std_log_direction=0.35))
    assert rec["std_log_direction"] == 0.35
    for d in ("warp", "weft", "bias"):
        rel = std[f"bend_k1_{d}"] / params[f"bend_k1_{d}"]
        assert wide[f"bend_k1_{d}"] / out[f"bend_k1_{d}"] == pytest.approx(np.hypot(rel, 0.35))


def test_outside_the_calibrated_lengths_the_nearest_end_is_used_and_flagged():
    bias = _bias()
    for ell, end in ((4.0, 10.0), (60.0, 30.0)):
        log_f, inside = bias.log_factor(ell)
        assert not inside and log_f == pytest.approx(bias.log_factor(end)[0])


def test_the_correction_applies_to_the_calibrated_fit_mesh_only():
    bias = _bias()
    assert bias.applies(0.02, 0.003, buckling=False)
    assert not bias.applies(0.02, 0.003, buckling=True)
    assert not bias.applies(0.01, 0.002, buckling=False)
    assert not bias.applies(0.02, None, buckling=False)
    assert not bias.applies(0.02, 0.003, buckling=False, capped_start=True)  # the fit from another start
    assert _bias(capped_start=True).applies(0.02, 0.003, buckling=False, capped_start=True)


def test_packaged_calibration_is_the_regression_of_the_recorded_rows(tmp_path):
    """The coefficients ``drapejax estimate`` uses are what ``experiments/mesh_bias_fit.py`` makes of
    the calibration rows kept in docs/results (converged captures of table fabrics, fitted on the fit
    mesh and read by each packaged network), and each corrects a stiffening: at the shortest
    calibrated bending length every estimator's factor is above one."""
    out = tmp_path / "mesh_bias.json"
    subprocess.run([sys.executable, "-m", "experiments.mesh_bias_fit", str(ROWS), "--write", str(out)], cwd=ROOT,
                   check=True, capture_output=True)
    made, packaged = json.loads(out.read_text()), json.loads(CALIBRATION.read_text())
    estimators = [k for k in packaged if isinstance(packaged[k], dict)]
    assert "fit_mesh" in estimators and set(estimators) == {k for k in made if isinstance(made[k], dict)}
    for key in estimators:
        for k in ("coef", "ref_mm", "std_log", "range_mm", "n"):
            assert made[key][k] == pytest.approx(packaged[key][k]), (key, k)
        assert made[key].get("std_log_direction") == pytest.approx(packaged[key].get("std_log_direction")), key
        assert made[key].get("capped_start") == packaged[key].get("capped_start"), key
        bias = default_bias(key)
        assert bias.log_factor(bias.range_mm[0])[0] > 0.0, key


def test_per_direction_scatter_is_the_maximum_likelihood_one():
    """The refined fit's per-direction scatter σ makes the left-one-out residuals, divided by
    √(Laplace² + σ²), of unit mean square (the maximum-likelihood equation), and it is wider than
    the overall rigidity's scatter: one drape splits its rigidity between the directions loosely."""
    from experiments.mesh_bias_fit import REF_MM, direction_scatter, leave_one_out, load_rows, predict, regress

    rows = list(load_rows([str(ROWS)])["fit_mesh"].values())
    x = np.log(np.array([r["bending_length_est_mm"] for r in rows]) / REF_MM)
    y = np.log([r["k1_overall_est"] / r["k1_overall_true"] for r in rows])
    packaged = default_bias("fit_mesh")
    degree = len(packaged.coef) - 1
    sigma, coverage = direction_scatter(rows, y - leave_one_out(x, y, degree), packaged.std_log)
    r2, s2 = [], []
    for i, row in enumerate(rows):
        keep = np.arange(len(y)) != i
        lf = predict(regress(x[keep], y[keep], degree), x[i])
        r2 += [(v - lf) ** 2 for v in row["log_ratio_direction"]]
        s2 += [s**2 for s in row["std_log_laplace"]]
    assert np.mean(np.array(r2) / (np.array(s2) + sigma**2)) == pytest.approx(1.0, abs=1e-6)
    assert sigma == pytest.approx(packaged.std_log_direction) and sigma > packaged.std_log
    assert coverage["laplace_and_direction_std"] > coverage["laplace_and_overall_std"] > coverage["laplace_only"]


def test_packaged_calibration_holds_on_fabrics_it_was_not_made_from(capsys):
    """Scored on recorded converged captures of seven other fabrics (``mesh_bias_fit --check``), every
    packaged estimator's correction lowers its median error of the overall rigidity, the refined fit's
    to within 15 %, and at least 80 % of the refined per-direction k1 lie inside the widened 2σ."""
    from experiments.mesh_bias_fit import check, load_rows

    packaged = json.loads(CALIBRATION.read_text())
    rows = load_rows([str(CHECK_ROWS)])
    assert set(rows) == {k for k in packaged if isinstance(packaged[k], dict)}
    for key, by_fabric in rows.items():
        assert not set(by_fabric) & set(packaged[key]["fabrics"]), key  # held out
        out = check(key, list(by_fabric.values()), packaged[key])
        med = out["median_abs_error"]
        assert med["corrected"] < med["uncorrected"], key
        if key == "fit_mesh":
            assert med["corrected"] < 0.15 and out["per_direction_inside_2sigma"] >= 0.8
