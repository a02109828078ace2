"""The command line's output: a short human summary with units by default, one JSON object with --json;
the summary functions on results shaped like the commands' own, including results missing keys."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from drapejax import summary

from helpers import PARAMS, STD

ROOT = Path(__file__).resolve().parents[1]


def _real_folder(shared_data) -> Path:
    folder = shared_data / "real_cusick" / "bdp_f02_sample_2_capture_1"
    if not folder.is_dir():
        pytest.skip(f"{folder} not found")
    return folder


def _cli(*args):
    r = subprocess.run([sys.executable, "-m", "drapejax.cli", *map(str, args)], capture_output=True, text=True,
                       timeout=600, cwd=ROOT)
    assert r.returncode == 0, r.stderr[-3000:]
    return r.stdout


def _assert_human(text: str, *units: str):
    lines = text.strip().splitlines()
    assert lines and len(lines) <= 25, text
    assert not any(line.lstrip().startswith(("{", "[")) for line in lines), text
    assert all(len(line) <= 130 for line in lines), text
    for u in units:
        assert u in text, (u, text)


def _assert_one_json_object(text: str) -> dict:
    obj = json.loads(text)  # raises unless stdout is exactly one JSON document
    assert isinstance(obj, dict)
    return obj


def test_inspect_prints_a_summary_and_json(shared_data):
    folder = _real_folder(shared_data)
    text = _cli("inspect", folder)
    _assert_human(text, "drape coefficient", "mm", "folds")
    assert text.startswith("drapejax inspect: drape coefficient")
    obj = _assert_one_json_object(_cli("inspect", folder, "--json"))
    assert {"dc", "folds", "r_mean_mm"} <= set(obj)
    assert f"{obj['folds']} folds" in text.splitlines()[0]


def test_estimate_no_refine_prints_a_summary_and_json(shared_data):
    folder = _real_folder(shared_data)
    text = _cli("estimate", folder, "--no-refine")
    _assert_human(text, "µN·m", "g/m²", "N/m", "warp", "weft", "bias", "not refined")
    obj = _assert_one_json_object(_cli("estimate", folder, "--no-refine", "--json"))
    assert {"params", "density_normalized", "method", "seconds"} <= set(obj)
    # a scan is read by the 3DH model trained on capped-membrane drapes, whose calibration is corrected for
    assert obj["method"].startswith("3dh") and obj["checkpoint"] == "inverse_3dh_buckling"
    assert obj["mesh_bias"]["factor"] > 0
    k1_warp = obj["params"]["bend_k1_warp"] * 1e6
    assert f"warp {summary.num(k1_warp)}" in text
    assert f"{summary.num(obj['params']['density'] * 1e3)} g/m²" in text


def test_estimate_to_json_is_one_object_with_the_export(shared_data):
    folder = _real_folder(shared_data)
    obj = _assert_one_json_object(_cli("estimate", folder, "--no-refine", "--to", "clo", "--json"))
    assert obj["export"]["target"] == "clo"


def test_every_option_of_every_command_has_help():
    from drapejax.cli import build_parser

    ap = build_parser()
    sub = next(a for a in ap._actions if a.__class__.__name__ == "_SubParsersAction")
    for name, p in sub.choices.items():
        for action in p._actions:
            assert action.help, (name, action.option_strings or action.dest)
        if name != "dataset":
            assert any("--json" in a.option_strings for a in p._actions), name


# --------------------------------------------------------------------------- summary functions

ERRORS = {"iou": 0.93, "dc_abs": 0.012, "spectral_mm": 3.1, "scan_mm": 4.2}


def _diagnose_result(selected=("off_centre",)) -> dict:
    return {
        "baseline": {"params": PARAMS, "std": STD, "error": ERRORS, "heldout_error": [ERRORS], "loss": 120.0,
                     "error_ratio": 1.8, "heldout_misfit": 300.0, "misfit_within_noise": False,
                     "expected": {"misfit": 250.0, "error_ratio": 1.6, "drops": 4,
                                  "per_drop": {"misfit": [1.0] * 4, "error_ratio": [1.0] * 4}}},
        "effects_tested": [{"name": "off_centre", "accepted": True}, {"name": "heavy_hem", "accepted": False}],
        "selected": list(selected),
        "selected_values": {"off_centre": {"theta": [0.02, 0.0], "specimen_centre_dx_mm": 19.7,
                                           "specimen_centre_dy_mm": -0.4}} if selected else {},
        "final": {"params": PARAMS, "std": STD, "error": ERRORS, "heldout_error": [ERRORS], "loss": 40.0,
                  "error_ratio": 0.9, "heldout_misfit": 90.0, "misfit_within_noise": True,
                  "expected": {"misfit": 80.0, "error_ratio": 0.85, "drops": 4}},
        "density_normalized": False, "within_noise_floor": True, "baseline_within_noise_floor": False,
        "noise_floor": {"iou": 0.9, "dc_abs": 0.02, "spectral_mm": 4.0, "scan_mm": 5.0},
        "mesh": {"spacing_m": 0.02, "rim_spacing_m": 0.003, "verts": 1234, "buckling": False},
        "residual": {"a": list(range(100))}, "signatures": {"off_centre": 0.8, "heavy_hem": 0.4},
        "reason": "no candidate improves the held-out misfit beyond the noise", "screen": None,
        "baseline_scan": None, "folders": ["a", "b", "c"], "report": "out/report.html", "seconds": 251.7,
    }


def test_diagnose_summary_states_the_selection_first():
    res = _diagnose_result()
    text = summary.diagnose(res)
    _assert_human(text, "µN·m", "g/m²", "mm")
    first = text.splitlines()[0]
    assert "selected effect" in first and "off_centre" in first
    assert "250 -> 80" in text and "1.6 -> 0.85" in text
    assert "within the noise floor: yes (baseline: no)" in text
    assert "specimen_centre_dx_mm 19.7" in text
    assert "warp 16.1 ± 1.6" in text  # k1 with its std, µN·m


def test_diagnose_summary_when_nothing_is_selected():
    text = summary.diagnose(_diagnose_result(selected=()))
    assert "no missing effect found" in text.splitlines()[0]
    refused = {**_diagnose_result(selected=()), "bench": {"selected": "bias_asymmetry", "refused": (
        "bias_asymmetry: with it the captures' error ratio on fresh drops rises (1.18 -> 1.79)")}}
    text = summary.diagnose(refused)
    assert "no missing effect found" in text.splitlines()[0]
    assert "bench readings asked for bias_asymmetry" in text and "not kept" in text


def test_demo_summary_says_whether_the_hidden_effect_was_found():
    res = {**_diagnose_result(), "measurements": ["d/measurements/c0", "d/measurements/c1"],
           "truth": {"effects": {"off_centre": {"theta": [0.02, 0.0], "specimen_centre_dx_mm": 20.0,
                                                "specimen_centre_dy_mm": 0.0}}},
           "found": True, "direction_agrees": {"off_centre": True}, "strength_ratio": {"off_centre": 0.98}}
    text = summary.demo(res)
    _assert_human(text)
    first = text.splitlines()[0]
    assert "found the hidden effect" in first and "off_centre" in first
    assert "250 -> 80" in text and "hidden (truth): off_centre" in text
    missed = summary.demo({**res, "found": False, "selected": ["heavy_hem"]})
    assert "did not find the hidden effect off_centre" in missed.splitlines()[0]
    assert "heavy_hem" in missed.splitlines()[0]


def test_refined_estimate_summary_has_units_std_fit_and_warnings():
    res = {"params": PARAMS, "std": STD,
           "identified": {"combination_log": {"bend_k1_warp": 0.5, "bend_k1_weft": 0.3, "bend_k1_bias": 0.2},
                          "std_log": 0.05, "data_share": {"bend_k1_warp": 0.8, "bend_k1_weft": 0.6,
                                                          "bend_k1_bias": 0.4}},
           "density_normalized": False,
           "fit": {"dc_measured": 0.669, "dc_simulated": 0.655, "iou": 0.95, "scan_mm": 3.3},
           "status": "converged", "init": "3dh", "spacing_m": 0.02, "rim_spacing_m": 0.003, "buckling": False,
           "bending_length_mm": 23.4, "warnings": ["bend_k1_bias: the drape supplied under half " * 5],
           "seconds": 95.2}
    text = summary.estimate(res)
    _assert_human(text, "µN·m", "g/m²", "converged", "20 mm", "3 mm", "warning:")
    assert "warp 16.1 ± 1.6" in text and "bias 16.6 ± 1.7" in text and "192 g/m²" in text
    assert "0.669 measured, 0.655 simulated" in text
    assert "membrane" not in text
    readings = {"readings": 3, "factor": {"warp": 3.45, "weft": 3.69, "bias": 3.24}}
    tensile = summary.estimate({**res, "membrane": readings})
    assert "α from 3 tensile reading(s): warp ×3.45" in tensile
    assert "mesh bias" not in text
    bias = {"factor": 1.52, "std_log": 0.15, "bending_length_mm": 21.0, "inside_calibration": True}
    corrected = summary.estimate({**res, "mesh_bias": bias, "params_fit_mesh": PARAMS})
    assert "the fit mesh's ÷ 1.52" in corrected and "params_fit_mesh" in corrected
    split = summary.estimate({**res, "mesh_bias": {**bias, "std_log_direction": 0.36}, "params_fit_mesh": PARAMS})
    assert "each direction's std includes ± 0.36" in split and "params_fit_mesh" in split
    network = summary.estimate({**res, "status": "not_refined", "mesh_bias": bias})
    assert "the network's ÷ 1.52" in network and "--no-mesh-bias" in network and "outside" not in network
    outside = summary.estimate({**res, "status": "not_refined", "mesh_bias": {**bias, "inside_calibration": False}})
    assert "outside the calibrated ones" in outside
    # a refined result carries the extrapolation among its warnings: said once, not twice
    warned = {**res, "mesh_bias": {**bias, "inside_calibration": False}, "params_fit_mesh": PARAMS,
              "warnings": ["the fitted bending length 9.0 mm lies outside the 11.5-26.9 mm the fit mesh's bias was "
                           "calibrated on; the nearest end's factor (÷1.52) was used"]}
    assert summary.estimate(warned).count("outside the") == 1


def test_density_normalised_estimate_summary():
    res = {"params": {"bend_k1_warp_per_density": 8.4e-05, "bend_k1_weft_per_density": 9.9e-05,
                      "bend_k1_bias_per_density": 8.6e-05, "stretch_beta_warp": 3.0},
           "density_normalized": True, "method": "2ds", "specimens": 3,
           "target_sd_between_specimens": {"log_k1_warp_per_density": 0.1, "log_k1_weft_per_density": 0.12,
                                           "log_k1_bias_per_density": 0.08, "r_warp": 0.1}}
    text = summary.estimate(res)
    assert "from 3 specimens" in text.splitlines()[0]
    assert "µN·m per g/m²" in text and "warp 0.084" in text  # 8.4e-5 m³/s² = 0.084 µN·m per g/m²
    assert "warp 10 %" in text


def test_summaries_of_results_missing_keys_do_not_crash():
    for name, fn in summary.SUMMARIES.items():
        for res in ({}, {"unexpected": [1, 2, 3]}, {"selected": None, "params": None, "cases": None}):
            text = fn(res)
            assert isinstance(text, str) and text.strip(), name
            assert summary.summarize(name, res).strip()
    partial = {k: v for k, v in _diagnose_result().items() if k not in ("final", "mesh", "noise_floor")}
    assert summary.diagnose(partial).splitlines()[0].endswith("off_centre")
    assert summary.summarize("inspect", {"dc": "not a number"})
    assert summary.summarize("estimate", {"params": {"bend_k1_warp": "x"}, "fit": [1, 2]})


def test_simulate_validate_bench_export_and_generic_summaries():
    text = summary.simulate({"out": "m", "status": "at_rest", "steps": 412, "verts": 1234, "seconds": 12.345,
                             "dc": 0.71, "spacing_mm": 3.7})
    assert text.splitlines()[0] == "drapejax simulate: at rest after 412 steps"
    assert "1234 vertices, 3.7 mm spacing" in text
    assert "drape coefficient  0.71" in text and "12.3 s" in text and "m" in text
    assert "NOT at rest" in summary.simulate({"status": "step_budget_exhausted"})
    cases = [{"gamma": g, "angle_deg": 0.0, "spacing_m": 0.005, "n_verts": 100, "hw_sim": 0.5, "hw_ref": 0.49,
              "rel_err": e, "converged": True} for g, e in ((0.1, 0.01), (100.0, 0.42))]
    text = summary.validate({"max_rel_err": 0.42, "tolerance": 0.03, "passed": False, "cases": cases})
    assert text.splitlines()[0] == "drapejax validate cantilever: FAILED: worst error 42 % (tolerance 3 %)"
    assert "Γ 100" in text and "mesh 5 mm" in text
    bench = {"verts": 900, "rest_s": 1.2, "compile_s": 30.0, "grad_s": 0.4, "batch_per_min": 40.0,
             "batch16_per_min": None, "batch_per_min_by_strategy": {"vmap": 40.0, "map": 30.0}, "loop_per_min": 20.0,
             "batch_speedup_vs_loop": 2.0, "peak_mb": 812.0, "newton_rest_s": None, "speedup_vs_newton": None,
             "spacing_mm": 30.0, "rest_s_runs": [1.2], "status": [0], "steps": [100], "batch_size": 2,
             "batch_strategy": "vmap", "batch_status": [0, 0], "backend": "cpu"}
    text = summary.bench(bench)
    _assert_human(text, "drapes/min", "MB", " s")
    assert "2 of 2 at rest" in text and "not timed" in text
    from drapejax.export import export_params, format_export

    exp = export_params(PARAMS, "kes")
    assert summary.export(exp) == format_export(exp)
    text = summary.generic({"a": 1.23456, "b": {"x": 1, "y": 2}, "c": list(range(100)), "d": {"k": list(range(9))}})
    assert "a                       1.23" in text and "100 items" in text and "x 1, y 2" in text
    _assert_human(text)
    assert summary.num(1.61e-05) == "1.61e-05" and summary.num(406.77) == "407" and summary.num(-0.04449) == "-0.0445"
    assert summary.num(None) == "n/a" and summary.num(float("inf")) == "inf"
