"""Carry a deformed state from one specimen mesh to another of the same specimen.

A Cusick drape made on nested meshes (``mesh.cusick_hierarchy``) ends on a finest level whose
vertices are not those of the mesh a dataset or a measurement folder was laid out on
(``mesh.cusick_mesh``). Both meshes cover the same flat specimen, so each target vertex is
placed where the source's deformed surface puts the material point under it: the barycentric
coordinates of the target vertex's rest position in the source triangle that contains it, applied
to that triangle's deformed corners (linear interpolation over the source's piecewise-linear
surface). A target vertex just outside the source's polygonal boundary takes the nearest
triangle's coordinates, extrapolated. Where the source mesh is at least as fine as the target,
the carried surface lies on the source's within its chords; where the meshes coincide, it is the
source's state itself.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .mesh import ClothMesh

CANDIDATES = 16
"""Source triangles, nearest by centroid, searched for each target vertex."""


def rest_barycentrics(source: ClothMesh, target: ClothMesh) -> tuple[np.ndarray, np.ndarray]:
    """For each vertex of ``target``: the source triangle under its rest position (m,) and the
    barycentric coordinates there (m, 3), from the two meshes' flat rest positions (x, y).

    The triangle is the candidate whose least barycentric coordinate is largest: inside it, all
    three are non-negative; outside the source (a boundary vertex of a finer polygon), the nearest
    one's coordinates, slightly negative.
    """
    sxy = np.asarray(source.rest, np.float64)[:, :2]
    txy = np.asarray(target.rest, np.float64)[:, :2]
    faces = np.asarray(source.faces)
    corners = sxy[faces]  # (f, 3, 2)
    k = min(CANDIDATES, len(faces))
    _, cand = cKDTree(corners.mean(axis=1)).query(txy, k=k)
    cand = cand.reshape(len(txy), k)
    a, b, c = (corners[cand, i] for i in range(3))  # (m, k, 2)
    v0, v1, v2 = b - a, c - a, txy[:, None, :] - a
    det = v0[..., 0] * v1[..., 1] - v0[..., 1] * v1[..., 0]
    l1 = (v2[..., 0] * v1[..., 1] - v2[..., 1] * v1[..., 0]) / det
    l2 = (v0[..., 0] * v2[..., 1] - v0[..., 1] * v2[..., 0]) / det
    bary = np.stack([1.0 - l1 - l2, l1, l2], axis=-1)  # (m, k, 3)
    best = np.argmax(bary.min(axis=-1), axis=1)
    rows = np.arange(len(txy))
    return cand[rows, best], bary[rows, best]


def transfer(x_source, source: ClothMesh, target: ClothMesh,
             barycentrics: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """``x_source`` (n_source, 3), a deformed state of ``source``, carried to ``target``'s vertices
    (n_target, 3) by ``rest_barycentrics`` (pass its result as ``barycentrics`` to carry many
    states between the same two meshes). Returns ``x_source`` itself when the meshes are one."""
    x = np.asarray(x_source, np.float64)
    if source is target:
        return x
    tri, bary = rest_barycentrics(source, target) if barycentrics is None else barycentrics
    corners = x[np.asarray(source.faces)[tri]]  # (m, 3, 3)
    return np.einsum("mi,mij->mj", bary, corners)


__all__ = ["rest_barycentrics", "transfer", "CANDIDATES"]
