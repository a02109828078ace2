"""Scalar descriptors of a Cusick drape: drape coefficient, folds, rim spectrum, hem heights.

Everything is computed from the top-view silhouette (so it applies to real photos as well as
scans and simulations), plus the hem curve and height map when a mesh or height map exists.
Drape coefficient after Cusick (1965) and ISO 9073-9; fold (node) counting and amplitudes as
in the drape-image indices surveyed by Carrera-Gallissà et al. (2017).
"""

from __future__ import annotations

import math
import os

import numpy as np
from jaxtyping import Float

from ..mesh import CUSICK_RADIUS_M, DISK_RADIUS_M
from .render import EXTENT_M, SilhouetteImage, boundary_curve, height_map, point_cloud_views, rim_profile, silhouette

HEIGHT_THRESHOLDS_MM = (10.0, 30.0, 50.0)
"""Depths below the support (mm) at which ``describe`` reports the fraction of fabric area."""


def projected_area_m2(silhouette: SilhouetteImage, extent_m: float = EXTENT_M) -> float:
    """Area (m²) of the fabric seen from above: fabric pixels (> 127) times the pixel area."""
    img = np.asarray(silhouette)
    return float(np.count_nonzero(img > 127 if img.dtype != bool else img) * (2.0 * extent_m / img.shape[0]) ** 2)


def specimen_area_m2(test: str, specimen_radius_m: float) -> float:
    """Flat area of a "square" specimen of that half side, or of a circular one of that radius, m²."""
    return 4.0 * specimen_radius_m**2 if test == "square" else math.pi * specimen_radius_m**2


def drape_coefficient(silhouette: SilhouetteImage, extent_m: float = EXTENT_M, *,
                      specimen_radius_m: float = CUSICK_RADIUS_M, disk_radius_m: float = DISK_RADIUS_M,
                      test: str = "cusick") -> float:
    """Cusick drape coefficient DC = (projected area − disc area)/(specimen area − disc area).

    1 for a specimen that stays flat, 0 for one hanging straight down from the disc edge.

    Args:
        silhouette: (n, n) top-view image, fabric > 127, on the measurement-format grid.
        extent_m: half side of the image window, m.
        specimen_radius_m: radius of the circular specimen ("cusick") or half side of the
            square one ("square"), m.
        disk_radius_m: radius of the support disc, m.
        test: "cusick" or "square".
    """
    if test not in ("cusick", "square"):
        raise ValueError(f"test must be 'cusick' or 'square', got {test!r}")
    specimen = specimen_area_m2(test, specimen_radius_m)
    disc = math.pi * disk_radius_m**2
    if not specimen > disc > 0:
        raise ValueError(f"the specimen ({test}, {specimen_radius_m} m) must be larger than the disc "
                         f"(radius {disk_radius_m} m)")
    return (projected_area_m2(silhouette, extent_m) - disc) / (specimen - disc)


def _smooth(profile: np.ndarray, smooth_deg: float) -> np.ndarray:
    r = np.asarray(profile, float)
    sigma = smooth_deg * len(r) / 360.0
    return _gaussian_wrap(r, sigma) if sigma > 0 else r


def _gaussian_wrap(r: np.ndarray, sigma: float, truncate: float = 4.0) -> np.ndarray:
    """Circular Gaussian smoothing: the normalised kernel exp(−x²/2σ²) on |x| ≤ ⌊truncate·σ + ½⌋ samples,
    wrapped around the ends (as ``scipy.ndimage.gaussian_filter1d(..., mode="wrap")``)."""
    radius = int(truncate * sigma + 0.5)
    x = np.arange(-radius, radius + 1)
    w = np.exp(-0.5 * (x / sigma) ** 2)
    w /= w.sum()
    idx = (np.arange(len(r))[:, None] + x[None, :]) % len(r)
    return r[idx] @ w


def _prominent_peaks(x: np.ndarray, min_prominence: float) -> np.ndarray:
    """Indices of the local maxima of ``x`` whose topographic prominence is at least ``min_prominence``.

    A maximum is a sample above its left neighbour and not below the samples up to the next lower one
    (a flat top counts once, at its middle); its prominence is its height above the higher of the two
    lowest points reached going left and right until the signal rises above it or ends. The rule of
    ``scipy.signal.find_peaks(x, prominence=...)``, written out here so that reading a drape does not
    import ``scipy.signal``.
    """
    n = len(x)
    peaks = []
    i = 1
    while i < n - 1:
        if x[i - 1] < x[i]:
            ahead = i + 1
            while ahead < n - 1 and x[ahead] == x[i]:
                ahead += 1
            if x[ahead] < x[i]:
                peaks.append((i + ahead - 1) // 2)
                i = ahead
        i += 1
    keep = []
    for p in peaks:
        top = x[p]
        left = np.flatnonzero(x[:p] > top)
        lo = left[-1] + 1 if len(left) else 0
        right = np.flatnonzero(x[p + 1:] > top)
        hi = p + 1 + right[0] if len(right) else n
        if top - max(x[lo:p + 1].min(), x[p:hi].min()) >= min_prominence:
            keep.append(p)
    return np.asarray(keep, int)


def fold_peaks(rim_profile: Float[np.ndarray, " a"], *, smooth_deg: float = 3.0,
               rel_prominence: float = 0.15) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the fold crests (maxima of r(φ)) and of the troughs between consecutive crests.

    The profile is smoothed circularly (Gaussian, ``smooth_deg`` degrees) and a crest must stand
    out by at least ``rel_prominence`` × (max − min of the smoothed profile).

    Args:
        rim_profile: (a,) radii at equally spaced angles φ_j = 2πj/a, m.
        smooth_deg: standard deviation of the circular smoothing, degrees.
        rel_prominence: minimum crest prominence relative to the profile's range.

    Returns:
        (crests, troughs): index arrays in increasing angle; one trough after each crest
        (empty when there are fewer than two crests).
    """
    r = _smooth(rim_profile, smooth_deg)
    a = len(r)
    span = float(r.max() - r.min())
    if span <= 1e-9 * max(float(np.abs(r).max()), 1e-12):
        return np.zeros(0, int), np.zeros(0, int)
    tiled = np.concatenate([r, r, r])
    peaks = _prominent_peaks(tiled, rel_prominence * span)
    crests = np.unique(peaks[(peaks >= a) & (peaks < 2 * a)] - a)
    if len(crests) < 2:
        return crests, np.zeros(0, int)
    troughs = []
    for i, c in enumerate(crests):
        nxt = crests[(i + 1) % len(crests)] + (a if i + 1 == len(crests) else 0)
        seg = tiled[a + c:a + nxt + 1]
        troughs.append((c + int(np.argmin(seg))) % a)
    return crests, np.asarray(troughs, int)


def fold_count(rim_profile: Float[np.ndarray, " a"], *, smooth_deg: float = 3.0,
               rel_prominence: float = 0.15) -> int:
    """Number of folds (nodes) of a drape: crests of the rim profile r(φ); see ``fold_peaks``."""
    return len(fold_peaks(rim_profile, smooth_deg=smooth_deg, rel_prominence=rel_prominence)[0])


def fold_amplitudes(rim_profile: Float[np.ndarray, " a"], *, smooth_deg: float = 3.0,
                    rel_prominence: float = 0.15) -> Float[np.ndarray, " k"]:
    """Crest radius minus the mean radius of its two neighbouring troughs, per fold, m.

    Read from the unsmoothed profile at the crest and trough angles found by ``fold_peaks``.
    Empty when there are fewer than two folds.
    """
    r = np.asarray(rim_profile, float)
    crests, troughs = fold_peaks(r, smooth_deg=smooth_deg, rel_prominence=rel_prominence)
    if len(troughs) == 0:
        return np.zeros(0)
    before = np.roll(troughs, 1)
    return r[crests] - 0.5 * (r[troughs] + r[before])


def rim_spectrum(rim_profile: Float[np.ndarray, " a"], n_harmonics: int = 16) -> Float[np.ndarray, " k"]:
    """Amplitudes of the angular Fourier harmonics k = 0..n_harmonics of r(φ), in the profile's unit.

    Entry 0 is the mean radius; entry k is the amplitude a_k of $a_k\\cos(kφ + θ_k)$. Magnitudes
    only, so the spectrum is invariant to rotating or mirroring the drape.
    """
    r = np.asarray(rim_profile, float)
    if r.ndim != 1 or len(r) < 2 * n_harmonics + 1:
        raise ValueError(f"rim profile must be 1D with at least {2 * n_harmonics + 1} samples, got shape {r.shape}")
    c = np.abs(np.fft.rfft(r))[: n_harmonics + 1] / len(r)
    c[1:] *= 2.0
    return c


def hem_heights_from_height_map(height: Float[np.ndarray, "n n"], extent_m: float = EXTENT_M, *,
                                n_angles: int = 360) -> Float[np.ndarray, " a"]:
    """Height (m) of the outermost fabric pixel along each ray φ_j = 2πj/n_angles: the visible
    hem, from a top-view height map alone (fabric = finite pixels).
    """
    z = np.asarray(height, float)
    n = z.shape[0]
    r = rim_profile(np.isfinite(z), extent_m, n_angles=n_angles)
    phi = 2 * np.pi * np.arange(n_angles) / n_angles
    h = 2.0 * extent_m / n
    rr = np.maximum(r - 0.5 * h, 0.0)
    col = np.clip(np.round((rr * np.cos(phi) + extent_m) / h - 0.5).astype(int), 0, n - 1)
    row = np.clip(np.round((extent_m - rr * np.sin(phi)) / h - 0.5).astype(int), 0, n - 1)
    return z[row, col]


def _describe(sil, sil_extent, height, height_extent, verts, faces, specimen_radius_m, disk_radius_m,
              test) -> dict:
    profile = rim_profile(sil, sil_extent)
    amp = fold_amplitudes(profile)
    spec = rim_spectrum(profile)
    out = {
        "dc": drape_coefficient(sil, sil_extent, specimen_radius_m=specimen_radius_m, disk_radius_m=disk_radius_m,
                                test=test),
        "folds": fold_count(profile),
        "fold_amplitude_mm": float(amp.mean() * 1e3) if amp.size else 0.0,
        "fold_amplitude_std_mm": float(amp.std() * 1e3) if amp.size else 0.0,
        "r_min_mm": float(profile.min() * 1e3),
        "r_max_mm": float(profile.max() * 1e3),
        "r_mean_mm": float(profile.mean() * 1e3),
        "dominant_harmonic": int(np.argmax(spec[1:]) + 1),
    }
    if verts is not None and faces is not None:
        hem_z = boundary_curve(verts, faces, n_samples=256)[:, 2]
    elif height is not None:
        hem_z = hem_heights_from_height_map(height, height_extent)
        hem_z = hem_z[np.isfinite(hem_z)]
    else:
        hem_z = None
    if hem_z is not None and hem_z.size:
        out["hem_height_mean_mm"] = float(hem_z.mean() * 1e3)
        out["hem_height_min_mm"] = float(hem_z.min() * 1e3)
        out["hem_height_max_mm"] = float(hem_z.max() * 1e3)
    if height is not None:
        z = np.asarray(height, float)
        z = z[np.isfinite(z)]
        for t in HEIGHT_THRESHOLDS_MM:
            out[f"area_below_{t:g}mm"] = float(np.mean(z < -t * 1e-3)) if z.size else 0.0
    return out


def describe_mesh(verts: Float[np.ndarray, "n 3"], faces, *, n: int = 256, extent_m: float = EXTENT_M,
                  specimen_radius_m: float = CUSICK_RADIUS_M, disk_radius_m: float = DISK_RADIUS_M,
                  test: str = "cusick") -> dict:
    """Descriptors of a draped mesh (simulation or scan), rendered on the measurement grid.

    Returns the same keys as ``describe``.
    """
    v = np.asarray(verts, float)
    f = np.asarray(faces)
    return _describe(silhouette(v, f, n=n, extent_m=extent_m), extent_m,
                     height_map(v, f, n=n, extent_m=extent_m), extent_m, v, f, specimen_radius_m, disk_radius_m,
                     test)


def describe(measurement) -> dict:
    """Plain-number descriptors of a measurement (a ``drapejax.io.Measurement`` or alike).

    Uses the stored silhouette (else the scan mesh rendered from above, a scanned point cloud's
    ``point_cloud_views``, or the photo rectified with ``drapejax.photo.rectify_photo``), the
    scan's hem curve for hem heights (else the height map along the outline), and the height map
    for area fractions below ``HEIGHT_THRESHOLDS_MM``.

    Returns:
        dict with "dc", "folds" (int), "fold_amplitude_mm", "fold_amplitude_std_mm",
        "r_min_mm", "r_max_mm", "r_mean_mm", "dominant_harmonic" (int), and when available
        "hem_height_mean_mm", "hem_height_min_mm", "hem_height_max_mm" and
        "area_below_{10,30,50}mm" (fractions of the seen fabric area).
    """
    verts = getattr(measurement, "scan_vertices", None)
    faces = getattr(measurement, "scan_faces", None)
    mesh = verts is not None and faces is not None and len(faces) > 0
    sil = measurement.silhouette
    sil_extent = measurement.silhouette_extent_m
    height = measurement.height
    height_extent = measurement.height_extent_m
    if sil is None and mesh:
        sil_extent = EXTENT_M if height is None else height_extent
        sil = silhouette(verts, faces, n=256 if height is None else height.shape[0], extent_m=sil_extent)
    elif sil is None and verts is not None:
        sil_extent = EXTENT_M if height is None else height_extent
        sil, cloud_height = point_cloud_views(verts, n=256 if height is None else height.shape[0], extent_m=sil_extent)
        if height is None:
            height, height_extent = cloud_height, sil_extent
    elif sil is None and getattr(measurement, "photo", None) is not None:
        from ..photo import photo_silhouette

        sil_extent = EXTENT_M
        sil = photo_silhouette(measurement, extent_m=sil_extent)
    elif sil is None:
        raise ValueError("measurement has no silhouette, scan mesh or photo: nothing to describe")
    if height is None and mesh:
        height_extent = sil_extent
        height = height_map(verts, faces, n=sil.shape[0], extent_m=sil_extent)
    return _describe(sil, sil_extent, height, height_extent, verts if mesh else None, faces if mesh else None,
                     measurement.specimen_radius_m, measurement.disk_radius_m, measurement.test)


def inspect(folder: str | os.PathLike) -> dict:
    """Load a measurement folder with ``drapejax.io.load_measurement`` and ``describe`` it."""
    from ..io import load_measurement

    return describe(load_measurement(folder))


__all__ = ["HEIGHT_THRESHOLDS_MM", "projected_area_m2", "specimen_area_m2", "drape_coefficient", "fold_peaks",
           "fold_count", "fold_amplitudes", "rim_spectrum", "hem_heights_from_height_map", "describe", "describe_mesh",
           "inspect"]
