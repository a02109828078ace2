"""Strip tensile readings (KES-FB1) in the measurement format, the membrane's response to them
(``refine.tensile``) and the membrane they set for a fit."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from drapejax.io import BenchRecord, MeasurementError, load_measurement, write_measurement
from drapejax.material import DIRECTIONS, FabricParams, example_params, scale_stretch
from drapejax.refine.tensile import measured_membrane_std, membrane_from_tensile, membrane_of_captures, tensile_force
from drapejax.virtual_lab import virtual_bench

STRAIN = 1e-4  # small enough for the linear law: β ε ≤ 1e-3


def _fabric(alpha=(600.0, 400.0, 80.0), beta=(0.0, 0.0, 0.0)):
    kw = {f"stretch_alpha_{d}": a for d, a in zip(DIRECTIONS, alpha)}
    kw.update({f"stretch_beta_{d}": b for d, b in zip(DIRECTIONS, beta)})
    return FabricParams.make(density=0.15, bend_k1_warp=5e-6, bend_k1_weft=4e-6, bend_k1_bias=3e-6, **kw)


@pytest.mark.parametrize("alpha", [(600.0, 400.0, 80.0), (2000.0, 150.0, 30.0)])
def test_small_strain_force_is_the_springs_with_free_contraction(alpha):
    """Along warp (weft) the bias springs add α_b α_f / (2 α_f + α_b) to α_w (the other way round):
    the free lateral contraction relieves part of them (module docstring of ``refine.tensile``)."""
    aw, af, ab = alpha
    p = _fabric(alpha)
    warp = float(tensile_force(p, "warp", STRAIN)) / STRAIN
    weft = float(tensile_force(p, "weft", STRAIN)) / STRAIN
    assert warp == pytest.approx(aw + ab * af / (2 * af + ab), rel=1e-3)
    assert weft == pytest.approx(af + ab * aw / (2 * aw + ab), rel=1e-3)


def test_bias_force_is_symmetric_in_warp_and_weft_and_linear_in_alpha():
    a = float(tensile_force(_fabric((600.0, 400.0, 80.0)), "bias", 0.01))
    b = float(tensile_force(_fabric((400.0, 600.0, 80.0)), "bias", 0.01))
    c = float(tensile_force(_fabric((1800.0, 1200.0, 240.0)), "bias", 0.01))
    assert a == pytest.approx(b, rel=1e-6)
    assert c == pytest.approx(3 * a, rel=1e-6)
    # a stiffening fabric (β > 0) carries more at the same strain
    assert float(tensile_force(_fabric(beta=(20.0, 20.0, 20.0)), "warp", 0.02)) > float(
        tensile_force(_fabric(), "warp", 0.02))


def test_readings_recover_the_membrane_from_a_wrong_start():
    truth = _fabric((900.0, 250.0, 60.0), beta=(5.0, 8.0, 3.0))
    readings = virtual_bench(truth, None, [("tensile", d) for d in DIRECTIONS], std=0.0)
    start = scale_stretch(_fabric((600.0, 400.0, 80.0), beta=(5.0, 8.0, 3.0)), 0.3)
    fitted, rec = membrane_from_tensile(readings, start)
    for d in DIRECTIONS:
        want = float(getattr(truth, f"stretch_alpha_{d}"))
        assert float(getattr(fitted, f"stretch_alpha_{d}")) == pytest.approx(want, rel=0.02), d
        assert float(getattr(fitted, f"stretch_beta_{d}")) == float(getattr(start, f"stretch_beta_{d}"))
    assert rec["readings"] == 3 and rec["rms_log_error"] < 0.01
    assert rec["std_log_scale"] < 0.06  # three cuts pin the overall membrane to about the readings' 5 %
    assert float(fitted.bend_k1_warp) == float(start.bend_k1_warp)


def test_one_reading_rescales_the_whole_membrane():
    truth = _fabric((1200.0, 800.0, 160.0))
    (reading,) = virtual_bench(truth, None, [("tensile", "warp")], std=0.0)
    fitted, rec = membrane_from_tensile([reading], _fabric())
    assert rec["factor"]["warp"] == pytest.approx(2.0, rel=0.01)
    assert rec["factor"]["weft"] == pytest.approx(2.0, rel=0.01)
    assert rec["factor"]["bias"] == pytest.approx(2.0, rel=0.01)
    # directions the reading did not load keep their prior width
    assert rec["std_log_alpha"]["weft"] > 5 * rec["std_log_alpha"]["warp"]


def test_noisy_readings_scatter_as_their_std():
    truth = example_params("light")
    readings = virtual_bench(truth, None, [("tensile", d) for d in DIRECTIONS], seed=3)
    _, rec = membrane_from_tensile(readings, scale_stretch(truth, 0.25))
    for d in DIRECTIONS:
        assert abs(np.log(rec["factor"][d] / 4.0)) < 4 * rec["std_log_alpha"][d], (d, rec)


def _folder(path, bench, density=0.2):
    sil = np.zeros((64, 64), np.uint8)
    sil[16:48, 16:48] = 255
    return write_measurement(path, test="cusick", specimen_radius_m=0.15, disk_radius_m=0.09,
                             areal_density_kg_m2=density, silhouette=sil, extent_m=0.16, bench=bench)


READING = BenchRecord("tensile", "warp", {"strain": 0.01, "force_n_per_m": 12.7})


def test_tensile_readings_round_trip_and_set_the_captures_membrane(tmp_path):
    bending = BenchRecord("pure_bending", "bias", {"curvature_per_m": 50.0, "moment_n": 4.9e-4})
    ms = [load_measurement(_folder(tmp_path / f"c{i}", [READING, bending])) for i in range(2)]
    assert ms[0].bench == (READING, bending) and READING.measured == 12.7
    start = _fabric()
    fitted, rec = membrane_of_captures(ms, start)
    assert rec["readings"] == 1  # repeated in both captures, counted once
    assert float(tensile_force(fitted, "warp", 0.01)) == pytest.approx(12.7, rel=1e-3)
    assert membrane_of_captures([load_measurement(_folder(tmp_path / "none", [bending]))], start) == (start, None)
    # one warp reading pins the warp; the mean log α keeps part of the prior on the other two
    assert 0.05 < measured_membrane_std(rec) < 0.5 and measured_membrane_std(None) is None


def test_tensile_readings_are_left_out_when_the_density_is_unknown(tmp_path):
    m = load_measurement(_folder(tmp_path / "m", [READING], density=None))
    start = _fabric()
    fitted, rec = membrane_of_captures([m], start)
    assert fitted is start and "density is unknown" in rec["ignored"]
    assert measured_membrane_std(rec) is None


def test_diagnose_tests_effects_on_bending_readings_only(tmp_path):
    from drapejax.diagnose import _bench_readings

    bending = BenchRecord("cantilever", "weft", {"overhang_m": 0.05, "width_m": 0.025, "tip_drop_m": 0.021})
    m = load_measurement(_folder(tmp_path / "m", [READING, bending]))
    assert _bench_readings([m, m]) == (bending,)


@pytest.mark.parametrize("entry, field", [
    ({"test": "tensile", "direction": "warp", "strain": 2, "force_n_per_m": 12.0}, "bench[0].strain"),
    ({"test": "tensile", "direction": "warp", "strain": 0.01, "force_n_per_m": 5e6}, "bench[0].force_n_per_m"),
    ({"test": "tensile", "direction": "warp", "strain": 0.01}, "bench[0].force_n_per_m"),
])
def test_bad_tensile_reading_names_its_field(tmp_path, entry, field):
    folder = _folder(tmp_path / "m", [READING])
    raw = json.loads((folder / "measurement.json").read_text())
    raw["bench"] = [entry]
    (folder / "measurement.json").write_text(json.dumps(raw))
    with pytest.raises(MeasurementError, match=re.escape(f"measurement.json field '{field}'")):
        load_measurement(folder)


def test_the_network_reads_the_drape_at_the_measured_membrane(tmp_path):
    """``estimate --no-refine``: the tensile readings replace the prior's stretching (and feed a
    "+S" network's stretching inputs); given stretching still wins."""
    from drapejax.inverse.estimate import InverseModel

    truth = _fabric((1500.0, 900.0, 120.0))
    readings = virtual_bench(truth, None, [("tensile", d) for d in DIRECTIONS], std=0.0)
    m = load_measurement(_folder(tmp_path / "m", readings))
    model = InverseModel.for_measurement(m)
    out = model.estimate_no_refine(m)
    assert out["stretch_source"] == "tensile" and out["membrane"]["readings"] == 3
    for d in DIRECTIONS:  # within the readings' 5 % (the prior on the direction ratios pulls a little)
        assert out["params"][f"stretch_alpha_{d}"] == pytest.approx(float(getattr(truth, f"stretch_alpha_{d}")),
                                                                    rel=0.05)
    plain = model.estimate_no_refine(load_measurement(_folder(tmp_path / "plain", [])))
    assert plain["stretch_source"] == "prior_median" and plain["membrane"] is None


def test_free_strains_are_solved_to_equilibrium_or_the_force_is_nan(monkeypatch):
    """The strip's lateral strain and shear are iterated until the free edges carry no traction
    (relative to the pull); a stiffening strip at 20 % strain converges, and too few Newton steps
    give NaN, not a force at a wrong equilibrium."""
    import jax.numpy as jnp

    from drapejax.refine import tensile

    p = _fabric(beta=(20.0, 20.0, 20.0))
    phi, eps = jnp.asarray(np.deg2rad(30.0)), jnp.asarray(0.2)
    full = float(tensile._force(p, phi, eps))
    assert np.isfinite(full) and full > 0
    monkeypatch.setattr(tensile, "_LATERAL_ITERATIONS", 100)
    assert float(tensile._force(p, phi, eps)) == pytest.approx(full, rel=1e-9)  # more steps change nothing
    monkeypatch.setattr(tensile, "_LATERAL_ITERATIONS", 1)
    assert np.isnan(float(tensile._force(p, phi, eps)))


def test_a_reading_the_law_cannot_take_is_named(monkeypatch):
    from drapejax.refine import tensile

    readings = virtual_bench(_fabric(), None, [("tensile", "weft")], std=0.0)
    monkeypatch.setattr(tensile, "_forces", lambda params, phi, strain: np.full(np.shape(phi), np.nan))
    with pytest.raises(ValueError, match="weft at strain"):
        membrane_from_tensile(readings, _fabric())
