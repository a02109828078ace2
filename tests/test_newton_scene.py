"""The Style3D scenes with a setup effect made in them (``newton_peer.hidden_effect_scene``): the
data of the independent-simulator loop. Geometry only: newton itself is not needed."""

import numpy as np
import pytest

from drapejax.bench.newton_peer import hidden_effect_scene
from drapejax.mesh import cusick_mesh


def _scene(effects, h=0.01):
    m = cusick_mesh(h)
    xy, faces, clamped = np.asarray(m.rest)[:, :2], np.asarray(m.faces), np.asarray(m.clamped)
    return (xy, faces, clamped), hidden_effect_scene(xy, faces, clamped, effects, spacing_m=h)


def _areas(xy, faces):
    e1, e2 = xy[faces[:, 1]] - xy[faces[:, 0]], xy[faces[:, 2]] - xy[faces[:, 0]]
    return 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])


def test_an_offset_specimen_is_the_same_disc_moved_over_a_support_left_in_place():
    (xy0, f0, c0), (xy, faces, clamped, mass) = _scene({"off_centre": [0.013, -0.004]})
    a, a0 = np.abs(_areas(xy, faces)), np.abs(_areas(xy0, f0))
    assert a.sum() == pytest.approx(a0.sum(), rel=1e-9)  # the cut edge is the same polygon, moved
    centre = (a[:, None] * xy[faces].mean(1)).sum(0) / a.sum()
    np.testing.assert_allclose(centre, [0.013, -0.004], atol=1e-3)
    r = np.linalg.norm(xy, axis=1)
    np.testing.assert_array_equal(clamped, r <= 0.09 * (1 + 1e-9))  # the support edge stays at the origin
    assert np.sum(np.isclose(r, 0.09)) >= 2 * np.pi * 0.09 / 0.01  # ... as a ring of the mesh
    assert np.all(a > 1e-3 * a.mean()) and np.all(mass == 1.0)
    assert clamped.sum() > 0.8 * c0.sum()


def test_a_heavy_hem_scales_the_mass_of_the_band_only():
    (xy0, f0, c0), (xy, faces, clamped, mass) = _scene({"heavy_hem": [2.0]})
    np.testing.assert_array_equal(xy, xy0)
    band = np.linalg.norm(xy, axis=1) > 0.15 - 0.01
    assert band.any() and np.all(mass[band] == 3.0) and np.all(mass[~band] == 1.0)


def test_effects_the_scene_cannot_make_are_refused_by_name():
    with pytest.raises(ValueError, match="edge_curl"):
        _scene({"edge_curl": [1.0]})
    with pytest.raises(ValueError, match="onto the support"):
        _scene({"off_centre": [0.06, 0.0]})
