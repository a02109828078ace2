"""``refine.quality``: a fit is judged against the capture-to-capture floor of the real scans,
and ``estimate`` warns when its drape misses its own capture by more than that."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drapejax.refine.quality import DC_BOUND, IOU_BOUND, fit_quality, fit_warnings


def _fit(dc_measured, dc_simulated, iou, scan_mm=3.0):
    return {"dc_measured": dc_measured, "dc_simulated": dc_simulated, "iou": iou, "scan_mm": scan_mm}


def test_fit_within_both_bounds_passes_without_reasons():
    q = fit_quality(_fit(0.50, 0.53, 0.92))
    assert q["within_floor"] is True and q["reasons"] == []
    assert q["dc_error"] == pytest.approx(0.03) and q["iou"] == pytest.approx(0.92)
    assert (q["dc_bound"], q["iou_bound"]) == (DC_BOUND, IOU_BOUND)
    assert fit_warnings(q) == []


def test_drape_coefficient_beyond_the_floor_fails_and_names_the_numbers():
    # a soft capture fitted far too stiff, with a silhouette that still overlaps well
    q = fit_quality(_fit(0.16, 0.30, 0.93))
    assert q["within_floor"] is False
    assert q["dc_error"] == pytest.approx(0.14)
    assert len(q["reasons"]) == 1
    reason = q["reasons"][0]
    for number in ("0.30", "0.16", "0.14", f"{DC_BOUND:.3f}"):
        assert number in reason
    (warning,) = fit_warnings(q)
    assert "unreliable" in warning and "0.14" in warning and "90th percentile" in warning


def test_error_is_absolute_and_the_bound_is_sharp():
    assert fit_quality(_fit(0.50, 0.50 + DC_BOUND - 0.002, 0.95))["within_floor"] is True
    assert fit_quality(_fit(0.50, 0.50 + DC_BOUND + 0.002, 0.95))["within_floor"] is False
    too_soft = fit_quality(_fit(0.60, 0.60 - DC_BOUND - 0.002, 0.95))  # fitted softer than measured
    assert too_soft["within_floor"] is False and too_soft["dc_error"] > DC_BOUND


def test_silhouette_below_the_floor_fails_even_with_the_right_drape_coefficient():
    q = fit_quality(_fit(0.50, 0.50, 0.80))
    assert q["within_floor"] is False and len(q["reasons"]) == 1
    assert "0.800" in q["reasons"][0] and f"{IOU_BOUND:.3f}" in q["reasons"][0]
    assert fit_quality(_fit(0.50, 0.50, IOU_BOUND + 0.002))["within_floor"] is True
    both = fit_quality(_fit(0.16, 0.30, 0.80))
    assert len(both["reasons"]) == 2 and len(fit_warnings(both)) == 1


def test_missing_or_nan_values_are_never_within_the_floor():
    q = fit_quality(_fit(None, 0.3, math.nan))
    assert q["within_floor"] is False and q["dc_error"] is None and q["iou"] is None
    assert len(q["reasons"]) == 2


def _capture(shared_data, name):
    from drapejax.io import load_measurement

    folder = shared_data / "real_cusick" / name
    if not folder.is_dir():
        pytest.skip(f"{folder} not found")
    return load_measurement(folder)


def test_a_scan_is_within_the_floor_of_itself_and_another_fabric_is_not(shared_data):
    """The scan's own mesh reproduces its capture; the stiffest fabric's scan (f17, DC 0.92) does not
    reproduce the softest (f11, DC 0.43)."""
    from drapejax.refine.pipeline import compare

    soft = _capture(shared_data, "bdp_f11_sample_1_capture_3")
    stiff = _capture(shared_data, "bdp_f17_sample_1_capture_1")
    same = fit_quality(compare(np.asarray(soft.scan_vertices, float), np.asarray(soft.scan_faces), soft))
    assert same["within_floor"] is True and same["dc_error"] < 0.01 and same["iou"] > 0.98
    other = fit_quality(compare(np.asarray(stiff.scan_vertices, float), np.asarray(stiff.scan_faces), soft))
    assert other["within_floor"] is False
    assert other["dc_error"] > 0.3 and any("drape coefficient" in r for r in other["reasons"])


@pytest.mark.slow
def test_estimate_reports_fit_quality_consistent_with_its_fit(shared_data):
    """Without refinement (the network's drape, about a minute on two CPU cores)."""
    from drapejax.refine.pipeline import estimate

    res = estimate(_capture(shared_data, "bdp_f11_sample_1_capture_3"), refine=False)
    fit, q = res["fit"], res["fit_quality"]
    assert res["status"] == "not_refined"  # the status stays the solver's
    assert q["dc_error"] == pytest.approx(abs(fit["dc_simulated"] - fit["dc_measured"]))
    assert q["iou"] == pytest.approx(fit["iou"])
    assert q["within_floor"] == (q["dc_error"] <= DC_BOUND and q["iou"] >= IOU_BOUND)
    poor = [w for w in res["warnings"] if w.startswith("poor fit")]
    assert len(poor) == (0 if q["within_floor"] else 1)
    if poor:
        assert res["warnings"][0] == poor[0]
