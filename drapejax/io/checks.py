"""Checks of the observation arrays, shared by the reader and the writer.

Each observation must have the shape, type and values the format allows (a two-tone
silhouette, a height map with NaN exactly off the fabric, an RGB photo, finite scan points and
faces that index them), and all must lie where the header's specimen can reach
(``_observations_within_reach``), so that a wrong unit or frame is refused by name rather than
meshed.
"""

from __future__ import annotations

import numpy as np

from .format import OUT_OF_REACH_FRACTION, REACH_FACTOR, SKIRT_RISE_FRACTION, _circumradius
from .measurement import _Fail

_MAX_MIDTONE_FRACTION = 0.1
"""A silhouette may have anti-aliased edges, but more than this fraction of pixels in
32..223 means the image is not a fabric mask."""


def _silhouette_mask(img: np.ndarray, fail: _Fail, file: str) -> np.ndarray:
    if img.ndim != 2:
        raise fail(file, "silhouette", f"expected an 8-bit grey image, got shape {img.shape}")
    if img.dtype != np.uint8:
        raise fail(file, "silhouette", f"expected 8-bit grey pixels, got {img.dtype}")
    if img.shape[0] != img.shape[1] or img.size == 0:
        raise fail(file, "silhouette", f"expected a square N x N image, got {img.shape}")
    midtone = np.mean((img >= 32) & (img <= 223))
    if midtone > _MAX_MIDTONE_FRACTION:
        raise fail(file, "silhouette", f"not a fabric mask: {midtone:.0%} of pixels are neither "
                                       f"near 0 nor near 255")
    if not np.any(img > 127):
        raise fail(file, "silhouette", f"shows no fabric (no pixel > 127, max {img.max()}); "
                                       "fabric pixels must be 255")
    return np.where(img > 127, np.uint8(255), np.uint8(0))


def _height_map(h: np.ndarray, fail: _Fail, file: str, silhouette: np.ndarray | None) -> np.ndarray:
    if h.ndim != 2 or h.shape[0] != h.shape[1] or h.size == 0:
        raise fail(file, "height_map", f"expected a square N x N array, got shape {h.shape}")
    if not np.issubdtype(h.dtype, np.floating):
        raise fail(file, "height_map", f"expected float32 heights in m, got {h.dtype}")
    h = h.astype(np.float32)
    if np.any(np.isinf(h)):
        raise fail(file, "height_map", f"{int(np.sum(np.isinf(h)))} infinite values "
                                       "(only NaN is allowed, where there is no fabric)")
    if np.all(np.isnan(h)):
        raise fail(file, "height_map", "all NaN: the height map shows no fabric")
    if silhouette is not None:
        if silhouette.shape != h.shape:
            raise fail(file, "height_map", f"grid {h.shape} differs from the silhouette grid "
                                           f"{silhouette.shape}")
        fabric = silhouette == 255
        holes = int(np.sum(fabric & np.isnan(h)))
        if holes:
            raise fail(file, "height_map", f"NaN at {holes} pixels where the silhouette shows fabric")
        stray = int(np.sum(~fabric & ~np.isnan(h)))
        if stray:
            raise fail(file, "height_map", f"finite heights at {stray} pixels where the silhouette "
                                           "shows no fabric (must be NaN)")
    return h


def _photo(img: np.ndarray, fail: _Fail, file: str) -> np.ndarray:
    if img.ndim != 3 or img.shape[2] != 3 or img.shape[0] == 0 or img.shape[1] == 0:
        raise fail(file, "photo", f"expected an RGB image (H x W x 3), got shape {img.shape}")
    if img.dtype != np.uint8:
        raise fail(file, "photo", f"expected 8-bit RGB pixels, got {img.dtype}")
    return img


def _within_reach(points: np.ndarray, head: dict, fail: _Fail, file: str, field: str, what: str) -> None:
    """Raise if more than ``OUT_OF_REACH_FRACTION`` of ``points`` (k, 3) in m (z NaN: not
    checked) lie where the header's specimen cannot reach (see ``REACH_FACTOR``), or the
    material beyond the disc edge stands above the disc top, naming the likely slip:
    millimetres or centimetres, a y-up or z-down export, an origin off the disc centre."""
    rc = _circumradius(head["test"], head["specimen_radius_m"])
    overhang = rc - head["disk_radius_m"]
    far, low, high = REACH_FACTOR * rc, -REACH_FACTOR * rc, REACH_FACTOR * overhang
    r, z = np.hypot(points[:, 0], points[:, 1]), points[:, 2]
    frame = "The format is in metres, z up, origin at the centre of the disc top."
    with np.errstate(invalid="ignore"):
        out = (r > far) | (z < low) | (z > high)
    if np.mean(out) > OUT_OF_REACH_FRACTION:
        scale = max(float(np.max(r)), float(np.nanmax(np.abs(z), initial=0.0))) / rc
        hint = (" Is it in millimetres (divide by 1000)?" if scale > 300 else
                " Is it in centimetres (divide by 100)?" if scale > 30 else
                " Is its vertical axis y (a y-up export)?" if np.nanmax(z, initial=-np.inf) > high else "")
        zs = "" if np.all(np.isnan(z)) else f", z from {np.nanmin(z):.3g} to {np.nanmax(z):.3g} m"
        raise fail(file, field, f"{int(np.sum(out))} of {len(out)} {what} lie where a specimen of "
                                f"{head['specimen_radius_m']:g} m on a {head['disk_radius_m']:g} m disc cannot reach "
                                f"(beyond {far:.3g} m from the disc centre, or z outside [{low:.3g}, {high:.3g}] "
                                f"m); they reach {np.max(r):.3g} m from the origin{zs}. {frame}{hint}")
    skirt = z[(r > head["disk_radius_m"]) & np.isfinite(z)]
    if len(skirt) and np.median(skirt) > SKIRT_RISE_FRACTION * overhang:
        raise fail(file, field, f"the {what} beyond the disc edge stand above the disc top (median z "
                                f"{np.median(skirt):.3g} m), where gravity hangs them below it. {frame} "
                                f"Is z pointing down, or the origin below the disc top?")


def _grid_points(image: np.ndarray, extent_m: float, values: np.ndarray | None) -> np.ndarray:
    """(k, 3) world x, y of the fabric pixels of an N x N grid (``image`` 255 or finite
    ``values``), z from ``values`` (NaN without)."""
    from ..observe.render import pixel_centres  # lazy: importing observe would slow every import of io by 0.7 s

    c = pixel_centres(image.shape[0], extent_m)
    rows, cols = np.nonzero(image)
    z = np.full(len(rows), np.nan) if values is None else values[rows, cols].astype(np.float64)
    return np.stack([c[cols], -c[rows], z], 1)


def _observations_within_reach(head: dict, fail: _Fail, files: dict, extents: dict, silhouette, height,
                               scan) -> None:
    """Check the silhouette's and height map's fabric pixels and the scan points (any may be
    None) against the specimen's reach (``_within_reach``); ``files`` and ``extents`` by
    observation name."""
    if silhouette is not None:
        _within_reach(_grid_points(silhouette == 255, extents["silhouette"], None), head, fail, files["silhouette"],
                      "silhouette", f"fabric pixels (on a grid of extent_m {extents['silhouette']:g})")
    if height is not None:
        _within_reach(_grid_points(np.isfinite(height), extents["height_map"], height), head, fail,
                      files["height_map"], "height_map",
                      f"fabric pixels (on a grid of extent_m {extents['height_map']:g})")
    if scan is not None:
        _within_reach(scan, head, fail, files["scan"], "scan", "points")


def _scan(vertices: np.ndarray, faces: np.ndarray | None, fail: _Fail, file: str):
    if vertices.ndim != 2 or vertices.shape[1] != 3 or len(vertices) == 0:
        raise fail(file, "scan", f"expected k x 3 vertices with k > 0, got shape {vertices.shape}")
    if not np.issubdtype(vertices.dtype, np.number) or np.issubdtype(vertices.dtype, np.complexfloating):
        raise fail(file, "scan", f"vertices must be real numbers, got {vertices.dtype}")
    vertices = vertices.astype(np.float64)
    if not np.all(np.isfinite(vertices)):
        raise fail(file, "scan", f"{int(np.sum(~np.isfinite(vertices).all(1)))} vertices are not finite")
    if faces is None or len(faces) == 0:
        return vertices, None
    if faces.ndim != 2 or faces.shape[1] != 3 or not np.issubdtype(faces.dtype, np.integer):
        raise fail(file, "scan", f"faces must be a j x 3 integer array, got {faces.dtype} "
                                 f"{faces.shape}")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise fail(file, "scan", f"face indices must lie in [0, {len(vertices)}), got "
                                 f"[{faces.min()}, {faces.max()}]")
    return vertices, faces.astype(np.int64)


def _read_only(a: np.ndarray | None) -> np.ndarray | None:
    if a is not None:
        a.setflags(write=False)
    return a
