"""Parameter schema, validation and the two-piece bending law."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from drapejax.energy import Bending, TwoPieceBending
from drapejax.material import (LOG_STRETCH_NAMES, LOG_TARGET_NAMES, PARAM_KEYS, PER_DENSITY_SUFFIX, FabricParams,
                               ParameterError, example_params, from_log_stretch, from_log_targets, from_log_theta,
                               from_matrix, from_per_density, load_params, plate_compliance, stack, strip_rigidity,
                               to_log_stretch, to_log_targets, to_log_theta, to_matrix, to_per_density, unstack,
                               validity)
from drapejax.mesh import build_mesh, strip_mesh

BASE = {"density": 0.2, "bend_k1_warp": 1.4e-5, "bend_k1_weft": 9e-6, "bend_k1_bias": 1.1e-5}


def test_defaults_and_round_trip(tmp_path):
    p = FabricParams.from_dict(BASE)
    d = p.to_dict()
    assert d["stretch_alpha_warp"] > 0 and d["bend_k2_warp"] == 0.0
    f = tmp_path / "p.json"
    f.write_text(json.dumps(d))
    assert load_params(f).to_dict() == d


@pytest.mark.parametrize("bad, word", [
    ({**BASE, "bend_k1_wrap": 1e-5}, "unknown"),
    ({**BASE, "bend_k1_warp": 13.8}, "bend_k1_warp"),  # µN·m given as SI
    ({**BASE, "density": -0.1}, "density"),
    ({**BASE, "density": "heavy"}, "density"),
    ({k: v for k, v in BASE.items() if k != "bend_k1_bias"}, "bend_k1_bias"),
    ({**BASE, "bend_k2_warp": -1e-6}, "monotone"),
    ({**BASE, "stretch_alpha_weft": 0.0}, "stretch_alpha_weft"),
])
def test_bad_parameters_name_the_key(bad, word):
    with pytest.raises(ParameterError, match=word):
        FabricParams.from_dict(bad, source="P.json")


def test_bad_file_errors(tmp_path):
    f = tmp_path / "p.json"
    f.write_text("{not json")
    with pytest.raises(ParameterError, match="p.json"):
        load_params(f)
    with pytest.raises(ParameterError, match="not found"):
        load_params(tmp_path / "missing.json")


def test_strip_rigidity_reproduces_the_three_measured_directions():
    p = example_params("mid")
    got = np.asarray(strip_rigidity(p, jnp.array([0.0, 90.0, 45.0])))
    np.testing.assert_allclose(got, [p.bend_k1_warp, p.bend_k1_weft, p.bend_k1_bias], rtol=1e-12)
    # A bias rigidity no positive-definite plate can have is flagged, and PD otherwise.
    bad = FabricParams.make(density=0.2, bend_k1_warp=1e-5, bend_k1_weft=1e-7, bend_k1_bias=1e-3)
    assert not bool(validity(bad))
    assert np.all(np.linalg.eigvalsh(np.asarray(plate_compliance(p))) > 0)


def _cylinder(mesh, kappa, angle_deg):
    x = np.asarray(mesh.rest)
    a = np.deg2rad(angle_deg)
    d = np.array([np.cos(a), np.sin(a)])
    s, t = x[:, :2] @ d, x[:, :2] @ np.array([-d[1], d[0]])
    r = 1.0 / kappa
    return jnp.asarray(np.stack([r * np.sin(s / r) * d[0] - t * d[1], r * np.sin(s / r) * d[1] + t * d[0],
                                 r * (1 - np.cos(s / r))], 1))


def test_two_piece_law_matches_its_moment_curve():
    """Energy per area of a cylinder: ½k0κ² below the switch, the integrated two-piece moment above."""
    held = strip_mesh(0.1, 0.1, 0.004, clamp_length_m=0.004)
    # no clamp: the cylinders bend the whole sheet, which a clamp would hold flat
    mesh = build_mesh(np.asarray(held.rest[:, :2]), np.asarray(held.faces), np.zeros(held.n_verts, bool), held.info)
    k0, s = 1e-5, 0.3
    term = TwoPieceBending(*(jnp.asarray(v) for v in (k0, k0, k0, s, s, s)))
    ks = np.deg2rad(15.0) / mesh.info.spacing_m
    p = FabricParams.from_dict(BASE)
    # The linear law with the same small-angle stiffness is the reference discretisation.
    iso = FabricParams.from_dict({**BASE, "bend_k1_warp": k0, "bend_k1_weft": k0, "bend_k1_bias": k0})
    x = _cylinder(mesh, 0.5 * ks, 10.0)
    assert float(term(x, mesh, p)) == pytest.approx(float(Bending()(x, mesh, iso)), rel=1e-9)
    kappa = 2.0 * ks
    x = _cylinder(mesh, kappa, 30.0)
    law = 0.5 * k0 * ks**2 + k0 * ks * (kappa - ks) + 0.5 * s * k0 * (kappa - ks) ** 2
    ratio = float(term(x, mesh, p)) / float(Bending()(x, mesh, iso))
    assert ratio == pytest.approx(law / (0.5 * k0 * kappa**2), rel=0.03)  # boundary vertices fit less exactly
    assert np.all(np.isfinite(np.asarray(jax.grad(lambda y: term(y, mesh, p))(mesh.rest))))


# --------------------------------------------------------------------------- parameter forms


def _fabrics() -> list[FabricParams]:
    """The three example fabrics with every field non-zero (stretch_beta too), so relative
    round-trip errors are defined for all 13."""
    out = []
    for i, name in enumerate(("light", "mid", "heavy")):
        d = example_params(name).to_dict()
        d.update(stretch_beta_warp=1.5 + i, stretch_beta_weft=-0.3 * (i + 1), stretch_beta_bias=4.0 - i)
        out.append(FabricParams.from_dict(d))
    return out


def _assert_same(a: FabricParams, b: FabricParams, rtol=1e-12):
    for k in PARAM_KEYS:
        np.testing.assert_allclose(np.asarray(getattr(a, k)), np.asarray(getattr(b, k)), rtol=rtol, atol=0, err_msg=k)


def test_flat_dict_round_trip():
    for p in _fabrics():
        d = p.to_dict()
        assert list(d) == list(PARAM_KEYS) and all(type(v) is float for v in d.values())
        _assert_same(FabricParams.from_dict(d), p)


def test_matrix_round_trip_single_and_batched():
    ps = _fabrics()
    b = stack(ps)
    m = to_matrix(b)
    assert m.shape == (3, 13) and m.dtype == np.float64
    _assert_same(from_matrix(m), b, rtol=0)
    for i, p in enumerate(ps):
        np.testing.assert_array_equal(to_matrix(p), m[i])
        _assert_same(from_matrix(to_matrix(p)), p, rtol=0)
    assert from_matrix(m, dtype=jnp.float32).density.dtype == jnp.float32
    with pytest.raises(ParameterError, match="13"):
        from_matrix(m[:, :12])


def test_per_density_round_trip():
    for p in _fabrics():
        pd = to_per_density(p)
        assert "density" not in pd and len(pd) == 12
        assert [k.removesuffix(PER_DENSITY_SUFFIX) for k in pd] == list(PARAM_KEYS[1:])
        assert all(k.endswith(PER_DENSITY_SUFFIX) != k.startswith("stretch_beta") for k in pd)
        rho = float(p.density)
        assert pd["bend_k1_warp_per_density"] == pytest.approx(float(p.bend_k1_warp) / rho, rel=1e-15)
        assert pd["stretch_beta_bias"] == float(p.stretch_beta_bias)
        _assert_same(FabricParams.from_dict(from_per_density(pd, rho)), p)
    with pytest.raises(ParameterError, match="P.json.*bend_k1_warp_per_density"):
        from_per_density({"bend_k1_warp_per_density": "stiff"}, 0.2, source="P.json")


def test_log_targets_round_trip_single_and_batched():
    ps = _fabrics()
    b = stack(ps)
    y, s = to_log_targets(b), to_log_stretch(b)
    assert y.shape == s.shape == (3, 6) and len(LOG_TARGET_NAMES) == len(LOG_STRETCH_NAMES) == 6
    np.testing.assert_array_equal(to_log_targets(to_matrix(b)), y)  # rows and the pytree give the same
    for i, p in enumerate(ps):
        np.testing.assert_array_equal(to_log_targets(p), y[i])
        np.testing.assert_array_equal(to_log_stretch(p), s[i])
        stretch = {k: v for k, v in p.to_dict().items() if k.startswith("stretch")}
        np.testing.assert_allclose(to_log_stretch(stretch, float(p.density)), s[i], rtol=1e-14)
        back = from_log_stretch(s[i], float(p.density))
        assert set(back) == set(stretch)
        np.testing.assert_allclose([back[k] for k in stretch], [float(v) for v in stretch.values()], rtol=1e-13)
        rho = float(p.density)
        np.testing.assert_allclose(y[i, 0], np.log(float(p.bend_k1_warp) / rho), rtol=1e-15)
        _assert_same(FabricParams.from_dict(from_log_targets(y[i], s[i], rho)), p)
        per = from_log_targets(y[i], s[i], None)
        assert list(per) == list(to_per_density(p))
        _assert_same(FabricParams.from_dict(from_per_density(per, rho)), p)
        # the limits leave a valid fabric alone
        assert from_log_targets(y[i], s[i], rho, r_min=-0.49, bias_fraction=0.99) == from_log_targets(y[i], s[i], rho)
    with pytest.raises(ParameterError, match="density"):
        to_log_stretch(stretch)


def test_log_targets_limits_clip_r_and_bias():
    p = _fabrics()[1]
    y, s = to_log_targets(p), to_log_stretch(p)
    y[3], y[2] = -3.0, y[2] + 5.0
    out = FabricParams.from_dict(from_log_targets(y, s, 0.2, r_min=-0.49, bias_fraction=0.99))
    assert float(out.bend_k2_warp) * 50.0 / float(out.bend_k1_warp) == pytest.approx(-0.49, rel=1e-12)
    assert bool(validity(out))
    assert not bool(validity(FabricParams.make(**from_log_targets(y, s, 0.2))))


def test_log_theta_round_trip_single_and_batched():
    ps = _fabrics()
    theta = np.array([[0.3, -0.2, 0.1], [-1.0, 0.5, 0.0], [0.7, 0.7, -0.4]])
    for init, th in zip(ps, theta):
        p = from_log_theta(init, jnp.asarray(th))
        np.testing.assert_allclose(np.asarray(to_log_theta(p, init)), th, rtol=1e-12, atol=1e-15)
        _assert_same(from_log_theta(init, to_log_theta(p, init)), p)
        assert float(p.bend_k2_weft) / float(p.bend_k1_weft) == pytest.approx(
            float(init.bend_k2_weft) / float(init.bend_k1_weft), rel=1e-12)
        assert float(p.stretch_alpha_bias) == float(init.stretch_alpha_bias)
    b = stack(ps)
    pb = from_log_theta(b, jnp.asarray(theta))
    np.testing.assert_allclose(np.asarray(to_log_theta(pb, b)), theta, rtol=1e-12, atol=1e-15)
    _assert_same(from_log_theta(b, to_log_theta(pb, b)), pb)
    for i, q in enumerate(unstack(pb)):
        _assert_same(q, from_log_theta(ps[i], jnp.asarray(theta[i])), rtol=0)
    jitted = jax.jit(from_log_theta)(b, jnp.asarray(theta))
    _assert_same(jitted, pb)
