"""Equinox networks of the learned inverse map (drape observation → bending parameters).

Every network maps ONE sample (vmap for batches) and has the same regression signature
``net(x, s) -> y``: ``x`` is the drape observation (or its latent code), ``s`` the optional
stretching input of the "+S" variants of seed 001 (shape ``(0,)`` when unused) and ``y`` the
standardised bending targets. Each class records the keyword arguments that rebuild its
skeleton in ``config()`` so checkpoints (``drapejax.inverse.train.save``) carry only
hyper-parameters in JSON and the weights in equinox's leaf format.

- ``SilhouetteAutoencoder`` — seed 001 §6.2.2 (2DS): six 3×3 stride-1 convolutions, each
  followed by 2×2 max-pooling and ReLU, a linear layer to a 512-d latent, mirrored decoder.
- ``MLPRegressor`` — seed 001 §6.2: two hidden layers of 512 with ReLU on latent (+ stretch).
- ``DepthCNN`` — seed 000 (3DI): a ResNet-18-style network (BasicBlocks, GroupNorm instead
  of BatchNorm so the module stays stateless) on 1, 2 or 4 depth views stacked as channels.
- ``CurveMLP`` — Ju & Choi 2020 (3DC): an MLP on the flattened 3D boundary curve.
- 3DH (this package): an ``MLPRegressor`` on a fixed descriptor of the scan (hem harmonics
  and ring profiles, ``drapejax.inverse.estimate.harmonic_feature``); with no hidden layer it
  is the closed-form ridge regression of ``drapejax.inverse.train.fit_ridge``.
"""

from __future__ import annotations

import inspect
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, PRNGKeyArray


def _param_dtype(module: eqx.Module):
    """Floating dtype of a module's weights (inputs are cast to it)."""
    return jax.tree_util.tree_leaves(eqx.filter(module, eqx.is_inexact_array))[0].dtype


def _abstract(cls, *args, **kwargs):
    """Shape-only layer (no random draw, hence no compilation); ``_materialise`` fills it."""
    if "key" in inspect.signature(cls).parameters:
        kwargs = {**kwargs, "key": jax.random.PRNGKey(0)}
    return eqx.filter_eval_shape(lambda: cls(*args, **kwargs))


def _is_abstract(x) -> bool:
    return isinstance(x, jax.ShapeDtypeStruct)


def _materialise(tree, key: PRNGKeyArray):
    """Concrete parameters for the shape-only leaves of ``tree``, from ONE random draw.

    Kernels of convolutions and linear layers get He-uniform values (±√(6/fan_in)): equinox's
    default (±1/√fan_in) shrinks the signal ~2.5× per ReLU layer and starves the 13-layer
    autoencoder of gradient below Adam's epsilon. Biases are zero and norm scales one. A
    single draw keeps construction to one XLA compilation instead of one per layer shape.

    Under ``eqx.filter_eval_shape`` (the key is a tracer) the leaves stay shapes: that is how a
    checkpoint's skeleton is built, with no draw at all.
    """
    if isinstance(key, jax.core.Tracer):
        return tree
    leaves, treedef = jax.tree_util.tree_flatten_with_path(tree, is_leaf=_is_abstract)
    kernels = [leaf for _, leaf in leaves if _is_abstract(leaf) and leaf.ndim >= 2]
    total = sum(leaf.size for leaf in kernels)
    u = np.asarray(jax.random.uniform(key, (max(total, 1),), minval=-1.0, maxval=1.0))
    out, offset = [], 0
    for path, leaf in leaves:
        if not _is_abstract(leaf):
            out.append(leaf)
            continue
        name = getattr(path[-1], "name", "")
        if leaf.ndim >= 2:
            bound = math.sqrt(6.0 / math.prod(leaf.shape[1:]))
            value = bound * u[offset:offset + leaf.size].reshape(leaf.shape)
            offset += leaf.size
        elif name == "weight":
            value = np.ones(leaf.shape)
        elif name == "bias":
            value = np.zeros(leaf.shape)
        else:
            raise TypeError(f"_materialise: no initialiser for parameter {jax.tree_util.keystr(path)}")
        out.append(jnp.asarray(value, dtype=leaf.dtype))
    return jax.tree_util.tree_unflatten(treedef, out)


class Standardizer(eqx.Module):
    """Per-feature affine normalisation ``(x - mean) / std`` kept inside the model pytree.

    Attributes:
        mean: (d,) feature mean, in the feature's own units.
        std: (d,) feature standard deviation (positive).
    """

    mean: Float[Array, " d"]
    std: Float[Array, " d"]

    def __init__(self, mean: Float[Array, " d"], std: Float[Array, " d"]):
        self.mean = jnp.asarray(mean)
        self.std = jnp.asarray(std)

    @classmethod
    def fit(cls, x: Float[Array, "n d"], *, min_std: float = 1e-6) -> "Standardizer":
        """Mean and std over the leading axis; near-constant features get std ``min_std``."""
        x = jnp.asarray(x)
        return cls(jnp.mean(x, axis=0), jnp.maximum(jnp.std(x, axis=0), min_std))

    @classmethod
    def identity(cls, size: int) -> "Standardizer":
        return cls(jnp.zeros(size), jnp.ones(size))

    def __call__(self, x: Float[Array, "*b d"]) -> Float[Array, "*b d"]:
        return (x - jnp.broadcast_to(self.mean, x.shape)) / jnp.broadcast_to(self.std, x.shape)

    def inverse(self, y: Float[Array, "*b d"]) -> Float[Array, "*b d"]:
        return y * jnp.broadcast_to(self.std, y.shape) + jnp.broadcast_to(self.mean, y.shape)

    @property
    def size(self) -> int:
        return self.mean.shape[0]


class SilhouetteAutoencoder(eqx.Module):
    """Convolutional autoencoder of a 1×N×N drape image (silhouette or height map), seed 001.

    Encoder: six [conv 3×3 stride 1 → max-pool 2×2 → ReLU] stages, then a linear layer to the
    latent. Decoder mirrors it: linear → six [nearest upsample ×2 → conv 3×3 (→ ReLU)] stages,
    with a sigmoid on the last one so reconstructions lie in [0, 1] like the inputs.

    Attributes:
        size: image side N in pixels (a power of two ≥ 64: six halvings must leave ≥ 1 px).
        channels: six encoder channel counts (the decoder uses them in reverse).
        latent: latent dimension (512 in seed 001).
    """

    enc_convs: tuple[eqx.nn.Conv2d, ...]
    enc_linear: eqx.nn.Linear
    dec_linear: eqx.nn.Linear
    dec_convs: tuple[eqx.nn.Conv2d, ...]
    size: int = eqx.field(static=True)
    channels: tuple[int, ...] = eqx.field(static=True)
    latent: int = eqx.field(static=True)

    def __init__(self, size: int = 128, channels=(8, 16, 32, 32, 64, 64), latent: int = 512, *,
                 key: PRNGKeyArray):
        channels = tuple(int(c) for c in channels)
        if len(channels) != 6:
            raise ValueError(f"SilhouetteAutoencoder: channels must list 6 layers, got {channels}")
        if size < 64 or size & (size - 1):
            raise ValueError(f"SilhouetteAutoencoder: size must be a power of two >= 64, got {size}")
        self.size, self.channels, self.latent = int(size), channels, int(latent)
        ins = (1,) + channels[:-1]
        flat = channels[-1] * self._bottleneck ** 2
        outs = channels[::-1][1:] + (1,)
        layers = (
            tuple(_abstract(eqx.nn.Conv2d, i, o, 3, padding=1) for i, o in zip(ins, channels)),
            _abstract(eqx.nn.Linear, flat, self.latent),
            _abstract(eqx.nn.Linear, self.latent, flat),
            tuple(_abstract(eqx.nn.Conv2d, i, o, 3, padding=1) for i, o in zip(channels[::-1], outs)),
        )
        self.enc_convs, self.enc_linear, self.dec_linear, self.dec_convs = _materialise(layers, key)

    @property
    def _bottleneck(self) -> int:
        return self.size // 2 ** 6

    def config(self) -> dict:
        return {"size": self.size, "channels": list(self.channels), "latent": self.latent}

    def encode(self, image: Float[Array, "1 N N"]) -> Float[Array, " latent"]:
        x = image.astype(_param_dtype(self))
        for conv in self.enc_convs:
            x = conv(x)
            c, h, w = x.shape
            x = jax.nn.relu(x.reshape(c, h // 2, 2, w // 2, 2).max(axis=(2, 4)))
        return self.enc_linear(x.reshape(-1))

    def decode_logits(self, z: Float[Array, " latent"]) -> Float[Array, "1 N N"]:
        b = self._bottleneck
        x = jax.nn.relu(self.dec_linear(z)).reshape(self.channels[-1], b, b)
        for i, conv in enumerate(self.dec_convs):
            x = conv(jnp.repeat(jnp.repeat(x, 2, axis=1), 2, axis=2))
            if i < len(self.dec_convs) - 1:
                x = jax.nn.relu(x)
        return x

    def decode(self, z: Float[Array, " latent"]) -> Float[Array, "1 N N"]:
        return jax.nn.sigmoid(self.decode_logits(z))

    def __call__(self, image: Float[Array, "1 N N"]) -> Float[Array, "1 N N"]:
        """Reconstruction of ``image`` (values in [0, 1])."""
        return self.decode(self.encode(image))


class MLPRegressor(eqx.Module):
    """Seed 001 bending regressor: MLP with ReLU hidden layers on [features, stretch].

    Attributes:
        in_size: feature size (the latent dimension for 2DS).
        out_size: number of targets.
        n_stretch: size of the stretching input (0 without "+S").
        hidden: hidden layer widths ((512, 512) in seed 001).
    """

    layers: tuple[eqx.nn.Linear, ...]
    in_size: int = eqx.field(static=True)
    out_size: int = eqx.field(static=True)
    n_stretch: int = eqx.field(static=True)
    hidden: tuple[int, ...] = eqx.field(static=True)

    def __init__(self, in_size: int, out_size: int, *, n_stretch: int = 0, hidden=(512, 512),
                 key: PRNGKeyArray):
        self.in_size, self.out_size, self.n_stretch = int(in_size), int(out_size), int(n_stretch)
        self.hidden = tuple(int(h) for h in hidden)
        sizes = (self.in_size + self.n_stretch,) + self.hidden + (self.out_size,)
        self.layers = _materialise(tuple(_abstract(eqx.nn.Linear, a, b) for a, b in zip(sizes[:-1], sizes[1:])), key)

    def config(self) -> dict:
        return {"in_size": self.in_size, "out_size": self.out_size, "n_stretch": self.n_stretch,
                "hidden": list(self.hidden)}

    def __call__(self, x: Float[Array, " in_size"], s: Float[Array, " n_stretch"]) -> Float[Array, " out_size"]:
        dt = _param_dtype(self)
        h = jnp.concatenate([x.reshape(-1).astype(dt), s.astype(dt)])
        for layer in self.layers[:-1]:
            h = jax.nn.relu(layer(h))
        return self.layers[-1](h)


class CurveMLP(MLPRegressor):
    """Ju & Choi 2020 (3DC): MLP on the flattened boundary curve (K, 3) in specimen radii.

    The original uses hidden layers (4096, 8192, 512); the default here is CPU-sized.
    """

    n_points: int = eqx.field(static=True)

    def __init__(self, n_points: int, out_size: int, *, n_stretch: int = 0, hidden=(256, 256, 128),
                 key: PRNGKeyArray):
        self.n_points = int(n_points)
        super().__init__(3 * self.n_points, out_size, n_stretch=n_stretch, hidden=hidden, key=key)

    def config(self) -> dict:
        return {"n_points": self.n_points, "out_size": self.out_size, "n_stretch": self.n_stretch,
                "hidden": list(self.hidden)}


def _groups(channels: int) -> int:
    return math.gcd(channels, 8)


class _BasicBlock(eqx.Module):
    """ResNet BasicBlock: two 3×3 convs with GroupNorm (or none), identity/1×1 shortcut.

    Built shape-only; the owning ``DepthCNN`` materialises its parameters.
    """

    conv1: eqx.nn.Conv2d
    conv2: eqx.nn.Conv2d
    norm1: eqx.nn.GroupNorm | None
    norm2: eqx.nn.GroupNorm | None
    shortcut: eqx.nn.Conv2d | None
    shortcut_norm: eqx.nn.GroupNorm | None

    def __init__(self, cin: int, cout: int, stride: int, norm: bool):
        self.conv1 = _abstract(eqx.nn.Conv2d, cin, cout, 3, stride=stride, padding=1, use_bias=not norm)
        self.conv2 = _abstract(eqx.nn.Conv2d, cout, cout, 3, padding=1, use_bias=not norm)
        self.norm1 = _abstract(eqx.nn.GroupNorm, _groups(cout), cout) if norm else None
        self.norm2 = _abstract(eqx.nn.GroupNorm, _groups(cout), cout) if norm else None
        needs_proj = stride != 1 or cin != cout
        self.shortcut = _abstract(eqx.nn.Conv2d, cin, cout, 1, stride=stride, use_bias=not norm) if needs_proj else None
        self.shortcut_norm = _abstract(eqx.nn.GroupNorm, _groups(cout), cout) if (needs_proj and norm) else None

    def __call__(self, x: Float[Array, "c h w"]) -> Float[Array, "c2 h2 w2"]:
        h = self.conv1(x)
        h = jax.nn.relu(self.norm1(h) if self.norm1 is not None else h)
        h = self.conv2(h)
        h = self.norm2(h) if self.norm2 is not None else h
        sc = x if self.shortcut is None else self.shortcut(x)
        sc = self.shortcut_norm(sc) if self.shortcut_norm is not None else sc
        return jax.nn.relu(h + sc)


class DepthCNN(eqx.Module):
    """ResNet-18-style regressor on depth views stacked as channels (seed 000, 3DI).

    Stem conv 3×3 stride 2 → max-pool 3×3 stride 2 → four stages of two BasicBlocks with
    widths (w, 2w, 4w, 8w), stride 2 at stages 2–4 → global average pool → concat stretch →
    MLP head.
    GroupNorm (``norm=True``) replaces BatchNorm so the module has no running state.

    Attributes:
        n_views: input channels (1, 2 or 4 depth views).
        out_size: number of targets.
        n_stretch: size of the stretching input (0 without "+S").
        width: channels of the first stage (64 in ResNet-18; small for CPU).
        head_hidden: width of the head's hidden layer.
        norm: GroupNorm after each convolution.
    """

    stem: eqx.nn.Conv2d
    stem_norm: eqx.nn.GroupNorm | None
    blocks: tuple[_BasicBlock, ...]
    head: MLPRegressor
    n_views: int = eqx.field(static=True)
    out_size: int = eqx.field(static=True)
    n_stretch: int = eqx.field(static=True)
    width: int = eqx.field(static=True)
    head_hidden: int = eqx.field(static=True)
    norm: bool = eqx.field(static=True)

    def __init__(self, n_views: int, out_size: int, *, n_stretch: int = 0, width: int = 8,
                 head_hidden: int = 128, norm: bool = True, key: PRNGKeyArray):
        self.n_views, self.out_size, self.n_stretch = int(n_views), int(out_size), int(n_stretch)
        self.width, self.head_hidden, self.norm = int(width), int(head_hidden), bool(norm)
        k_body, k_head = jax.random.split(key)
        w = self.width
        stem = _abstract(eqx.nn.Conv2d, self.n_views, w, 3, stride=2, padding=1, use_bias=not norm)
        stem_norm = _abstract(eqx.nn.GroupNorm, _groups(w), w) if norm else None
        widths = (w, w, 2 * w, 2 * w, 4 * w, 4 * w, 8 * w, 8 * w)
        blocks, cin = [], w
        for i, cout in enumerate(widths):
            blocks.append(_BasicBlock(cin, cout, 2 if (i % 2 == 0 and i > 0) else 1, norm))
            cin = cout
        self.stem, self.stem_norm, self.blocks = _materialise((stem, stem_norm, tuple(blocks)), k_body)
        self.head = MLPRegressor(8 * w, self.out_size, n_stretch=self.n_stretch, hidden=(self.head_hidden,),
                                 key=k_head)

    def config(self) -> dict:
        return {"n_views": self.n_views, "out_size": self.out_size, "n_stretch": self.n_stretch,
                "width": self.width, "head_hidden": self.head_hidden, "norm": self.norm}

    def __call__(self, views: Float[Array, "n_views S S"], s: Float[Array, " n_stretch"]) -> Float[Array, " out_size"]:
        h = self.stem(views.astype(_param_dtype(self)))
        h = jax.nn.relu(self.stem_norm(h) if self.stem_norm is not None else h)
        h = eqx.nn.MaxPool2d(3, stride=2, padding=1)(h)
        for block in self.blocks:
            h = block(h)
        return self.head(jnp.mean(h, axis=(1, 2)), s)


class InverseNet(eqx.Module):
    """Observation (+ stretching) → bending targets, with all normalisations inside.

    For the image methods (2DS silhouettes, 3DD height maps) ``encoder`` is a trained
    ``SilhouetteAutoencoder`` whose latent is standardised by ``x_norm`` before the
    ``MLPRegressor``; for 3DH the fixed descriptor of ``estimate.harmonic_feature`` is
    standardised by ``x_norm``; for 3DI/3DC the regressor reads the preprocessed observation
    directly (``encoder`` and ``x_norm`` are None).

    Attributes:
        encoder: autoencoder for image methods, else None.
        regressor: MLPRegressor, DepthCNN or CurveMLP.
        x_norm: standardisation of the latent (image methods) or descriptor (3DH), else None.
        s_norm: standardisation of the stretching input (size 0 without "+S").
        y_norm: standardisation of the targets.
        method: one of ``METHODS``.
    """

    encoder: SilhouetteAutoencoder | None
    regressor: eqx.Module
    x_norm: Standardizer | None
    s_norm: Standardizer
    y_norm: Standardizer
    method: str = eqx.field(static=True)

    def __init__(self, method: str, regressor: eqx.Module, s_norm: Standardizer, y_norm: Standardizer,
                 encoder: SilhouetteAutoencoder | None = None, x_norm: Standardizer | None = None):
        if method not in METHODS:
            raise ValueError(f"InverseNet: unknown method {method!r}; choose from {METHODS}")
        if (encoder is None) != (method not in IMAGE_METHODS):
            raise ValueError(f"InverseNet: method {method!r} needs an encoder exactly when it is one of "
                             f"{IMAGE_METHODS}")
        if (x_norm is None) != (method not in IMAGE_METHODS + FEATURE_METHODS):
            raise ValueError(f"InverseNet: method {method!r} needs x_norm exactly when it is one of "
                             f"{IMAGE_METHODS + FEATURE_METHODS}")
        self.method, self.regressor, self.s_norm, self.y_norm = method, regressor, s_norm, y_norm
        self.encoder, self.x_norm = encoder, x_norm

    def config(self) -> dict:
        return {
            "method": self.method,
            "regressor": {"class": type(self.regressor).__name__, "config": self.regressor.config()},
            "encoder": None if self.encoder is None else self.encoder.config(),
            "n_stretch": self.s_norm.size,
            "n_targets": self.y_norm.size,
        }

    @classmethod
    def skeleton(cls, config: dict, *, key: PRNGKeyArray) -> "InverseNet":
        """An untrained InverseNet with the structure described by ``config()``."""
        k1, k2 = jax.random.split(key)
        reg = NETS[config["regressor"]["class"]](**config["regressor"]["config"], key=k1)
        enc = None if config["encoder"] is None else SilhouetteAutoencoder(**config["encoder"], key=k2)
        x_norm = None
        if enc is not None:
            x_norm = Standardizer.identity(enc.latent)
        elif config["method"] in FEATURE_METHODS:
            x_norm = Standardizer.identity(config["regressor"]["config"]["in_size"])
        return cls(config["method"], reg, Standardizer.identity(config["n_stretch"]),
                   Standardizer.identity(config["n_targets"]), encoder=enc, x_norm=x_norm)

    def features(self, obs: Array) -> Array:
        """Regressor input of one preprocessed observation (the standardised latent for images)."""
        x = obs if self.encoder is None else self.encoder.encode(obs)
        return x if self.x_norm is None else self.x_norm(x)

    def __call__(self, obs: Array, s_raw: Float[Array, " n_stretch"]) -> Float[Array, " n_targets"]:
        """Raw (de-standardised) targets of one preprocessed observation and stretching input."""
        return self.y_norm.inverse(self.regressor(self.features(obs), self.s_norm(s_raw)))


METHODS = ("2ds", "3dd", "3di", "3dc", "3dh")
IMAGE_METHODS = ("2ds", "3dd")
FEATURE_METHODS = ("3dh",)
"""Methods whose regressor reads a fixed, hand-made descriptor (standardised by ``x_norm``)."""

NETS = {c.__name__: c for c in (SilhouetteAutoencoder, MLPRegressor, CurveMLP, DepthCNN)}
"""Classes whose skeleton ``cls(**config, key=...)`` rebuilds from ``config()``."""

__all__ = ["Standardizer", "SilhouetteAutoencoder", "MLPRegressor", "CurveMLP", "DepthCNN",
           "InverseNet", "METHODS", "IMAGE_METHODS", "FEATURE_METHODS", "NETS"]
