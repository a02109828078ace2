"""Parameter schema, validation and the two-piece bending law."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from drapejax.energy import Bending, TwoPieceBending
from drapejax.material import (FabricParams, ParameterError, example_params, load_params, plate_compliance,
                               strip_rigidity, validity)
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
