"""Bench readings on strips (cantilever, pure bending) in the measurement format, and the diagnosis
stage that tests candidate effects on them (``drapejax.diagnose.bench``)."""

from __future__ import annotations

import dataclasses
import json
import re

import numpy as np
import pytest

from drapejax.diagnose.bench import BenchFit, bench_evidence
from drapejax.diagnose.strip import ReadingResponse
from drapejax.effects import REGISTRY
from drapejax.io import BenchRecord, MeasurementError, load_measurement, write_measurement
from drapejax.material import DIRECTIONS, example_params
from drapejax.virtual_lab import virtual_bench

READINGS = [BenchRecord("cantilever", "weft", {"overhang_m": 0.05, "width_m": 0.025, "tip_drop_m": 0.021}),
            BenchRecord("pure_bending", "bias", {"curvature_per_m": 50.0, "moment_n": 4.9e-4}),
            BenchRecord("pure_bending", "counter_bias", {"curvature_per_m": 50.0, "moment_n": 4.1e-4})]


def _folder(tmp_path, bench):
    sil = np.zeros((64, 64), np.uint8)
    sil[16:48, 16:48] = 255
    return write_measurement(tmp_path / "m", test="cusick", specimen_radius_m=0.15, disk_radius_m=0.09,
                             areal_density_kg_m2=0.2, silhouette=sil, extent_m=0.16, bench=bench)


def test_bench_readings_round_trip(tmp_path):
    m = load_measurement(_folder(tmp_path, READINGS))
    assert m.bench == tuple(READINGS)
    assert load_measurement(_folder(tmp_path / "none", ())).bench == ()


@pytest.mark.parametrize("entry, field", [
    ({"test": "cantilever", "direction": "weft", "overhang_m": 50, "width_m": 0.025, "tip_drop_m": 0.02},
     "bench[0].overhang_m"),
    ({"test": "cantilever", "direction": "weft", "overhang_m": 0.05, "width_m": 0.025, "tip_drop_m": 0.06},
     "bench[0].tip_drop_m"),
    ({"test": "pure_bending", "direction": "weft", "curvature_per_m": 50}, "bench[0].moment_n"),
    ({"test": "pure_bending", "direction": "diagonal", "curvature_per_m": 50, "moment_n": 1e-4}, "bench[0].direction"),
    ({"test": "drape", "direction": "weft"}, "bench[0].test"),
    ({"test": "pure_bending", "direction": "weft", "curvature_per_m": -5, "moment_n": 1e-4},
     "bench[0].curvature_per_m"),
])
def test_bad_bench_reading_names_its_field(tmp_path, entry, field):
    folder = _folder(tmp_path, READINGS)
    raw = json.loads((folder / "measurement.json").read_text())
    raw["bench"] = [entry]
    (folder / "measurement.json").write_text(json.dumps(raw))
    with pytest.raises(MeasurementError, match=re.escape(f"measurement.json field '{field}'")):
        load_measurement(folder)


@pytest.mark.parametrize("tests", [
    [("pure_bending", "bias")],
    pytest.param([("cantilever", "weft")], marks=pytest.mark.experiment),  # strip solves: about 2 minutes
])
def test_simulated_readings_match_a_noiseless_virtual_bench(tests):
    """A reading made by the virtual lab without noise is what the model simulates for the same
    fabric: zero residual along every cut, and readings that respond to k1 along their cut the
    physical way (a stiffer strip droops less and carries more moment)."""
    p = example_params("mid")
    records = virtual_bench(p, None, tests, std=0.0)
    resp = ReadingResponse(records, p)
    np.testing.assert_allclose(resp.residual(), 0.0, atol=1e-9)
    for r, slope in zip(records, resp.slope()):
        assert (0.5 < slope) if r.test != "cantilever" else (0.3 < -slope < 1.5), (r, slope)


@pytest.fixture(scope="module")
def friction_readings():
    p = example_params("mid")
    hidden = {"bending_friction": [20.0]}
    tests = [("pure_bending", d) for d in DIRECTIONS]
    saturated = virtual_bench(p, {"bending_saturation": [0.5]}, tests, seed=3)
    return p, virtual_bench(p, hidden, tests, seed=3), virtual_bench(p, None, tests, seed=3), saturated


def test_bench_readings_find_friction_that_a_stiffer_k1_absorbed(friction_readings):
    """The drape's baseline takes a frictional couple for a stiffer k1 (×1.5: the fit mesh's
    baseline on "mid" with θ = 20 1/m); pure bending readings along the three cuts find it at about
    its strength, leaving the readings within their repeatability where k1 alone cannot, and a
    hem band, which no strip feels, is not tried."""
    p, hidden, _, _ = friction_readings
    stiff = dataclasses.replace(p, **{f"bend_k1_{d}": getattr(p, f"bend_k1_{d}") * 1.5 for d in DIRECTIONS})
    ev = bench_evidence(hidden, stiff, [REGISTRY["bending_friction"], REGISTRY["heavy_hem"]])
    fr = ev["effects"]["bending_friction"]
    assert ev["selected"] == "bending_friction", fr["why"]
    assert 14.0 < fr["theta"]["friction_moment_over_k1_per_m"] < 28.0
    std = BenchFit().std
    assert fr["error_after"] < 1.5 * std < 3 * std < fr["error_baseline_refit"]
    assert ev["effects"]["heavy_hem"] == {"felt": False, "found": False, "why": "a strip does not feel it"}


def test_clean_bench_readings_find_nothing(friction_readings):
    p, _, clean, _ = friction_readings
    stiff = dataclasses.replace(p, **{f"bend_k1_{d}": getattr(p, f"bend_k1_{d}") * 1.3 for d in DIRECTIONS})
    ev = bench_evidence(clean, stiff, [REGISTRY["bending_friction"]])
    assert ev["selected"] is None
    assert not ev["effects"]["bending_friction"]["found"]


def test_a_look_alike_is_not_named_and_the_unloading_branch_names_the_effect(friction_readings):
    """Bending saturation softens a strip at large curvature, as a frictional couple's share of the
    moment falls with it. From the 50 and 150 1/m loading rows alone a saturated fabric is a stiffer
    k1: neither effect lowers the objective. The 10 1/m row shows that something is there (both
    fall far beyond the χ² needed), and the loading branch names the saturation only where it beats
    the friction by the margin; the friction, the look-alike, is never named. The unloading branch
    tells them apart: the saturated strip gives back along it what it took, where a couple would
    resist the other way, so with both branches the saturation is named."""
    p, _, _, saturated = friction_readings
    stiff = dataclasses.replace(p, **{f"bend_k1_{d}": getattr(p, f"bend_k1_{d}") * 1.5 for d in DIRECTIONS})
    both = [REGISTRY["bending_friction"], REGISTRY["bending_saturation"]]
    loading = [r for r in saturated if r.test == "pure_bending"]
    assert len(loading) < len(saturated)  # the virtual pure bending test reads both branches
    upper = bench_evidence([r for r in loading if r.values["curvature_per_m"] >= 50.0], stiff, both)
    assert upper["selected"] is None
    assert all(e["chi2_drop"] < e["chi2_needed"] for e in upper["effects"].values()), upper["effects"]
    ev = bench_evidence(loading, stiff, both)
    assert all(e["chi2_drop"] > 3 * e["chi2_needed"] for e in ev["effects"].values()), ev["effects"]
    assert ev["selected"] in (None, "bending_saturation")
    if ev["selected"] is None:
        assert ev["ambiguous"] == ["bending_friction", "bending_saturation"]
    loop = bench_evidence(saturated, stiff, both)
    assert loop["selected"] == "bending_saturation", loop["effects"]


def test_the_unloading_branch_names_a_frictional_couple():
    """The other way round: a hidden frictional couple (θ = 10 1/m) on one warp strip, fitted as
    the base model 1.3 times too stiff. Its loading rows alone are matched by a saturation as well
    (ambiguous); its unloading rows fall below the loading ones by the hysteresis, which only the
    couple makes, and name it."""
    p = example_params("mid")
    stiff = dataclasses.replace(p, **{f"bend_k1_{d}": getattr(p, f"bend_k1_{d}") * 1.3 for d in DIRECTIONS})
    readings = virtual_bench(p, {"bending_friction": [10.0]}, [("pure_bending", "warp")], seed=3)
    load = {r.values["curvature_per_m"]: r.measured for r in readings if r.test == "pure_bending"}
    assert all(r.measured < 0.85 * load[r.values["curvature_per_m"]] for r in readings
               if r.test == "pure_bending_unloading")
    both = [REGISTRY["bending_friction"], REGISTRY["bending_saturation"]]
    loading = bench_evidence([r for r in readings if r.test == "pure_bending"], stiff, both)
    assert loading["selected"] is None and loading["ambiguous"] == ["bending_friction", "bending_saturation"]
    loop = bench_evidence(readings, stiff, both)
    assert loop["selected"] == "bending_friction", loop["effects"]


def test_a_strip_along_the_counter_bias_finds_an_asymmetry_the_three_cuts_cannot():
    """A fabric twice as stiff along +45° as along 135° (bias asymmetry θ = 1), fitted as the
    base model with every k1 1.3 times too stiff (what a drape's baseline absorbs). Pure bending
    along warp, weft and bias is matched by the k1 alone, so nothing is found; with a strip along
    the counter bias as well the asymmetry is found at about its strength. (With the two bias
    strips alone, warp and weft k1 free under their weak prior take up part of the difference:
    a bias strip's moment depends on them too.)"""
    p = example_params("mid")
    hidden = {"bias_asymmetry": [1.0]}
    stiff = dataclasses.replace(p, **{f"bend_k1_{d}": getattr(p, f"bend_k1_{d}") * 1.3 for d in DIRECTIONS})
    candidates = [REGISTRY["bias_asymmetry"], REGISTRY["bending_friction"]]
    three = [("pure_bending", d) for d in DIRECTIONS]
    ev = bench_evidence(virtual_bench(p, hidden, three, seed=4), stiff, candidates)
    assert ev["selected"] is None and not ev["effects"]["bias_asymmetry"]["found"]
    ev = bench_evidence(virtual_bench(p, hidden, three + [("pure_bending", "counter_bias")], seed=4), stiff, candidates)
    found = ev["effects"]["bias_asymmetry"]
    assert ev["selected"] == "bias_asymmetry", found["why"]
    assert 1.6 < found["theta"]["plus45_over_minus45_rigidity"] < 2.5, found["theta"]
    assert found["error_after"] < 2 * BenchFit().std < found["error_baseline_refit"]


def test_measure_stores_bench_readings_and_names_a_bad_one(tmp_path):
    import cv2

    from drapejax.io import build_measurement

    sil = np.zeros((64, 64), np.uint8)
    sil[16:48, 16:48] = 255
    cv2.imwrite(str(tmp_path / "top.png"), sil)
    readings = tmp_path / "kes.json"
    readings.write_text(json.dumps([r.to_json() for r in READINGS]))
    res = build_measurement(tmp_path / "m", areal_density_kg_m2=0.2, silhouette=tmp_path / "top.png",
                            extent_m=0.16, bench=readings)
    assert res["bench"] == [r.to_json() for r in READINGS]
    assert load_measurement(tmp_path / "m").bench == tuple(READINGS)
    readings.write_text(json.dumps({"bench": [{**READINGS[1].to_json(), "moment_n": 490.0}]}))
    with pytest.raises(MeasurementError, match=re.escape(f"--bench {readings}: measurement.json field "
                                                         "'bench[0].moment_n'")):
        build_measurement(tmp_path / "bad", areal_density_kg_m2=0.2, silhouette=tmp_path / "top.png",
                          extent_m=0.16, bench=readings)
    assert not (tmp_path / "bad").exists()
