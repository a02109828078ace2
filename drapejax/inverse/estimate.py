"""Amortised estimate of bending parameters from one drape measurement (no refinement).

Target convention (both seeds): stiffness is divided by the areal density and log-scaled, so
the network never needs the density:

    y = [log(k1_warp/ρ), log(k1_weft/ρ), log(k1_bias/ρ), r_warp, r_weft, r_bias]

with k1/ρ in m³/s² and the dimensionless softening ratio r_d = k2_d·KAPPA_RANGE/k1_d
(the bending law stays monotone for r > −1/2). The optional "+S" input is the stretching
vector s = [log(α_warp/ρ), log(α_weft/ρ), log(α_bias/ρ), β_warp, β_weft, β_bias] with α/ρ in
m²/s² (``material.to_log_targets``, ``to_log_stretch`` and back ``from_log_targets``).
Standardisation of y and s is stored inside the checkpointed ``InverseNet``.

Observations are brought to the training grid (``image_to_grid``) in the canonical frame
(warp along +x). When the warp angle is unknown the estimate is averaged over ``tta`` equally
spaced in-plane rotations (test-time augmentation); when it is known it is averaged over the
exact symmetries of an orthotropic drape (identity, both axis mirrors, 180°).
"""

from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path

import cv2
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Float

from ..material import (DIRECTIONS, LOG_STRETCH_NAMES, LOG_TARGET_NAMES, STRETCH_KEYS, FabricParams, check,
                        from_log_stretch, from_log_targets, to_log_stretch, to_log_targets)
from ..mesh_bias import bending_length_mm, correct, default_bias
from ..photo import photo_silhouette
from .nets import IMAGE_METHODS, InverseNet
from .train import canonical_curve, load, save

TARGET_NAMES = LOG_TARGET_NAMES
STRETCH_INPUT_NAMES = LOG_STRETCH_NAMES
HEIGHT_DEPTH_M = 0.08
"""Height maps enter 3DD as (z + HEIGHT_DEPTH_M)/HEIGHT_DEPTH_M clipped to [0, 1], 0 = no fabric:
the 6 cm overhang of the Cusick specimen cannot hang lower than z = −0.06 m; 2 cm of margin."""
R_MIN = -0.49
"""Lower clip of predicted r = k2·KAPPA_RANGE/k1: keeps the bending law monotone (r > −1/2)."""
_DATA = Path(__file__).resolve().parents[1] / "data"
DEFAULT_CHECKPOINT = _DATA / "inverse_2ds.eqx"
"""The packaged 2DS model: any top view, photo, point cloud or scan mesh."""
SCAN_CHECKPOINT = _DATA / "inverse_3dh.eqx"
"""The packaged rotation-invariant 3DH model, for a scan mesh whose warp angle was not recorded."""
ORIENTED_SCAN_CHECKPOINT = _DATA / "inverse_3dh_oriented.eqx"
"""The packaged 3DH model with the hem's phases (``phase_harmonics`` 5), for a scan mesh whose warp
angle is known: the phases tell warp from weft, which the invariant descriptor leaves to the prior."""
BUCKLING_SCAN_CHECKPOINTS = {False: _DATA / "inverse_3dh_buckling.eqx",
                             True: _DATA / "inverse_3dh_oriented_buckling.eqx"}
"""The two 3DH models (warp angle unknown / known) trained on drapes of the fit mesh with the
membrane's compression capped (``energy.Membrane(buckling=True)``), which fold as converged ones
do: on drapes of a uniform 5 mm mesh they explain 0.86 / 0.91 of the overall stiffness's variance,
where the default ones, trained on uniform 15 mm drapes, read them 0.2-0.9 too stiff in log
(``docs/results/2026-11-29-inverse-training-datasets.md``, the buckling-model section)."""


class EstimateError(ValueError):
    """A measurement that the inverse model cannot use; the message names the missing input."""


# --------------------------------------------------------------------------- targets


def targets_from_params(params: Float[np.ndarray, "n 13"]) -> Float[np.ndarray, "n 6"]:
    """Network targets (``TARGET_NAMES``) of parameter rows in ``PARAM_KEYS`` order (SI):
    ``material.to_log_targets``."""
    return to_log_targets(params)


def stretch_inputs_from_params(params: Float[np.ndarray, "n 13"]) -> Float[np.ndarray, "n 6"]:
    """"+S" stretching inputs (``STRETCH_INPUT_NAMES``) of parameter rows in ``PARAM_KEYS`` order:
    ``material.to_log_stretch``."""
    return to_log_stretch(params)


def _stretch_inputs_from_dict(stretch: dict, density: float) -> np.ndarray:
    missing = [k for k in STRETCH_KEYS if k not in stretch]
    if missing:
        raise EstimateError(f"stretching estimate lacks {missing}")
    return to_log_stretch(stretch, density)


def params_from_targets(y: Float[np.ndarray, "6"], s: Float[np.ndarray, "6"], density: float | None) -> dict:
    """Parameter dict of targets ``y`` and stretching inputs ``s``, valid by construction.

    ``material.from_log_targets`` with r clipped to ``R_MIN`` and k1_bias to 0.99 of the largest
    value compatible with a positive-definite plate (``drapejax.material.validity``); both limits
    are invariant under the density scaling, so they are applied before it.

    Args:
        y: targets in ``TARGET_NAMES`` order.
        s: stretching inputs in ``STRETCH_INPUT_NAMES`` order.
        density: areal density in kg/m², or None for density-normalised output.

    Returns:
        With a density: the flat SI schema (``PARAM_KEYS``), checked by ``material.check``.
        Without: ``bend_k1_<d>_per_density`` (m³/s²), ``bend_k2_<d>_per_density`` (m⁴/s²),
        ``stretch_alpha_<d>_per_density`` (m²/s²) and ``stretch_beta_<d>``.
    """
    vals = from_log_targets(y, s, density, r_min=R_MIN, bias_fraction=0.99)
    if density is not None:
        check(FabricParams.make(**vals), source="estimate")
    return vals


# --------------------------------------------------------------------------- preprocessing


def _rot(deg: float) -> np.ndarray:
    a = math.radians(deg)
    return np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])


def image_to_grid(image: Float[np.ndarray, "M M"], extent_m: float, *, size: int, grid_extent_m: float,
                  transform: Float[np.ndarray, "2 2"] | None = None) -> Float[np.ndarray, "size size"]:
    """Resample a top-view image onto the network grid, optionally transformed in-plane.

    Both grids follow the measurement spec (x, y in [−extent, extent], column ~ +x, row 0 at
    +y). The output at world point p shows the input at ``transform⁻¹ p`` (so ``transform``
    maps the measured drape into the canonical frame). Bilinear, zero outside; when the input
    is finer than the output it is rendered at a multiple of the resolution and area-averaged.

    Args:
        image: (M, M) float image (silhouette in [0, 1], or a height feature).
        extent_m: half side of the input image, m.
        size: output side N, px.
        grid_extent_m: half side of the output grid, m.
        transform: 2×2 world-frame map (rotation/mirror); identity when None.
    """
    image = np.asarray(image, np.float32)
    m = image.shape[0]
    a_inv = np.linalg.inv(np.eye(2) if transform is None else np.asarray(transform, float))
    q = max(1, math.ceil((2 * grid_extent_m / size) / (2 * extent_m / m) - 1e-9))
    n = size * q
    # destination pixel (c, r) -> world (x, y) -> source world -> source pixel (c_s, r_s)
    hd, hs = 2 * grid_extent_m / n, 2 * extent_m / m
    dst_to_world = np.array([[hd, 0.0, -grid_extent_m + 0.5 * hd], [0.0, -hd, grid_extent_m - 0.5 * hd]])
    world_to_src = np.array([[1 / hs, 0.0, extent_m / hs - 0.5], [0.0, -1 / hs, extent_m / hs - 0.5]])
    lin = world_to_src[:, :2] @ a_inv
    affine = np.concatenate([lin @ dst_to_world[:, :2],
                             (lin @ dst_to_world[:, 2] + world_to_src[:, 2])[:, None]], axis=1)
    out = cv2.warpAffine(image, affine, (n, n), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
    if q > 1:
        out = cv2.resize(out, (size, size), interpolation=cv2.INTER_AREA)
    return out


def silhouette_feature(silhouette: np.ndarray) -> Float[np.ndarray, "M M"]:
    """Silhouette (uint8 0/255 or bool) as a float image in [0, 1]."""
    sil = np.asarray(silhouette)
    return (sil > 0).astype(np.float32) if sil.dtype == bool else sil.astype(np.float32) / 255.0


def height_feature(height: np.ndarray) -> Float[np.ndarray, "M M"]:
    """Height map z (m, NaN = no fabric) as the 3DD image (z + 0.08 m)/0.08 m in [0, 1], 0 = empty."""
    h = np.asarray(height, np.float32)
    f = np.clip((h + HEIGHT_DEPTH_M) / HEIGHT_DEPTH_M, 0.0, 1.0)
    return np.where(np.isfinite(h), f, 0.0).astype(np.float32)


def depth_feature(depth: Float[np.ndarray, "V S S"], views, near_m: float, far_m: float) -> Float[np.ndarray, "v S S"]:
    """Selected depth views (``drapejax.observe.depth_views``: m, background 0) as images in [0, 1].

    Fabric maps to (far − d)/(far − near), clipped, so nearer fabric is brighter; background
    stays 0. ``near_m``/``far_m`` are the depth range of the training set.
    """
    d = np.asarray(depth, np.float32)[list(views)]
    f = np.clip((far_m - d) / (far_m - near_m), 0.0, 1.0)
    return np.where(np.isfinite(d) & (d > 0), f, 0.0).astype(np.float32)


def curve_feature(boundary: Float[np.ndarray, "K 3"], specimen_radius_m: float) -> Float[np.ndarray, "K 3"]:
    """Boundary curve in specimen radii, counter-clockwise from the smallest polar angle."""
    return np.asarray(canonical_curve(jnp.asarray(boundary, float) / specimen_radius_m), np.float32)


HARMONICS = 16
"""3DH: amplitudes of harmonics 0..HARMONICS-1 of the hem's radius and height."""
PHASE_HARMONICS = 5
"""3DH default: real and imaginary parts of harmonics 0..PHASE_HARMONICS-1 (they carry the warp direction)."""
RINGS = 12
"""3DH: number of rings (support edge to ``ring_outer_m``) of the top view's height and coverage profiles."""


def harmonic_feature(boundary: Float[np.ndarray, "K 3"], height: Float[np.ndarray, "M M"], height_extent_m: float,
                     *, specimen_radius_m: float, ring_inner_m: float, ring_outer_m: float,
                     phase_harmonics: int = PHASE_HARMONICS) -> Float[np.ndarray, " d"]:
    """3DH descriptor of one drape: hem harmonics and ring profiles of the top view.

    - the hem's radius r(s) and height z(s) (``boundary`` resampled uniformly by arc length from
      polar angle 0, as ``observe.boundary_curve`` returns it), in specimen radii: amplitudes of
      harmonics 0..``HARMONICS``-1 (unchanged by an in-plane rotation), then the real and
      imaginary parts of harmonics 0..``phase_harmonics``-1, which carry the warp direction
      (0: a rotation-invariant descriptor, for scans whose warp angle is unknown);
    - the height map (NaN off the fabric, counted as 0) averaged over ``RINGS`` rings of equal
      width from ``ring_inner_m`` (the support's edge) to ``ring_outer_m``, and the fraction of
      each ring the fabric covers. The clamped part is left out: a real one is flat, while a
      simulated one sags by micrometres in a way a regression can latch onto.
    """
    b = np.asarray(boundary, float) / specimen_radius_m
    c = np.fft.rfft(np.stack([np.hypot(b[:, 0], b[:, 1]), b[:, 2]]), axis=1) / len(b)
    h = np.asarray(height, float)
    n = h.shape[-1]
    centre = (np.arange(n) - n / 2 + 0.5) * (2 * height_extent_m / n)
    radius = np.hypot(*np.meshgrid(centre, centre)).ravel()
    ring = ((radius - ring_inner_m) / (ring_outer_m - ring_inner_m) * RINGS).astype(int)
    inside = (radius >= ring_inner_m) & (ring < RINGS)
    count = np.maximum(np.bincount(ring[inside], minlength=RINGS), 1)
    profile = lambda w: np.bincount(ring[inside], weights=w.ravel()[inside], minlength=RINGS) / count  # noqa: E731
    return np.concatenate([np.abs(c[:, :HARMONICS]).ravel(), c[:, :phase_harmonics].real.ravel(),
                           c[:, :phase_harmonics].imag.ravel(), profile(np.nan_to_num(h, nan=0.0)),
                           profile(np.isfinite(h).astype(float))]).astype(np.float32)


# --------------------------------------------------------------------------- the estimator


@eqx.filter_jit
def _predict_batch(net: InverseNet, obs, s):
    return jax.vmap(net)(obs, s)


class InverseModel:
    """Trained inverse map: ``InverseNet`` + the preprocessing and target conventions in ``meta``.

    ``meta`` keys: ``method`` ("2ds", "3dd", "3di", "3dc", "3dh"), ``stretch_input`` (bool, "+S"),
    ``size``/``grid_extent_m`` (image grid), ``source_size``/``source_extent_m`` (grid of the
    training renders, used for scan-only input and 3DH's height map),
    ``views``/``depth_near_m``/``depth_far_m``/``depth_size`` (3DI), ``n_points``/``specimen_radius_m``
    (3DC, 3DH), ``ring_inner_m``/``ring_outer_m``/``phase_harmonics`` (3DH), ``stretch_median`` (the
    median stretching input of the training set, i.e. of the prior it was sampled from), ``augment``,
    optionally ``target_range`` ([per-target minima, maxima] of the training targets).

    Args:
        net: the trained network.
        meta: conventions (as written by ``experiments/train_inverse.py``).
        stretch_knn: optional fitted ``drapejax.inverse.tags.StretchKNN``; used for the
            stretching estimate of measurements that carry a tag.
    """

    def __init__(self, net: InverseNet, meta: dict, stretch_knn=None):
        missing = [k for k in _META_KEYS[net.method] if k not in meta]
        if missing:
            raise EstimateError(f"InverseModel ({net.method}): meta lacks {missing}")
        self.net, self.meta, self.stretch_knn = net, dict(meta), stretch_knn
        self.checkpoint: str | None = None  # the packaged file's stem, which names its mesh-bias calibration

    @property
    def method(self) -> str:
        return self.net.method

    @classmethod
    def load(cls, path: str | Path, stretch_knn=None) -> "InverseModel":
        net, meta = load(path)
        if not isinstance(net, InverseNet):
            raise EstimateError(f"{path}: holds a {type(net).__name__}, not an InverseNet")
        model = cls(net, meta, stretch_knn)
        model.checkpoint = Path(path).stem
        return model

    @classmethod
    def load_default(cls, stretch_knn=None) -> "InverseModel":
        """The packaged 2DS model ``drapejax/data/inverse_2ds.eqx`` (+ ``inverse_2ds.json``)."""
        return cls.load(DEFAULT_CHECKPOINT, stretch_knn)

    @classmethod
    def for_measurement(cls, measurement, stretch_knn=None, buckling: bool = False) -> "InverseModel":
        """The packaged model best suited to ``measurement``: for a scan mesh a 3DH model (more
        accurate on simulated drapes, and more repeatable between drops of real ones; see
        ``docs/results/2026-11-28-inverse-3dh-descriptor.md``), the oriented one when the warp angle is
        known, the rotation-invariant one when it is not; without a scan mesh the 2DS model.
        ``buckling`` picks the 3DH models trained on drapes with the membrane's compression capped
        (``BUCKLING_SCAN_CHECKPOINTS``), the start that goes with a fit that caps it; the 2DS model is
        the same either way."""
        return cls.load(cls.checkpoint_for(measurement, buckling), stretch_knn)

    @staticmethod
    def checkpoint_for(measurement, buckling: bool = False) -> Path:
        """The packaged checkpoint ``for_measurement`` loads for ``measurement``."""
        if not measurement.has_scan_mesh:
            return DEFAULT_CHECKPOINT
        oriented = measurement.warp_angle_deg is not None
        if buckling:
            return BUCKLING_SCAN_CHECKPOINTS[oriented]
        return ORIENTED_SCAN_CHECKPOINT if oriented else SCAN_CHECKPOINT

    @staticmethod
    def amortised_checkpoint_for(measurement) -> Path:
        """The packaged checkpoint ``drapejax estimate --no-refine`` reads ``measurement`` with: for a
        scan mesh the 3DH model trained on drapes with the membrane's compression capped
        (``checkpoint_for(measurement, buckling=True)``), else the 2DS model. Those drapes fold as
        converged ones do, so on converged captures of fabrics left out of the calibration this
        model, bias-corrected, is the closest amortised estimate (6–8 % median error of the overall
        rigidity, against 16–21 % for the other 3DH models; on 12 drapes of Newton's Style3D 30 %
        against 34 %: ``docs/results/2026-12-07-mesh-bias.md``). The refinement's start stays
        ``checkpoint_for(measurement, buckling)``, since the fit's own bias calibration was made from it."""
        return InverseModel.checkpoint_for(measurement, buckling=True)

    def save(self, path: str | Path, *, weights_dtype=None) -> Path:
        """Write the network checkpoint (see ``train.save``; float32 weights halve the file)."""
        return save(path, self.net, self.meta, weights_dtype=weights_dtype)

    # ---------------------------------------------------------------- observations

    def _transforms(self, warp_angle_deg: float | None, tta: int) -> list[np.ndarray]:
        if warp_angle_deg is None:
            return [_rot(360.0 * k / tta) for k in range(tta)]
        canon = _rot(-float(warp_angle_deg))
        return [canon, np.diag([-1.0, 1.0]) @ canon, np.diag([1.0, -1.0]) @ canon, -canon]

    def _top_view(self, m) -> tuple[np.ndarray, float] | None:
        """(image feature, its half extent in m) of a measured top view (stored, else from a scanned
        point cloud or the rectified photo), or None when a scan mesh is to be rendered instead."""
        if self.method == "2ds" and m.silhouette is not None:
            return silhouette_feature(m.silhouette), m.silhouette_extent_m
        if self.method == "2ds" and m.height is not None:
            return np.isfinite(m.height).astype(np.float32), m.height_extent_m
        if self.method == "3dd" and m.height is not None:
            return height_feature(m.height), m.height_extent_m
        if m.has_scan_mesh:
            return None  # rendered from the scan mesh like the training data
        from .. import observe  # lazy, as in ``observations``

        ext = float(self.meta["source_extent_m"])
        if self.method in ("2ds", "3dd") and m.scan_vertices is not None:
            sil, h = observe.point_cloud_views(m.scan_vertices, n=int(self.meta["source_size"]), extent_m=ext)
            return (silhouette_feature(sil) if self.method == "2ds" else height_feature(h)), ext
        if self.method == "2ds" and getattr(m, "photo", None) is not None:
            return silhouette_feature(photo_silhouette(m, extent_m=ext)), ext
        return None

    def observations(self, measurement, transforms: list[np.ndarray]) -> np.ndarray:
        """Preprocessed network inputs of ``measurement``, one per world-frame transform.

        Top-view images are resampled; otherwise the scan mesh is turned by each transform
        and rendered with ``drapejax.observe`` exactly as the training data was.
        """
        m, meta = measurement, self.meta
        top = self._top_view(m) if self.method in IMAGE_METHODS else None
        if top is not None:
            return np.stack([image_to_grid(top[0], top[1], size=int(meta["size"]),
                                           grid_extent_m=float(meta["grid_extent_m"]), transform=a)
                             for a in transforms])[:, None]
        if not m.has_scan_mesh:
            raise EstimateError(f"{getattr(m, 'path', None) or 'measurement'}: method '{self.method}' needs "
                                f"{_NEEDS[self.method]}")
        from .. import observe  # lazy: renderers are only needed for scan input

        faces = np.asarray(m.scan_faces)

        def view(a: np.ndarray) -> np.ndarray:
            v = np.asarray(m.scan_vertices, float).copy()
            v[:, :2] = v[:, :2] @ np.asarray(a).T
            if self.method in IMAGE_METHODS:  # render like the training data, then resample
                n_src, ext_src = int(meta["source_size"]), float(meta["source_extent_m"])
                if self.method == "2ds":
                    img = silhouette_feature(observe.silhouette(v, faces, n=n_src, extent_m=ext_src))
                else:
                    img = height_feature(observe.height_map(v, faces, n=n_src, extent_m=ext_src))
                return image_to_grid(img, ext_src, size=int(meta["size"]),
                                     grid_extent_m=float(meta["grid_extent_m"]))[None]
            if self.method == "3di":
                depth = observe.depth_views(v, faces, n_views=4, size=int(meta["depth_size"]))
                return depth_feature(depth, meta["views"], float(meta["depth_near_m"]), float(meta["depth_far_m"]))
            boundary = observe.boundary_curve(v, faces, n_samples=int(meta["n_points"]))
            if self.method == "3dh":
                ext = float(meta["source_extent_m"])
                height = observe.height_map(v, faces, n=int(meta["source_size"]), extent_m=ext)
                return harmonic_feature(boundary, height, ext, specimen_radius_m=float(meta["specimen_radius_m"]),
                                        ring_inner_m=float(meta["ring_inner_m"]),
                                        ring_outer_m=float(meta["ring_outer_m"]),
                                        phase_harmonics=int(meta["phase_harmonics"]))
            return curve_feature(boundary, float(meta["specimen_radius_m"]))

        return np.stack([view(a) for a in transforms])

    # ---------------------------------------------------------------- estimate

    def _stretch(self, measurement, stretch: dict | None) -> tuple[np.ndarray, str, dict | None]:
        """The "+S" stretching inputs, their source and, when the measurement holds strip tensile
        readings, the record of the membrane they set (``refine.tensile.membrane_of_captures``,
        started from the tag kNN or prior median: the network then reads the drape at the measured
        membrane). Stretching ``given`` by the caller wins over the readings."""
        from ..refine.tensile import measured_membrane_std, membrane_of_captures

        rho = measurement.areal_density_kg_m2
        tag = getattr(measurement, "tag", None)
        if stretch is not None:
            if rho is None:
                raise EstimateError("a stretching estimate in N/m needs the areal density to be normalised")
            return _stretch_inputs_from_dict(stretch, rho), "given", None
        s, source = np.asarray(self.meta["stretch_median"], float), "prior_median"
        if tag and self.stretch_knn is not None:
            rho_tag = rho if rho is not None else (1e-3 * tag["density_gsm"] if tag.get("density_gsm") else None)
            if rho_tag is not None:
                s, source = _stretch_inputs_from_dict(self.stretch_knn.predict(tag), rho_tag), "tag_knn"
        start = FabricParams.make(density=1.0 if rho is None else rho, bend_k1_warp=1.0, bend_k1_weft=1.0,
                                  bend_k1_bias=1.0, **from_log_stretch(s, rho or 1.0))
        fitted, membrane = membrane_of_captures([measurement], start)
        if measured_membrane_std(membrane) is None:  # no reading, or left out
            return s, source, membrane
        return _stretch_inputs_from_dict({k: float(getattr(fitted, k)) for k in STRETCH_KEYS}, rho), "tensile", membrane

    def predict_targets(self, obs: Float[np.ndarray, "n ..."],
                        stretch: Float[np.ndarray, "6"] | Float[np.ndarray, "n 6"] | None = None
                        ) -> Float[np.ndarray, "n 6"]:
        """Targets (``TARGET_NAMES``) the network gives a batch of preprocessed inputs, unclipped.

        Args:
            obs: one row per drape, as ``observations`` or the training script's features give them.
            stretch: the "+S" stretching inputs (``STRETCH_INPUT_NAMES``), one for all rows or one
                per row; required when the model takes them, ignored otherwise.
        """
        obs = np.asarray(obs)
        if not self.meta["stretch_input"]:
            s = np.zeros((len(obs), 0), obs.dtype)
        elif stretch is None:
            raise EstimateError(f"InverseModel ({self.method}+s) needs the stretching inputs")
        else:
            s = np.broadcast_to(np.asarray(stretch, obs.dtype), (len(obs), len(STRETCH_INPUT_NAMES)))
        return np.asarray(_predict_batch(self.net, obs, s))

    def clip_to_training_range(self, y: Float[np.ndarray, "... 6"]) -> tuple[np.ndarray, np.ndarray]:
        """``y`` clipped to the range of the training targets (``meta["target_range"]``, where the
        checkpoint has it), and where it was clipped: no extrapolation past the prior the model saw."""
        y = np.asarray(y, float)
        if "target_range" not in self.meta:
            return y, np.zeros(y.shape, bool)
        lo, hi = (np.asarray(b, float) for b in self.meta["target_range"])
        return np.clip(y, lo, hi), (y < lo) | (y > hi)

    def estimate_no_refine(self, measurement, *, stretch: dict | None = None, tta: int = 8,
                           mesh_bias: bool = True) -> dict:
        """Amortised parameter estimate of one ``drapejax.io.Measurement``.

        Args:
            measurement: the drape measurement (silhouette, height map and/or scan).
            stretch: stretching parameters in SI (``STRETCH_KEYS``) to use instead of the
                tensile readings / tag kNN / prior median.
            tta: number of in-plane rotations averaged when the warp angle is unknown. With a
                model trained without ``augment=rotation`` this averaging mixes warp and weft;
                an orientation-agnostic model (the packaged one) keeps the prior's convention
                that warp is the stiffer direction.

        Returns:
            ``{"params": ..., "density_normalized": bool, "seconds": float, "method": str,
            "stretch_source": "given" | "tag_knn" | "prior_median" | "tensile", "membrane", "orientation":
            "known" | "unknown (averaged over N rotations)", "outside_training_range": [...]}``.
            ``membrane`` is null without tensile readings, else the record of the membrane they set
            (``refine.tensile.membrane_of_captures``: α per direction, its factor on the tag's or
            prior's, or why they were left out).
            ``params`` is the SI schema when the areal density is known, else density-normalised
            (see ``params_from_targets``). Targets beyond the range of the model's training set
            (``meta["target_range"]``, where the checkpoint has it) are clipped to it and named in
            ``outside_training_range``: the drape lies outside the prior the model has seen.
            ``mesh_bias``: see ``estimate_specimens``. ``checkpoint``: the packaged file's stem (which
            names its calibration), or None for a model not loaded from a file.
        """
        out = self.estimate_specimens([measurement], stretch=stretch, tta=tta, mesh_bias=mesh_bias)
        del out["specimens"], out["target_sd_between_specimens"]
        return out

    def estimate_specimens(self, measurements, *, stretch: dict | None = None, tta: int = 8,
                           mesh_bias: bool = True) -> dict:
        """One estimate from several specimens (or drops) of one fabric: the mean of their targets.

        A drape's fold pattern is set by small chances of the drop, and it moves a single drape's
        estimate (the "drop-seed noise" of ``docs/results/2026-11-29-inverse-training-datasets.md``);
        the mean over specimens averages that out. Stretching comes from the first measurement (its tag
        or ``stretch``); the areal density is the specimens' mean, and must be given for all of them or
        for none.

        The network learnt from drapes on meshes that are not converged, which drape lower than a
        converged drape at equal k1, so it reads k1 too stiff. With ``mesh_bias`` (and a packaged
        checkpoint calibrated in ``drapejax/data/mesh_bias.json``) k1 and k2 are divided by the
        checkpoint's calibrated factor at the estimated bending length (``mesh_bias.correct``), and
        the record is returned as ``mesh_bias`` (null otherwise); ``refine.estimate`` starts its fit
        from the uncorrected values, as its own calibration was made.

        Returns:
            ``estimate_no_refine``'s dictionary, with ``specimens`` (their number) and
            ``target_sd_between_specimens`` (per ``TARGET_NAMES``, the spread the mean averages).
        """
        t0 = time.perf_counter()
        ms = list(measurements)
        if not ms:
            raise EstimateError("estimate_specimens needs at least one measurement")
        rho = [m.areal_density_kg_m2 for m in ms]
        if len({r is None for r in rho}) > 1:
            missing = next(getattr(m, "path", None) or f"measurement {i}" for i, m in enumerate(ms) if rho[i] is None)
            raise EstimateError(f"{missing}: areal_density_kg_m2 missing, but other specimens give it; "
                                f"give it for all specimens or for none")
        density = None if rho[0] is None else float(np.mean(rho))
        s, source, membrane = self._stretch(dataclasses.replace(ms[0], areal_density_kg_m2=density), stretch)
        ys = np.stack([self.predict_targets(self.observations(m, self._transforms(m.warp_angle_deg, tta)), s).mean(0)
                       for m in ms])
        y, clipped = self.clip_to_training_range(ys.mean(0))
        outside = [name for name, c in zip(TARGET_NAMES, clipped) if c]
        params = params_from_targets(y, s, density)
        bias = default_bias(self.checkpoint) if mesh_bias and self.checkpoint else None
        bias_record = None
        if bias is not None:
            params, _, bias_record = correct(params, None, bending_length_mm(params), bias)
        known = all(m.warp_angle_deg is not None for m in ms)
        sd = ys.std(0, ddof=1) if len(ms) > 1 else np.zeros(len(TARGET_NAMES))
        return {"params": params, "density_normalized": density is None,
                "seconds": time.perf_counter() - t0,
                "method": self.method + ("+s" if self.meta["stretch_input"] else ""), "stretch_source": source,
                "membrane": membrane, "orientation": "known" if known else f"unknown (averaged over {tta} rotations)",
                "outside_training_range": outside, "checkpoint": self.checkpoint, "mesh_bias": bias_record,
                "specimens": len(ms),
                "target_sd_between_specimens": dict(zip(TARGET_NAMES, sd.tolist()))}


_NEEDS = {"2ds": "a silhouette, a height map, a photo or a scan", "3dd": "a height map or a scan",
          "3di": "a scan mesh (scan.file with faces)", "3dc": "a scan mesh (scan.file with faces)",
          "3dh": "a scan mesh (scan.file with faces)"}
_COMMON_META = ("stretch_input", "stretch_median")
_META_KEYS = {
    "2ds": _COMMON_META + ("size", "grid_extent_m", "source_size", "source_extent_m"),
    "3dd": _COMMON_META + ("size", "grid_extent_m", "source_size", "source_extent_m"),
    "3di": _COMMON_META + ("views", "depth_near_m", "depth_far_m", "depth_size"),
    "3dc": _COMMON_META + ("n_points", "specimen_radius_m"),
    "3dh": _COMMON_META + ("n_points", "specimen_radius_m", "source_size", "source_extent_m", "ring_inner_m",
                           "ring_outer_m", "phase_harmonics"),
}

__all__ = ["DIRECTIONS", "TARGET_NAMES", "STRETCH_INPUT_NAMES", "HEIGHT_DEPTH_M", "R_MIN", "DEFAULT_CHECKPOINT",
           "SCAN_CHECKPOINT", "ORIENTED_SCAN_CHECKPOINT", "BUCKLING_SCAN_CHECKPOINTS", "EstimateError",
           "targets_from_params", "stretch_inputs_from_params", "params_from_targets", "image_to_grid",
           "silhouette_feature", "height_feature", "depth_feature", "curve_feature", "HARMONICS", "PHASE_HARMONICS",
           "RINGS", "harmonic_feature", "InverseModel"]
