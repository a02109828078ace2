"""The independent-simulator study's summary states issue-level figures the way they are defined:
the overall rigidity is the geometric mean of k1 over warp, weft and bias (``material.mean_k1``),
and a per-direction k1 counts as inside its 2σ when |log(estimate / truth)| ≤ 2 × its reported
std of log k1."""

from __future__ import annotations

import argparse
import math

import pytest

from experiments.independent_sim import summary


def _row(ratio, std):
    return {"network_k1_ratio": [2.0, 2.0, 2.0], "scan_model_k1_ratio": [1.0, 1.0, 1.0],
            "refined_k1_ratio": ratio, "refined_std_log": std,
            "fit": {"dc_simulated": 0.50, "dc_measured": 0.52}}


def test_overall_error_is_the_geometric_mean_and_coverage_counts_each_direction():
    rows = [_row([1.1, 1.1, 1.1], [0.1, 0.1, 0.1]),          # overall +10 %; all inside 2σ (0.095 ≤ 0.2)
            _row([2.0, 0.5, 1.0], [0.1, 0.1, 0.1]),          # overall 0 %; warp and weft outside (0.69 > 0.2)
            _row([1.3, 1.3, 1.3], [0.1, 0.2, 0.1])]          # overall +30 %; weft inside only (0.26 ≤ 0.4)
    out = summary(rows, argparse.Namespace(spacing_mm=10.0, converged_mm=5.0))
    assert out["n"] == 3
    assert out["median_overall_rel_error_refined"] == pytest.approx(0.1)
    assert out["median_overall_rel_error_network"] == pytest.approx(1.0)
    assert out["median_overall_rel_error_scan_model"] == pytest.approx(0.0, abs=1e-12)
    assert out["refined_inside_2sigma"] == pytest.approx(5 / 9)
    assert out["median_abs_log_k1_error_refined"][0] == pytest.approx(math.log(1.3))
    assert out["median_fit_dc_abs"] == pytest.approx(0.02)
    assert "median_simulator_gap" not in out  # --no-gap rows carry none


def test_amortised_only_rows_have_no_refined_figures():
    rows = [{k: v for k, v in _row([1.0] * 3, [0.1] * 3).items() if k.startswith(("network", "scan"))}]
    out = summary(rows, argparse.Namespace(spacing_mm=7.0, converged_mm=None))
    assert "median_overall_rel_error_refined" not in out and "refined_inside_2sigma" not in out
    assert out["median_overall_rel_error_network"] == pytest.approx(1.0)
