r"""Anisotropic bending from a per-triangle shape operator of its three hinge angles.

Each triangle $t$ gets a curvature tensor $K_t$ (2x2, material axes) from the dihedral angles
$\theta_i$ at its three edges (Grinspun, Gingold, Reisman and Zorin 2006, "Computing discrete
shape operators on general meshes"). Across edge $i$ the surface normal turns by
$\theta_i = \tau_i^\top (g_{t'} - g_t)$ in the small-slope limit, with $\tau_i$ the edge's
outward in-plane normal and $g_t$ the slope of the linear interpolant on $t$. For a quadratic
surface $z = \tfrac12 p^\top K p$ each $g_t$ is linear in $K$ and fixed by the rest triangle, so
$\theta_i = a_i^\top (K_{11}, K_{12}, K_{22})$ exactly, on any triangulation; the three edges give
three equations for the three entries of $K_t$ (rows fixed at rest, ``hinge_operator``). A
triangle on a free edge lacks that edge's equation; the edge's natural boundary condition, no
bending moment about it, takes its place (which gives a narrow strip its anticlastic curvature).

The energy is $\sum_t A_t\,w(K_t)$ with ``bending.bending_density``'s anisotropic nonlinear $w$,
the same constitutive law as ``Bending`` (so the same material parameters mean the same fabric),
but each element's stencil is the triangle and its three neighbours' opposite vertices (6
vertices, an 18x18 element Hessian) instead of a vertex 1-ring fit and its 2-ring hourglass
control (22 vertices). Every non-rigid shape has nonzero hinge angles, so the discretisation has
no zero-energy (hourglass) modes to control.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from ._base import AbstractEnergy, normalize
from .bending import bending_density, linear_density, plate_terms


def edge_neighbours(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(m, 3) each: the vertex opposite edge i of triangle t in the triangle across that edge, and
    that triangle, or -1.

    Edge i of triangle (a, b, c) is the one opposite its i-th vertex."""
    m = faces.shape[0]
    a = np.stack([faces[:, 1], faces[:, 2], faces[:, 0]], 1)  # edge i from a[:, i] to b[:, i]
    b = np.stack([faces[:, 2], faces[:, 0], faces[:, 1]], 1)
    key = np.minimum(a, b).astype(np.int64) * (faces.max() + 1) + np.maximum(a, b)
    flat = key.reshape(-1)
    order = np.argsort(flat, kind="stable")
    opp, tri = -np.ones(3 * m, np.int64), -np.ones(3 * m, np.int64)
    same = flat[order[1:]] == flat[order[:-1]]
    i, j = order[:-1][same], order[1:][same]
    own = faces.reshape(-1)  # vertex i of triangle t is opposite edge i
    opp[i], opp[j] = own[j], own[i]
    tri[i], tri[j] = j // 3, i // 3
    return opp.reshape(m, 3), tri.reshape(m, 3)


def hinge_operator(faces: np.ndarray, uv: np.ndarray, clamped: np.ndarray, neighbours=None
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Host-side rest data of every triangle (``mesh.build_mesh`` stores it in the mesh): its
    stencil (m, 6); the rows (m, 3, 3) giving each hinge angle from (K_uu, K_uv, K_vv); its edges'
    outward unit normals in material axes (m, 3, 2); which edges have a triangle across (m, 3); its
    rest area (m,). Only triangles with a free vertex are kept: the clamped ones are held flat, and
    a hinge on the clamp line measures the turn from the clamped plane, whose slope on the line is
    the surface's own there (not a clamped triangle's), so a clamped root bends as the continuum's.
    ``neighbours``: ``edge_neighbours(faces)`` when the caller already has it."""
    faces = np.asarray(faces, np.int64)
    uv = np.asarray(uv, np.float64)
    m = faces.shape[0]
    opp, opp_tri = edge_neighbours(faces) if neighbours is None else neighbours
    clamped = np.asarray(clamped, bool)
    clamped_tri = clamped[faces].all(1)
    p = uv[faces]  # (m, 3, 2)
    basis = [np.array([[1.0, 0.0], [0.0, 0.0]]), np.array([[0.0, 1.0], [1.0, 0.0]]), np.array([[0.0, 0.0], [0.0, 1.0]])]

    def slope(tri, k):
        """Gradient (.., 2) of the linear interpolant of q(p) = p K p / 2 on triangles tri (.., 3, 2)."""
        q = 0.5 * np.einsum("...i,ij,...j->...", tri, k, tri)
        d = np.stack([tri[..., 1, :] - tri[..., 0, :], tri[..., 2, :] - tri[..., 0, :]], -2)
        return np.linalg.solve(d, np.stack([q[..., 1] - q[..., 0], q[..., 2] - q[..., 0]], -1)[..., None])[..., 0]

    rows = np.zeros((m, 3, 3))
    normals = np.zeros((m, 3, 2))
    for i in range(3):
        a, b = p[:, (i + 1) % 3], p[:, (i + 2) % 3]
        e = b - a
        tau = np.stack([e[:, 1], -e[:, 0]], 1) / np.linalg.norm(e, axis=1, keepdims=True)  # outward for CCW
        normals[:, i] = tau
        nb = np.stack([a, b, uv[np.maximum(opp[:, i], 0)]], 1)
        nb = np.where((opp[:, i] >= 0)[:, None, None], nb, p)
        held = (opp[:, i] >= 0) & clamped_tri[np.maximum(opp_tri[:, i], 0)]
        for j, k in enumerate(basis):
            # clamp: the surface's own slope on the line
            across = np.where(held[:, None], (0.5 * (a + b)) @ k, slope(nb, k))
            rows[:, i, j] = np.where(opp[:, i] >= 0, np.sum(tau * (across - slope(p, k)), 1), 0.0)
    stencil = np.concatenate([faces, np.where(opp >= 0, opp, faces)], 1)
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    keep = ~clamped_tri
    return stencil[keep], rows[keep], normals[keep], (opp[keep] >= 0).astype(np.float64), area[keep]


def jump_pairs(faces: np.ndarray, clamped: np.ndarray, stencil: np.ndarray, neighbours=None
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pairs of kept triangles (``hinge_operator``'s order and ``stencil``) that share an edge:
    (P, 2) triangle indices; each pair's stencil (P, 8), the union of its two 6-vertex stencils
    (padded with its first vertex); and (P, 12) the positions in it of the first triangle's
    stencil, then the second's. ``neighbours``: ``edge_neighbours(faces)`` when the caller has it."""
    faces = np.asarray(faces, np.int64)
    kept = np.flatnonzero(~np.asarray(clamped, bool)[faces].all(1))
    index = -np.ones(faces.shape[0], np.int64)
    index[kept] = np.arange(kept.size)
    _, opp_tri = edge_neighbours(faces) if neighbours is None else neighbours
    t = np.repeat(np.arange(faces.shape[0]), 3)
    u = opp_tri.reshape(-1)
    whole = (opp_tri >= 0).all(1)  # a triangle on a free edge has its curvature partly from the edge condition
    ok = (u > t) & (index[t] >= 0) & (index[np.maximum(u, 0)] >= 0) & whole[t] & whole[np.maximum(u, 0)]
    pairs = np.stack([index[t[ok]], index[u[ok]]], 1).reshape(-1, 2)
    union, maps = np.zeros((len(pairs), 8), np.int64), np.zeros((len(pairs), 12), np.int64)
    for k, (a, b) in enumerate(pairs):
        verts = list(dict.fromkeys(stencil[a].tolist() + stencil[b].tolist()))
        if len(verts) > 8:
            raise ValueError("jump_pairs: two triangles sharing an edge span more than 8 vertices")
        verts += [verts[0]] * (8 - len(verts))
        union[k] = verts
        maps[k] = [verts.index(v) for v in np.concatenate([stencil[a], stencil[b]])]
    return pairs, union, maps


def hinge_angles(xe, has):
    """Signed dihedral angles (3,) at the edges of triangle xe[:3] with its neighbours' opposite
    vertices xe[3:]; positive where the surface turns towards its normal (as $K$ does)."""
    n = normalize(jnp.cross(xe[1] - xe[0], xe[2] - xe[0]))
    out = []
    for i in range(3):
        a, b = xe[(i + 1) % 3], xe[(i + 2) % 3]
        nb = normalize(jnp.cross(a - b, xe[3 + i] - b))  # the neighbour (b, a, opposite) is counter-clockwise too
        e = normalize(a - b)
        s = jnp.dot(jnp.cross(n, nb), e)
        out.append(jnp.where(has[i] > 0, jnp.arctan2(s, jnp.dot(n, nb)), 0.0))
    return jnp.stack(out)


def _solve3(a, b):
    """a⁻¹ b for one 3x3 system by Cramer's rule: elementwise arithmetic, no LAPACK call (a batched
    CPU LU is split over XLA's intra-op threads, and two such calls scheduled at once by two energy
    terms deadlock on a 2-core machine, as the batched eigh does: ``solve._sparse.psd_project``)."""
    c0, c1, c2 = a[:, 0], a[:, 1], a[:, 2]
    det = jnp.dot(c0, jnp.cross(c1, c2))
    return jnp.stack([jnp.dot(b, jnp.cross(c1, c2)), jnp.dot(c0, jnp.cross(b, c2)),
                      jnp.dot(c0, jnp.cross(c1, b))]) / det


def curvature(xe, rows, normals, has, params):
    """Curvature tensor (2, 2) of one triangle from its stencil: the three hinge equations, each
    missing one (a free edge) replaced by the free edge's natural condition, no bending moment
    about the edge (τᵀMτ = 0 with the plate's linear moment M = Dκ, ``bending.plate_terms``)."""
    d11, d12, d22, d66 = plate_terms(params)
    t1, t2 = normals[:, 0], normals[:, 1]
    free_rows = jnp.stack([t1 * t1 * d11 + t2 * t2 * d12, 4.0 * t1 * t2 * d66, t1 * t1 * d12 + t2 * t2 * d22], 1)
    largest = jnp.max(jnp.abs(rows))
    scale = jnp.where(largest > 0, largest, 1.0) / (d11 + d22)
    a = jnp.where(has[:, None] > 0, rows, scale * free_rows)
    k = _solve3(a, hinge_angles(xe, has))
    return jnp.stack([jnp.stack([k[0], k[1]]), jnp.stack([k[1], k[2]])])


class ShapeOperatorBending(AbstractEnergy):
    """Cloth bending on per-triangle hinge shape operators (module docstring); replaces
    ``Bending`` and ``HourglassControl`` together (``shape_operator_energies``)."""

    def elements(self, mesh):
        return mesh.tri_stencil, (mesh.tri_hinge_rows, mesh.tri_edge_normal, mesh.tri_area, mesh.tri_has_edge)

    def element_energy(self, xe, data, params):
        rows, normals, area, has = data
        return area * bending_density(curvature(xe, rows, normals, has, params), params)


JUMP_BETA = 5.0
"""Default weight of ``CurvatureJumpControl`` (dimensionless)."""


class CurvatureJumpControl(AbstractEnergy):
    r"""Penalty on the jump of the shape-operator curvature across each edge:
    $E = \beta \sum_{(t,t')} \tfrac{A_t + A_{t'}}{3}\, \tfrac12 (K_t - K_{t'})^\top D (K_t - K_{t'})$.

    Per-triangle hinge curvatures (``ShapeOperatorBending``) are exact for every quadratic surface,
    but on meshes of mixed vertex valence a pattern of alternating triangle curvatures bends the
    sheet for less energy than its smooth equivalent: a cantilever on a criss-cross mesh droops 50 %
    too far, on a jittered Delaunay mesh 6-9 %. The jump is zero for every quadratic surface, so
    the penalty adds no stiffness to uniform bending, and only O(h²) to smooth curvature gradients,
    while it charges the alternating pattern (an interior-penalty stabilisation in the spirit of
    the C0 interior-penalty plate methods, Engel et al. 2002). Pairs with a triangle on a free
    edge are left out: its curvature comes partly from the edge condition, not from hinges. With
    β = 5 the jittered cantilever is within 1 % of the master curve at 5 and 2.5 mm for Γ ≤ 10.
    The penalty charges curvature gradients too (O(h²)), and a Cusick drape's fold crests are steep
    ones: on uniform 10 mm meshes it raised the drape coefficient of "mid" from about 0.52 to 0.72,
    so it is not yet a model for coarse Cusick meshes. Each element is a pair of triangles sharing
    an edge (8 vertices). Like the hourglass control of the vertex fit, it shapes the equilibrium,
    not the way to it: the drop's time steps leave it out (``in_drop``)."""

    beta: float = JUMP_BETA
    in_drop = False

    def elements(self, mesh):
        a, b = mesh.tri_pairs[:, 0], mesh.tri_pairs[:, 1]
        side = lambda t: (mesh.tri_hinge_rows[t], mesh.tri_edge_normal[t], mesh.tri_has_edge[t])
        return mesh.tri_pair_stencil, (mesh.tri_pair_map, side(a), side(b), (mesh.tri_area[a] + mesh.tri_area[b]) / 3.0)

    def element_energy(self, xe, data, params):
        maps, da, db, area = data
        ka = curvature(xe[maps[:6]], *da, params)
        kb = curvature(xe[maps[6:]], *db, params)
        return self.beta * area * linear_density(ka - kb, params)
