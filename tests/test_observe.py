"""Renderers, soft renderers, descriptors and metrics against analytic shapes and the real scans."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from drapejax.io import load_measurement
from drapejax.observe import (
    align_rotation_z,
    aligned_iou,
    boundary_curve,
    depth_views,
    describe,
    describe_mesh,
    drape_coefficient,
    fold_amplitudes,
    fold_count,
    height_map,
    hem_heights_from_height_map,
    inspect,
    iou,
    mean_curvature,
    mean_relative_curvature_difference,
    mean_vertex_displacement_mm,
    pixel_centres,
    point_cloud_mesh,
    point_cloud_views,
    rim_profile,
    rim_spectrum,
    sample_surface,
    scan_distance_mm,
    silhouette,
    soft_depth_views,
    soft_height_map,
    soft_rim_profile,
    soft_silhouette,
    spectral_distance,
    view_axes,
)

E = 0.16  # image half side, m
N = 256
PIX = 2 * E / N


def polar_mesh(radius, n_rings=30, n_angles=256, z=None):
    """Star-shaped flat (or z(x, y)) mesh: rings scaled by radius(φ), a centre vertex, a quad strip."""
    phi = 2 * np.pi * np.arange(n_angles) / n_angles
    rho = np.linspace(0, 1, n_rings + 1)[1:]
    r = rho[:, None] * radius(phi)[None, :]
    xy = np.concatenate([[[0.0, 0.0]], np.stack([r * np.cos(phi), r * np.sin(phi)], -1).reshape(-1, 2)])
    idx = 1 + np.arange(n_rings * n_angles).reshape(n_rings, n_angles)
    nxt = np.roll(idx, -1, axis=1)
    faces = [np.stack([np.zeros(n_angles, int), idx[0], nxt[0]], 1)]
    faces.append(np.stack([idx[:-1], idx[1:], nxt[1:]], -1).reshape(-1, 3))
    faces.append(np.stack([idx[:-1], nxt[1:], nxt[:-1]], -1).reshape(-1, 3))
    zz = np.zeros(len(xy)) if z is None else z(xy[:, 0], xy[:, 1])
    return np.concatenate([xy, zz[:, None]], 1), np.concatenate(faces)


def disc(radius, **kw):
    return polar_mesh(lambda p: np.full_like(p, radius), **kw)


def star(p):
    return 0.12 + 0.015 * np.cos(5 * p) + 0.01 * np.cos(2 * p + 0.3)


def rotz(v, deg):
    a = np.deg2rad(deg)
    return v @ np.array([[np.cos(a), np.sin(a), 0], [-np.sin(a), np.cos(a), 0], [0, 0, 1]])


@pytest.fixture(scope="module")
def real(shared_data):
    folders = sorted((shared_data / "real_cusick").iterdir())
    assert len(folders) == 48
    return folders


@pytest.fixture(scope="module")
def scan(real):
    m = load_measurement(real[0])
    return np.asarray(m.scan_vertices, float), np.asarray(m.scan_faces), m


# ---- hard renderers ----------------------------------------------------------------------


def test_flat_disc_area_and_drape_coefficient():
    for radius, dc in ((0.15, 1.0), (0.09, 0.0), (0.12, (0.12**2 - 0.09**2) / (0.15**2 - 0.09**2))):
        s = silhouette(*disc(radius))
        area = np.count_nonzero(s) * PIX**2
        assert area == pytest.approx(np.pi * radius**2, rel=0.01)
        assert drape_coefficient(s, E) == pytest.approx(dc, abs=0.01)
    assert set(np.unique(s)) == {0, 255} and s.dtype == np.uint8


def test_square_drape_coefficient():
    a = 0.1503  # a flat 30 cm square: 240 × 240 pixel centres inside
    v = np.array([[-a, -a, 0], [a, -a, 0], [a, a, 0], [-a, a, 0.0]])
    s = silhouette(v, np.array([[0, 1, 2], [0, 2, 3]]))
    assert np.count_nonzero(s) == 240**2
    assert drape_coefficient(s, E, specimen_radius_m=0.15, test="square") == pytest.approx(1.0, abs=1e-12)


def test_tilted_plane_height_exact_at_pixel_centres():
    a, b, c, half = 0.3, -0.2, -0.01, 0.1003
    g = np.linspace(-half, half, 11)
    x, y = np.meshgrid(g, g)
    v = np.stack([x.ravel(), y.ravel(), a * x.ravel() + b * y.ravel() + c], 1)
    i = np.arange(10)[:, None] * 11 + np.arange(10)[None, :]
    faces = np.concatenate([np.stack([i, i + 1, i + 12], -1).reshape(-1, 3),
                            np.stack([i, i + 12, i + 11], -1).reshape(-1, 3)])
    h = height_map(v, faces)
    pc = pixel_centres(N, E)
    px, py = np.meshgrid(pc, pc[::-1])  # row 0 is +y
    inside = (np.abs(px) < half) & (np.abs(py) < half)
    assert np.array_equal(np.isfinite(h), inside)
    np.testing.assert_allclose(h[inside], (a * px + b * py + c)[inside], atol=1e-7)
    assert np.array_equal(silhouette(v, faces) > 0, inside)


def cone_depth(n_views, size, k, radius, el=45.0, az=-90.0, dist=0.5):
    """Exact orthographic depth of the cone z = -k r (r <= radius): first ray hit, 0 if none."""
    out = []
    c = pixel_centres(size, E)
    u, w = np.meshgrid(c, c[::-1])
    for right, up, d in view_axes(n_views, el, az):
        p0 = u[..., None] * right + w[..., None] * up + dist * d
        qa = d[2] ** 2 - k**2 * (d[0] ** 2 + d[1] ** 2)
        qb = -2 * (p0[..., 2] * d[2] - k**2 * (p0[..., 0] * d[0] + p0[..., 1] * d[1]))
        qc = p0[..., 2] ** 2 - k**2 * (p0[..., 0] ** 2 + p0[..., 1] ** 2)
        disc_ = np.sqrt(np.maximum(qb**2 - 4 * qa * qc, 0))
        best = np.full(u.shape, np.inf)
        for t in ((-qb - disc_) / (2 * qa), (-qb + disc_) / (2 * qa)):
            p = p0 - t[..., None] * d
            ok = (qb**2 >= 4 * qa * qc) & (p[..., 2] <= 1e-12) & (np.hypot(p[..., 0], p[..., 1]) <= radius)
            best = np.where(ok & (t < best), t, best)
        out.append(np.where(np.isfinite(best), best, 0.0))
    return np.stack(out)


def test_cone_depth_views():
    k, radius = 0.5, 0.12
    v, f = disc(radius, n_rings=40, z=lambda x, y: -k * np.hypot(x, y))
    d = depth_views(v, f, n_views=4, size=128)
    exact = cone_depth(4, 128, k, radius)
    assert d.shape == (4, 128, 128) and d.dtype == np.float32
    both = (d > 0) & (exact > 0)
    assert np.mean((d > 0) != (exact > 0)) < 0.005  # only edge pixels may differ
    assert np.max(np.abs(d - exact)[both]) < 3e-4
    # The cone is axisymmetric: the four views agree.
    assert np.mean(np.abs(d[0] - d[2])) < 1e-3
    with pytest.raises(ValueError, match="n_views"):
        depth_views(v, f, n_views=3)


def test_rim_profile_and_orientation_of_a_star():
    v, f = polar_mesh(star)
    r = rim_profile(silhouette(v, f), E)
    phi = 2 * np.pi * np.arange(360) / 360
    assert np.max(np.abs(r - star(phi))) < 1.5 * PIX
    assert np.mean(np.abs(r - star(phi))) < 0.3 * PIX


def test_boundary_curve_of_a_cone():
    k, radius = 0.5, 0.12
    v, f = polar_mesh(lambda p: np.full_like(p, radius), n_angles=200, z=lambda x, y: -k * np.hypot(x, y))
    hem = boundary_curve(rotz(v, 17.0), f, n_samples=128)
    assert hem.shape == (128, 3)
    np.testing.assert_allclose(np.hypot(hem[:, 0], hem[:, 1]), radius, rtol=2e-4)
    np.testing.assert_allclose(hem[:, 2], -k * radius, atol=1e-12)
    assert hem[0, 1] == pytest.approx(0.0, abs=1e-12) and hem[0, 0] > 0
    ang = np.unwrap(np.arctan2(hem[:, 1], hem[:, 0]))
    assert np.all(np.diff(ang) > 0)  # counter-clockwise
    step = np.linalg.norm(np.diff(np.concatenate([hem, hem[:1]]), axis=0), axis=1)
    np.testing.assert_allclose(step, 2 * np.pi * radius / 128, rtol=2e-3)
    assert describe_mesh(v, f)["hem_height_mean_mm"] == pytest.approx(-k * radius * 1e3)
    # From the height map alone: the outermost pixel centre lies within a pixel of the hem.
    seen = hem_heights_from_height_map(height_map(v, f), E)
    assert np.all(np.abs(seen + k * radius) < k * 1.5 * PIX)


def test_real_scan_round_trip(real):
    """The stored images were rendered from scan.ply; see the note on their pixel convention."""
    pc = pixel_centres(N, E)
    radius = np.hypot(pc[None, :], pc[::-1, None])
    for folder in real:
        m = load_measurement(folder)
        v, f = np.asarray(m.scan_vertices, float), np.asarray(m.scan_faces)
        s, h = silhouette(v, f), height_map(v, f)
        assert iou(s, m.silhouette) >= 0.98
        skirt = np.isfinite(h) & np.isfinite(m.height) & (radius > 0.095)
        assert np.median(np.abs(h - m.height)[skirt]) < 1.5e-3
    # The stored images put pixel (i, j) at (-E + j·PIX, E - i·PIX), half a pixel off the
    # spec's centres, and fill every pixel a triangle touches: undoing the offset, our
    # silhouette lies inside the stored one and the stored one within one pixel of ours.
    shifted = silhouette(v + [0.5 * PIX, -0.5 * PIX, 0], f) > 0
    stored = m.silhouette > 0
    assert np.count_nonzero(shifted & ~stored) <= 5
    grown = shifted.copy()
    for ax in (0, 1):
        for sh in (-1, 1):
            grown |= np.roll(shifted, sh, axis=ax)
    grown |= np.roll(np.roll(shifted, 1, 0), 1, 1) | np.roll(np.roll(shifted, -1, 0), -1, 1)
    grown |= np.roll(np.roll(shifted, 1, 0), -1, 1) | np.roll(np.roll(shifted, -1, 0), 1, 1)
    assert np.count_nonzero(stored & ~grown) == 0


# ---- descriptors ---------------------------------------------------------------------------


def test_point_cloud_views_match_the_scan_mesh(real):
    """A scan given as points only (no faces) has the mesh's top views and scan distance: its bare
    vertices, and 20 000 uniformly random points on its surface (about 2 mm apart), on real
    scans of two fabrics. Bridging the gaps between folds (a convex hull) would raise the drape coefficient
    by tenths; leaving the gaps between samples open would lower it."""
    for folder in (real[0], real[20]):
        m = load_measurement(folder)
        v, f = np.asarray(m.scan_vertices, float), np.asarray(m.scan_faces)
        sil, hm = silhouette(v, f), height_map(v, f)
        for cloud, dc_tol in ((v, 0.005), (sample_surface(v, f, 20000, seed=0)[0], 0.02)):
            sil_c, hm_c = point_cloud_views(cloud)
            a, b = sil > 0, sil_c > 0
            assert (a & b).sum() / (a | b).sum() > 0.985, (folder.name, len(cloud))
            assert abs(drape_coefficient(sil_c) - drape_coefficient(sil)) < dc_tol, (folder.name, len(cloud))
            assert np.quantile(np.abs(hm_c[a & b] - hm[a & b]), 0.95) < 1e-3
            assert np.all(np.isnan(hm_c[~b])) and np.all(np.isfinite(hm_c[b]))
        cloud_only = describe(dataclasses.replace(m, silhouette=None, height=None, scan_faces=None))
        assert abs(cloud_only["dc"] - drape_coefficient(sil)) < 0.005 and cloud_only["hem_height_mean_mm"] < 0
        # the alpha-shape surface stands in for the scan mesh in the scan distance to another capture
        other = load_measurement(real[real.index(folder) + 1])
        vo, fo = np.asarray(other.scan_vertices, float), np.asarray(other.scan_faces)
        ref = scan_distance_mm(vo, fo, v, f, mirror=True, n_points=2000)
        for cloud in (v, sample_surface(v, f, 20000, seed=0)[0]):
            assert abs(scan_distance_mm(vo, fo, *point_cloud_mesh(cloud), mirror=True, n_points=2000) - ref) < 0.1


def test_fold_count_and_spectrum_of_synthetic_profiles():
    phi = 2 * np.pi * np.arange(360) / 360
    for k in range(3, 15):
        for amp, phase in ((0.003, 0.0), (0.02, 1.1), (0.01, 2.5)):
            r = 0.12 + amp * np.cos(k * phi + phase)
            assert fold_count(r) == k
            spec = rim_spectrum(r, 16)
            expected = np.zeros(17)
            expected[0], expected[k] = 0.12, amp
            np.testing.assert_allclose(spec, expected, atol=1e-12)
            # Crest minus trough is 2·amp, reduced only by sampling the cosine at 1° steps.
            np.testing.assert_allclose(fold_amplitudes(r), 2 * amp, rtol=1 - np.cos(np.pi * k / 360))
    noisy = 0.12 + 0.01 * np.cos(7 * phi) + 0.0005 * np.random.default_rng(0).standard_normal(360)
    assert fold_count(noisy) == 7
    assert fold_count(np.full(360, 0.12)) == 0


def test_peak_finding_and_smoothing_follow_scipy():
    """The fold finder's own prominence rule and circular smoothing give SciPy's answers exactly,
    plateaus and wide kernels included (they are written out so that reading a drape does not
    import ``scipy.signal``)."""
    from scipy.ndimage import gaussian_filter1d
    from scipy.signal import find_peaks

    from drapejax.observe.descriptors import _gaussian_wrap, _prominent_peaks

    rng = np.random.default_rng(0)
    for t in range(400):
        x = rng.normal(size=int(rng.integers(3, 300)))
        if t % 3 == 0:
            x = np.round(2 * x) / 2  # flat tops
        if t % 5 == 0:
            x = np.cumsum(x)
        min_prominence = abs(rng.normal()) * 0.3 * (x.max() - x.min())
        np.testing.assert_array_equal(_prominent_peaks(x, min_prominence), find_peaks(x, prominence=min_prominence)[0])
        sigma = rng.uniform(0.2, 2 * len(x))
        np.testing.assert_allclose(_gaussian_wrap(x, sigma), gaussian_filter1d(x, sigma, mode="wrap"), atol=1e-12)


def test_real_folders_descriptors(real):
    for folder in real:
        d = inspect(folder)
        assert 0.0 < d["dc"] < 1.0, folder.name
        assert 3 <= d["folds"] <= 12, folder.name
        assert all(isinstance(x, (int, float)) for x in d.values())
        assert -60 < d["hem_height_mean_mm"] < 0 and d["r_min_mm"] > 90 and d["r_max_mm"] < 160


# ---- metrics -------------------------------------------------------------------------------


def test_aligned_iou_recovers_rotation_and_mirror():
    v, f = polar_mesh(star)
    base = silhouette(v, f)
    rotated = silhouette(rotz(v, 37.0), f)
    score, angle, mirrored = aligned_iou(rotated, base)
    assert score > 0.99 and angle == pytest.approx(37.0, abs=0.5) and not mirrored
    assert iou(rotated, base) < 0.95
    flipped = silhouette(v * [1, -1, 1], f)
    assert aligned_iou(flipped, base, mirror=True)[2]
    assert aligned_iou(flipped, base, mirror=True)[0] > aligned_iou(flipped, base)[0] + 0.02


def test_spectral_distance_is_rotation_invariant():
    v, f = polar_mesh(star)
    a = rim_profile(silhouette(v, f), E)
    b = rim_profile(silhouette(rotz(v, 23.0), f), E)
    other = rim_profile(silhouette(*polar_mesh(lambda p: 0.12 + 0.015 * np.cos(6 * p))), E)
    assert spectral_distance(a, b) < 0.2
    assert spectral_distance(a, other) > 10.0
    assert spectral_distance(a, np.roll(a, 40)) == pytest.approx(0.0, abs=1e-9)


def test_scan_distance(scan):
    v, f, _ = scan
    assert scan_distance_mm(v, f, v, f, align_rotation=False) < 0.01
    flat, ff = disc(0.12)
    assert scan_distance_mm(flat, ff, flat + [0, 0, 0.002], ff, align_rotation=False) == pytest.approx(2.0, abs=0.01)
    turned = rotz(v, 30.0)
    assert scan_distance_mm(turned, f, v, f, align_rotation=False) > 1.0
    assert scan_distance_mm(turned, f, v, f) < 0.05
    angle, mirrored = align_rotation_z(turned, f, v, f, mirror=True)
    assert angle == pytest.approx(330.0, abs=0.2) and not mirrored


def test_vertex_displacement_and_curvature(scan):
    v, f, _ = scan
    shifted = rotz(v, -12.0) + [0, 0, 0.002]
    assert mean_vertex_displacement_mm(shifted, f, v, f, correspondence=True) == pytest.approx(2.0, abs=1e-6)
    assert mean_vertex_displacement_mm(v, f, v, f) < 0.01
    assert mean_relative_curvature_difference(shifted, f, v, f) < 0.02
    sphere_v, sphere_f = polar_mesh(lambda p: np.full_like(p, 0.5 * np.pi), n_rings=60, n_angles=120)
    # Map the flat disc of radius π/2 onto a hemisphere of radius 5 cm (r → polar angle).
    rr = np.hypot(sphere_v[:, 0], sphere_v[:, 1])
    ph = np.arctan2(sphere_v[:, 1], sphere_v[:, 0])
    hemi = 0.05 * np.stack([np.sin(rr) * np.cos(ph), np.sin(rr) * np.sin(ph), np.cos(rr)], 1)
    h = mean_curvature(hemi, sphere_f)
    interior = np.isfinite(h) & (rr > 0.1)
    np.testing.assert_allclose(h[interior], 20.0, rtol=0.02)
    assert np.isnan(h[rr > 0.5 * np.pi - 1e-9]).all()


# ---- soft renderers ------------------------------------------------------------------------


def test_soft_silhouette_converges_to_hard(scan):
    v, f, _ = scan
    hard = silhouette(v, f) > 0
    V, F = jnp.asarray(v), jnp.asarray(f)
    errors, ious = [], []
    for sharp in (200.0, 400.0, 800.0):
        s = np.asarray(soft_silhouette(V, F, sharpness=jnp.asarray(sharp)))
        errors.append(np.mean(np.abs(s - hard)))
        ious.append(iou(s > 0.5, hard))
    assert errors[0] > errors[1] > errors[2]
    assert ious[-1] >= 0.97
    grad = jax.grad(lambda x: soft_silhouette(x, F, sharpness=jnp.asarray(800.0)).sum())(V)
    assert np.isfinite(np.asarray(grad)).all() and np.abs(np.asarray(grad)).max() > 0


def grid_square(half, z, cells):
    g = np.linspace(-half, half, cells + 1)
    x, y = np.meshgrid(g, g)
    v = np.stack([x.ravel(), y.ravel(), np.full(x.size, z)], 1)
    i = np.arange(cells)[:, None] * (cells + 1) + np.arange(cells)[None, :]
    f = np.concatenate([np.stack([i, i + 1, i + cells + 2], -1).reshape(-1, 3),
                        np.stack([i, i + cells + 2, i + cells + 1], -1).reshape(-1, 3)])
    return v, f


def test_soft_height_map_picks_the_top_layer():
    # Two overlapping horizontal squares, 2 cm apart: the hard map sees the top one.
    vt, ft = grid_square(0.05, 0.0, 25)
    vb, fb = grid_square(0.075, -0.02, 38)
    v, f = np.concatenate([vt, vb]), np.concatenate([ft, fb + len(vt)])
    hard = height_map(v, f)
    pc = pixel_centres(N, E)
    core = (np.abs(pc)[None, :] < 0.05 - 4 * PIX) & (np.abs(pc)[::-1, None] < 0.05 - 4 * PIX)
    assert np.all(hard[core] == 0.0)
    errs = []
    for sharp in (200.0, 800.0, 3200.0):
        soft = np.asarray(soft_height_map(jnp.asarray(v), jnp.asarray(f), sharpness=jnp.asarray(sharp)))
        errs.append(np.mean(np.abs(soft - hard)[core]))
    assert errs[0] > errs[1] > errs[2]
    assert errs[2] < 1e-5


def test_soft_height_map_on_a_real_scan_and_gradients(scan):
    v, f, _ = scan
    V, F = jnp.asarray(v), jnp.asarray(f)
    hard = height_map(v, f)
    soft = np.asarray(soft_height_map(V, F, sharpness=jnp.asarray(1600.0)))
    both = np.isfinite(hard) & np.isfinite(soft)
    assert np.median(np.abs(soft - hard)[both]) < 1e-5 and np.mean(np.abs(soft - hard)[both]) < 2e-4
    mask = jnp.asarray(np.isfinite(hard))

    def loss(x):
        h = soft_height_map(x, F, sharpness=jnp.asarray(800.0))
        return jnp.sum(jnp.where(mask, h, 0.0) ** 2)

    grad = np.asarray(jax.grad(loss)(V))
    assert np.isfinite(grad).all() and np.abs(grad[:, 2]).max() > 0


def test_soft_rim_profile_converges_on_a_disc(scan):
    radius, rho = 0.13, 0.004
    v, _ = disc(radius, n_rings=20, n_angles=160)
    # The sharp limit: the largest reach p·e − (p·e⊥)²/(2ρ) over the vertices, per ray.
    phi = 2 * np.pi * np.arange(360) / 360
    along = v[:, :1] * np.cos(phi) + v[:, 1:2] * np.sin(phi)
    across = -v[:, :1] * np.sin(phi) + v[:, 1:2] * np.cos(phi)
    limit = np.max(along - across**2 / (2 * rho), axis=0)
    soft = [np.asarray(soft_rim_profile(jnp.asarray(v), sharpness=jnp.asarray(b), vertex_radius_m=rho))
            for b in (1e3, 1e4, 1e5)]
    errs = [np.max(np.abs(s - limit)) for s in soft]
    assert errs[0] > errs[1] > errs[2] and errs[2] < 5e-5
    # The limit lies within ρ/8·(spacing/ρ)² below the true hem: 0.8 mm at 5 mm vertex spacing.
    assert np.all((soft[1] < radius + 0.3e-3) & (soft[1] > radius - 0.9e-3))
    sv, sf, _ = scan
    hard = rim_profile(silhouette(sv, sf), E)
    soft = np.asarray(soft_rim_profile(jnp.asarray(sv), sharpness=jnp.asarray(1e4)))
    assert np.mean(np.abs(soft - hard)) < 1.5e-3
    grad = jax.grad(lambda x: soft_rim_profile(x, sharpness=jnp.asarray(1e4)).sum())(jnp.asarray(sv))
    assert np.isfinite(np.asarray(grad)).all()


def test_soft_depth_views_match_the_cone():
    k, radius = 0.5, 0.12
    v, f = disc(radius, n_rings=40, z=lambda x, y: -k * np.hypot(x, y))
    exact = cone_depth(2, 128, k, radius)
    soft = np.asarray(soft_depth_views(jnp.asarray(v), jnp.asarray(f), sharpness=jnp.asarray(2000.0),
                                       n_views=2, size=128))
    assert soft.shape == (2, 128, 128)
    inner = exact > 0
    for ax in (1, 2):
        inner &= np.roll(exact > 0, 2, axis=ax) & np.roll(exact > 0, -2, axis=ax)
    assert np.median(np.abs(soft - exact)[inner]) < 2e-4
    assert np.mean((soft > 0.25) != (exact > 0)) < 0.01
    grad = jax.grad(lambda x: soft_depth_views(x, jnp.asarray(f), sharpness=jnp.asarray(2000.0), n_views=2,
                                               size=128).sum())(jnp.asarray(v))
    assert np.isfinite(np.asarray(grad)).all()


def test_inspect_matches_describe_of_scan(real):
    m = load_measurement(real[0])
    from_folder = inspect(real[0])
    from_mesh = describe_mesh(np.asarray(m.scan_vertices, float), np.asarray(m.scan_faces))
    assert from_folder["hem_height_mean_mm"] == pytest.approx(from_mesh["hem_height_mean_mm"])
    assert from_folder["folds"] == from_mesh["folds"]
    assert from_folder["dc"] == pytest.approx(from_mesh["dc"], abs=0.03)


def _full_march_rim_profile(img, extent_m, n_angles=360):
    """The outermost half-crossing along each ray, marching every quarter-pixel sample."""
    n = img.shape[0]
    mask = (img > 127).astype(float)
    h = 2.0 * extent_m / n
    r = np.arange(0.0, extent_m * np.sqrt(2.0), h / 4)
    phi = 2 * np.pi * np.arange(n_angles) / n_angles
    col = (r[None, :] * np.cos(phi)[:, None] + extent_m) / h - 0.5
    row = (extent_m - r[None, :] * np.sin(phi)[:, None]) / h - 0.5
    c0, r0 = np.floor(col).astype(int), np.floor(row).astype(int)
    fc, fr = col - c0, row - r0
    c0, r0 = np.clip(c0 + 1, 0, n), np.clip(r0 + 1, 0, n)
    p = np.pad(mask, 1)
    val = ((1 - fr) * ((1 - fc) * p[r0, c0] + fc * p[r0, c0 + 1])
           + fr * ((1 - fc) * p[r0 + 1, c0] + fc * p[r0 + 1, c0 + 1]))
    out = np.zeros(n_angles)
    for a in range(n_angles):
        ins = np.flatnonzero(val[a] >= 0.5)
        if ins.size:
            k = ins[-1]
            k1 = min(k + 1, len(r) - 1)
            frac = 0.0 if k == len(r) - 1 else (val[a, k] - 0.5) / (val[a, k] - val[a, k1])
            out[a] = r[k] + frac * (r[k1] - r[k])
    return out


def test_rim_profile_equals_the_full_ray_march():
    """The rim profile marches only where the outermost crossing can be, and finds the radii of a
    march over every sample: on discs off the centre with specks of noise, fabric touching the
    image border, an empty and a full image."""
    import cv2

    rng = np.random.default_rng(3)
    images = []
    for _ in range(12):
        m = np.zeros((128, 128), np.uint8)
        cv2.circle(m, (64 + int(rng.integers(-10, 10)), 64 + int(rng.integers(-10, 10))), int(rng.integers(3, 75)),
                   255, -1)
        m[rng.random(m.shape) < 0.01] = 255
        images.append(m)
    images += [np.zeros((128, 128), np.uint8), np.full((128, 128), 255, np.uint8)]
    for img in images:
        for extent in (0.16, 0.2):
            np.testing.assert_array_equal(rim_profile(img, extent), _full_march_rim_profile(img, extent))
