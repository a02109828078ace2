"""Train one inverse-map input method on a generated dataset (seed 001 Table 2, seed 000 views).

    python -m experiments.train_inverse data.dir=DATASET net=2ds_s
    python -m experiments.train_inverse data.dir=DATASET net=2ds augment=rotation +export=drapejax/data/inverse_2ds.eqx
    python -m experiments.train_inverse +experiment=table2 data.dir=DATASET   # every method, ±S
    python -m experiments.train_inverse +experiment=views data.dir=DATASET    # 3DI with 1/2/4 views

DATASET is a directory written by ``drapejax.inverse.dataset.generate``. Prints one JSON line
{"method", "n_train", "r2_train", "r2_val", "rmse_train", "rmse_val", "seconds", ...}, also
written to ``result.json`` in the Hydra run directory (and appended to ``results`` when that
path is set); returns the validation R² (for Hydra sweepers).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import hydra
import jax
import jax.numpy as jnp
import numpy as np
from omegaconf import DictConfig, OmegaConf

from drapejax.inverse import estimate as est
from drapejax.inverse.dataset import OBSERVATION_SETTINGS
from drapejax.inverse.nets import FEATURE_METHODS, IMAGE_METHODS, CurveMLP, DepthCNN, InverseNet, Standardizer
from drapejax.inverse.train import (augment_curves, augment_images, evaluate, fit_ridge, predict, r2_rmse,
                                    train_autoencoder, train_regressor)
from drapejax.mesh import CUSICK_RADIUS_M

if __package__:  # python -m experiments.train_inverse
    from .common import K1_COLUMNS, harmonic_features, harmonic_meta, load_dataset, split
else:  # python experiments/train_inverse.py
    from common import K1_COLUMNS, harmonic_features, harmonic_meta, load_dataset, split


def observations(net: DictConfig, data: dict, meta: dict) -> np.ndarray:
    """Preprocessed network inputs of every sample (the estimator's conventions); fills ``meta``."""
    method = net.method
    if method in IMAGE_METHODS:
        name = "silhouette" if method == "2ds" else "height"
        src_extent = OBSERVATION_SETTINGS[name]["extent_m"]
        feature = est.silhouette_feature if method == "2ds" else est.height_feature
        meta.update(size=int(net.size), grid_extent_m=float(net.grid_extent_m),
                    source_size=int(data[name].shape[-1]), source_extent_m=float(src_extent))
        return np.stack([est.image_to_grid(feature(im), src_extent, size=meta["size"],
                                           grid_extent_m=meta["grid_extent_m"]) for im in data[name]])[:, None]
    if method == "3di":
        depth = data["depth4"]
        fg = depth[np.isfinite(depth) & (depth > 0)]
        near, far = float(fg.min()), float(fg.max())
        meta.update(views=list(net.views), depth_near_m=near, depth_far_m=far + 0.1 * (far - near),
                    depth_size=int(depth.shape[-1]))
        return np.stack([est.depth_feature(d, meta["views"], meta["depth_near_m"], meta["depth_far_m"]) for d in depth])
    meta.update(n_points=int(data["boundary"].shape[1]), specimen_radius_m=CUSICK_RADIUS_M)
    if method == "3dh":
        meta.update(harmonic_meta(data, int(net.phase_harmonics)))
        return harmonic_features(data, meta)
    return np.stack([est.curve_feature(b, CUSICK_RADIUS_M) for b in data["boundary"]])


def encode(ae, images: np.ndarray, *, key, augment: str, copies: int) -> tuple[np.ndarray, np.ndarray]:
    """Latents of ``copies`` randomly transformed versions of each image (1 untransformed copy
    for ``augment="none"``); returns (latents (n·copies, d), sample index of each row)."""
    copies = 1 if augment == "none" else copies
    transform = jax.jit(lambda k, x: augment_images(k, x, augment))
    zs, idx = [], []
    for c in range(copies):
        for i in range(0, len(images), 256):
            x = images[i:i + 256]
            if augment != "none":
                x = np.asarray(transform(jax.random.fold_in(key, c * len(images) + i), jnp.asarray(x)))
            zs.append(predict(ae.encode, x))
            idx.append(np.arange(i, i + len(x)))
    return np.concatenate(zs), np.concatenate(idx)


def run(cfg: DictConfig) -> dict:
    """Train and evaluate the configured method; returns the result record (and exports)."""
    t0 = time.perf_counter()
    net, tr = cfg.net, cfg.train
    augment = str(cfg.augment)
    if net.method in ("3di", "3dh") and augment != "none":
        raise ValueError(f"augment={augment!r}: in-plane augmentation of oblique depth views and of the 3DH "
                         f"descriptor is not implemented; use augment=none for {net.method.upper()}")
    data = load_dataset(cfg.data.dir, cfg.data.max_samples)
    n = len(data["params"])
    meta = {"method": str(net.method), "stretch_input": bool(net.stretch), "augment": augment,
            "target_names": list(est.TARGET_NAMES), "stretch_input_names": list(est.STRETCH_INPUT_NAMES),
            "dataset": str(Path(cfg.data.dir).resolve())}
    obs = observations(net, data, meta)
    y = est.targets_from_params(data["params"])
    s_raw = est.stretch_inputs_from_params(data["params"])
    val, train = split(n, cfg.data.val_fraction, cfg.data.seed)
    meta["stretch_median"] = np.median(s_raw[train], axis=0).tolist()
    meta["target_range"] = [y[train].min(axis=0).tolist(), y[train].max(axis=0).tolist()]
    y_norm = Standardizer.fit(jnp.asarray(y[train]))
    s_norm = Standardizer.fit(jnp.asarray(s_raw[train])) if net.stretch else Standardizer.identity(0)
    ys = np.asarray(y_norm(jnp.asarray(y)))
    ss = np.asarray(s_norm(jnp.asarray(s_raw))) if net.stretch else np.zeros((n, 0), np.float32)
    key = jax.random.PRNGKey(tr.seed)
    k_ae, k_enc, k_reg, k_model = jax.random.split(key, 4)
    log = print if cfg.verbose else None

    if net.method in IMAGE_METHODS:
        ae = train_autoencoder(obs[train], key=k_ae, epochs=tr.ae.epochs, batch=tr.ae.batch, lr=tr.ae.lr,
                               channels=tuple(net.channels), latent=net.latent, augment=augment,
                               patience=tr.ae.patience, log=log)
        z_tr, rows = encode(ae, obs[train], key=k_enc, augment=augment, copies=cfg.augment_copies)
        z_val, vrows = encode(ae, obs[val], key=jax.random.fold_in(k_enc, 1), augment=augment, copies=1)
        x_norm = Standardizer.fit(jnp.asarray(z_tr))
        x_tr, x_val = np.asarray(x_norm(jnp.asarray(z_tr))), np.asarray(x_norm(jnp.asarray(z_val)))
        tr_idx, val_idx = train[rows], val[vrows]
        reg, hist = train_regressor(x_tr, ys[tr_idx], stretch=ss[tr_idx], key=k_reg, hidden=tuple(net.hidden),
                                    epochs=tr.reg.epochs, batch=tr.reg.batch, lr=tr.reg.lr,
                                    val_data=(x_val, ss[val_idx], ys[val_idx]), patience=tr.reg.patience, log=log)
        model = InverseNet(net.method, reg, s_norm, y_norm, encoder=ae, x_norm=x_norm)
    elif net.method in FEATURE_METHODS:
        x_norm = Standardizer.fit(jnp.asarray(obs[train]))
        xs = np.asarray(x_norm(jnp.asarray(obs)))
        x_tr, x_val, tr_idx, val_idx = xs[train], xs[val], train, val
        if len(net.hidden):
            reg, hist = train_regressor(x_tr, ys[train], stretch=ss[train], key=k_reg, hidden=tuple(net.hidden),
                                        epochs=tr.reg.epochs, batch=tr.reg.batch, lr=tr.reg.lr,
                                        val_data=(x_val, ss[val], ys[val]), patience=tr.reg.patience, log=log)
        else:
            reg, hist = fit_ridge(x_tr, ys[train], stretch=ss[train])
            meta["ridge_alpha"] = hist["alpha"]
        model = InverseNet(net.method, reg, s_norm, y_norm, x_norm=x_norm)
    else:
        if net.method == "3di":
            model0 = DepthCNN(len(net.views), y.shape[1], n_stretch=ss.shape[1], width=net.width,
                              head_hidden=net.head_hidden, norm=net.norm, key=k_model)
            aug = None
        else:
            model0 = CurveMLP(obs.shape[1], y.shape[1], n_stretch=ss.shape[1], hidden=tuple(net.hidden), key=k_model)
            aug = None if augment == "none" else (lambda k, x: augment_curves(k, x, augment))
        x_tr, x_val, tr_idx, val_idx = obs[train], obs[val], train, val
        if aug is not None:  # validate on transformed copies, as the model will be used
            x_val = np.asarray(aug(jax.random.fold_in(k_enc, 2), jnp.asarray(x_val)))
        reg, hist = train_regressor(x_tr, ys[tr_idx], stretch=ss[tr_idx], key=k_reg, model=model0,
                                    epochs=tr.reg.epochs, batch=tr.reg.batch, lr=tr.reg.lr,
                                    val_data=(x_val, ss[val_idx], ys[val_idx]), patience=tr.reg.patience,
                                    augment=aug, log=log)
        model = InverseNet(net.method, reg, s_norm, y_norm)

    m_tr = evaluate(reg, (x_tr, ss[tr_idx]), ys[tr_idx])
    pred_val = predict(reg, x_val, ss[val_idx])
    m_val = r2_rmse(pred_val, ys[val_idx])
    # Overall stiffness (mean log k1/rho over the three directions): identifiable even where the
    # warp/weft split is not (unknown orientation, fold noise).
    overall = lambda a: np.asarray(y_norm.inverse(jnp.asarray(a)))[:, K1_COLUMNS].mean(axis=1, keepdims=True)
    m_overall = r2_rmse(overall(pred_val), overall(ys[val_idx]))
    result = {
        "method": (net.method.upper() + ("+S" if net.stretch else "")
                   + (f"-{len(net.views)}v" if net.method == "3di" else "")
                   + ("-inv" if net.method == "3dh" and not net.phase_harmonics else "")),
        "n_train": int(len(train)), "n_val": int(len(val)),
        "r2_train": m_tr["r2"]["mean"], "r2_val": m_val["r2"]["mean"],
        "rmse_train": m_tr["rmse"]["mean"], "rmse_val": m_val["rmse"]["mean"],
        "r2_val_per_target": dict(zip(est.TARGET_NAMES, m_val["r2"]["per_target"])),
        "r2_val_log_k1_mean_per_density": m_overall["r2"]["mean"],
        "augment": augment, "best_epoch": hist["best_epoch"], "seconds": time.perf_counter() - t0,
    }
    meta["metrics"] = result
    if cfg.get("export"):
        est.InverseModel(model, meta).save(cfg.export, weights_dtype=np.float32)  # shipped: half the size
        result["export"] = str(Path(cfg.export).resolve())
    return result


@hydra.main(version_base=None, config_path="../configs", config_name="train_inverse")
def main(cfg: DictConfig) -> float:
    if cfg.verbose:
        print(OmegaConf.to_yaml(cfg))
    result = run(cfg)
    line = json.dumps(result)
    print(line)
    out_dir = Path(hydra.core.hydra_config.HydraConfig.get().runtime.output_dir)
    (out_dir / "result.json").write_text(line + "\n")
    if cfg.results:
        with open(cfg.results, "a") as f:
            f.write(line + "\n")
    return result["r2_val"]


if __name__ == "__main__":
    main()
