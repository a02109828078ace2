"""The HTML diagnosis report: conclusion first, one verdict, readable tables, self-contained figures
with scale and colour bars, and the result's data as a JSON file beside the page.

Built from hand-made residual reports on small grids (no simulation), so it runs in seconds."""

from __future__ import annotations

import base64
import json
import re

import cv2
import numpy as np
import pytest

from drapejax.diagnose.report import PANEL, render_html, verdict, write_report
from drapejax.diagnose.residuals import NoiseFloor, ResidualReport, Views

from helpers import PARAMS, STD

EXT = 0.16
N = 48

FLOOR = {"iou": 0.9, "dc_abs": 0.03, "spectral_mm": 6.0, "scan_mm": 3.0}


def _views(radius_m: float, centre_m=(0.0, 0.0)) -> Views:
    c = -EXT + (np.arange(N) + 0.5) * 2 * EXT / N
    x, y = np.meshgrid(c, c[::-1])
    rho = np.hypot(x - centre_m[0], y - centre_m[1])
    inside = rho <= radius_m
    z = -0.6 * np.clip(rho - 0.09, 0.0, None)
    return Views(np.where(inside, 255, 0).astype(np.uint8), np.where(inside, z, np.nan), EXT)


def _residuals(shift_m: float) -> ResidualReport:
    meas, sim = _views(0.12, (shift_m, 0.0)), _views(0.12)
    phi = np.linspace(0, 2 * np.pi, 36, endpoint=False)
    rim_m = 0.12 + shift_m * np.cos(phi)
    rim_s = np.full(36, 0.12)
    spectrum = np.zeros(17)
    spectrum[1] = shift_m
    errors = {"iou": 0.95 - 5 * shift_m, "dc_abs": 0.01, "spectral_mm": 2.0 + 200 * shift_m, "scan_mm": 1.5}
    floor = NoiseFloor(**FLOOR)
    return ResidualReport(
        errors=errors, errors_within_floor=floor.within(errors), noise_floor=floor, angle_deg=0.0, mirrored=False,
        measured=meas, simulated=sim,
        silhouette_residual=(meas.silhouette > 127).astype(np.int8) - (sim.silhouette > 127).astype(np.int8),
        height_residual=meas.height - sim.height, rim_measured=rim_m, rim_simulated=rim_s, rim_residual=rim_m - rim_s,
        rim_residual_spectrum=spectrum,
        symmetry={"odd_fraction": 0.9, "mirror_antisymmetric_fraction": 0.1, "low_fraction": 0.95,
                  "dominant_harmonic": 1},
        bands={"near_disc": {"height_mm": 1.0, "silhouette": 0.0}, "mid": {"height_mm": 4.0, "silhouette": 0.1},
               "hem": {"height_mm": 7.0, "silhouette": 0.2}},
        rim_mean_mm=0.0)


def _model(ratio: float, misfit_ok: bool, misfit: float) -> dict:
    held = {"iou": 0.93, "dc_abs": 0.012, "spectral_mm": 3.1, "scan_mm": 2.2}
    return {"params": PARAMS, "std": STD, "error": held, "heldout_error": [held, held], "loss": 40.0,
            "error_ratio": ratio, "heldout_misfit": [misfit], "misfit_within_noise": misfit_ok,
            "expected": {"misfit": misfit, "error_ratio": ratio, "drops": 3}}


def _result(selected=("off_centre",), *, within=True, final_ratio=0.8, final_misfit_ok=True) -> dict:
    return {
        "baseline": _model(1.7, False, 250.0),
        "effects_tested": [{"name": "off_centre", "with": [], "signature": 0.9, "error_ratio": 0.8,
                            "gain_noise_units": 12.0, "bic_gain": 40.0, "accepted": True, "reason": "accepted"},
                           {"name": "heavy_hem", "with": [], "signature": 0.2, "error_ratio": 1.5,
                            "gain_noise_units": 1.0, "bic_gain": -3.0, "accepted": False,
                            "reason": "misfit drop below the penalty"}],
        "selected": list(selected),
        "selected_values": {"off_centre": {"theta": [0.0197, -0.0004], "specimen_centre_dx_mm": 19.7,
                                           "specimen_centre_dy_mm": -0.4}} if selected else {},
        "final": _model(final_ratio, final_misfit_ok, 80.0),
        "density_normalized": False, "within_noise_floor": within, "baseline_within_noise_floor": False,
        "noise_floor": FLOOR, "reason": "no candidate improves the held-out misfit beyond the noise",
        "folders": [], "report": None,
    }


def _write(tmp_path, result, **kw):
    before, after = _residuals(0.02), _residuals(0.002)
    path = write_report(tmp_path / "out" / "report.html", result, before, after, **kw)
    return path, path.read_text(encoding="utf-8")


def _head(text: str) -> str:
    """The page up to its first table: what the conclusion must say on its own."""
    assert "<table" in text
    return text[:text.index("<table")]


def _images(text: str) -> list[np.ndarray]:
    """The page's inline PNGs, decoded (RGB)."""
    out = []
    for src in re.findall(r'<img[^>]*\ssrc="([^"]+)"', text):
        raw = base64.b64decode(src.split(",", 1)[1])
        out.append(cv2.imdecode(np.frombuffer(raw, np.uint8), cv2.IMREAD_COLOR)[..., ::-1])
    return out


def test_page_is_self_contained_and_links_its_json(tmp_path):
    result = _result()
    path, text = _write(tmp_path, result)
    assert text.startswith("<!DOCTYPE html>")
    for banned in ("http://", "https://", "<script", "<link", "@import", "url("):
        assert banned not in text, banned
    imgs = re.findall(r"<img\b[^>]*>", text)
    assert len(imgs) >= 12
    assert all(re.search(r'\ssrc="data:image/png;base64,[A-Za-z0-9+/=]+"', tag) for tag in imgs)
    data = path.with_suffix(".json")
    assert f'href="{data.name}"' in text
    assert json.loads(data.read_text())["selected"] == ["off_centre"]
    assert sorted(p.name for p in path.parent.iterdir()) == ["report.html", "report.json"]


def test_no_raw_json_on_the_page(tmp_path):
    _, text = _write(tmp_path, _result())
    assert "<pre" not in text
    assert '{"' not in text and "{&quot;" not in text and "&quot;:" not in text
    # tables say yes/no, not Python's booleans
    visible = re.sub(r"<[^>]+>", " ", re.sub(r'src="[^"]+"', "", text))
    assert not re.search(r"\b(True|False|None)\b", visible)


def test_conclusion_comes_first_with_strength_errors_and_bending_in_tool_units(tmp_path):
    _, text = _write(tmp_path, _result())
    head = _head(text)
    assert "<img" not in head
    assert "Selected effect" in head and "off_centre" in head
    assert "specimen centre dx 19.7 mm" in head  # strength, with units
    assert "19.7 mm from the disc centre" in head  # where
    assert "baseline 1.70 → final 0.800" in head  # held-out error ratio against the floor
    assert "warp 16.1 ± 1.6" in head and "µN·m" in head  # k1 in µN·m with its std
    # CLO's bending fields in g·mm²/s² (1e-9 N·m): 16.1 µN·m = 16100
    assert "Bending-Warp 16100" in head and "g·mm²/s²" in head
    # the tool table shows what a tool has no field for, in export.py's words
    assert "Marvelous Designer" in text and "slider whose mapping to physical units" in text


def test_exactly_one_verdict_consistent_with_the_numbers(tmp_path):
    # errors inside the floor (ratio 0.8) but a misfit larger than noise: the verdict says so once
    result = _result(within=False, final_ratio=0.8, final_misfit_ok=False)
    _, text = _write(tmp_path, result)
    assert text.count('class="verdict"') == 1 and text.count("Verdict:") == 1
    v = verdict(result)
    assert v.within is False and v.error_ratio_ok is True and v.misfit_ok is False
    assert ("outside the noise floor" in v.text and "misfit" in v.text
            and "inside the capture-to-capture floor" in v.text)
    assert re.search(r"verdict part 1: held-out error ratio ≤ 1</td><td></td><td></td><td>no</td><td>yes</td>", text)
    assert re.search(r"verdict part 2: held-out misfit consistent with noise</td><td></td><td></td><td>no</td>"
                     r"<td>no</td>", text)
    assert not re.search(r"within (the )?noise floor\W*(True|False)", text, re.I)
    within = verdict(_result())
    assert within.within is True and within.text.startswith("Verdict: within the noise floor")
    assert "outside" in verdict(_result(within=False, final_ratio=1.4, final_misfit_ok=True)).text


def test_no_effect_selected_says_so_and_why(tmp_path):
    _, text = _write(tmp_path, _result(selected=(), within=False, final_ratio=1.7, final_misfit_ok=False))
    head = _head(text)
    assert "No effect selected: no candidate improves the held-out misfit beyond the noise" in head
    assert "Selected effect" not in head
    assert "the baseline model still misses something" in head


def test_a_rescaled_membrane_is_stated_in_the_conclusion(tmp_path):
    scan = {"factor": 4.0, "kept": "k1 refit at the scan's best factor",
            "compare": {"baseline fit": 38.2, "scan's best factor": 6.1, "k1 refit at the scan's best factor": 3.4}}
    _, text = _write(tmp_path, {**_result(selected=()), "membrane_scan": scan})
    head = _head(text)
    assert "α times 4.00" in head and "score 3.40 on the captures against 38.2" in head
    _, plain = _write(tmp_path, {**_result(selected=()), "membrane_scan": {**scan, "factor": 1.0}})
    assert "Membrane stiffness" not in _head(plain)


def test_a_membrane_from_tensile_readings_is_stated_in_the_conclusion(tmp_path):
    rec = {"readings": 3, "alpha": {"warp": 612.0, "weft": 395.0, "bias": 81.0},
           "factor": {"warp": 3.6, "weft": 3.8, "bias": 3.2}}
    _, text = _write(tmp_path, {**_result(selected=()), "tensile": rec})
    assert "from 3 tensile reading(s)" in _head(text) and "warp 612" in _head(text)
    _, ignored = _write(tmp_path, {**_result(selected=()), "tensile": {"readings": 1, "ignored": "no density"}})
    assert "Tensile readings not used: no density" in _head(ignored)


def test_truth_from_the_capture_folder_is_shown_beside_the_estimate(tmp_path):
    folder = tmp_path / "capture_1"
    folder.mkdir()
    truth = {"params": {**PARAMS, "bend_k1_warp": 1.38e-05},
             "effects": {"off_centre": {"theta": [0.02, 0.0], "specimen_centre_dx_mm": 20.0,
                                        "specimen_centre_dy_mm": 0.0}}}
    (folder / "truth.json").write_text(json.dumps(truth))
    _, text = _write(tmp_path, {**_result(), "folders": [str(folder)]})
    head = _head(text)
    assert "Truth (virtual lab): hidden effect <b>off_centre</b> with specimen centre dx 20.0 mm" in head
    assert "the selection matches it" in head
    assert "(truth: 13.8, 19.1, 16.6 µN·m)" in head
    missed = render_html(_result(selected=()), _residuals(0.02), None, title="t", truth=truth)
    assert "the selection does not match it" in _head(missed)


def test_density_normalised_estimate_gets_no_invented_tool_values(tmp_path):
    per = {f"bend_k1_{d}_per_density": PARAMS[f"bend_k1_{d}"] / PARAMS["density"] for d in ("warp", "weft", "bias")}
    result = _result()
    result["final"] = {**result["final"], "params": per, "std": {}}
    result["density_normalized"] = True
    _, text = _write(tmp_path, result)
    head = _head(text)
    assert "µN·m per kg/m²" in head and "In tool units: not available" in head and "density" in head
    assert "Bending-Warp" not in text


def test_figures_have_scale_bars_and_colour_bars(tmp_path):
    _, text = _write(tmp_path, _result())
    imgs = _images(text)
    captions = re.findall(r"<figcaption>([^<]*)</figcaption>", text)
    assert len(imgs) == len(captions)
    bar_px = int(round(0.05 / (2 * EXT / PANEL)))  # the 5 cm bar on a ±16 cm window
    for img, cap in zip(imgs, captions):
        if "rim" in cap:
            continue
        row = img[PANEL - 11]  # the scale bar's row in the lower-left corner
        dark = np.flatnonzero(np.all(row[:PANEL // 2] < 40, axis=1))
        assert dark.size and abs((dark.max() - dark.min()) - bar_px) <= 1, cap
        if "height" in cap:  # colour-mapped: a colour bar below the panel, with its numeric ends
            assert img.shape[0] == PANEL + 46, cap
            strip = img[PANEL + 4:PANEL + 16, 14:PANEL - 14].astype(int)
            assert np.ptp(strip[:, :, 0]) > 150 or np.ptp(strip[:, :, 2]) > 150, cap
    assert "5 cm" not in text  # the bar's label is drawn in the image, not left to the caption


@pytest.mark.parametrize("extent_m,label_m", [(0.16, 0.05), (1.0, 0.5), (0.02, 0.01)])
def test_scale_bar_length_follows_the_window(extent_m, label_m):
    from drapejax.diagnose.report import _scale_bar

    img = _scale_bar(np.full((PANEL, PANEL, 3), 255, np.uint8), extent_m)
    row = img[PANEL - 11]
    dark = np.flatnonzero(np.all(row < 40, axis=1))
    assert abs((dark.max() - dark.min()) - label_m / (2 * extent_m) * PANEL) <= 1


def test_a_json_path_is_refused(tmp_path):
    with pytest.raises(ValueError, match="give a .html path"):
        write_report(tmp_path / "report.json", _result(), _residuals(0.02))


def test_bench_readings_get_their_tables_and_an_effect_they_found_is_said_to_be_theirs(tmp_path):
    """An effect found by the bench readings (``diagnose.bench``) is named in the conclusion as
    theirs, and the page shows the readings and what each candidate made of them."""
    result = _result(selected=())
    result.update(selected=["bending_friction"], selected_by={"bending_friction": "bench readings"},
                  selected_values={"bending_friction": {"theta": [18.0], "friction_moment_over_k1_per_m": 18.0}})
    result["bench"] = {
        "readings": [{"test": "pure_bending", "direction": "weft", "curvature_per_m": 50.0, "moment_n": 6.1e-4,
                      "simulated": 6.7e-4, "residual_log_k1": -0.08}],
        "error_before": 0.21, "selected": "bending_friction", "ambiguous": None,
        "effects": {"bending_friction": {"felt": True, "theta": {"friction_moment_over_k1_per_m": 18.0},
                                         "chi2_drop": 12.0, "chi2_needed": 6.6, "error_baseline_refit": 0.11,
                                         "error_after": 0.02, "found": True, "why": "the readings ask for it"},
                    "heavy_hem": {"felt": False, "found": False, "why": "a strip does not feel it"}}}
    _, text = _write(tmp_path, result)
    assert "Found by the bench readings on strips" in _head(text)
    assert "Bench readings on strips of the fabric" in text and "a strip does not feel it" in text
    assert "pure_bending" in text and "the readings ask for it" in text


def test_a_bench_finding_the_captures_refused_is_said_so(tmp_path):
    """When the captures' fresh drops refuse the readings' effect (``diagnose.bench_refused``), the
    bench section says it was not kept and why, and the conclusion does not claim it."""
    result = _result(selected=())
    reason = "bias_asymmetry: with it the captures' error ratio on fresh drops rises (1.18 -> 1.79)"
    result["bench"] = {"readings": [], "error_before": 0.28, "selected": "bias_asymmetry", "refused": reason,
                       "effects": {}}
    _, text = _write(tmp_path, result)
    assert "not kept: " in text and "1.18 -&gt; 1.79" in text
    assert "Found by the bench readings on strips" not in _head(text)
