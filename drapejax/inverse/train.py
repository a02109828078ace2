"""Training, evaluation, augmentation and checkpoints of the inverse-map networks.

``fit`` is the one generic loop (optax Adam, a jit-compiled step, early stopping on a
validation split, best-validation weights returned); ``train_autoencoder`` and
``train_regressor`` are the two recipes of seed 001 §6.2 built on it; ``fit_ridge`` is the
closed-form linear alternative (the packaged 3DH model). ``evaluate`` reports R²
per target (1 − SSE/SST, then averaged, as in seed 001's tables) and RMSE on standardised
targets.

Augmentation and the drape's symmetries (world frame of the measurement spec: x = warp,
y = weft, images with column ~ +x and row 0 = +y):

- Rotation by 180° and the mirrors about the warp and the weft axes map a drape of an
  orthotropic fabric to a drape of the SAME parameters: the simulated material has no
  bending/twist coupling and equal ±45° bias, and the specimen, disc and gravity are
  symmetric. ``"symmetry"`` augments with these (labels unchanged).
- A mirror about a diagonal, or a 90° rotation, swaps warp and weft: it is a drape of a
  DIFFERENT fabric (k_warp ↔ k_weft), so it is not a label-preserving augmentation, and a
  general mirror is not either. Real twills also break the ±45° mirror (left/right bias
  differ, seed 001 Fig. 11b), so even the axis mirrors are exact only for the simulator.
- ``"rotation"`` (uniform random in-plane rotation, plus the symmetry mirrors) trains an
  orientation-agnostic model for measurements whose warp angle is unknown (the real scans).
  Such a model cannot tell warp from weft from the drape alone; it learns the prior's
  convention (warp is usually the stiffer direction) and its warp/weft R² is lower.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, PRNGKeyArray, PyTree

from .nets import NETS, InverseNet, MLPRegressor, SilhouetteAutoencoder

AUGMENT_MODES = ("none", "symmetry", "rotation")

CHECKPOINT_FORMAT = "drapejax-inverse-checkpoint/1"


class CheckpointError(ValueError):
    """A checkpoint file that is missing, malformed or does not match its JSON header."""


# --------------------------------------------------------------------------- augmentation


def rotate_images(images: Float[Array, "*b N N"], angle_rad: Float[Array, ""]) -> Float[Array, "*b N N"]:
    """Rotate square images counter-clockwise (in the world x-y frame) about their centre.

    Bilinear interpolation, zero outside the image. Column index grows with +x and row
    index with −y (measurement spec), so a positive angle turns +x towards +y.

    Args:
        images: (..., N, N) images sharing one rotation.
        angle_rad: rotation angle, radians.
    """
    n = images.shape[-1]
    ctr = (n - 1) / 2.0
    row, col = jnp.meshgrid(jnp.arange(n, dtype=float), jnp.arange(n, dtype=float), indexing="ij")
    x, y = col - ctr, ctr - row
    c, s = jnp.cos(angle_rad), jnp.sin(angle_rad)
    src_col = c * x + s * y + ctr
    src_row = ctr - (-s * x + c * y)
    flat = images.reshape((-1, n, n))
    out = jax.vmap(lambda im: jax.scipy.ndimage.map_coordinates(
        im, [src_row, src_col], order=1, mode="constant", cval=0.0))(flat)
    return out.reshape(images.shape).astype(images.dtype)


def canonical_curve(curve: Float[Array, "K 3"]) -> Float[Array, "K 3"]:
    """Order a closed boundary curve counter-clockwise starting at the smallest polar angle.

    Makes the 3DC input independent of how the loop was traversed, so rotated and mirrored
    curves stay comparable point by point. Points must already be uniformly spaced.
    """
    x, y = curve[:, 0], curve[:, 1]
    signed_area = 0.5 * jnp.sum(x * jnp.roll(y, -1) - jnp.roll(x, -1) * y)
    curve = jnp.where(signed_area < 0, curve[::-1], curve)
    angle = jnp.mod(jnp.arctan2(curve[:, 1], curve[:, 0]), 2 * jnp.pi)
    k = curve.shape[0]
    return curve[(jnp.arange(k) + jnp.argmin(angle)) % k]


def rotate_curves(curve: Float[Array, "K 3"], angle_rad: Float[Array, ""]) -> Float[Array, "K 3"]:
    """Rotate a boundary curve about z by ``angle_rad`` (counter-clockwise) and re-canonicalise."""
    c, s = jnp.cos(angle_rad), jnp.sin(angle_rad)
    rot = jnp.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]], dtype=curve.dtype)
    return canonical_curve(curve @ rot.T)


def _draws(key: PRNGKeyArray, b: int, mode: str):
    if mode not in AUGMENT_MODES:
        raise ValueError(f"unknown augmentation {mode!r}; choose from {AUGMENT_MODES}")
    k1, k2, k3 = jax.random.split(key, 3)
    flip_x = jax.random.bernoulli(k1, 0.5, (b,))
    flip_y = jax.random.bernoulli(k2, 0.5, (b,))
    angle = jax.random.uniform(k3, (b,), maxval=2 * jnp.pi) if mode == "rotation" else jnp.zeros(b)
    return flip_x, flip_y, angle


def augment_images(key: PRNGKeyArray, images: Float[Array, "b c N N"], mode: str) -> Float[Array, "b c N N"]:
    """Random label-preserving transform of each image of a batch (see module docstring)."""
    if mode == "none":
        return images
    flip_x, flip_y, angle = _draws(key, images.shape[0], mode)

    def one(im, fx, fy, a):
        im = jnp.where(fx, im[..., ::-1], im)
        im = jnp.where(fy, im[..., ::-1, :], im)
        return rotate_images(im, a) if mode == "rotation" else im

    return jax.vmap(one)(images, flip_x, flip_y, angle)


def augment_curves(key: PRNGKeyArray, curves: Float[Array, "b K 3"], mode: str) -> Float[Array, "b K 3"]:
    """Random label-preserving transform of each boundary curve of a batch."""
    if mode == "none":
        return curves
    flip_x, flip_y, angle = _draws(key, curves.shape[0], mode)

    def one(c, fx, fy, a):
        sign = jnp.stack([jnp.where(fx, -1.0, 1.0), jnp.where(fy, -1.0, 1.0), jnp.ones(())])
        return rotate_curves(c * sign.astype(c.dtype)[None, :], a)

    return jax.vmap(one)(curves, flip_x, flip_y, angle)


# --------------------------------------------------------------------------- training loop


def _batches(tree: tuple, idx: np.ndarray):
    return tuple(np.asarray(a[idx]) for a in tree)


def fit(model: PyTree, loss_fn: Callable[[PyTree, tuple], Array], data: Sequence[np.ndarray], *,
        key: PRNGKeyArray, epochs: int = 100, batch: int = 64, lr: float = 1e-3,
        val_data: Sequence[np.ndarray] | None = None, val_fraction: float = 0.1, patience: int = 10,
        augment: Callable[[PRNGKeyArray, tuple], tuple] | None = None,
        log: Callable[[str], None] | None = None) -> tuple[PyTree, dict]:
    """Minimise ``loss_fn(model, batch)`` with Adam; early-stop on a validation split.

    Args:
        model: equinox model; all its floating arrays are trained.
        loss_fn: mean loss of a batch tuple (same structure as ``data``).
        data: tuple of arrays with a common leading axis n.
        key: PRNG key for the split, shuffling and augmentation.
        epochs: maximum number of passes over the training split.
        batch: minibatch size (the last incomplete batch of an epoch is dropped).
        lr: Adam learning rate.
        val_data: explicit validation tuple; else ``val_fraction`` of ``data`` is held out.
        patience: stop after this many epochs without a better validation loss.
        augment: ``augment(key, batch) -> batch`` applied inside the jit-compiled step.
        log: called with one line per epoch.

    Returns:
        (the model with the lowest validation loss, history dict with per-epoch
        ``train_loss``/``val_loss``, ``best_epoch``, ``best_val_loss``, ``seconds``).
    """
    t0 = time.perf_counter()
    data = tuple(np.asarray(a) for a in data)
    n = len(data[0])
    key, k_split = jax.random.split(key)
    if val_data is None:
        n_val = max(1, int(round(val_fraction * n)))
        if n - n_val < 1:
            raise ValueError(f"fit: {n} samples are too few for a validation split of {val_fraction}")
        perm = np.asarray(jax.random.permutation(k_split, n))
        val_data = _batches(data, perm[:n_val])
        data = _batches(data, perm[n_val:])
    val_data = tuple(np.asarray(a) for a in val_data)
    n_train, n_val = len(data[0]), len(val_data[0])
    batch = min(batch, n_train)
    import optax  # training only; reading a checkpoint does not need it

    optim = optax.adam(lr)
    opt_state = optim.init(eqx.filter(model, eqx.is_inexact_array))

    @eqx.filter_jit
    def step(model, opt_state, b, k):
        if augment is not None:
            b = augment(k, b)
        loss, grads = eqx.filter_value_and_grad(loss_fn)(model, b)
        updates, opt_state = optim.update(grads, opt_state, eqx.filter(model, eqx.is_inexact_array))
        return eqx.apply_updates(model, updates), opt_state, loss

    eval_loss = eqx.filter_jit(loss_fn)

    def val_loss(model):
        total = 0.0
        for i in range(0, n_val, batch):
            b = tuple(a[i:i + batch] for a in val_data)
            total += float(eval_loss(model, b)) * len(b[0])
        return total / n_val

    best_model, best_loss, best_epoch = model, val_loss(model), 0
    hist_train, hist_val = [], []
    for epoch in range(1, epochs + 1):
        key, k_perm = jax.random.split(key)
        perm = np.asarray(jax.random.permutation(k_perm, n_train))
        losses = []
        for i in range(0, n_train - batch + 1, batch):
            key, k_step = jax.random.split(key)
            model, opt_state, loss = step(model, opt_state, _batches(data, perm[i:i + batch]), k_step)
            losses.append(loss)
        hist_train.append(float(np.mean(jnp.stack(losses))))
        hist_val.append(val_loss(model))
        if hist_val[-1] < best_loss:
            best_model, best_loss, best_epoch = model, hist_val[-1], epoch
        if log is not None:
            log(f"epoch {epoch:4d}  train {hist_train[-1]:.4g}  val {hist_val[-1]:.4g}  "
                f"best {best_loss:.4g}@{best_epoch}")
        if epoch - best_epoch >= patience:
            break
    history = {"train_loss": hist_train, "val_loss": hist_val, "best_epoch": best_epoch,
               "best_val_loss": best_loss, "seconds": time.perf_counter() - t0}
    return best_model, history


def _mse(pred, y):
    return jnp.mean((pred - y.astype(pred.dtype)) ** 2)


def train_autoencoder(images: Float[np.ndarray, "n 1 N N"], *, key: PRNGKeyArray, epochs: int = 100,
                      batch: int = 64, lr: float = 1e-3, channels=(8, 16, 32, 32, 64, 64),
                      latent: int = 512, augment: str = "none", patience: int = 10,
                      val_fraction: float = 0.1, log: Callable[[str], None] | None = None) -> SilhouetteAutoencoder:
    """Train the seed 001 autoencoder with a pixel MSE reconstruction loss.

    Args:
        images: (n, 1, N, N) images with values in [0, 1] (N a power of two ≥ 64).
        key: PRNG key (initialisation, split, shuffling, augmentation).
        epochs, batch, lr: Adam schedule (seed 001: 100 epochs, batch 64, lr 1e-3).
        channels, latent: architecture (see ``SilhouetteAutoencoder``).
        augment: "none", "symmetry" or "rotation" (module docstring).
    """
    images = np.asarray(images)
    if images.ndim != 4 or images.shape[1] != 1 or images.shape[2] != images.shape[3]:
        raise ValueError(f"train_autoencoder: images must be (n, 1, N, N), got {images.shape}")
    k_init, k_fit = jax.random.split(key)
    ae = SilhouetteAutoencoder(images.shape[-1], channels, latent, key=k_init)

    def loss(model, b):
        (x,) = b
        return _mse(jax.vmap(model)(x), x)

    aug = None if augment == "none" else (lambda k, b: (augment_images(k, b[0], augment),))
    ae, _ = fit(ae, loss, (images,), key=k_fit, epochs=epochs, batch=batch, lr=lr, augment=aug,
                patience=patience, val_fraction=val_fraction, log=log)
    return ae


def train_regressor(features: np.ndarray, targets: Float[np.ndarray, "n t"], *, key: PRNGKeyArray,
                    stretch: Float[np.ndarray, "n s"] | None = None, model: eqx.Module | None = None,
                    hidden=(512, 512), epochs: int = 100, batch: int = 64, lr: float = 1e-3,
                    val_data: tuple | None = None, val_fraction: float = 0.1, patience: int = 10,
                    augment: Callable[[PRNGKeyArray, Array], Array] | None = None,
                    log: Callable[[str], None] | None = None) -> tuple[eqx.Module, dict]:
    """Fit ``model(x, s) -> y`` to standardised targets with an MSE loss (seed 001 §6.2).

    Args:
        features: (n, ...) regressor inputs (standardised latents, depth views or curves).
        targets: (n, t) standardised targets.
        key: PRNG key.
        stretch: (n, s) standardised stretching inputs for "+S", else None.
        model: network to train (DepthCNN, CurveMLP, ...); default a fresh ``MLPRegressor``
            with ``hidden`` layers on flat features.
        val_data: optional explicit (features, stretch, targets) validation tuple.
        augment: ``augment(key, features) -> features`` applied to each training batch.

    Returns:
        (trained model, fit history).
    """
    features, targets = np.asarray(features), np.asarray(targets)
    n = len(features)
    stretch = np.zeros((n, 0), features.dtype) if stretch is None else np.asarray(stretch)
    if len(targets) != n or len(stretch) != n:
        raise ValueError(f"train_regressor: features ({n}), stretch ({len(stretch)}) and targets "
                         f"({len(targets)}) must have the same number of samples")
    k_init, k_fit = jax.random.split(key)
    if model is None:
        model = MLPRegressor(int(np.prod(features.shape[1:])), targets.shape[1], n_stretch=stretch.shape[1],
                             hidden=hidden, key=k_init)

    def loss(m, b):
        x, s, y = b
        return _mse(jax.vmap(m)(x, s), y)

    aug = None if augment is None else (lambda k, b: (augment(k, b[0]), b[1], b[2]))
    return fit(model, loss, (features, stretch, targets), key=k_fit, epochs=epochs, batch=batch, lr=lr,
               val_data=val_data, val_fraction=val_fraction, patience=patience, augment=aug, log=log)


def fit_ridge(features: Float[np.ndarray, "n d"], targets: Float[np.ndarray, "n t"], *,
              stretch: Float[np.ndarray, "n s"] | None = None,
              alphas: Sequence[float] = tuple(np.logspace(-3, 3, 13))) -> tuple[MLPRegressor, dict]:
    """Closed-form ridge regression as a linear ``MLPRegressor`` (no hidden layer).

    Each target's penalty is chosen from ``alphas`` by efficient leave-one-out cross-validation
    (scikit-learn ``RidgeCV``). Inputs and targets should already be standardised, so one
    penalty per target suits every feature.

    Returns:
        (the linear regressor, ``{"alpha": [chosen penalty per target], "best_epoch": None}``).
    """
    from sklearn.linear_model import RidgeCV

    x = np.asarray(features, float).reshape(len(features), -1)
    s = np.zeros((len(x), 0)) if stretch is None else np.asarray(stretch, float)
    xs = np.concatenate([x, s], axis=1)
    ridge = RidgeCV(alphas=np.asarray(alphas, float), alpha_per_target=True).fit(xs, np.asarray(targets, float))
    model = MLPRegressor(x.shape[1], targets.shape[1], n_stretch=s.shape[1], hidden=(), key=jax.random.PRNGKey(0))
    layer = model.layers[0]
    layer = eqx.tree_at(lambda lin: (lin.weight, lin.bias), layer,
                        (jnp.asarray(ridge.coef_, layer.weight.dtype), jnp.asarray(ridge.intercept_, layer.bias.dtype)))
    model = eqx.tree_at(lambda m: m.layers, model, (layer,))
    return model, {"alpha": np.atleast_1d(ridge.alpha_).tolist(), "best_epoch": None}


# --------------------------------------------------------------------------- evaluation


@eqx.filter_jit
def _vmapped(model, *inputs):
    return jax.vmap(model)(*inputs)


def predict(model: Callable, *inputs: np.ndarray, batch: int = 256) -> np.ndarray:
    """``vmap(model)(*inputs)`` evaluated in chunks of ``batch`` samples, as NumPy."""
    n = len(inputs[0])
    out = [np.asarray(_vmapped(model, *(np.asarray(a[i:i + batch]) for a in inputs)))
           for i in range(0, n, batch)]
    return np.concatenate(out, axis=0)


def r2_rmse(pred: Float[np.ndarray, "n t"], y: Float[np.ndarray, "n t"]) -> dict:
    """R² (1 − SSE/SST per target, then the mean) and RMSE (per target and overall)."""
    pred, y = np.asarray(pred, float), np.asarray(y, float)
    sse = np.sum((pred - y) ** 2, axis=0)
    sst = np.sum((y - y.mean(axis=0, keepdims=True)) ** 2, axis=0)
    r2 = 1.0 - sse / np.maximum(sst, 1e-300)
    rmse = np.sqrt(sse / len(y))
    return {"r2": {"per_target": r2.tolist(), "mean": float(np.mean(r2))},
            "rmse": {"per_target": rmse.tolist(), "mean": float(np.sqrt(np.mean((pred - y) ** 2)))}}


def evaluate(model: Callable, X: np.ndarray | tuple, Y: Float[np.ndarray, "n t"], *, batch: int = 256) -> dict:
    """R² and RMSE of ``model`` on standardised targets ``Y``.

    Args:
        model: per-sample callable; ``X`` is its input array, or a tuple of its positional inputs.
        Y: (n, t) standardised targets.

    Returns:
        ``{"r2": {"per_target": [...], "mean": float}, "rmse": {"per_target": [...], "mean": float}}``.
    """
    X = X if isinstance(X, tuple) else (X,)
    return r2_rmse(predict(model, *X, batch=batch), Y)


# --------------------------------------------------------------------------- checkpoints


def _header_path(path: Path) -> Path:
    return path.with_suffix(".json")


def save(path: str | Path, model: eqx.Module, meta: dict, *, weights_dtype=None) -> Path:
    """Write ``model`` weights to ``path`` (equinox leaves) and a JSON header beside it.

    The header ``<path stem>.json`` holds the class and ``config()`` that rebuild the skeleton
    plus ``meta`` (target conventions, preprocessing, metrics: anything JSON-serialisable).
    ``weights_dtype`` (e.g. ``np.float32``: half the file of float64) stores the floating-point
    weights in that dtype; None keeps the model's (an exact round trip). ``load`` casts stored
    weights to the skeleton's dtype either way.
    """
    path = Path(path)
    if type(model).__name__ not in _LOADABLE:
        raise CheckpointError(f"{path}: cannot save a {type(model).__name__}; known: {sorted(_LOADABLE)}")
    path.parent.mkdir(parents=True, exist_ok=True)
    header = {"format": CHECKPOINT_FORMAT, "class": type(model).__name__, "config": model.config(),
              "meta": meta}
    _header_path(path).write_text(json.dumps(header, indent=1))
    if weights_dtype is not None:
        model = jax.tree.map(lambda a: a.astype(weights_dtype) if eqx.is_inexact_array(a) else a, model)
    eqx.tree_serialise_leaves(path, model)
    return path


def _load_as_skeleton_dtype(f, x):
    """Deserialise a leaf, casting stored floats (see ``save``'s ``weights_dtype``) to the skeleton's dtype.

    The skeleton holds shapes only (``jax.ShapeDtypeStruct``, from ``eqx.filter_eval_shape``): drawing its
    random initial weights would cost a compiled program per layer, all thrown away."""
    if isinstance(x, jax.ShapeDtypeStruct) or eqx.is_inexact_array(x):
        out = np.load(f)
        if out.shape != x.shape:
            raise ValueError(f"stored shape {out.shape}, expected {x.shape}")
        return jax.device_put(out.astype(x.dtype, copy=False))  # on the host: jnp casts compile a program each
    return eqx.default_deserialise_filter_spec(f, x)


def load(path: str | Path) -> tuple[eqx.Module, dict]:
    """Read a checkpoint written by ``save``; returns (model, meta)."""
    path = Path(path)
    hpath = _header_path(path)
    for p in (path, hpath):
        if not p.is_file():
            raise CheckpointError(f"{p}: checkpoint file not found")
    try:
        header = json.loads(hpath.read_text())
    except json.JSONDecodeError as e:
        raise CheckpointError(f"{hpath}: invalid JSON ({e.msg} at line {e.lineno})") from None
    if not isinstance(header, dict) or header.get("format") != CHECKPOINT_FORMAT:
        raise CheckpointError(f"{hpath}: 'format' must be {CHECKPOINT_FORMAT!r}")
    cls = _LOADABLE.get(header.get("class"))
    if cls is None:
        raise CheckpointError(f"{hpath}: unknown 'class' {header.get('class')!r}; known: {sorted(_LOADABLE)}")
    try:
        key = jax.ShapeDtypeStruct((2,), jnp.uint32)
        if cls is InverseNet:
            skeleton = eqx.filter_eval_shape(InverseNet.skeleton, header["config"], key=key)
        else:
            skeleton = eqx.filter_eval_shape(cls, **header["config"], key=key)
    except (KeyError, TypeError, ValueError) as e:
        raise CheckpointError(f"{hpath}: 'config' does not describe a {cls.__name__} ({e})") from None
    try:
        model = eqx.tree_deserialise_leaves(path, skeleton, filter_spec=_load_as_skeleton_dtype)
    except Exception as e:  # equinox/numpy raise various errors on a truncated or mismatched file
        raise CheckpointError(f"{path}: weights do not match the header {hpath.name} "
                              f"({type(e).__name__}: {e})") from None
    return model, header.get("meta", {})


_LOADABLE = {**NETS, "InverseNet": InverseNet}

__all__ = ["AUGMENT_MODES", "CheckpointError", "rotate_images", "canonical_curve", "rotate_curves", "fit_ridge",
           "augment_images", "augment_curves", "fit", "train_autoencoder", "train_regressor", "predict",
           "r2_rmse", "evaluate", "save", "load"]
