"""What the fit compares: the targets measured on a capture and the same features of a rest state.

Measured side (``measured_targets``, ``Targets``): the drape coefficient, the rim-profile
harmonic amplitudes 1..12 (phase-invariant: fold placement is random from drop to drop), the
mean hem height and ring heights when a height map or scan exists, and the rim components that
depend on the phase (warp-aligned and bias second harmonic, world-frame first harmonic), all
from the silhouette rendered as for the measurement. Simulated side: the same values of a rest
mesh (``hard_features``, used by ``Misfit.hard``) and their soft surrogates
(``_soft_features``), whose Jacobian the fit steps with; ``_F`` is the layout both share. These
are the features of the library's observation types (``observe.types``); any other registered
type adds its own measured features to ``Targets.extra``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import jax.numpy as jnp
import numpy as np
from jaxtyping import Float

from .. import observe
from ..io import Measurement
from ..mesh import ClothMesh
from ..observe.types import REGISTRY
from ..photo import photo_silhouette
from .errors import RefineError

N_HARMONICS = 12

RING_RADII_M = (0.10, 0.12)
"""World radii (m) of the rings whose mean fabric height (top view) is fitted: with the hem
height they give the hanging profile's shape, which tells a heavier hem from softer fabric."""
PROFILE_RADII_M = (0.095, 0.100, 0.105, 0.110, 0.115, 0.120)
"""World radii (m) of the hanging skirt's height profile that effect selection scores
(``Misfit(profile=True)``): from the disc edge out to where every fold trough is still fabric in
top view (farther out a ring sees fabric only under fold crests, and its mean height swings by
10–20 mm from drop to drop)."""

RING_HALF_WIDTH_M = 0.005
EXTENT_M = 0.16
N_ANGLES = 360


@dataclass(frozen=True)
class Targets:
    """Measured observables: DC, harmonic amplitudes 1..12 (m), mean hem z (m or None), the
    silhouette, the warp-frame 2nd-harmonic components (``warp_anisotropy``, ``bias_shear``; None
    when the warp angle is unknown), the world-frame first harmonic (Re, Im) c1 (m) and the
    ring heights at ``RING_RADII_M`` and ``PROFILE_RADII_M`` (m or None), the world-frame first
    harmonic of the height on the ``PROFILE_RADII_M`` rings (``height_first_harmonic``, m or None), and ``extra``: the
    measured features of every other observation type the capture holds, by name
    (``observe.types.AbstractObservation.target``)."""

    dc: float
    harmonics: np.ndarray
    hem_m: float | None
    silhouette: np.ndarray
    aniso_m: float | None
    c1_m: np.ndarray
    shear_m: float | None
    rings_m: np.ndarray | None
    profile_m: np.ndarray | None = None
    height_c1_m: np.ndarray | None = None
    extra: dict[str, np.ndarray] = field(default_factory=dict)


def _sil_from(m: Measurement) -> tuple[np.ndarray, float]:
    """Top-view silhouette: spec-exact render of the scan mesh when there is one, else the stored
    silhouette, the height map's footprint, the scanned point cloud's view, the rectified photo."""
    if m.has_scan_mesh:
        v = np.asarray(m.scan_vertices, float)
        return observe.silhouette(v, np.asarray(m.scan_faces), n=256, extent_m=EXTENT_M), EXTENT_M
    if m.silhouette is not None:
        return np.asarray(m.silhouette), m.silhouette_extent_m
    if m.height is not None:
        return np.where(np.isfinite(m.height), 255, 0).astype(np.uint8), m.height_extent_m
    if m.scan_vertices is not None:
        return observe.point_cloud_views(m.scan_vertices, n=256, extent_m=EXTENT_M)[0], EXTENT_M
    if m.photo is not None:
        return photo_silhouette(m, extent_m=EXTENT_M), EXTENT_M
    raise RefineError(f"{getattr(m, 'path', 'measurement')}: needs a silhouette, a height map, a photo or a scan")


def hard_features(sil, extent_m, height, height_extent_m, specimen_radius_m, disk_radius_m, test="cusick"):
    """(drape coefficient, rim harmonic amplitudes 1..12 in m, mean hem height in m or None) of a silhouette
    and an optional height map: the hard features the fit compares (``measured_targets``, ``Misfit.hard``).
    Public because the experiments score rest meshes and re-drops with the same features."""
    dc = observe.drape_coefficient(sil, extent_m, specimen_radius_m=specimen_radius_m, disk_radius_m=disk_radius_m,
                                   test=test)
    spec = observe.rim_spectrum(observe.rim_profile(sil, extent_m, n_angles=N_ANGLES), N_HARMONICS)[1:]
    hem = None
    if height is not None:
        hem = float(np.nanmean(observe.descriptors.hem_heights_from_height_map(height, height_extent_m)))
    return dc, spec, hem


def measured_targets(m: Measurement) -> Targets:
    """Phase-invariant targets of a measurement (scan rendered with the spec-exact renderer if present;
    a point-cloud scan stands in for a missing height map)."""
    if m.test not in ("cusick", "square"):
        raise RefineError(f"{getattr(m, 'path', 'measurement')}: refinement supports tests 'cusick' and 'square', "
                          f"got {m.test!r}")
    sil, ext = _sil_from(m)
    height, hext = m.height, m.height_extent_m
    if m.has_scan_mesh:
        height = observe.height_map(np.asarray(m.scan_vertices, float), np.asarray(m.scan_faces), n=256,
                                    extent_m=EXTENT_M)
        hext = EXTENT_M
    elif height is None and m.scan_vertices is not None:
        height, hext = observe.point_cloud_views(m.scan_vertices, n=256, extent_m=EXTENT_M)[1], EXTENT_M
    dc, spec, hem = hard_features(sil, ext, height, hext, m.specimen_radius_m, m.disk_radius_m, m.test)
    profile = observe.rim_profile(sil, ext, n_angles=N_ANGLES)
    aniso = shear = None
    if m.warp_angle_deg is not None:
        aniso, shear = warp_anisotropy(profile, m.warp_angle_deg), bias_shear(profile, m.warp_angle_deg)
    rings = None if height is None else ring_heights(height, hext)
    heights = None if height is None else ring_heights(height, hext, PROFILE_RADII_M)
    height_c1 = None if height is None else height_first_harmonic(height, hext)
    extra = {name: np.asarray(t, float) for name, obs in REGISTRY.items()
             if obs.present(m) and (t := obs.target(m)) is not None}
    return Targets(dc=float(dc), harmonics=spec, hem_m=hem, silhouette=sil, aniso_m=aniso, c1_m=first_harmonic(profile),
                   shear_m=shear, rings_m=rings, profile_m=heights, height_c1_m=height_c1, extra=extra)


def warp_anisotropy(profile: Float[np.ndarray, " a"], warp_angle_deg: float) -> float:
    """2·Re(c₂ e^{-2iψ}) of the rim profile r(φ) (m): > 0 when the drape reaches farther along the warp.

    The only phase-dependent residual: warp and weft are swapped by a 90° rotation, which the
    harmonic amplitudes cannot see, so when the warp angle ψ is known this ±-sign of the
    second harmonic along the warp tells the stiffer direction.
    """
    r = np.asarray(profile, float)
    phi = 2 * np.pi * np.arange(len(r)) / len(r)
    return float(2.0 * np.mean(r * np.cos(2.0 * (phi - np.deg2rad(warp_angle_deg)))))


def bias_shear(profile: Float[np.ndarray, " a"], warp_angle_deg: float) -> float:
    """2·Im(c₂ e^{-2iψ}) of r(φ) (m): > 0 when the drape reaches farther along the +45° bias than
    the −45° one. Zero by symmetry for any material the base model has (equal bias directions)."""
    r = np.asarray(profile, float)
    phi = 2 * np.pi * np.arange(len(r)) / len(r)
    return float(2.0 * np.mean(r * np.sin(2.0 * (phi - np.deg2rad(warp_angle_deg)))))


def first_harmonic(profile: Float[np.ndarray, " a"]) -> np.ndarray:
    """(Re, Im) of 2·c₁ of r(φ) in the world frame (m): how far, and towards where, the drape is
    off-centre. Zero by symmetry for a centred specimen of any homogeneous material."""
    r = np.asarray(profile, float)
    phi = 2 * np.pi * np.arange(len(r)) / len(r)
    return np.array([2.0 * np.mean(r * np.cos(phi)), 2.0 * np.mean(r * np.sin(phi))])


def _polar_pixels(height: Float[np.ndarray, "n n"], extent_m: float) -> tuple[np.ndarray, ...]:
    """(z, radius, azimuth) of every pixel of a top-view height map, world frame (rows run from +y down)."""
    z = np.asarray(height, float)
    c = observe.pixel_centres(z.shape[0], extent_m)
    xx, yy = np.meshgrid(c, c[::-1])
    return z, np.hypot(xx, yy), np.arctan2(yy, xx)


def ring_heights(height: Float[np.ndarray, "n n"], extent_m: float,
                 radii_m: Sequence[float] = RING_RADII_M) -> np.ndarray:
    """Mean top-view fabric height (m) in thin rings at ``radii_m`` (NaN-free fabric pixels)."""
    z, rho, _ = _polar_pixels(height, extent_m)
    out = []
    for r0 in radii_m:
        sel = (np.abs(rho - r0) <= RING_HALF_WIDTH_M) & np.isfinite(z)
        out.append(float(z[sel].mean()) if sel.any() else 0.0)
    return np.array(out)


def height_first_harmonic(height: Float[np.ndarray, "n n"], extent_m: float,
                          radii_m: Sequence[float] = PROFILE_RADII_M, sectors: int = 36) -> np.ndarray:
    """(a, b) of the skirt's height z(φ) ≈ a0 + a cos φ + b sin φ in the world frame (m), fitted on
    each thin ring at ``radii_m`` and averaged over the rings: how much lower the skirt hangs
    towards +x (a < 0) and +y (b < 0) than on the opposite side.

    A specimen laid off-centre shows here and hardly in its silhouette: its longer overhang hangs
    more steeply and reaches about as far as the shorter one (13 mm off-centre on Style3D: the
    edge 61 mm below the support on the long side, 30 mm on the short one, the rim's first
    harmonic under 1 mm, ``experiments/offset_geometry.py``). Each ring is averaged over
    ``sectors`` equal angular sectors before the least-squares fit, over the sectors that hold
    fabric, so fold troughs missing from an outer ring do not bias it."""
    z, rho, phi = _polar_pixels(height, extent_m)
    sector = np.minimum(((phi + np.pi) / (2 * np.pi) * sectors).astype(int), sectors - 1)
    mid = -np.pi + (np.arange(sectors) + 0.5) * 2 * np.pi / sectors
    out = []
    for r0 in radii_m:
        sel = (np.abs(rho - r0) <= RING_HALF_WIDTH_M) & np.isfinite(z)
        n = np.bincount(sector[sel], minlength=sectors)
        zs = np.bincount(sector[sel], weights=z[sel], minlength=sectors)
        ok = n > 0
        if ok.sum() < 4:
            continue
        design = np.c_[np.ones(ok.sum()), np.cos(mid[ok]), np.sin(mid[ok])]
        out.append(np.linalg.lstsq(design, zs[ok] / n[ok], rcond=None)[0][1:])
    return np.mean(out, axis=0) if out else np.zeros(2)


def _soft_features(x, mesh: ClothMesh, spacing_m: float):
    """Soft feature vector of rest positions x (n,3), laid out as ``Problem.hard`` (see ``_F``)."""
    r = observe.soft_rim_profile(x, sharpness=2.0 / spacing_m * 10.0, n_angles=N_ANGLES, vertex_radius_m=spacing_m)
    info = mesh.info
    area = 0.5 * jnp.mean(r**2) * 2 * jnp.pi
    disc = math.pi * info.disk_radius_m**2
    square = info.test == "square"
    dc = (area - disc) / (observe.descriptors.specimen_area_m2(info.test, info.specimen_radius_m) - disc)
    c = jnp.fft.rfft(r)[1:N_HARMONICS + 1] / N_ANGLES
    amp = 2.0 * jnp.sqrt(jnp.real(c) ** 2 + jnp.imag(c) ** 2 + 1e-12)
    rad = jnp.max(jnp.abs(mesh.rest[:, :2]), axis=1) if square else jnp.linalg.norm(mesh.rest[:, :2], axis=1)
    hem = rad > info.specimen_radius_m - 0.5 * spacing_m
    z = jnp.sum(jnp.where(hem, x[:, 2], 0.0)) / jnp.sum(hem)
    phi = 2 * jnp.pi * jnp.arange(N_ANGLES) / N_ANGLES
    psi = jnp.deg2rad(info.warp_angle_deg)
    aniso = 2.0 * jnp.mean(r * jnp.cos(2.0 * (phi - psi)))
    shear = 2.0 * jnp.mean(r * jnp.sin(2.0 * (phi - psi)))
    c1 = 2.0 * jnp.stack([jnp.mean(r * jnp.cos(phi)), jnp.mean(r * jnp.sin(phi))])
    rho = jnp.linalg.norm(x[:, :2], axis=1)
    rings = []
    for r0 in RING_RADII_M:
        w = mesh.vertex_area * jnp.exp(-0.5 * ((rho - r0) / RING_HALF_WIDTH_M) ** 2)
        rings.append(jnp.sum(w * x[:, 2]) / jnp.maximum(jnp.sum(w), 1e-12))
    return jnp.concatenate([dc[None], amp, z[None], aniso[None], shear[None], c1, jnp.stack(rings)])


_F = {"dc": 0, "amp": 1, "hem": 1 + N_HARMONICS, "aniso": 2 + N_HARMONICS, "shear": 3 + N_HARMONICS,
      "c1": 4 + N_HARMONICS, "rings": 6 + N_HARMONICS}
"""Layout of the feature vector (soft and hard): DC, harmonic amplitudes 1..12, mean hem z,
warp anisotropy, bias shear, first harmonic (Re, Im), ring heights."""


def fold_rms(amp: np.ndarray) -> float:
    """RMS amplitude (m) of rim harmonics 3..12: fold depth, independent of fold phase and count (the fold
    depth row of ``observe.types``' silhouette misfit; public because the experiments report it)."""
    return float(np.sqrt(np.mean(np.asarray(amp)[2:] ** 2)))
