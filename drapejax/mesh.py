"""Specimen meshes: built once on the host with NumPy, then held as a static ``ClothMesh``.

All specimens are unstructured triangle meshes whose resolution knob is the target edge
length ``spacing_m``. Cusick and square specimens conform to the support-disc edge (a ring of
vertices at exactly the disc radius), so the clamped region is exact.
"""

from __future__ import annotations

import dataclasses
import functools

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

CUSICK_RADIUS_M = 0.15
DISK_RADIUS_M = 0.09
RIM_ASPECT = 3.0  # circumferential over radial spacing in a graded rim band (see cusick_mesh)


@dataclasses.dataclass(frozen=True)
class SpecimenInfo:
    """Static description of the test geometry (hashable, used as a static field)."""

    test: str  # "cusick", "square", "cantilever" or "mesh"
    spacing_m: float
    specimen_radius_m: float = CUSICK_RADIUS_M  # circle radius or square half side
    disk_radius_m: float = DISK_RADIUS_M
    warp_angle_deg: float = 0.0
    strip_length_m: float = 0.0
    strip_width_m: float = 0.0


class ClothMesh(eqx.Module):
    r"""Static topology and rest geometry of a cloth specimen.

    Attributes:
        rest: (n, 3) flat rest positions in the world frame, m (z = 0 on the support).
        uv: (n, 2) material coordinates, m: u along warp, v along weft.
        faces: (m, 3) vertex indices, counter-clockwise in uv.
        area: (m,) rest triangle areas, m².
        vertex_area: (n,) lumped (one third) rest areas, m².
        dm_inv: (m, 2, 2) inverse of the rest edge matrix in uv coordinates.
        curv_verts: (c,) vertices that carry bending (all but the clamped interior).
        nbr: (c, k) neighbourhood of each such vertex used for its curvature fit (padded
            with the vertex itself).
        fit: (c, 5, k) least-squares operator mapping neighbour offsets to the first and
            second derivatives (∂u, ∂v, ∂uu, ∂uv, ∂vv) of the embedding at the vertex.
        curv_area: (c,) rest area over which each such vertex bends, m² (``_curvature_fit``).
        curv_quartic: (c, 3, 16) the fit's response to quartic offsets (``energy.bending.arc_moments``).
        hinge_rows: (l,) rows of ``curv_verts`` on the clamp line.
        hinge_curv: (l, 3) the (K_uu, K_uv, K_vv) each one's fit reports per radian of a hinge
            rotation about the line, 1/m.
        hinge_normal: (l, 2) the unit in-plane normal to the line there, towards the free side,
            in material axes.
        hg_nbr: (h, k2+1) each free vertex, then its 2-ring (padded with the vertex itself),
            for the hourglass control (``energy.hourglass``).
        hg_res: (h, k2, k2) residual operator $I - \Phi\Phi^+$ of a least-squares cubic fit
            $\Phi$ of the 2-ring offsets in uv.
        hg_tan: (h, 2, k2) operator from the offsets to the fitted tangents (∂u, ∂v).
        hg_weight: (h, k2, 3) per-offset weights of (D11, D12 + 2 D66, D22), 1/m² (see
            ``energy.hourglass``).
        clamped: (n,) vertices held by the clamp.
        hg_hinge_rows: (g,) rows of ``hg_nbr`` whose stencil reaches a clamped vertex.
        tri_stencil: (t, 6) each triangle that can bend (a free vertex in its stencil): its
            vertices, then the vertex across each of its edges (edge i is opposite its vertex i;
            the triangle's own vertex where no triangle lies across), for ``energy.shape_operator``.
        tri_hinge_rows: (t, 3, 3) each hinge angle of a triangle from its curvature tensor
            (K_uu, K_uv, K_vv) (``energy.shape_operator.hinge_operator``).
        tri_edge_normal: (t, 3, 2) the outward unit normals of a triangle's edges, material axes.
        tri_has_edge: (t, 3) 1 where a triangle lies across edge i, else 0.
        tri_area: (t,) their rest areas, m².
        tri_pairs: (q, 2) pairs of those triangles that share an edge (``CurvatureJumpControl``).
        tri_pair_stencil: (q, 8) the union of each pair's two stencils.
        tri_pair_map: (q, 12) positions in it of the first triangle's stencil, then the second's.
        info: static description of the specimen.
    """

    rest: Float[Array, "n 3"]
    uv: Float[Array, "n 2"]
    faces: Int[Array, "m 3"]
    area: Float[Array, " m"]
    vertex_area: Float[Array, " n"]
    dm_inv: Float[Array, "m 2 2"]
    curv_verts: Int[Array, " c"]
    nbr: Int[Array, "c k"]
    fit: Float[Array, "c 5 k"]
    curv_area: Float[Array, " c"]
    curv_quartic: Float[Array, "c 3 16"]
    hinge_rows: Int[Array, " l"]
    hinge_curv: Float[Array, "l 3"]
    hinge_normal: Float[Array, "l 2"]
    hg_nbr: Int[Array, "h k1"]
    hg_res: Float[Array, "h k2 k2"]
    hg_tan: Float[Array, "h 2 k2"]
    hg_weight: Float[Array, "h k2 3"]
    clamped: Bool[Array, " n"]
    hg_hinge_rows: Int[Array, " g"]
    tri_stencil: Int[Array, "t 6"]
    tri_hinge_rows: Float[Array, "t 3 3"]
    tri_edge_normal: Float[Array, "t 3 2"]
    tri_has_edge: Float[Array, "t 3"]
    tri_area: Float[Array, " t"]
    tri_pairs: Int[Array, "q 2"]
    tri_pair_stencil: Int[Array, "q 8"]
    tri_pair_map: Int[Array, "q 12"]
    info: SpecimenInfo = eqx.field(static=True)

    @property
    def n_verts(self) -> int:
        return self.rest.shape[0]

    @property
    def n_faces(self) -> int:
        return self.faces.shape[0]


def _rot(deg: float) -> np.ndarray:
    a = np.deg2rad(deg)
    return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])


def build_mesh(xy: np.ndarray, faces: np.ndarray, clamped: np.ndarray, info: SpecimenInfo,
               z: np.ndarray | None = None) -> ClothMesh:
    """Assemble a ``ClothMesh`` from host arrays (drops degenerate triangles, fixes orientation)."""
    xy = np.asarray(xy, float)
    faces = np.asarray(faces, np.int64)
    # Material frame: warp at ``warp_angle_deg`` counter-clockwise from +x.
    uv = xy @ _rot(info.warp_angle_deg)  # row-vector form of R(-angle) @ p
    e1 = uv[faces[:, 1]] - uv[faces[:, 0]]
    e2 = uv[faces[:, 2]] - uv[faces[:, 0]]
    signed = 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    keep = np.abs(signed) > 1e-6 * info.spacing_m**2
    faces, signed = faces[keep], signed[keep]
    flip = signed < 0
    faces[flip] = faces[flip][:, [0, 2, 1]]
    area = np.abs(signed)
    p = uv[faces]  # (m,3,2)
    dm = np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]], -1)  # columns are edges
    dm_inv = np.linalg.inv(dm)
    n = xy.shape[0]
    varea = np.zeros(n)
    np.add.at(varea, faces.ravel(), np.repeat(area / 3.0, 3))
    used = np.zeros(n, bool)
    used[faces.ravel()] = True
    if not used.all():
        remap = -np.ones(n, np.int64)
        remap[used] = np.arange(used.sum())
        faces = remap[faces]
        xy, uv, varea, clamped = xy[used], uv[used], varea[used], np.asarray(clamped)[used]
        z = None if z is None else np.asarray(z)[used]
    clamped = np.asarray(clamped, bool)
    adj = vertex_adjacency(faces, len(uv))
    curv_verts, nbr, fit, curv_area, hinge_curv, hinge_normal = _curvature_fit(faces, adj, uv, clamped, area)
    hinge_rows = np.flatnonzero(np.any(hinge_curv != 0, 1))
    hg_nbr, hg_res, hg_tan, hg_weight = _cubic_stencils(adj, uv, clamped, varea)
    rest = np.concatenate([xy, (np.zeros(len(xy)) if z is None else z)[:, None]], 1)
    from .energy.bending import arc_moments  # host NumPy; energy imports mesh
    from .energy.shape_operator import edge_neighbours, hinge_operator, jump_pairs

    across = edge_neighbours(faces)
    tri_stencil, tri_hinge_rows, tri_edge_normal, tri_has_edge, tri_area = hinge_operator(faces, uv, clamped, across)
    tri_pairs, tri_pair_stencil, tri_pair_map = jump_pairs(faces, clamped, tri_stencil, across)
    f = jnp.asarray
    return ClothMesh(rest=f(rest), uv=f(uv), faces=f(faces.astype(np.int32)), area=f(area), vertex_area=f(varea),
                     dm_inv=f(dm_inv), curv_verts=f(curv_verts.astype(np.int32)), nbr=f(nbr.astype(np.int32)),
                     fit=f(fit), curv_area=f(curv_area), curv_quartic=f(arc_moments(uv, curv_verts, nbr, fit, clamped)),
                     hinge_rows=f(hinge_rows.astype(np.int32)),
                     hinge_curv=f(hinge_curv[hinge_rows]), hinge_normal=f(hinge_normal[hinge_rows]),
                     hg_nbr=f(hg_nbr.astype(np.int32)), hg_res=f(hg_res), hg_tan=f(hg_tan), hg_weight=f(hg_weight),
                     clamped=f(clamped), hg_hinge_rows=f(np.flatnonzero(clamped[hg_nbr].any(1)).astype(np.int32)),
                     tri_stencil=f(tri_stencil.astype(np.int32)), tri_hinge_rows=f(tri_hinge_rows),
                     tri_edge_normal=f(tri_edge_normal),
                     tri_has_edge=f(tri_has_edge), tri_area=f(tri_area),
                     tri_pairs=f(tri_pairs.astype(np.int32)), tri_pair_stencil=f(tri_pair_stencil.astype(np.int32)),
                     tri_pair_map=f(tri_pair_map.astype(np.int32)), info=info)


def vertex_adjacency(faces: np.ndarray, n: int) -> list[set[int | np.integer]]:
    """The 1-ring of each of ``n`` vertices: the vertices it shares a triangle with."""
    adj = [set() for _ in range(n)]
    for a, b, c in np.asarray(faces):
        adj[a].update((b, c))
        adj[b].update((a, c))
        adj[c].update((a, b))
    return adj


def _curvature_fit(faces: np.ndarray, adj: list[set[int | np.integer]], uv: np.ndarray, clamped: np.ndarray,
                   area: np.ndarray, min_nb: int = 6) -> tuple[np.ndarray, ...]:
    """Per-vertex neighbourhoods, second-order Taylor-fit operators and bending areas.

    The 1-ring is used where it has at least ``min_nb`` vertices, else it is topped up with the nearest 2-ring
    vertices (boundary and low-valence vertices) to ``min_nb + 1``, so the fit of (∂u, ∂v, ∂uu, ∂uv, ∂vv) is
    over-determined and exact for quadratic embeddings on any triangulation. Vertices whose whole 1-ring is
    clamped carry no bending and are skipped.

    The clamp holds its material flat, so the curvature jumps at the clamp line (a built-in edge). A vertex on
    the clamp line takes its tangent plane (∂u, ∂v) from its clamped neighbours alone and its second derivatives
    from its free neighbours relative to that plane. Its bending area is its share of the clamp line divided by
    the curvature its fit reports for a unit hinge rotation about the line, so the clamp resists a hinge exactly
    as a continuous built-in edge does (h/2 times the share on a regular grid) whatever the stencil. A single
    quadratic fitted across the line sees half the root curvature and a plain free-side area lets the free side
    hinge cheaply: both made clamped cantilevers droop 7-38% too far. Other vertices bend over one third of each
    incident triangle that is not wholly clamped. ``adj``: the 1-rings (``vertex_adjacency``). Returns (verts,
    nbr, fit, bend_area, hinge_curv, hinge_normal): on the clamp line the fitted curvature of a unit hinge and
    the line's normal (``ClothMesh``), else 0.
    """
    n = uv.shape[0]
    interior = np.array([clamped[v] and all(clamped[w] for w in adj[v]) for v in range(n)], bool)
    barea = np.zeros(n)
    live = ~np.all(clamped[faces], 1)
    np.add.at(barea, faces[live].ravel(), np.repeat(area[live] / 3.0, 3))

    def quad(d: np.ndarray) -> np.ndarray:
        return np.stack([0.5 * d[:, 0] ** 2, d[:, 0] * d[:, 1], 0.5 * d[:, 1] ** 2], 1)

    def clamp_line_fit(d: np.ndarray, flat: np.ndarray) -> np.ndarray:
        """(5, k) operator: tangents from the clamped offsets, curvature from the free ones."""
        pc = np.linalg.pinv(d[flat])  # (2, kc)
        pf = np.linalg.pinv(quad(d[~flat]))  # (3, kf)
        f = np.zeros((5, len(d)))
        f[:2, flat] = pc
        f[2:, ~flat] = pf
        f[2:, flat] = -pf @ d[~flat] @ pc
        return f

    hinge_k, hinge_n = np.zeros((n, 3)), np.zeros((n, 2))

    def hinge_area(v: int, h: np.ndarray, d: np.ndarray, f: np.ndarray) -> float:
        """Clamp-line length share over the fitted curvature of a unit hinge about the line."""
        line = [w for w in adj[v] if clamped[w] and not interior[w]]
        seg = [uv[w] - uv[v] for w in line]
        if not seg:
            return barea[v]
        t = seg[0] - seg[1] if len(seg) == 2 else seg[0]
        nrm = np.array([-t[1], t[0]]) / np.linalg.norm(t)
        free = ~clamped[h]
        if np.mean(d[free] @ nrm) < 0:
            nrm = -nrm
        k = f[2:, free] @ np.maximum(d[free] @ nrm, 0.0)  # (K_uu, K_uv, K_vv) per unit hinge angle
        k_nn = k[0] * nrm[0] ** 2 + 2 * k[1] * nrm[0] * nrm[1] + k[2] * nrm[1] ** 2
        if k_nn <= 0:
            return barea[v]
        hinge_k[v], hinge_n[v] = k, nrm
        return 0.5 * sum(np.linalg.norm(x) for x in seg[:2]) / k_nn

    verts, hoods, fits = [], [], []
    for v in range(n):
        if interior[v]:
            continue
        s = {w for w in adj[v] if not interior[w]}
        ring2 = set().union(*(adj[w] for w in s)) - s - {v}
        ring2 = np.fromiter((w for w in ring2 if not interior[w] and (clamped[v] or not clamped[w])), np.int64)
        near = list(ring2[np.argsort(np.sum((uv[ring2] - uv[v]) ** 2, 1))])
        h = list(s)
        if clamped[v]:
            # clamp line: the quadratic part comes from free neighbours only; top up to 4 of them
            h += [w for w in adj[v] if interior[w]]
            free_near = [w for w in near if not clamped[w]]
            while sum(not clamped[w] for w in h) < 4 and free_near:
                h.append(free_near.pop(0))
        elif len(h) < min_nb:
            h += near[: min_nb + 2 - len(h)]
        h = np.asarray(h, np.int64)
        d = uv[h] - uv[v]
        verts.append(v)
        hoods.append(h)
        if clamped[v]:
            fits.append(clamp_line_fit(d, clamped[h]))
            barea[v] = hinge_area(v, h, d, fits[-1])
        else:
            fits.append(np.linalg.pinv(np.concatenate([d, quad(d)], 1)))
    k = max(len(h) for h in hoods)
    verts = np.asarray(verts, np.int64)
    nbr = np.repeat(verts[:, None], k, 1)
    fit = np.zeros((len(verts), 5, k))
    for i, (h, f) in enumerate(zip(hoods, fits)):
        nbr[i, : len(h)] = h
        fit[i, :, : len(h)] = f
    return verts, nbr, fit, barea[verts], hinge_k[verts], hinge_n[verts]


def _cubic_stencils(adj: list[set[int | np.integer]], uv: np.ndarray, clamped: np.ndarray, varea: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    r"""2-ring cubic-fit stencils of the free vertices for ``energy.hourglass``.

    For free vertex v with 2-ring offsets $d_j$ (uv, m) the design $\Phi$ holds the nine monomials of a cubic
    without constant term; ``res`` $= I - \Phi\Phi^+$ maps the offsets' normal components to the part no cubic
    explains, ``tan`` the first two rows of $\Phi^+$. ``weight`` holds $A_v/k_v \cdot (c^4, 2c^2s^2,
    s^4)/\ell^4$ per offset, the direction cosines $(c, s)$ and length ℓ of $d_j$, so that $\sum_j
    w_j\cdot(D_{11}, D_{12}+2D_{66}, D_{22})\,r_j^2$ is the directional rigidity times the squared residual
    curvature, averaged over the 2-ring. ``adj``: the 1-rings (``vertex_adjacency``). Returns (nbr, res, tan,
    weight) with rows padded to the largest 2-ring.
    """
    verts = np.flatnonzero(~clamped)
    hoods = [np.array(sorted((set().union(*(adj[w] for w in adj[v])) | adj[v]) - {v}), np.int64) for v in verts]
    k = max((len(h) for h in hoods), default=1)
    nbr = np.repeat(verts[:, None], k + 1, 1)
    for i, h in enumerate(hoods):
        nbr[i, 1:len(h) + 1] = h
    d = uv[nbr[:, 1:]] - uv[verts][:, None]  # (h, k, 2); padding rows are zero
    l2 = np.sum(d * d, -1)
    pad = l2 == 0.0
    sc = np.sqrt(np.sum(l2, 1) / np.maximum(np.sum(~pad, 1), 1))[:, None]
    a, b = d[..., 0] / sc, d[..., 1] / sc
    design = np.stack([a, b, a * a / 2, a * b, b * b / 2, a**3 / 6, a * a * b / 2, a * b * b / 2, b**3 / 6], -1)
    pinv = np.linalg.pinv(design)  # zero rows (padding) get zero columns
    res = np.eye(k) * ~pad[:, :, None] - design @ pinv
    tan = pinv[:, :2] / sc[:, :, None]
    l2s = np.where(pad, 1.0, l2)
    c2, s2 = d[..., 0] ** 2 / l2s, d[..., 1] ** 2 / l2s
    share = (varea[verts] / np.maximum(np.sum(~pad, 1), 1))[:, None]
    weight = np.where(pad, 0.0, share / l2s**2)[..., None] * np.stack([c2 * c2, 2 * c2 * s2, s2 * s2], -1)
    return nbr, res, tan, weight


def _ring(r: float, h: float, rng: np.random.Generator, jitter: bool = True) -> np.ndarray:
    k = max(6, int(round(2 * np.pi * r / h)))
    t = 2 * np.pi * (np.arange(k) + (rng.uniform() if jitter else 0.0)) / k
    return r * np.stack([np.cos(t), np.sin(t)], 1)


def _inner_disk_points(r_disk: float, h: float, rng, coarsen: float = 1.6) -> list[np.ndarray]:
    """Rings inside the clamped disc, coarsening towards the centre (the clamp carries no physics)."""
    pts, r, step = [], r_disk - h, h
    while r > 1.5 * step:
        pts.append(_ring(r, min(step, 0.4 * r * np.pi), rng))
        step *= coarsen
        r -= step
    pts.append(np.zeros((1, 2)))
    return pts


def _skirt_radii(r0: float, r1: float, h: float, h_rim: float, growth: float = 1.3) -> np.ndarray:
    """Ring radii from the disc edge ``r0`` to the hem ``r1``: steps start at ``h_rim`` and grow
    geometrically to ``h`` (uniform ``h`` when ``h_rim >= h``), then fill the rest evenly."""
    radii, r, step = [r0], r0, min(h_rim, h)
    while step < h and r + step < r1 - 0.5 * step:
        r += step
        radii.append(r)
        step *= growth
    n = max(1, int(round((r1 - r) / h)) if len(radii) == 1 else int(np.ceil((r1 - r) / h - 1e-9)))
    return np.concatenate([radii[:-1], np.linspace(r, r1, n + 1)])


def cusick_mesh(spacing_m: float = 0.005, *, radius_m: float = CUSICK_RADIUS_M,
                disk_radius_m: float = DISK_RADIUS_M, warp_angle_deg: float = 0.0,
                mesh_seed: int = 0, rim_spacing_m: float | None = None) -> ClothMesh:
    """Circular Cusick specimen on a support disc (ISO 9073-9: 30 cm specimen, 18 cm disc).

    Concentric rings with random angular phase per ring (an unstructured Delaunay mesh); one ring lies exactly
    on the disc edge and one on the hem. Spacing is ``spacing_m``, or, with ``rim_spacing_m``, the radial step
    starts at that value on the disc edge and grows by 1.3 per ring up to ``spacing_m`` (the points along those
    rings ``RIM_ASPECT`` times as far apart, at most ``spacing_m``). The skirt's bend over the disc edge is a
    boundary layer narrower than 10 mm for a mid-weight fabric, where a uniform coarse mesh hinges too cheaply
    (``docs/results/2026-12-05-arc-correction.md``).

    Equal arguments return the same (immutable) mesh object, so the jitted drops built around it are reused
    rather than compiled again (``drapejax.solve._reuse``).
    """
    return _cusick_mesh(float(spacing_m), float(radius_m), float(disk_radius_m), float(warp_angle_deg),
                        int(mesh_seed), None if rim_spacing_m is None else float(rim_spacing_m))


@functools.lru_cache(maxsize=32)
def _cusick_mesh(h: float, radius_m: float, disk_radius_m: float, warp_angle_deg: float, mesh_seed: int,
                 rim_spacing_m: float | None) -> ClothMesh:
    h_rim = h if rim_spacing_m is None else rim_spacing_m
    rng = np.random.default_rng(mesh_seed)
    pts = _inner_disk_points(disk_radius_m, min(h, RIM_ASPECT * h_rim), rng)
    radii = _skirt_radii(disk_radius_m, radius_m, h, h_rim)
    steps = np.diff(radii)
    for i, r in enumerate(radii):
        pts.append(_ring(r, min(h, RIM_ASPECT * steps[min(i, len(steps) - 1)]), rng))
    xy = np.concatenate(pts)
    faces = _delaunay(xy)
    clamped = np.linalg.norm(xy, axis=1) <= disk_radius_m * (1 + 1e-9)
    info = SpecimenInfo("cusick", h, radius_m, disk_radius_m, warp_angle_deg)
    return build_mesh(xy, faces, clamped, info)


def _jittered_grid(x0, x1, y0, y1, h, rng, jitter=0.3):
    nx = max(1, int(round((x1 - x0) / h)))
    ny = max(1, int(round((y1 - y0) / h)))
    xs, ys = np.linspace(x0, x1, nx + 1), np.linspace(y0, y1, ny + 1)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    p = np.stack([gx.ravel(), gy.ravel()], 1)
    interior = (p[:, 0] > x0 + 1e-12) & (p[:, 0] < x1 - 1e-12) & (p[:, 1] > y0 + 1e-12) & (p[:, 1] < y1 - 1e-12)
    hx, hy = (x1 - x0) / nx, (y1 - y0) / ny
    p[interior] += rng.uniform(-jitter, jitter, (interior.sum(), 2)) * [hx, hy]
    # Boundary points slide along their edge only.
    onx = ~interior & (np.abs(p[:, 1] - y0) > 1e-12) & (np.abs(p[:, 1] - y1) > 1e-12)
    p[onx, 1] += rng.uniform(-jitter, jitter, onx.sum()) * hy
    ony = ~interior & (np.abs(p[:, 0] - x0) > 1e-12) & (np.abs(p[:, 0] - x1) > 1e-12)
    p[ony, 0] += rng.uniform(-jitter, jitter, ony.sum()) * hx
    return p


def square_mesh(spacing_m: float = 0.005, *, half_side_m: float = 0.15,
                disk_radius_m: float = DISK_RADIUS_M, warp_angle_deg: float = 0.0,
                mesh_seed: int = 0) -> ClothMesh:
    """Square specimen of side 2·half_side on the same support disc."""
    h = float(spacing_m)
    rng = np.random.default_rng(mesh_seed)
    grid = _jittered_grid(-half_side_m, half_side_m, -half_side_m, half_side_m, h, rng)
    r = np.linalg.norm(grid, axis=1)
    grid = grid[r > disk_radius_m + 0.6 * h]
    pts = _inner_disk_points(disk_radius_m, h, rng) + [_ring(disk_radius_m, h, rng), grid]
    xy = np.concatenate(pts)
    faces = _delaunay(xy)
    clamped = np.linalg.norm(xy, axis=1) <= disk_radius_m * (1 + 1e-9)
    info = SpecimenInfo("square", h, half_side_m, disk_radius_m, warp_angle_deg)
    return build_mesh(xy, faces, clamped, info)


def strip_mesh(length_m: float, width_m: float, spacing_m: float, *, angle_deg: float = 0.0,
               clamp_length_m: float | None = None, mesh_seed: int = 0) -> ClothMesh:
    """Cantilever strip along +x, clamped horizontally for x <= 0, free end at x = length.

    ``angle_deg`` is the angle of the strip axis from the warp (the warp lies at
    ``-angle_deg`` from +x in the world frame).
    """
    h = float(spacing_m)
    rng = np.random.default_rng(mesh_seed)
    c = clamp_length_m if clamp_length_m is not None else 2 * h
    free = _jittered_grid(0.0, length_m, -width_m / 2, width_m / 2, h, rng)
    ny = max(1, int(round(width_m / h)))
    clamp_cols = [np.stack([np.full(ny + 1, x), np.linspace(-width_m / 2, width_m / 2, ny + 1)], 1)
                  for x in np.linspace(-c, -h, max(1, int(round(c / h))))]
    xy = np.concatenate([free] + clamp_cols)
    xy = np.unique(np.round(xy, 12), axis=0)
    faces = _delaunay(xy)
    clamped = xy[:, 0] <= 1e-12
    info = SpecimenInfo("cantilever", h, 0.0, 0.0, -angle_deg, length_m, width_m)
    return build_mesh(xy, faces, clamped, info)


def _delaunay(xy: np.ndarray) -> np.ndarray:
    """Delaunay triangles of planar points (SciPy's, imported here: only mesh builders need it)."""
    from scipy.spatial import Delaunay

    return Delaunay(xy).simplices


def from_trimesh(mesh_or_path, *, clamped=None, spacing_m: float | None = None,
                 warp_angle_deg: float = 0.0, disk_radius_m: float = DISK_RADIUS_M) -> ClothMesh:
    """Any flat triangle mesh (a path readable by trimesh, or a ``trimesh.Trimesh``).

    The mesh is taken as the flat rest shape in its xy-plane. ``clamped`` is a boolean
    array; by default vertices within the support-disc radius are clamped.
    """
    import trimesh

    tm = (mesh_or_path if isinstance(mesh_or_path, trimesh.Trimesh)
          else trimesh.load(mesh_or_path, force="mesh", process=False))
    v = np.asarray(tm.vertices, float)
    if np.ptp(v[:, 2]) > 1e-6 * max(np.ptp(v[:, 0]), 1e-12):
        raise ValueError(f"{mesh_or_path}: rest mesh must be flat in the xy-plane (z spread {np.ptp(v[:, 2]):.3g} m)")
    f = np.asarray(tm.faces, np.int64)
    if spacing_m is None:
        spacing_m = float(np.mean(np.linalg.norm(v[f[:, 1]] - v[f[:, 0]], axis=1)))
    if clamped is None:
        clamped = np.linalg.norm(v[:, :2], axis=1) <= disk_radius_m * (1 + 1e-9)
    r = float(np.max(np.linalg.norm(v[:, :2], axis=1)))
    info = SpecimenInfo("mesh", float(spacing_m), r, disk_radius_m, warp_angle_deg)
    return build_mesh(v[:, :2], f, clamped, info)


def specimen_mesh(test: str, spacing_m: float, *, warp_angle_deg: float = 0.0, mesh_seed: int = 0,
                  size_m: float | None = None, rim_spacing_m: float | None = None) -> ClothMesh:
    """Mesh for a named drape test ('cusick' or 'square'; ``rim_spacing_m``: Cusick only)."""
    if test == "cusick":
        return cusick_mesh(spacing_m, radius_m=size_m or CUSICK_RADIUS_M, warp_angle_deg=warp_angle_deg,
                           mesh_seed=mesh_seed, rim_spacing_m=rim_spacing_m)
    if rim_spacing_m is not None:
        raise ValueError(f"rim_spacing_m grades Cusick meshes only, not test {test!r}")
    if test == "square":
        return square_mesh(spacing_m, half_side_m=size_m or CUSICK_RADIUS_M, warp_angle_deg=warp_angle_deg,
                           mesh_seed=mesh_seed)
    raise ValueError(f"unknown test {test!r}: expected 'cusick' or 'square'")


class Prolongation(eqx.Module):
    """The map from a coarse mesh's vertex positions to those of its uniform subdivision.

    Every fine vertex is a coarse vertex (both parents the same) or the midpoint of a coarse edge, so ``fine =
    0.5 (x[parents[:, 0]] + x[parents[:, 1]])`` reproduces a coarse shape exactly on the fine mesh: each coarse
    triangle's four children carry its deformation gradient, and prolongation adds no membrane strain. Clamped
    fine vertices take their rest positions (the midpoint of a clamped chord is moved onto the disc edge at
    rest).

    Attributes:
        parents: (n_fine, 2) coarse vertex indices.
    """

    parents: Int[Array, "nf 2"]

    def __call__(self, x_coarse: Float[Array, "nc 3"], fine: ClothMesh) -> Float[Array, "nf 3"]:
        x = 0.5 * (x_coarse[self.parents[:, 0]] + x_coarse[self.parents[:, 1]])
        return jnp.where(fine.clamped[:, None], fine.rest, x)


def subdivide(mesh: ClothMesh) -> tuple[ClothMesh, Prolongation]:
    """Split every triangle of ``mesh`` into four by its edge midpoints (Loop-style topology, no smoothing): the
    nested fine mesh at half the spacing, and the ``Prolongation`` onto it.

    A midpoint of an edge on the specimen's outer circle or on the support-disc edge is moved radially onto that
    circle, so the fine mesh keeps the exact clamp line and hem; inside, the fine mesh is nested in the coarse
    one. Cusick and square specimens from ``cusick_mesh`` or ``square_mesh`` (with the disc edge a ring of
    vertices) keep their clamp set exactly.
    """
    faces = np.asarray(mesh.faces, np.int64)
    xy = np.asarray(mesh.rest)[:, :2]
    n = xy.shape[0]
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    uniq, inverse = np.unique(edges, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    mid = 0.5 * (xy[uniq[:, 0]] + xy[uniq[:, 1]])
    info = mesh.info
    r = np.linalg.norm(xy, axis=1)
    for radius in (info.disk_radius_m, info.specimen_radius_m if info.test == "cusick" else 0.0):
        if radius <= 0.0:
            continue
        on = np.isclose(r, radius, rtol=1e-9, atol=1e-12)
        both = on[uniq[:, 0]] & on[uniq[:, 1]]
        rm = np.linalg.norm(mid[both], axis=1)
        mid[both] *= (radius / np.where(rm > 0, rm, 1.0))[:, None]
    m = faces.shape[0]
    e01, e12, e20 = (n + inverse[k * m:(k + 1) * m] for k in range(3))
    a, b, c = faces.T
    fine_faces = np.concatenate([np.stack([a, e01, e20], 1), np.stack([e01, b, e12], 1),
                                 np.stack([e20, e12, c], 1), np.stack([e01, e12, e20], 1)])
    fine_xy = np.concatenate([xy, mid])
    clamped_c = np.asarray(mesh.clamped, bool)
    clamped = np.concatenate([clamped_c, clamped_c[uniq[:, 0]] & clamped_c[uniq[:, 1]]])
    if info.test in ("cusick", "square"):
        clamped = np.linalg.norm(fine_xy, axis=1) <= info.disk_radius_m * (1 + 1e-9)
    fine = build_mesh(fine_xy, fine_faces, clamped, dataclasses.replace(info, spacing_m=0.5 * info.spacing_m))
    if fine.n_verts != fine_xy.shape[0]:
        raise ValueError("subdivide: the coarse mesh has vertices in no triangle; cannot nest it")
    parents = np.concatenate([np.stack([np.arange(n), np.arange(n)], 1), uniq])
    return fine, Prolongation(parents=jnp.asarray(parents.astype(np.int32)))


@functools.lru_cache(maxsize=16)
def nested_cusick_meshes(spacing_m: float, levels: int, *, rim_spacing_m: float | None = None,
                         radius_m: float = CUSICK_RADIUS_M, disk_radius_m: float = DISK_RADIUS_M,
                         warp_angle_deg: float = 0.0, mesh_seed: int = 0
                         ) -> tuple[tuple[ClothMesh, ...], tuple[Prolongation, ...]]:
    """A Cusick mesh hierarchy: ``cusick_mesh(spacing_m, rim_spacing_m=...)`` and its ``levels - 1`` successive
    uniform subdivisions (finest last, spacing ``spacing_m / 2**(levels-1)``), with the prolongations between
    consecutive levels. Equal arguments return the same objects (so jitted programs built around them are reused)."""
    if levels < 1:
        raise ValueError(f"nested_cusick_meshes: levels must be at least 1, got {levels}")
    meshes = [cusick_mesh(spacing_m, radius_m=radius_m, disk_radius_m=disk_radius_m, warp_angle_deg=warp_angle_deg,
                          mesh_seed=mesh_seed, rim_spacing_m=rim_spacing_m)]
    prolongs = []
    for _ in range(levels - 1):
        fine, p = subdivide(meshes[-1])
        meshes.append(fine)
        prolongs.append(p)
    return tuple(meshes), tuple(prolongs)


COARSEST_SPACING_M = 0.02
"""Interior spacing above which ``cusick_hierarchy`` adds no coarser level (the dynamic drop runs
on the coarsest level, which must still resolve the fold pattern)."""
RIM_RATIO = 5.0
"""Interior over disc-edge spacing of ``cusick_hierarchy``'s levels when no rim spacing is given."""


def hierarchy_rim_spacing(spacing_m: float, rim_spacing_m: float | None = None) -> float:
    """The disc-edge spacing of ``cusick_hierarchy``'s finest level: ``rim_spacing_m``, at most
    ``spacing_m``, or ``spacing_m / RIM_RATIO`` when not given."""
    return spacing_m / RIM_RATIO if rim_spacing_m is None else min(rim_spacing_m, spacing_m)


def cusick_hierarchy(spacing_m: float, rim_spacing_m: float | None = None, *, coarsest_spacing_m=COARSEST_SPACING_M,
                     warp_angle_deg: float = 0.0, mesh_seed: int = 0, radius_m: float = CUSICK_RADIUS_M,
                     disk_radius_m: float = DISK_RADIUS_M) -> tuple[tuple[ClothMesh, ...], tuple[Prolongation, ...]]:
    """The nested Cusick meshes whose finest level has interior spacing ``spacing_m`` and disc-edge
    spacing ``rim_spacing_m`` (default ``spacing_m / RIM_RATIO``): the coarsest level is the rim-graded
    mesh at ``spacing_m * 2**(levels - 1)``, the largest such spacing not above ``coarsest_spacing_m``
    (one level when ``spacing_m`` is already that coarse); radii as ``cusick_mesh``."""
    if spacing_m <= 0 or (rim_spacing_m is not None and rim_spacing_m <= 0):
        raise ValueError(f"cusick_hierarchy: spacings must be positive, got {spacing_m}, {rim_spacing_m}")
    levels = 1 + max(0, int(np.floor(np.log2(coarsest_spacing_m / spacing_m) + 1e-9)))
    scale = 2.0 ** (levels - 1)
    rim = hierarchy_rim_spacing(spacing_m, rim_spacing_m)
    return nested_cusick_meshes(spacing_m * scale, levels, rim_spacing_m=rim * scale, radius_m=radius_m,
                                disk_radius_m=disk_radius_m, warp_angle_deg=warp_angle_deg, mesh_seed=mesh_seed)


__all__ = ["ClothMesh", "SpecimenInfo", "build_mesh", "cusick_mesh", "square_mesh", "strip_mesh", "from_trimesh",
           "specimen_mesh", "vertex_adjacency", "subdivide", "nested_cusick_meshes", "cusick_hierarchy",
           "hierarchy_rim_spacing", "COARSEST_SPACING_M", "RIM_RATIO", "Prolongation", "CUSICK_RADIUS_M",
           "DISK_RADIUS_M"]
