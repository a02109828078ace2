"""Inverse-map networks: shapes, augmentation geometry, a learnable synthetic task, checkpoints, estimator."""

import dataclasses
import json
import math
import subprocess
import sys
from types import SimpleNamespace

import cv2
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from drapejax.material import KAPPA_RANGE, PARAM_KEYS, FabricParams, check, example_params, validity
from drapejax.inverse import estimate as est
from drapejax.inverse.nets import (CurveMLP, DepthCNN, InverseNet, MLPRegressor, SilhouetteAutoencoder,
                                   Standardizer)
from drapejax.inverse.train import (CheckpointError, augment_images, evaluate, fit, fit_ridge, load, predict,
                                    rotate_curves, rotate_images, save, train_autoencoder, train_regressor)

N = 64
EXTENT = 0.16


def test_forward_shapes(key):
    ks = jax.random.split(key, 6)
    call = eqx.filter_jit(lambda net, *a: net(*a))
    ae = SilhouetteAutoencoder(N, (4, 4, 8, 8, 8, 8), latent=16, key=ks[0])
    img = jnp.zeros((1, N, N))
    assert call(ae.encode, img).shape == (16,)
    rec = call(ae, img)
    assert rec.shape == (1, N, N) and bool(jnp.all((rec >= 0) & (rec <= 1)))
    assert call(MLPRegressor(16, 6, n_stretch=6, key=ks[1]), jnp.zeros(16), jnp.zeros(6)).shape == (6,)
    shape = lambda net, *a: eqx.filter_eval_shape(net, *a).shape  # noqa: E731  (traced, not compiled)
    assert shape(CurveMLP(32, 6, hidden=(16,), key=ks[2]), jnp.zeros((32, 3)), jnp.zeros(0)) == (6,)
    for v in (1, 2, 4):
        net = DepthCNN(v, 6, n_stretch=6, width=4, head_hidden=8, key=ks[3])
        assert shape(net, jnp.zeros((v, 32, 32)), jnp.zeros(6)) == (6,)
        assert net.blocks[-1].conv2.weight.shape[0] == 8 * 4
    inv = InverseNet("2ds", MLPRegressor(16, 6, key=ks[4]), Standardizer.identity(0), Standardizer.identity(6),
                     encoder=ae, x_norm=Standardizer.identity(16))
    assert call(inv, img, jnp.zeros(0)).shape == (6,)
    skeleton = InverseNet.skeleton(inv.config(), key=ks[5])
    assert jax.tree_util.tree_structure(skeleton) == jax.tree_util.tree_structure(inv)
    lin = MLPRegressor(80, 6, hidden=(), key=ks[4])
    h = InverseNet("3dh", lin, Standardizer.identity(0), Standardizer.identity(6), x_norm=Standardizer.identity(80))
    assert call(h, jnp.zeros(80), jnp.zeros(0)).shape == (6,)
    assert jax.tree_util.tree_structure(InverseNet.skeleton(h.config(), key=ks[5])) == jax.tree_util.tree_structure(h)
    with pytest.raises(ValueError, match="x_norm"):
        InverseNet("3dh", lin, Standardizer.identity(0), Standardizer.identity(6))
    with pytest.raises(ValueError, match="power of two"):
        SilhouetteAutoencoder(96, key=key)


def _ellipse(a_px: float, b_px: float, n: int = N, angle_deg: float = 0.0) -> np.ndarray:
    img = np.zeros((n * 4, n * 4), np.uint8)
    cv2.ellipse(img, (2 * n, 2 * n), (int(round(4 * a_px)), int(round(4 * b_px))), -angle_deg, 0, 360, 255, -1)
    return cv2.resize(img.astype(np.float32) / 255.0, (n, n), interpolation=cv2.INTER_AREA)


def test_rotation_preserves_mass_and_matches_estimator_frame():
    img = _ellipse(24, 10)
    for deg in (17.0, 45.0, 90.0, 133.0, 250.0):
        rot = np.asarray(rotate_images(jnp.asarray(img), math.radians(deg)))
        assert abs(rot.sum() - img.sum()) < 0.01 * img.sum()
        # the training augmentation and the estimator's resampling use the same convention:
        # a counter-clockwise turn of the world frame (x = columns, y = rows upwards)
        ref = _ellipse(24, 10, angle_deg=deg)
        grid = est.image_to_grid(img, EXTENT, size=N, grid_extent_m=EXTENT, transform=est._rot(deg))
        assert np.abs(rot - ref).mean() < 0.02
        assert np.abs(grid - ref).mean() < 0.02
    batch = jnp.asarray(np.stack([img, _ellipse(15, 15)])[:, None])
    aug = augment_images(jax.random.PRNGKey(3), batch, "rotation")
    np.testing.assert_allclose(np.asarray(aug).sum(axis=(1, 2, 3)), np.asarray(batch).sum(axis=(1, 2, 3)), rtol=0.01)


def test_curve_rotation_keeps_shape_and_canonical_start():
    phi = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    r = 0.12 + 0.02 * np.cos(5 * phi)
    curve = np.stack([r * np.cos(phi), r * np.sin(phi), -0.05 + 0.01 * np.sin(5 * phi)], axis=1)
    out = np.asarray(rotate_curves(jnp.asarray(curve), 1.0))
    np.testing.assert_allclose(np.sort(np.hypot(out[:, 0], out[:, 1])), np.sort(r), atol=1e-12)
    np.testing.assert_allclose(np.sort(out[:, 2]), np.sort(curve[:, 2]), atol=1e-12)
    ang = np.mod(np.arctan2(out[:, 1], out[:, 0]), 2 * np.pi)
    assert ang[0] == ang.min() and np.all(np.diff(np.unwrap(ang)) > 0)  # counter-clockwise from +x
    # a mirrored (clockwise) curve is re-ordered counter-clockwise
    mirrored = np.asarray(rotate_curves(jnp.asarray(curve * np.array([1.0, -1.0, 1.0])), 0.0))
    assert np.all(np.diff(np.unwrap(np.arctan2(mirrored[:, 1], mirrored[:, 0]))) > 0)


@pytest.fixture(scope="module")
def trained_ellipses():
    """A tiny 2DS pipeline trained on ellipses whose semi-axes encode two targets."""
    rng = np.random.default_rng(0)
    n = 320
    a = rng.uniform(8, 28, n)
    b = rng.uniform(8, 28, n)
    images = np.stack([_ellipse(ai, bi) for ai, bi in zip(a, b)])[:, None]
    targets = np.stack([np.log(a * b), np.log(a / b)], axis=1)
    y_norm = Standardizer.fit(targets[:256])
    y = np.asarray(y_norm(jnp.asarray(targets)))
    k1, k2 = jax.random.split(jax.random.PRNGKey(1))
    ae = train_autoencoder(images[:256], key=k1, epochs=8, batch=32, lr=3e-3, channels=(4, 8, 8, 16, 16, 16),
                           latent=32)
    z = predict(ae.encode, images)
    x_norm = Standardizer.fit(z[:256])
    zs = np.asarray(x_norm(jnp.asarray(z)))
    reg, hist = train_regressor(zs[:256], y[:256], key=k2, hidden=(64, 64), epochs=150, batch=32, lr=3e-3,
                                patience=30)
    net = InverseNet("2ds", reg, Standardizer.identity(0), y_norm, encoder=ae, x_norm=x_norm)
    return SimpleNamespace(net=net, reg=reg, hist=hist, images=images, y=y, zs=zs, targets=targets, ae=ae)


def test_end_to_end_training_beats_constant_predictor(trained_ellipses):
    t = trained_ellipses
    s0 = np.zeros((len(t.zs), 0))
    val = evaluate(t.reg, (t.zs[256:], s0[256:]), t.y[256:])
    assert val["r2"]["mean"] > 0.5, val
    assert min(val["r2"]["per_target"]) > 0.3, val
    # a constant predictor (the training mean, 0 in standardised units) has R² <= 0 on held-out data
    const = 1 - np.sum(t.y[256:] ** 2, axis=0) / np.sum((t.y[256:] - t.y[256:].mean(0)) ** 2, axis=0)
    assert np.all(const <= 1e-12)
    # the bundled network reproduces the raw targets from images
    raw = predict(t.net, t.images[256:], s0[256:])
    assert np.corrcoef(raw[:, 0], t.targets[256:, 0])[0, 1] > 0.8
    h = t.hist
    assert h["best_val_loss"] == min([h["best_val_loss"], *h["val_loss"]])
    # the autoencoder learned to reconstruct: pixel MSE well below that of predicting the mean image
    rec = predict(t.ae, t.images[256:])
    mse = np.mean((rec - t.images[256:]) ** 2)
    assert mse < 0.5 * np.mean((t.images[256:] - t.images[:256].mean(0, keepdims=True)) ** 2), mse


def test_fit_early_stopping_returns_best_model(key):
    rng = np.random.default_rng(0)
    x = rng.uniform(-1, 1, (96, 1))
    y = np.sin(3 * x) + 0.3 * rng.normal(size=(96, 1))  # noisy: validation loss stops improving
    s = np.zeros((96, 0))
    model = MLPRegressor(1, 1, hidden=(32,), key=key)
    loss = lambda m, b: jnp.mean((jax.vmap(m)(b[0], b[1]) - b[2]) ** 2)  # noqa: E731
    val = (x[64:], s[64:], y[64:])
    best, hist = fit(model, loss, (x[:64], s[:64], y[:64]), val_data=val, key=key, epochs=300, batch=16,
                     lr=0.05, patience=5)
    n_run = len(hist["val_loss"])
    assert n_run == hist["best_epoch"] + 5 < 300  # stopped `patience` epochs after the best one
    assert float(loss(best, val)) == pytest.approx(hist["best_val_loss"], rel=1e-9)
    assert hist["best_val_loss"] == min(hist["val_loss"]) < float(loss(model, val))


def test_fit_ridge_recovers_a_linear_map():
    """Closed-form ridge with a leave-one-out penalty: a noisy linear map is recovered, a pure-noise
    target is shrunk towards its mean (the largest penalty wins), and the regressor is a plain linear layer."""
    rng = np.random.default_rng(0)
    x, s = rng.normal(size=(400, 12)), rng.normal(size=(400, 2))
    w = rng.normal(size=(14, 1))
    y = np.concatenate([np.c_[x, s] @ w + 0.5 + 0.01 * rng.normal(size=(400, 1)), rng.normal(size=(400, 1))], 1)
    reg, info = fit_ridge(x[:300], y[:300], stretch=s[:300], alphas=np.logspace(-4, 4, 17))
    assert len(reg.layers) == 1 and reg.n_stretch == 2 and len(info["alpha"]) == 2
    np.testing.assert_allclose(np.asarray(reg.layers[0].weight[0]), w[:, 0], atol=2e-3)
    assert float(reg.layers[0].bias[0]) == pytest.approx(0.5, abs=2e-3)
    r2 = evaluate(reg, (x[300:], s[300:]), y[300:])["r2"]["per_target"]
    assert r2[0] > 0.999 and -0.05 < r2[1] <= 0.01
    assert info["alpha"][1] > 100 * info["alpha"][0]


def _draped_disc(turn_deg: float, a2: float):
    """A Cusick-like drape without simulation: the skirt is pulled in to half its width, with an
    elliptic (cos 2θ) and a six-fold component, hangs 0.7 of its width down, then turned about z."""
    from drapejax.mesh import cusick_mesh

    mesh = cusick_mesh(0.01)
    uv = np.asarray(mesh.uv, float)
    rho, th = np.hypot(*uv.T), np.arctan2(uv[:, 1], uv[:, 0])
    skirt = np.maximum(rho - 0.09, 0.0)
    r = np.minimum(rho, 0.09) + skirt * (0.5 + a2 * np.cos(2 * th) + 0.08 * np.cos(6 * th))
    t = th + np.radians(turn_deg)
    return np.stack([r * np.cos(t), r * np.sin(t), -0.7 * skirt], 1), np.asarray(mesh.faces)


def test_harmonic_descriptor_is_rotation_invariant_and_its_phases_turn_with_the_drape():
    from drapejax import observe

    def feature(v, f, phase_harmonics=est.PHASE_HARMONICS):
        return est.harmonic_feature(observe.boundary_curve(v, f, n_samples=256), observe.height_map(v, f, n=256),
                                    0.16, specimen_radius_m=0.15, ring_inner_m=0.09, ring_outer_m=0.16,
                                    phase_harmonics=phase_harmonics)

    drape = _draped_disc(0, 0.06)
    base, turned, other = feature(*drape), feature(*_draped_disc(37, 0.06)), feature(*_draped_disc(0, 0.03))
    h, p, r = est.HARMONICS, est.PHASE_HARMONICS, est.RINGS
    assert base.shape == (2 * h + 4 * p + 2 * r,)
    amp, heights, cover = slice(0, 2 * h), slice(2 * h + 4 * p, 2 * h + 4 * p + r), slice(2 * h + 4 * p + r, None)
    # rotation-invariant parts: equal up to resampling and rasterisation, well inside the change a
    # different drape (half the ellipticity) makes
    np.testing.assert_allclose(turned[amp], base[amp], atol=1e-5)
    assert np.abs(turned[heights] - base[heights]).max() < 1e-3 < np.abs(other[heights] - base[heights]).max()
    assert np.abs(turned[cover] - base[cover]).max() < 0.02 < np.abs(other[cover] - base[cover]).max()
    assert np.abs(other[amp] - base[amp]).max() > 1e-3
    # the complex radius harmonic k = 2 turns by -2 x 37 degrees: r'(θ) = r(θ - 37°)
    c2 = lambda x: x[2 * h + 2] + 1j * x[2 * h + 2 * p + 2]  # noqa: E731
    assert abs(c2(turned)) == pytest.approx(abs(c2(base)), rel=1e-3)
    assert np.degrees(np.angle(c2(turned) / c2(base))) == pytest.approx(-74.0, abs=2.0)
    invariant = feature(*drape, phase_harmonics=0)
    np.testing.assert_array_equal(invariant, np.r_[base[amp], base[heights], base[cover]])


def test_checkpoint_round_trip_is_exact(trained_ellipses, tmp_path):
    t = trained_ellipses
    path = save(tmp_path / "m.eqx", t.net, {"note": "ellipses"})
    net2, meta = load(path)
    assert meta == {"note": "ellipses"}
    s0 = np.zeros((8, 0))
    np.testing.assert_array_equal(predict(t.net, t.images[:8], s0), predict(net2, t.images[:8], s0))
    (tmp_path / "m.json").write_text("{not json")
    with pytest.raises(CheckpointError, match="m.json"):
        load(path)
    with pytest.raises(CheckpointError, match="not found"):
        load(tmp_path / "missing.eqx")


def test_float32_checkpoint_loads_at_model_precision(trained_ellipses, tmp_path):
    """Weights stored as float32 (the shipped checkpoint) load into the float64 skeleton and
    predict what the model does to float32 rounding, from a file half the size."""
    t = trained_ellipses
    full = save(tmp_path / "f64.eqx", t.net, {})
    half = save(tmp_path / "f32.eqx", t.net, {}, weights_dtype=np.float32)
    assert half.stat().st_size < 0.55 * full.stat().st_size
    net2, _ = load(half)
    assert {leaf.dtype for leaf in jax.tree.leaves(net2) if eqx.is_inexact_array(leaf)} == \
        {leaf.dtype for leaf in jax.tree.leaves(t.net) if eqx.is_inexact_array(leaf)}
    s0 = np.zeros((8, 0))
    np.testing.assert_allclose(predict(net2, t.images[:8], s0), predict(t.net, t.images[:8], s0), rtol=1e-4, atol=1e-5)


def test_targets_round_trip_and_validity_projection():
    p = example_params("mid")
    row = np.array([[p.to_dict()[k] for k in PARAM_KEYS]])
    y = est.targets_from_params(row)[0]
    s = est.stretch_inputs_from_params(row)[0]
    out = est.params_from_targets(y, s, p.to_dict()["density"])
    assert list(out) == list(PARAM_KEYS)
    np.testing.assert_allclose([out[k] for k in PARAM_KEYS], row[0], rtol=1e-12)
    per = est.params_from_targets(y, s, None)
    np.testing.assert_allclose(per["bend_k1_warp_per_density"], 13.8e-6 / 0.197, rtol=1e-12)
    # predictions outside the valid set are projected into it: softening beyond monotone, bias too stiff
    bad = np.array([np.log(1e-4), np.log(1e-5), np.log(5e-3), -0.9, 0.0, 0.0])
    fixed = est.params_from_targets(bad, s, 0.2)
    assert bool(validity(FabricParams.make(**fixed)))
    assert fixed["bend_k2_warp"] * KAPPA_RANGE / fixed["bend_k1_warp"] == pytest.approx(est.R_MIN)


def _measurement(sil: np.ndarray, density, angle):
    from drapejax.io import Measurement

    return Measurement(path=None, test="cusick", specimen_radius_m=0.15, disk_radius_m=0.09,
                       areal_density_kg_m2=density, warp_angle_deg=angle, tag=None, silhouette=sil,
                       silhouette_extent_m=EXTENT, height=None, height_extent_m=None, photo=None, photo_marker=None,
                       scan_vertices=None, scan_faces=None, extra={})


def _tiny_model(key, tmp_path, stretch_input: bool) -> est.InverseModel:
    k1, k2 = jax.random.split(key)
    ae = SilhouetteAutoencoder(N, (4, 4, 8, 8, 8, 8), latent=16, key=k1)
    ns = 6 if stretch_input else 0
    params = np.array([[example_params(n).to_dict()[k] for k in PARAM_KEYS] for n in ("light", "mid", "heavy")])
    y_norm = Standardizer.fit(jnp.asarray(est.targets_from_params(params)))
    s_in = est.stretch_inputs_from_params(params)
    s_norm = Standardizer.fit(jnp.asarray(s_in)) if stretch_input else Standardizer.identity(0)
    net = InverseNet("2ds", MLPRegressor(16, 6, n_stretch=ns, hidden=(8,), key=k2), s_norm, y_norm, encoder=ae,
                     x_norm=Standardizer.identity(16))
    meta = {"method": "2ds", "stretch_input": stretch_input, "size": N, "grid_extent_m": EXTENT,
            "source_size": 256, "source_extent_m": EXTENT,
            "stretch_median": np.median(s_in, axis=0).tolist(), "augment": "rotation"}
    est.InverseModel(net, meta).save(tmp_path / "tiny.eqx")
    return est.InverseModel.load(tmp_path / "tiny.eqx")


@pytest.mark.parametrize("stretch_input", [False, True])
def test_estimate_no_refine_returns_si_params(key, tmp_path, stretch_input):
    model = _tiny_model(key, tmp_path, stretch_input)
    sil = (_ellipse(100, 80, n=256) > 0.5).astype(np.uint8) * 255  # 256 px spec silhouette, resampled to 64
    out = model.estimate_no_refine(_measurement(sil, 0.2, None), tta=4)
    assert list(out["params"]) == list(PARAM_KEYS) and out["density_normalized"] is False
    check(FabricParams.from_dict(out["params"]))
    assert out["stretch_source"] == "prior_median" and out["seconds"] > 0
    assert "unknown" in out["orientation"]
    known = model.estimate_no_refine(_measurement(sil, None, 30.0))
    assert known["density_normalized"] is True and known["orientation"] == "known"
    assert set(known["params"]) == {f"bend_k{i}_{d}_per_density" for i in (1, 2) for d in est.DIRECTIONS} | {
        f"stretch_alpha_{d}_per_density" for d in est.DIRECTIONS} | {f"stretch_beta_{d}" for d in est.DIRECTIONS}
    given = {k: v for k, v in example_params("heavy").to_dict().items() if k.startswith("stretch")}
    with_s = model.estimate_no_refine(_measurement(sil, 0.2, 0.0), stretch=given)
    assert with_s["stretch_source"] == "given"
    assert with_s["params"]["stretch_alpha_warp"] == pytest.approx(given["stretch_alpha_warp"])
    with pytest.raises(est.EstimateError, match="needs a silhouette"):
        model.estimate_no_refine(_measurement(None, 0.2, 0.0))


def test_estimate_on_real_measurement(key, tmp_path, shared_data):
    io = pytest.importorskip("drapejax.io")
    folder = sorted((shared_data / "real_cusick").iterdir())[0]
    m = io.load_measurement(folder)
    model = _tiny_model(key, tmp_path, False)
    out = model.estimate_no_refine(m, tta=2)
    assert out["density_normalized"] == (m.areal_density_kg_m2 is None)
    assert all(math.isfinite(v) for v in out["params"].values())
    # scan only: the silhouette is rendered from the mesh and lands on nearly the same input
    scan_only = dataclasses.replace(m, silhouette=None, height=None)
    transforms = model._transforms(None, 2)
    from_png, from_scan = model.observations(m, transforms), model.observations(scan_only, transforms)
    assert np.abs(from_png - from_scan).mean() < 0.02


def test_estimate_reads_a_folder_with_only_a_point_cloud_or_only_a_photo(key, tmp_path, single_observation):
    """The format allows a measurement with any one observation. A folder holding only a
    point-cloud scan, or only a photo (rendered from a real scan, tilted 8°), is estimated, and
    the network sees nearly the input the stored silhouette gives."""
    from drapejax import io

    m, cloud, photo = single_observation
    alone = [io.load_measurement(cloud), io.load_measurement(photo)]
    assert alone[0].scan_faces is None and alone[0].silhouette is None and alone[1].photo is not None
    model = _tiny_model(key, tmp_path, False)
    transforms = model._transforms(None, 2)
    ref = model.observations(m, transforms)
    for a in alone:
        assert np.abs(model.observations(a, transforms) - ref).mean() < 0.02, a.path
        assert all(math.isfinite(x) for x in model.estimate_no_refine(a, tta=2)["params"].values())


def _turned(vertices, deg: float) -> np.ndarray:
    """Scan vertices turned counter-clockwise by ``deg`` about the vertical axis."""
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.asarray(vertices, float) @ np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]])


def test_packaged_models_are_picked_by_observation_and_the_scan_model_ignores_the_turn(shared_data,
                                                                                       single_observation):
    """A measurement with a scan mesh gets the packaged 3DH model, one without (a point cloud) the 2DS
    model. The rotation-invariant 3DH estimate of a real scan barely moves when the scan is turned
    by 40°, and stays inside the range of its training set."""
    from drapejax import io

    m, cloud, _ = single_observation
    model = est.InverseModel.for_measurement(m)
    assert model.method == "3dh" and model.meta["phase_harmonics"] == 0
    assert est.InverseModel.for_measurement(io.load_measurement(cloud)).method == "2ds"
    out = model.estimate_no_refine(m)
    assert out["method"] == "3dh" and out["outside_training_range"] == []
    v = _turned(m.scan_vertices, 40.0)
    turned = model.estimate_no_refine(dataclasses.replace(m, scan_vertices=v))
    for k in ("bend_k1_warp", "bend_k1_weft", "bend_k1_bias"):
        assert turned["params"][k] == pytest.approx(out["params"][k], rel=0.08), k  # held-out RMSE: 0.37-0.62 in log


def test_buckling_picks_the_scan_models_trained_with_the_cap(single_observation):
    """``buckling=True`` (the start of a fit with the capped membrane) reads a scan with the 3DH
    models trained on capped drapes: invariant without a recorded warp angle, oriented with one,
    as blind to a 40° turn as the default model; without a scan mesh it is still the 2DS model."""
    from drapejax import io

    m, cloud, _ = single_observation
    model = est.InverseModel.for_measurement(m, buckling=True)
    assert model.method == "3dh" and model.meta["phase_harmonics"] == 0
    oriented = est.InverseModel.for_measurement(dataclasses.replace(m, warp_angle_deg=0.0), buckling=True)
    assert oriented.meta["phase_harmonics"] == est.PHASE_HARMONICS
    assert est.InverseModel.for_measurement(io.load_measurement(cloud), buckling=True).method == "2ds"
    out = model.estimate_no_refine(m)
    default = est.InverseModel.for_measurement(m).estimate_no_refine(m)
    keys = ("bend_k1_warp", "bend_k1_weft", "bend_k1_bias")
    assert max(abs(math.log(out["params"][k] / default["params"][k])) for k in keys) > 0.01  # another model
    turned = model.estimate_no_refine(dataclasses.replace(m, scan_vertices=_turned(m.scan_vertices, 40.0)))
    for k in keys:
        assert turned["params"][k] == pytest.approx(out["params"][k], rel=0.08), k


def test_a_recorded_warp_angle_picks_the_oriented_scan_model_which_turns_with_the_warp(shared_data):
    """With the warp angle recorded, a scan mesh gets the 3DH model with the hem's phases. Its
    estimate is the same when the drape and its recorded warp are turned together by 40°, and
    changes when the drape turns under a warp still recorded at 0°: it reads the drape in the
    material frame."""
    from drapejax import io

    m = dataclasses.replace(io.load_measurement(sorted((shared_data / "real_cusick").iterdir())[0]),
                            warp_angle_deg=0.0)
    model = est.InverseModel.for_measurement(m)
    assert model.method == "3dh" and model.meta["phase_harmonics"] == est.PHASE_HARMONICS
    out = model.estimate_no_refine(m)
    assert out["orientation"] == "known"
    v = _turned(m.scan_vertices, 40.0)
    turned = model.estimate_no_refine(dataclasses.replace(m, scan_vertices=v, warp_angle_deg=40.0))
    misread = model.estimate_no_refine(dataclasses.replace(m, scan_vertices=v))  # warp still recorded at 0°
    keys = ("bend_k1_warp", "bend_k1_weft", "bend_k1_bias")
    for k in keys:
        assert turned["params"][k] == pytest.approx(out["params"][k], rel=0.01), k
    assert max(abs(math.log(misread["params"][k] / out["params"][k])) for k in keys) > 0.05


def test_estimates_beyond_the_training_range_are_clipped_and_named(key, tmp_path):
    model = _tiny_model(key, tmp_path, False)
    sil = (_ellipse(100, 80, n=256) > 0.5).astype(np.uint8) * 255
    free = model.estimate_no_refine(_measurement(sil, None, 0.0))
    y = np.log([free["params"][f"bend_k1_{d}_per_density"] for d in est.DIRECTIONS])
    lo, hi = np.full(6, -30.0), np.full(6, 10.0)
    hi[0] = y[0] - 1.0  # only the warp stiffness lies beyond the range
    model.meta["target_range"] = [lo.tolist(), hi.tolist()]
    out = model.estimate_no_refine(_measurement(sil, None, 0.0))
    assert out["outside_training_range"] == ["log_k1_warp_per_density"]
    assert out["params"]["bend_k1_warp_per_density"] == pytest.approx(math.exp(hi[0]), rel=1e-5)
    assert out["params"]["bend_k1_weft_per_density"] == pytest.approx(free["params"]["bend_k1_weft_per_density"])


def test_predict_targets_scores_a_batch_row_by_row(key, tmp_path):
    """The public batch prediction gives each row what the network gives it alone, takes one
    stretching input for all rows or one per row, and refuses a "+S" model without it."""
    model = _tiny_model(key, tmp_path, True)
    sils = [(_ellipse(100 - 10 * i, 80, n=256) > 0.5).astype(np.uint8) * 255 for i in range(3)]
    obs = np.stack([model.observations(_measurement(s, 0.2, 0.0), model._transforms(0.0, 1))[0] for s in sils])
    s = np.asarray(model.meta["stretch_median"])
    y = model.predict_targets(obs, s)
    assert y.shape == (3, 6) and np.ptp(y[:, 0]) > 0
    for i in range(3):
        np.testing.assert_allclose(model.predict_targets(obs[i:i + 1], s)[0], y[i], rtol=1e-5)
    np.testing.assert_allclose(model.predict_targets(obs, np.tile(s, (3, 1))), y, rtol=1e-6)
    with pytest.raises(est.EstimateError, match="stretching"):
        model.predict_targets(obs)
    model.meta["target_range"] = [(y.min(0) + 1e-3).tolist(), (y.max(0) + 1.0).tolist()]
    clipped, where = model.clip_to_training_range(y)
    assert where[:, 0].sum() == 1 and clipped[:, 0].min() == pytest.approx(y[:, 0].min() + 1e-3)


def test_several_specimens_of_one_fabric_give_the_mean_of_their_estimates(shared_data, tmp_path):
    """``drapejax estimate A B C --no-refine`` reads specimens of one fabric as one estimate: the
    mean of their log k1/ρ (each specimen's own estimate), with the spread between them; a
    specimen without the areal density the others give is one error that names it."""
    from drapejax import io

    dirs = sorted(p for p in (shared_data / "real_cusick").iterdir() if p.name.startswith("bdp_f01_"))[:3]
    r = subprocess.run([sys.executable, "-m", "drapejax.cli", "estimate", *map(str, dirs), "--no-refine", "--json",
                        "--no-mesh-bias"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    out = json.loads(r.stdout)
    ms = [io.load_measurement(d) for d in dirs]
    model = est.InverseModel.load(est.InverseModel.amortised_checkpoint_for(ms[0]))  # what --no-refine reads with
    assert out["checkpoint"] == model.checkpoint
    singles = [model.estimate_no_refine(m, mesh_bias=False) for m in ms]
    corrected = model.estimate_specimens(ms)  # the mean, then the network's calibrated stiffness bias divided out
    assert out["mesh_bias"] is None and corrected["mesh_bias"]["factor"] > 1.0
    for key, value in out["params"].items():
        if key.startswith("bend_k1_"):
            assert corrected["params"][key] == pytest.approx(value / corrected["mesh_bias"]["factor"], rel=1e-9)
    assert out["specimens"] == 3 and not out["outside_training_range"]
    suffix = "_per_density" if out["density_normalized"] else ""
    rho = [1.0 if suffix else m.areal_density_kg_m2 for m in ms]
    for d in ("warp", "weft"):
        key = f"bend_k1_{d}{suffix}"
        logs = [math.log(s["params"][key] / r_) for s, r_ in zip(singles, rho)]
        assert out["params"][key] == pytest.approx(np.mean(rho) * math.exp(np.mean(logs)), rel=1e-9)
        assert out["target_sd_between_specimens"][f"log_k1_{d}_per_density"] == pytest.approx(np.std(logs, ddof=1))
    assert out["target_sd_between_specimens"]["log_k1_warp_per_density"] > 0  # the specimens differ
    if ms[0].areal_density_kg_m2 is not None:
        with pytest.raises(est.EstimateError, match="areal_density_kg_m2 missing"):
            model.estimate_specimens([ms[0], dataclasses.replace(ms[1], areal_density_kg_m2=None)])
