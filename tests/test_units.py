"""Unit conversions, cantilever helpers and the 618-fabric reference file."""

import numpy as np
import pytest
from scipy.integrate import solve_bvp

from drapejax import units
from drapejax.material import G

# Spec table (units-and-ranges.md, "Conversions"): SI value of one unit.
SPEC_FACTORS = [
    ("g*mm^2/s^2", 1e-9),
    ("gf*cm^2/cm", 9.807e-5),
    ("mg*cm", 9.807e-8),
    ("uN*m", 1e-6),
    ("g/s^2", 1e-3),
    ("g/m^2", 1e-3),
    ("fabrics618_linear", 1e-9),
    ("fabrics618_nonlinear", 1e-12),
]


@pytest.mark.parametrize("name, si", SPEC_FACTORS)
def test_spec_factors(name, si):
    # The spec rounds the weight-based factors (gf, mg) to four digits.
    assert units.to_si(1.0, name) == pytest.approx(si, rel=1e-4)
    assert units.from_si(si, name) == pytest.approx(1.0, rel=1e-4)


def test_decimal_factors_are_exact():
    assert units.to_si(1.0, "uN*m") == 1e-6
    assert units.to_si(1.0, "g*mm^2/s^2") == 1e-9
    assert units.to_si(1.0, "gsm") == 1e-3
    assert units.to_si(1.0, "fabrics618_nonlinear") == 1e-12


@pytest.mark.parametrize("name", sorted(units.UNITS))
def test_round_trip(name):
    x = np.array([1e-3, 0.7, 13.8, 4.2e5])
    np.testing.assert_allclose(units.from_si(units.to_si(x, name), name), x, rtol=1e-14)


def test_typographic_spellings_and_aliases():
    assert units.get_unit("µN·m") is units.UNITS["uN*m"]
    assert units.get_unit("μN m") is units.UNITS["uN*m"]
    assert units.get_unit("g·mm²/s²") is units.UNITS["g*mm^2/s^2"]
    assert units.get_unit("GSM") is units.UNITS["g/m^2"]
    assert units.get_unit("bs3356") is units.UNITS["mg*cm"]


def test_unknown_unit_is_named():
    with pytest.raises(ValueError, match="furlong"):
        units.to_si(1.0, "furlong*m")


def test_flexural_rigidity_matches_weight_times_cube_in_si():
    # BS 3356: G = W c^3 in mg*cm (W areal mass in mg/cm^2, c in cm) is the weight per area
    # times c^3; in SI that is rho * g0 * c^3.
    w_mg_cm2, c_cm = 19.7, 1.86
    rho_si = w_mg_cm2 * 1e-6 / 1e-4
    expected = rho_si * units.STANDARD_GRAVITY * (c_cm * 1e-2) ** 3
    assert units.to_si(w_mg_cm2 * c_cm**3, "mg*cm") == pytest.approx(expected, rel=1e-12)
    # KES-F B in gf*cm^2/cm: a moment per width of 1 gf*cm per cm per 1/cm curvature.
    assert units.to_si(1.0, "gf*cm^2/cm") == pytest.approx(1e-3 * units.STANDARD_GRAVITY * 1e-2)


def test_cantilever_bending_length_is_half_the_overhang():
    overhang = np.array([0.02, 0.04, 0.06])
    rho = 0.2
    c = units.bending_length_m(units.cantilever_k1_from_overhang(overhang, rho), rho)
    np.testing.assert_allclose(c, overhang / 2, rtol=2e-4)
    assert units.cantilever_k1_from_overhang(0.04, rho) == pytest.approx(rho * G * 0.04**3 / 8.004)


def _heavy_elastica_tip(gamma):
    """Tip angle (deg), H/L, W/L of a strip clamped horizontally under its own weight."""
    def rhs(s, y):
        return np.vstack([y[1], -gamma * (1 - s) * np.cos(y[0])])

    def bc(ya, yb):
        return np.array([ya[0], yb[1]])

    s = np.linspace(0, 1, 201)
    guess = np.vstack([np.minimum(1.5, gamma / 6) * s * (2 - s), np.zeros_like(s)])
    sol = solve_bvp(rhs, bc, s, guess, tol=1e-8, max_nodes=100000)
    assert sol.success
    fine = np.linspace(0, 1, 4001)
    theta = sol.sol(fine)[0]
    ds = fine[1] - fine[0]
    drop = np.sum((np.sin(theta[1:]) + np.sin(theta[:-1])) / 2) * ds
    reach = np.sum((np.cos(theta[1:]) + np.cos(theta[:-1])) / 2) * ds
    return np.degrees(np.arctan2(drop, reach)), drop, reach


def test_cantilever_gamma_gives_the_41_5_degree_chord():
    # Check the spec's heavy-elastica table first, so the solver is trusted.
    for gamma, h_l, w_l in [(1.0, 0.1235, 0.9913), (5.0, 0.4959, 0.8467), (10.0, 0.7002, 0.6564)]:
        _, drop, reach = _heavy_elastica_tip(gamma)
        assert drop == pytest.approx(h_l, abs=2e-4)
        assert reach == pytest.approx(w_l, abs=2e-4)
    chord_deg, _, _ = _heavy_elastica_tip(units.CANTILEVER_GAMMA)
    assert chord_deg == pytest.approx(41.5, abs=0.01)


@pytest.fixture(scope="module")
def fabrics(shared_data):
    return units.load_fabrics_618(shared_data / "reference" / "fabrics_618_bending.csv")


Q = [0.0, 0.05, 0.5, 0.95, 1.0]


def _assert_quantiles(x, table, rel):
    np.testing.assert_allclose(np.quantile(x, Q), table, rtol=rel)


def test_618_file_matches_the_range_table(fabrics):
    assert set(fabrics) == {"density", "k1_warp", "k1_weft", "k1_bias",
                            "k2_warp", "k2_weft", "k2_bias"}
    assert all(v.shape == (618,) for v in fabrics.values())
    rho = fabrics["density"]
    assert np.median(units.from_si(rho, "g/m^2")) == pytest.approx(197, abs=2)
    assert np.median(units.from_si(fabrics["k1_warp"], "uN*m")) == pytest.approx(13.8, abs=0.5)
    _assert_quantiles(units.from_si(rho, "g/m^2"), [15, 31, 197, 488, 870], 0.025)
    _assert_quantiles(units.from_si(fabrics["k1_warp"], "uN*m"), [0.34, 1.1, 13.8, 110, 266], 0.025)
    _assert_quantiles(units.from_si(fabrics["k1_weft"], "uN*m"), [0.22, 0.89, 8.8, 50, 123], 0.025)
    _assert_quantiles(units.from_si(fabrics["k1_bias"], "uN*m"), [0.33, 0.86, 11.5, 66, 89], 0.025)
    # The table's bending length and Cusick number use the warp-weft geometric mean of k1.
    k1 = np.sqrt(fabrics["k1_warp"] * fabrics["k1_weft"])
    _assert_quantiles(units.bending_length_m(k1, rho) * 1e3, [7.7, 11.5, 18.6, 27.9, 38], 0.02)
    _assert_quantiles(rho * G * 0.06**3 / k1, [3.9, 10, 33, 142, 474], 0.02)
    _assert_quantiles(fabrics["k1_warp"] / fabrics["k1_weft"], [0.18, 0.39, 1.48, 4.6, 11.9], 0.025)
    # k2 statistics quoted in the spec are those of the warp direction.
    assert np.sum(fabrics["k2_warp"] < 0) == 613
    assert np.median(fabrics["k1_warp"] / np.abs(fabrics["k2_warp"])) == pytest.approx(370, rel=0.02)


def test_618_reader_names_missing_column_and_bad_value(tmp_path):
    bad_header = tmp_path / "header.csv"
    bad_header.write_text("density[kg.m-2], linear warp[SI*1e9]\n0.1, 2.0\n")
    with pytest.raises(ValueError, match=r"header\.csv.*linear weft"):
        units.load_fabrics_618(bad_header)
    header = ("density[kg.m-2], linear warp[SI*1e9], linear weft[SI*1e9], linear diag[SI*1e9], "
              "nonlinear warp[SI*1e12], nonlinear weft[SI*1e12], nonlinear diag[SI*1e12]\n")
    bad_value = tmp_path / "value.csv"
    bad_value.write_text(header + "0.1, 1, 2, 3, -1, -2, -3\n0.2, 1, x, 3, -1, -2, -3\n")
    with pytest.raises(ValueError, match=r"value\.csv: line 3: column 'linear weft'"):
        units.load_fabrics_618(bad_value)
    with pytest.raises(ValueError, match="missing"):
        units.load_fabrics_618(tmp_path / "missing.csv")
    good = tmp_path / "good.csv"
    good.write_text(header + "0.1, 1, 2, 3, -1, -2, -3\n")
    one = units.load_fabrics_618(good)
    assert one["k1_bias"][0] == pytest.approx(3e-9)
    assert one["k2_weft"][0] == pytest.approx(-2e-12)
