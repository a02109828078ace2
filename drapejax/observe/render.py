"""Exact ("hard") renderers of a drape mesh: top-view silhouette and height map, oblique depth
views, the 3D hem curve, and the rim profile of a silhouette image.

NumPy on the host. All images follow the measurement format's grid: N×N pixels covering
x, y ∈ [-extent, extent] (m), column index growing with +x, row index growing with -y, pixel
centres at -extent + (i + 0.5)·2·extent/N. A pixel belongs to a triangle when its centre lies
inside the triangle's projection (edges included).
"""

from __future__ import annotations

import functools

import numpy as np
from jaxtyping import Bool, Float, Int, UInt8

EXTENT_M = 0.16
"""Half side of the default image window, m (measurement format)."""

ALPHA_EDGE_FACTOR = 2.5
"""``point_cloud_mesh`` drops Delaunay triangles whose longest edge exceeds this many times the
median one: above the 99th percentile of a uniformly random sampling (2.5x its median), far
below the centimetres between neighbouring folds."""

CAMERA_DISTANCE_M = 0.5
"""Distance from the origin to the image plane of ``depth_views``, m."""

SilhouetteImage = UInt8[np.ndarray, "px px"] | Bool[np.ndarray, "px px"]
"""A square top-view silhouette: uint8 (fabric > 127, as ``silhouette`` renders it) or a boolean mask."""


def _check_mesh(verts, faces) -> tuple[np.ndarray, np.ndarray]:
    v = np.asarray(verts, float)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"verts must have shape (n, 3), got {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3 or not np.issubdtype(f.dtype, np.integer):
        raise ValueError(f"faces must be an integer array of shape (m, 3), got {f.dtype} {f.shape}")
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise ValueError(f"faces index vertices outside [0, {len(v)})")
    return v, f.astype(np.int64)


def pixel_centres(n: int, extent_m: float) -> Float[np.ndarray, " n"]:
    """Coordinates (m) of the pixel centres along one image axis, increasing."""
    return -extent_m + (np.arange(n) + 0.5) * (2.0 * extent_m / n)


def rasterize_max(xy: Float[np.ndarray, "n 2"], value: Float[np.ndarray, " n"],
                  faces: Int[np.ndarray, "m 3"], *, n: int, extent_m: float) -> Float[np.ndarray, "px px"]:
    """Largest linearly-interpolated ``value`` over the triangles covering each pixel centre.

    Vectorised barycentric test over every triangle's pixel bounding box (cost proportional to
    the summed bounding-box areas), then a max z-buffer.

    Args:
        xy: (n, 2) projected vertex positions in image-plane coordinates, m.
        value: (n,) per-vertex value to interpolate (e.g. height z, m).
        faces: (m, 3) vertex indices.
        n: image size in pixels.
        extent_m: the image covers [-extent_m, extent_m] on both axes.

    Returns:
        (n, n) array, -inf where no triangle covers the pixel centre.
    """
    h = 2.0 * extent_m / n
    col = (xy[:, 0] + extent_m) / h - 0.5
    row = (extent_m - xy[:, 1]) / h - 0.5
    pc, pr, pv = col[faces], row[faces], value[faces]  # (m, 3)
    det = (pc[:, 1] - pc[:, 0]) * (pr[:, 2] - pr[:, 0]) - (pc[:, 2] - pc[:, 0]) * (pr[:, 1] - pr[:, 0])
    c0 = np.clip(np.ceil(pc.min(1)), 0, n).astype(np.int64)
    c1 = np.clip(np.floor(pc.max(1)), -1, n - 1).astype(np.int64)
    r0 = np.clip(np.ceil(pr.min(1)), 0, n).astype(np.int64)
    r1 = np.clip(np.floor(pr.max(1)), -1, n - 1).astype(np.int64)
    w = np.maximum(c1 - c0 + 1, 0)
    cnt = w * np.maximum(r1 - r0 + 1, 0)
    keep = (cnt > 0) & (np.abs(det) > 1e-12)
    out = np.full(n * n, -np.inf)
    if not keep.any():
        return out.reshape(n, n)
    fi = np.flatnonzero(keep)
    cnt, w = cnt[fi], w[fi]
    tri = np.repeat(fi, cnt)
    local = np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt)
    wr = np.repeat(w, cnt)
    cc = np.repeat(c0[fi], cnt) + local % wr
    rr = np.repeat(r0[fi], cnt) + local // wr
    ac, ar = pc[tri], pr[tri]
    dx0, dy0 = ac[:, 0] - cc, ar[:, 0] - rr
    dx1, dy1 = ac[:, 1] - cc, ar[:, 1] - rr
    dx2, dy2 = ac[:, 2] - cc, ar[:, 2] - rr
    d = det[tri]
    l0 = (dx1 * dy2 - dx2 * dy1) / d
    l1 = (dx2 * dy0 - dx0 * dy2) / d
    l2 = 1.0 - l0 - l1
    tol = -1e-9
    inside = (l0 >= tol) & (l1 >= tol) & (l2 >= tol)
    vals = (l0 * pv[tri, 0] + l1 * pv[tri, 1] + l2 * pv[tri, 2])[inside]
    np.maximum.at(out, (rr * n + cc)[inside], vals)
    return out.reshape(n, n)


def height_map(verts: Float[np.ndarray, "n 3"], faces: Int[np.ndarray, "m 3"], *, n: int = 256,
               extent_m: float = EXTENT_M) -> Float[np.ndarray, "px px"]:
    """Top-view height map: z (m) of the highest fabric surface at each pixel centre, NaN elsewhere.

    Args:
        verts: (n, 3) vertex positions in the world frame, m.
        faces: (m, 3) triangle vertex indices.
        n: image size in pixels.
        extent_m: half side of the square image window, m.

    Returns:
        float32 (n, n) on the measurement-format grid (row 0 is +y).
    """
    v, f = _check_mesh(verts, faces)
    z = rasterize_max(v[:, :2], v[:, 2], f, n=n, extent_m=extent_m)
    return np.where(np.isfinite(z), z, np.nan).astype(np.float32)


def silhouette(verts: Float[np.ndarray, "n 3"], faces: Int[np.ndarray, "m 3"], *, n: int = 256,
               extent_m: float = EXTENT_M) -> UInt8[np.ndarray, "px px"]:
    """Orthographic top-view silhouette: 255 where a pixel centre sees fabric, 0 elsewhere.

    Args:
        verts: (n, 3) vertex positions in the world frame, m.
        faces: (m, 3) triangle vertex indices.
        n: image size in pixels.
        extent_m: half side of the square image window, m.

    Returns:
        uint8 (n, n) on the measurement-format grid (row 0 is +y).
    """
    v, f = _check_mesh(verts, faces)
    z = rasterize_max(v[:, :2], v[:, 2], f, n=n, extent_m=extent_m)
    return np.where(np.isfinite(z), 255, 0).astype(np.uint8)


def point_cloud_mesh(points: Float[np.ndarray, "k 3"]) -> tuple[Float[np.ndarray, "j 3"], Int[np.ndarray, "m 3"]]:
    """Triangle mesh (vertices m, faces) through a scanned point cloud (a scan without faces).

    The points' top-view positions are triangulated (Delaunay) and a triangle is kept where its
    longest edge is at most ``ALPHA_EDGE_FACTOR`` times the median one, measured in the top view
    or in 3D: the first suits a scanner that samples by projected area, the second one that
    samples the surface, where steep skirt regions crowd together in the top view. So the
    surface spans the gaps between neighbouring samples (random or even) but not the open space
    between folds (an alpha shape). Clouds above 400 000 points are subsampled to that many.

    The last few clouds' meshes are kept (keyed by the points' values, returned read-only): a
    fit asks for the same scan's views, heights and scan distance many times.
    """
    p = np.ascontiguousarray(points, float)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"points must have shape (k, 3), got {p.shape}")
    return _alpha_mesh(p.shape, p.tobytes())


@functools.lru_cache(maxsize=8)
def _alpha_mesh(shape: tuple, data: bytes) -> tuple[np.ndarray, np.ndarray]:
    p = np.frombuffer(data, float).reshape(shape)
    p = np.unique(p[np.all(np.isfinite(p), axis=1)], axis=0)
    if len(p) > 400_000:  # far below a pixel's spacing at the default grid: subsample for time
        p = p[np.random.default_rng(0).permutation(len(p))[:400_000]]
    if len(p) < 3:
        raise ValueError(f"a point cloud needs at least 3 distinct finite points, got {len(p)}")
    from scipy.spatial import Delaunay

    tri = Delaunay(p[:, :2]).simplices
    keep = np.zeros(len(tri), bool)
    for q in (p[:, :2], p):
        edge = np.max([np.linalg.norm(q[tri[:, a]] - q[tri[:, b]], axis=1) for a, b in ((0, 1), (1, 2), (2, 0))], 0)
        keep |= edge <= ALPHA_EDGE_FACTOR * np.median(edge)
    faces = tri[keep].astype(np.int64)
    p.flags.writeable = faces.flags.writeable = False
    return p, faces


def point_cloud_views(points: Float[np.ndarray, "k 3"], *, n: int = 256,
                      extent_m: float = EXTENT_M) -> tuple[UInt8[np.ndarray, "px px"], Float[np.ndarray, "px px"]]:
    """Top-view silhouette and height map of a scanned point cloud: ``point_cloud_mesh`` rendered
    like a scan mesh (pixel centres inside a triangle), so the outline lies on the outermost
    samples, not a pixel outside them.

    Returns:
        (uint8 silhouette, float32 height map with NaN outside), both (n, n) on the
        measurement-format grid (row 0 is +y).
    """
    v, f = point_cloud_mesh(points)
    z = rasterize_max(v[:, :2], v[:, 2], f, n=n, extent_m=extent_m)
    return np.where(np.isfinite(z), 255, 0).astype(np.uint8), np.where(np.isfinite(z), z, np.nan).astype(np.float32)


def view_axes(n_views: int, elevation_deg: float, azimuth_deg: float) -> Float[np.ndarray, "v 3 3"]:
    """Orthonormal camera frames (right, up, towards-camera) of the oblique views.

    View k looks at the origin from azimuth ``azimuth_deg + 360·k/n_views`` (degrees from +x,
    counter-clockwise) and ``elevation_deg`` above the horizon. At elevation 90° and azimuth -90°
    the frame is the top view (right = +x, up = +y).
    """
    if n_views not in (1, 2, 4):
        raise ValueError(f"n_views must be 1, 2 or 4 (as in Feng et al. 2022), got {n_views}")
    el = np.deg2rad(elevation_deg)
    out = []
    for k in range(n_views):
        az = np.deg2rad(azimuth_deg + 360.0 * k / n_views)
        right = np.array([-np.sin(az), np.cos(az), 0.0])
        up = np.array([-np.sin(el) * np.cos(az), -np.sin(el) * np.sin(az), np.cos(el)])
        towards = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        out.append(np.stack([right, up, towards]))
    return np.stack(out)


def depth_views(verts: Float[np.ndarray, "n 3"], faces: Int[np.ndarray, "m 3"], *, n_views: int,
                size: int = 128, elevation_deg: float = 45.0, azimuth_deg: float = -90.0,
                extent_m: float = EXTENT_M,
                camera_distance_m: float = CAMERA_DISTANCE_M) -> Float[np.ndarray, "v size size"]:
    """Orthographic depth images of the drape from 1, 2 or 4 oblique views (Feng et al. 2022).

    One view looks from ``azimuth_deg`` (default: from -y, the front); two views are opposite;
    four are 90° apart. Depth is the distance (m) from an image plane ``camera_distance_m`` from
    the origin, along the viewing direction, to the nearest fabric; background pixels are 0.

    Args:
        verts: (n, 3) vertex positions in the world frame, m.
        faces: (m, 3) triangle vertex indices.
        n_views: 1, 2 or 4.
        size: image size in pixels; each image covers [-extent_m, extent_m] in the image plane.
        elevation_deg: camera elevation above the horizontal plane, degrees.
        azimuth_deg: azimuth of the first camera, degrees counter-clockwise from +x.
        extent_m: half side of the image window, m.
        camera_distance_m: distance of the image plane from the origin, m.

    Returns:
        float32 (n_views, size, size); row 0 is the top of the image.
    """
    v, f = _check_mesh(verts, faces)
    out = []
    for right, up, towards in view_axes(n_views, elevation_deg, azimuth_deg):
        near = rasterize_max(np.stack([v @ right, v @ up], 1), v @ towards, f, n=size, extent_m=extent_m)
        out.append(np.where(np.isfinite(near), camera_distance_m - near, 0.0))
    return np.stack(out).astype(np.float32)


def boundary_loops(faces: Int[np.ndarray, "m 3"]) -> list[np.ndarray]:
    """Closed loops of boundary edges (edges used by exactly one triangle), as vertex index arrays."""
    f = np.asarray(faces, np.int64)
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    uniq, count = np.unique(e, axis=0, return_counts=True)
    be = uniq[count == 1]
    adj: dict[int, list[int]] = {}
    for k, (a, b) in enumerate(be):
        adj.setdefault(int(a), []).append(k)
        adj.setdefault(int(b), []).append(k)
    used = np.zeros(len(be), bool)
    loops = []
    for k0 in range(len(be)):
        if used[k0]:
            continue
        used[k0] = True
        start, cur = int(be[k0, 0]), int(be[k0, 1])
        loop = [start]
        while cur != start:
            loop.append(cur)
            nxt = [k for k in adj[cur] if not used[k]]
            if not nxt:
                break
            used[nxt[0]] = True
            a, b = be[nxt[0]]
            cur = int(b) if a == cur else int(a)
        loops.append(np.asarray(loop))
    return loops


def boundary_curve(verts: Float[np.ndarray, "n 3"], faces: Int[np.ndarray, "m 3"], *,
                   n_samples: int = 128) -> Float[np.ndarray, "s 3"]:
    """The 3D hem curve, resampled uniformly by arc length (the 3DC descriptor of Ju & Choi 2020).

    The hem is the longest boundary loop of the mesh (the outer edge of a specimen, or of a scan
    with holes). It is oriented counter-clockwise seen from above and starts where it crosses
    the positive x axis (polar angle 0; the outermost crossing if there are several).

    Args:
        verts: (n, 3) vertex positions, m.
        faces: (m, 3) triangle vertex indices.
        n_samples: number of points returned.

    Returns:
        (n_samples, 3) points on the hem, m.
    """
    v, f = _check_mesh(verts, faces)
    loops = boundary_loops(f)
    if not loops:
        raise ValueError("mesh has no boundary: cannot extract a hem curve")
    lengths = [np.linalg.norm(np.diff(v[np.append(lp, lp[0])], axis=0), axis=1).sum() for lp in loops]
    p = v[loops[int(np.argmax(lengths))]]
    x, y = p[:, 0], p[:, 1]
    if np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) < 0:
        p = p[::-1]
    q = np.roll(p, -1, axis=0)
    up = (p[:, 1] < 0) & (q[:, 1] >= 0)
    t = np.where(up, -p[:, 1] / np.where(up, q[:, 1] - p[:, 1], 1.0), 0.0)
    cross = p + t[:, None] * (q - p)
    cand = np.flatnonzero(up & (cross[:, 0] > 0))
    if cand.size:
        i = cand[np.argmax(cross[cand, 0])]
        p = np.concatenate([cross[i:i + 1], np.roll(p, -(i + 1), axis=0)])
    else:
        p = np.roll(p, -int(np.argmin(np.mod(np.arctan2(p[:, 1], p[:, 0]), 2 * np.pi))), axis=0)
    closed = np.concatenate([p, p[:1]])
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(closed, axis=0), axis=1))])
    target = np.arange(n_samples) * (s[-1] / n_samples)
    return np.stack([np.interp(target, s, closed[:, d]) for d in range(3)], 1)


def rim_profile(silhouette: SilhouetteImage, extent_m: float = EXTENT_M, *,
                n_angles: int = 360) -> Float[np.ndarray, " a"]:
    """Radius r(φ) (m) of the outer silhouette boundary at angles φ_j = 2πj/n_angles from +x.

    Marches outward along each ray in quarter-pixel steps through the bilinearly interpolated
    image and returns the outermost radius where it crosses one half (the fabric boundary), so it
    works for rendered and real silhouettes alike. A ray that meets no fabric gives 0.

    Args:
        silhouette: (n, n) image, fabric > 127 (or a boolean mask), measurement-format grid.
        extent_m: half side of the image window, m.
        n_angles: number of equally spaced angles.

    Returns:
        (n_angles,) radii, m.
    """
    img = np.asarray(silhouette)
    if img.ndim != 2 or img.shape[0] != img.shape[1]:
        raise ValueError(f"silhouette must be a square 2D image, got shape {img.shape}")
    n = img.shape[0]
    mask = (img > 127 if img.dtype != bool else img).astype(float)
    h = 2.0 * extent_m / n
    r = np.arange(0.0, extent_m * np.sqrt(2.0), h / 4)
    phi = 2 * np.pi * np.arange(n_angles) / n_angles
    cos, sin = np.cos(phi), np.sin(phi)
    padded = np.pad(mask, 1)
    out = np.zeros(n_angles)
    rows_fab, cols_fab = np.nonzero(mask)
    if rows_fab.size == 0:
        return out
    # Samples farther out than every fabric pixel centre by a pixel diagonal interpolate four
    # empty pixels (exactly 0), so the march stops one sample past them; and it first marches the
    # outer half of that range only, a ray without fabric there is marched again from the centre.
    # The radii found are those of the full march.
    # (Samples outside the image read its border pixels: fabric on the border leaves no such margin.)
    r_fab = np.max(np.hypot(cols_fab + 0.5 - n / 2.0, n / 2.0 - rows_fab - 0.5)) * h
    border = mask[0].any() or mask[-1].any() or mask[:, 0].any() or mask[:, -1].any()
    stop = len(r) if border else min(len(r), int(np.searchsorted(r, r_fab + np.sqrt(2.0) * h, side="right")) + 1)
    start = stop // 2
    val = _ray_values(padded, r[start:stop], cos, sin, extent_m, h, n)
    inside = val >= 0.5
    hit = inside.any(axis=1)
    miss = np.flatnonzero(~hit)
    last = start + inside.shape[1] - 1 - np.argmax(inside[:, ::-1], axis=1)
    full = None
    if miss.size:
        full = _ray_values(padded, r[:stop], cos[miss], sin[miss], extent_m, h, n)
        inside_full = full >= 0.5
        last[miss] = inside_full.shape[1] - 1 - np.argmax(inside_full[:, ::-1], axis=1)
        hit[miss] = inside_full.any(axis=1)

    def value(rows, k):
        v = np.empty(len(rows))
        outer = k >= start
        v[outer] = val[rows[outer], k[outer] - start]
        if np.any(~outer):
            pos = np.searchsorted(miss, rows[~outer])
            v[~outer] = full[pos, k[~outer]]
        return v

    j = np.flatnonzero(hit)
    k = last[j]
    at_end = k == len(r) - 1
    k1 = np.minimum(k + 1, len(r) - 1)
    v0 = value(j, k)
    v1 = np.where(k1 < stop, value(j, np.minimum(k1, stop - 1)), 0.0)
    frac = np.where(at_end, 0.0, (v0 - 0.5) / np.where(at_end, 1.0, v0 - v1))
    out[j] = r[k] + frac * (r[k1] - r[k])
    return out


def _ray_values(padded: np.ndarray, r: np.ndarray, cos: np.ndarray, sin: np.ndarray, extent_m: float, h: float,
                n: int) -> np.ndarray:
    """Bilinear interpolation of the zero-padded mask at radii ``r`` along the rays (cos, sin)."""
    x = r[None, :] * cos[:, None]
    y = r[None, :] * sin[:, None]
    col = (x + extent_m) / h - 0.5
    row = (extent_m - y) / h - 0.5
    c0 = np.floor(col).astype(int)
    r0 = np.floor(row).astype(int)
    fc, fr = col - c0, row - r0
    c0 = np.clip(c0 + 1, 0, n)
    r0 = np.clip(r0 + 1, 0, n)
    return ((1 - fr) * ((1 - fc) * padded[r0, c0] + fc * padded[r0, c0 + 1])
            + fr * ((1 - fc) * padded[r0 + 1, c0] + fc * padded[r0 + 1, c0 + 1]))


__all__ = ["EXTENT_M", "CAMERA_DISTANCE_M", "pixel_centres", "rasterize_max", "height_map", "silhouette",
           "view_axes", "depth_views", "boundary_loops", "boundary_curve", "rim_profile"]
