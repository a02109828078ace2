"""Comparison metrics between two drapes (measured vs simulated, or capture vs capture).

Real scans carry no warp direction (``warp_angle_deg`` is None), so every orientation-dependent
metric can search over the in-plane rotation about the disc axis (flag ``align_rotation`` or,
for images, ``aligned_iou``), and optionally over a mirror image (the specimen turned over).
Mesh metrics follow Feng et al. 2022 (mean vertex displacement in mm, relative mean-curvature
difference).
"""

from __future__ import annotations

import collections
import hashlib

import cv2
import numpy as np
from jaxtyping import Float, Int

from ..mesh import CUSICK_RADIUS_M, DISK_RADIUS_M
from .descriptors import drape_coefficient, rim_spectrum
from .render import EXTENT_M, SilhouetteImage, boundary_loops


def _mask(img) -> np.ndarray:
    a = np.asarray(img)
    return a if a.dtype == bool else a > 127


def iou(sil_a: SilhouetteImage, sil_b: SilhouetteImage) -> float:
    """Intersection over union of two silhouettes on the same grid (fabric > 127), no alignment."""
    a, b = _mask(sil_a), _mask(sil_b)
    if a.shape != b.shape:
        raise ValueError(f"silhouettes must share a grid, got shapes {a.shape} and {b.shape}")
    union = np.count_nonzero(a | b)
    return float(np.count_nonzero(a & b) / union) if union else 1.0


def rotate_image(img: np.ndarray, angle_deg: float, *, mirror: bool = False) -> np.ndarray:
    """Rotate a measurement-grid image counter-clockwise (world frame) about the disc axis.

    With ``mirror`` the image is first reflected y → -y. Nearest-neighbour resampling.
    """
    a = np.asarray(img)
    if mirror:
        a = a[::-1]
    n = a.shape[0]
    c = (n - 1) / 2.0
    m = cv2.getRotationMatrix2D((c, c), float(angle_deg), 1.0)
    return cv2.warpAffine(a.astype(np.uint8), m, (n, n), flags=cv2.INTER_NEAREST, borderValue=0)


def aligned_iou(sil_a: SilhouetteImage, sil_b: SilhouetteImage, *, mirror: bool = False,
                step_deg: float = 1.0, refine_deg: float = 0.1) -> tuple[float, float, bool]:
    """IoU maximised over rotations of ``sil_b`` about the disc axis (and its mirror image).

    Coarse search every ``step_deg`` over 360°, then a local search every ``refine_deg`` around
    the best angle.

    Args:
        sil_a: (n, n) reference silhouette (fabric > 127).
        sil_b: (n, n) silhouette to rotate, same grid.
        mirror: also search over ``sil_b`` reflected y → -y.
        step_deg: coarse angular step, degrees.
        refine_deg: fine angular step, degrees (0 skips refinement).

    Returns:
        (iou, angle_deg, mirrored): rotating ``sil_b`` (mirrored first if ``mirrored``)
        counter-clockwise by ``angle_deg`` makes it best match ``sil_a``.
    """
    a = _mask(sil_a)
    b = _mask(sil_b).astype(np.uint8)
    if a.shape != b.shape:
        raise ValueError(f"silhouettes must share a grid, got shapes {a.shape} and {b.shape}")
    best = (-1.0, 0.0, False)
    for mir in (False, True) if mirror else (False,):
        for ang in np.arange(0.0, 360.0, step_deg):
            s = iou(a, rotate_image(b, ang, mirror=mir).astype(bool))
            if s > best[0]:
                best = (s, float(ang), mir)
        if refine_deg > 0:
            _, a0, m0 = best
            if m0 == mir:
                for ang in a0 + np.arange(-step_deg, step_deg + 1e-9, refine_deg):
                    s = iou(a, rotate_image(b, ang, mirror=mir).astype(bool))
                    if s > best[0]:
                        best = (s, float(ang % 360.0), mir)
    return best


def spectral_distance(profile_a: Float[np.ndarray, " a"], profile_b: Float[np.ndarray, " b"], *,
                      n_harmonics: int = 16) -> float:
    """Phase-invariant distance (mm) between two rim profiles r(φ) given in metres.

    Euclidean distance between the harmonic amplitudes k = 0..n_harmonics (``rim_spectrum``);
    invariant to rotating or mirroring either drape, and to the profiles' sampling.
    """
    return float(np.linalg.norm(rim_spectrum(profile_a, n_harmonics) - rim_spectrum(profile_b, n_harmonics)) * 1e3)


def dc_difference(sil_a: SilhouetteImage, sil_b: SilhouetteImage, *,
                  extent_m: float = EXTENT_M, specimen_radius_m: float = CUSICK_RADIUS_M,
                  disk_radius_m: float = DISK_RADIUS_M, test: str = "cusick") -> float:
    """Drape coefficient of ``sil_a`` minus that of ``sil_b`` (both on the same window)."""
    kw = dict(specimen_radius_m=specimen_radius_m, disk_radius_m=disk_radius_m, test=test)
    return drape_coefficient(sil_a, extent_m, **kw) - drape_coefficient(sil_b, extent_m, **kw)


def rotate_about_axis(verts: Float[np.ndarray, "n 3"], angle_deg: float, *,
                      mirror: bool = False) -> Float[np.ndarray, "n 3"]:
    """Mirror y → -y (optional), then rotate counter-clockwise by ``angle_deg`` about the disc axis."""
    v = np.asarray(verts, float)
    a = np.deg2rad(angle_deg)
    c, s = np.cos(a), np.sin(a)
    x, y = v[:, 0], (-v[:, 1] if mirror else v[:, 1])
    return np.stack([c * x - s * y, s * x + c * y, v[:, 2]], 1)


def _mesh(verts, faces, name: str) -> tuple[np.ndarray, np.ndarray]:
    v = np.asarray(verts, float)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
        raise ValueError(f"{name}: expected verts (n, 3) and faces (m, 3) with m > 0, got {v.shape} and {f.shape}")
    return v, f.astype(np.int64)


def triangle_areas(tri: Float[np.ndarray, "m 3 3"]) -> np.ndarray:
    """(m,) areas of triangles given by their corner coordinates (m, 3, 3), m²."""
    return 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)


def sample_surface(verts, faces, n_points: int, *, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Area-uniform random points (n_points, 3) on a triangle mesh and their face indices.

    Deterministic for a given ``seed``.
    """
    v, f = _mesh(verts, faces, "sample_surface")
    tri = v[f]
    area = triangle_areas(tri)
    rng = np.random.default_rng(seed)
    fi = rng.choice(len(f), size=n_points, p=area / area.sum())
    u, w = rng.random(n_points), rng.random(n_points)
    flip = u + w > 1
    u, w = np.where(flip, 1 - u, u), np.where(flip, 1 - w, w)
    t = tri[fi]
    return t[:, 0] + u[:, None] * (t[:, 1] - t[:, 0]) + w[:, None] * (t[:, 2] - t[:, 0]), fi


class _Surface:
    """Exact point-to-surface distance: k nearest dense samples give candidate triangles.

    Build it with ``_surface`` so that the surface of a mesh compared again and again (a capture
    scored against many simulated drapes) is sampled and indexed once."""

    def __init__(self, verts, faces, *, n_dense: int = 40000, k: int = 12):
        self.v, self.f = _mesh(verts, faces, "surface")
        pts, self.face_of = sample_surface(self.v, self.f, n_dense, seed=1)
        pts = np.concatenate([pts, self.v])
        vface = np.zeros(len(self.v), np.int64)
        vface[self.f.ravel()] = np.repeat(np.arange(len(self.f)), 3)
        self.face_of = np.concatenate([self.face_of, vface])
        from scipy.spatial import cKDTree

        self.tree = cKDTree(pts)
        self.k = k

    def approx(self, p: np.ndarray) -> np.ndarray:
        return self.tree.query(p)[0]

    def distance(self, p: np.ndarray) -> np.ndarray:
        _, idx = self.tree.query(p, k=self.k)
        cand = self.face_of[idx]  # (q, k)
        tris = self.v[self.f[cand.ravel()]]
        q = np.repeat(p, self.k, axis=0)
        import trimesh

        closest = trimesh.triangles.closest_point(tris, q)
        return np.linalg.norm(closest - q, axis=1).reshape(len(p), self.k).min(1)


_SURFACES: "collections.OrderedDict[bytes, _Surface]" = collections.OrderedDict()
_SURFACE_CACHE_SIZE = 16


def _surface(verts, faces, *, n_dense: int = 40000) -> _Surface:
    """``_Surface(verts, faces, n_dense=...)``, reused for a mesh with the same vertices and faces
    (a small least-recently-used cache keyed by a digest of their bytes)."""
    v, f = _mesh(verts, faces, "surface")
    key = hashlib.blake2b(v.tobytes() + f.tobytes() + str((v.shape, f.shape, n_dense)).encode(),
                          digest_size=16).digest()
    surf = _SURFACES.get(key)
    if surf is None:
        surf = _SURFACES[key] = _Surface(v, f, n_dense=n_dense)
        while len(_SURFACES) > _SURFACE_CACHE_SIZE:
            _SURFACES.popitem(last=False)
    else:
        _SURFACES.move_to_end(key)
    return surf


def align_rotation_z(verts_a, faces_a, verts_b, faces_b, *, mirror: bool = False, n_points: int = 2000,
                     step_deg: float = 5.0) -> tuple[float, bool]:
    """Rotation about the disc axis (and mirror) of mesh a that best fits mesh b.

    Minimises the mean nearest-sample distance from ``n_points`` points on a to dense samples on
    b: a coarse scan every ``step_deg`` with a quarter of the points, then a bounded scalar
    refinement (to 0.05°) around the two best angles.

    Returns:
        (angle_deg, mirrored): apply ``mirror y → -y`` (if mirrored) then a counter-clockwise
        rotation by angle_deg to a.
    """
    from scipy.optimize import minimize_scalar

    pa, _ = sample_surface(verts_a, faces_a, n_points, seed=0)
    coarse = pa[: max(n_points // 4, 1)]
    surf = _surface(verts_b, faces_b, n_dense=20000)

    def cost(p, ang, mir):
        return float(surf.approx(rotate_about_axis(p, ang, mirror=mir)).mean())

    results = []
    for mir in (False, True) if mirror else (False,):
        angs = np.arange(0.0, 360.0, step_deg)
        # Every coarse angle's points in one tree query; each row's mean as ``cost`` takes it.
        d = surf.approx(np.concatenate([rotate_about_axis(coarse, a, mirror=mir) for a in angs]))
        d = d.reshape(len(angs), len(coarse))
        costs = np.array([float(d[i].mean()) for i in range(len(angs))])
        for a0 in angs[np.argsort(costs)[:2]]:
            r = minimize_scalar(lambda a: cost(pa, a, mir), bounds=(a0 - step_deg, a0 + step_deg),
                                method="bounded", options={"xatol": 0.05})
            results.append((float(r.fun), float(r.x) % 360.0, mir))
    _, ang, mir = min(results)
    return ang, mir


def _aligned(verts_a, faces_a, verts_b, faces_b, align_rotation: bool, mirror: bool) -> np.ndarray:
    va, _ = _mesh(verts_a, faces_a, "mesh a")
    if not align_rotation:
        return va
    ang, mir = align_rotation_z(verts_a, faces_a, verts_b, faces_b, mirror=mirror)
    return rotate_about_axis(va, ang, mirror=mir)


def scan_distance_mm(verts_a: Float[np.ndarray, "n 3"], faces_a: Int[np.ndarray, "m 3"],
                     verts_b: Float[np.ndarray, "k 3"], faces_b: Int[np.ndarray, "j 3"], *,
                     align_rotation: bool = True, mirror: bool = False, n_points: int = 5000) -> float:
    """Symmetric mean point-to-surface distance (mm) between two draped meshes.

    ``n_points`` area-uniform points on each surface; exact distance to the other surface (nearest
    of the candidate triangles found through a dense point sampling); the two means are averaged.

    Args:
        verts_a, faces_a: first mesh, m.
        verts_b, faces_b: second mesh, m.
        align_rotation: first rotate a about the disc axis to best fit b (unknown orientation).
        mirror: let the alignment also consider the mirror image of a.
        n_points: points sampled on each surface.
    """
    va = _aligned(verts_a, faces_a, verts_b, faces_b, align_rotation, mirror)
    fa = np.asarray(faces_a)
    pa, _ = sample_surface(va, fa, n_points, seed=2)
    pb, _ = sample_surface(verts_b, faces_b, n_points, seed=3)
    d_ab = _surface(verts_b, faces_b).distance(pa).mean()
    d_ba = _surface(va, fa).distance(pb).mean()
    return float(0.5 * (d_ab + d_ba) * 1e3)


def _check_correspondence(va: np.ndarray, vb: np.ndarray) -> None:
    if va.shape != vb.shape:
        raise ValueError(f"correspondence=True needs meshes with the same vertices, got {va.shape} and {vb.shape}")


def _kabsch_z(va: np.ndarray, vb: np.ndarray, mirror: bool) -> np.ndarray:
    """Best rotation about z (and mirror) of va onto corresponding vb, applied to va."""
    best = None
    for mir in (False, True) if mirror else (False,):
        a = rotate_about_axis(va, 0.0, mirror=mir)
        ang = np.degrees(np.arctan2(np.sum(a[:, 0] * vb[:, 1] - a[:, 1] * vb[:, 0]),
                                    np.sum(a[:, 0] * vb[:, 0] + a[:, 1] * vb[:, 1])))
        out = rotate_about_axis(va, ang, mirror=mir)
        err = np.linalg.norm(out - vb, axis=1).mean()
        if best is None or err < best[0]:
            best = (err, out)
    return best[1]


def mean_vertex_displacement_mm(verts_a: Float[np.ndarray, "n 3"], faces_a: Int[np.ndarray, "m 3"],
                                verts_b: Float[np.ndarray, "k 3"], faces_b: Int[np.ndarray, "j 3"], *,
                                align_rotation: bool = True, mirror: bool = False,
                                correspondence: bool = False) -> float:
    """Mean distance (mm) from the vertices of mesh a to mesh b (Feng et al. 2022, metric 1).

    Each vertex of a is compared with the nearest point of surface b, after ``align_rotation_z``.
    With ``correspondence`` (meshes with the same vertices, e.g. two simulations of one
    ``ClothMesh``) vertex i of a is compared with vertex i of b, after the best rotation about z
    in closed form.
    """
    va, _ = _mesh(verts_a, faces_a, "mesh a")
    vb, _ = _mesh(verts_b, faces_b, "mesh b")
    if correspondence:
        _check_correspondence(va, vb)
        va = _kabsch_z(va, vb, mirror) if align_rotation else va
        return float(np.linalg.norm(va - vb, axis=1).mean() * 1e3)
    va = _aligned(verts_a, faces_a, verts_b, faces_b, align_rotation, mirror)
    return float(_Surface(vb, faces_b).distance(va).mean() * 1e3)


def mean_curvature(verts: Float[np.ndarray, "n 3"], faces: Int[np.ndarray, "m 3"]) -> Float[np.ndarray, " n"]:
    """Signed mean curvature (1/m) per vertex from the cotangent Laplacian; NaN on the boundary.

    $H_i = -\\tfrac12 (Δx)_i·n_i$ with $(Δx)_i = \\frac{1}{2A_i}\\sum_j(\\cot α_{ij}+\\cot β_{ij})(x_j-x_i)$
    and $A_i$ the barycentric area; positive for a sphere with outward normals. Normals are
    oriented so that the mesh's total upward projected area is positive (the drape's top side).
    """
    v, f = _mesh(verts, faces, "mean_curvature")
    tri = v[f]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    if cross[:, 2].sum() < 0:
        cross = -cross
        f = f[:, [0, 2, 1]]
        tri = v[f]
    area2 = np.linalg.norm(cross, axis=1)
    n = len(v)
    lap = np.zeros((n, 3))
    for i in range(3):
        j, k = (i + 1) % 3, (i + 2) % 3
        e1, e2 = tri[:, j] - tri[:, i], tri[:, k] - tri[:, i]
        cot = np.einsum("ij,ij->i", e1, e2) / np.maximum(area2, 1e-300)
        d = tri[:, k] - tri[:, j]
        np.add.at(lap, f[:, j], cot[:, None] * d)
        np.add.at(lap, f[:, k], -cot[:, None] * d)
    varea = np.zeros(n)
    np.add.at(varea, f.ravel(), np.repeat(area2 / 6.0, 3))
    vn = np.zeros((n, 3))
    np.add.at(vn, f.ravel(), np.repeat(cross, 3, axis=0))
    vn /= np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-300)
    h = -0.5 * np.einsum("ij,ij->i", lap / (2.0 * np.maximum(varea, 1e-300))[:, None], vn)
    boundary = np.zeros(n, bool)
    for loop in boundary_loops(f):
        boundary[loop] = True
    used = np.zeros(n, bool)
    used[f.ravel()] = True
    h[boundary | ~used] = np.nan
    return h


def mean_relative_curvature_difference(verts_a: Float[np.ndarray, "n 3"], faces_a: Int[np.ndarray, "m 3"],
                                       verts_b: Float[np.ndarray, "k 3"], faces_b: Int[np.ndarray, "j 3"], *,
                                       align_rotation: bool = True, mirror: bool = False,
                                       correspondence: bool = False) -> float:
    """Relative mean-curvature difference of mesh a against reference b (Feng et al. 2022, metric 2).

    $\\sum_i |H_a(i) − H_b(π(i))| / \\sum_i |H_b(π(i))|$ over interior vertices i of a, with π(i) the
    nearest interior vertex of b after rotation alignment (π(i) = i with ``correspondence``).
    A ratio of sums, so vertices with H ≈ 0 do not blow it up.
    """
    va, _ = _mesh(verts_a, faces_a, "mesh a")
    vb, _ = _mesh(verts_b, faces_b, "mesh b")
    ha, hb = mean_curvature(va, faces_a), mean_curvature(vb, faces_b)
    if correspondence:
        _check_correspondence(va, vb)
        ok = np.isfinite(ha) & np.isfinite(hb)
        diff, ref = ha[ok] - hb[ok], hb[ok]
    else:
        va = _aligned(va, faces_a, vb, faces_b, align_rotation, mirror)
        okb = np.flatnonzero(np.isfinite(hb))
        oka = np.isfinite(ha)
        from scipy.spatial import cKDTree

        _, j = cKDTree(vb[okb]).query(va[oka])
        ref = hb[okb[j]]
        diff = ha[oka] - ref
    return float(np.abs(diff).sum() / np.abs(ref).sum())


def mean_abs_curvature(verts: Float[np.ndarray, "n 3"], faces: Int[np.ndarray, "m 3"]) -> float:
    """Area-weighted mean of |H| (1/m) over the interior vertices: how sharply a drape is folded."""
    v, f = _mesh(verts, faces, "mean_abs_curvature")
    h = mean_curvature(v, f)
    tri = v[f]
    area = triangle_areas(tri)
    varea = np.zeros(len(v))
    np.add.at(varea, f.ravel(), np.repeat(area / 3.0, 3))
    ok = np.isfinite(h)
    return float(np.sum(np.abs(h[ok]) * varea[ok]) / np.sum(varea[ok]))


def relative_curvature_level_difference(verts_a: Float[np.ndarray, "n 3"], faces_a: Int[np.ndarray, "m 3"],
                                        verts_b: Float[np.ndarray, "k 3"],
                                        faces_b: Int[np.ndarray, "j 3"]) -> float:
    """|H̄_a − H̄_b| / H̄_b with H̄ the ``mean_abs_curvature``: orientation- and noise-robust.

    A global reading of Feng et al.'s metric 2 (their values, 1–19%, are of this size, whereas
    the pointwise ``mean_relative_curvature_difference`` of two re-drops is of order 1).
    """
    ha, hb = mean_abs_curvature(verts_a, faces_a), mean_abs_curvature(verts_b, faces_b)
    return float(abs(ha - hb) / hb)


__all__ = ["triangle_areas", "iou", "rotate_image", "rotate_about_axis", "aligned_iou", "spectral_distance",
           "dc_difference", "sample_surface", "align_rotation_z", "scan_distance_mm", "mean_vertex_displacement_mm",
           "mean_curvature", "mean_relative_curvature_difference", "mean_abs_curvature",
           "relative_curvature_level_difference"]
