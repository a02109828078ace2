"""Self-contact of neighbouring folds: a fabric thickness h that keeps fold walls apart.

Vertex pairs of the overhang that are far apart on the specimen (material distance
> ``min_sep`` mesh spacings, so no mesh neighbours) but close in azimuth and radius (the
walls of one fold and of its neighbours) repel when nearer than h:
$\\tfrac12 k_A \\min(A_i, A_j)\\,(h - d_{ij})_+^2$. The candidate list is fixed on the host from
the rest mesh, so the term costs O(pairs) and works inside ``drape``/``equilibrium``; it is
vertex–vertex only, i.e. it resolves contact at the mesh spacing (fine meshes for thin h).
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ..energy import AbstractEnergy, safe_norm
from ._base import Effect


def candidate_pairs(mesh, *, max_dpsi_deg: float = 50.0, max_dr_m: float = 0.04, min_sep: float = 2.5):
    """(p, 2) overhang vertex pairs that neighbouring folds can bring into contact."""
    uv = np.asarray(mesh.uv)
    r = np.hypot(uv[:, 0], uv[:, 1])
    idx = np.flatnonzero(r > mesh.info.disk_radius_m + 0.5 * mesh.info.spacing_m)
    i, j = np.triu_indices(len(idx), 1)
    i, j = idx[i], idx[j]
    psi = np.arctan2(uv[:, 1], uv[:, 0])
    dpsi = np.abs(np.angle(np.exp(1j * (psi[i] - psi[j]))))
    sep = np.linalg.norm(uv[i] - uv[j], axis=1)
    keep = ((np.rad2deg(dpsi) <= max_dpsi_deg) & (np.abs(r[i] - r[j]) <= max_dr_m)
            & (sep > min_sep * mesh.info.spacing_m))
    return np.stack([i[keep], j[keep]], 1)


class SelfContactTerm(AbstractEnergy):
    thickness_m: jnp.ndarray
    pairs: jnp.ndarray  # (p, 2) int, from ``candidate_pairs``
    stiffness_n_per_m3: float = eqx.field(static=True, default=1e7)

    def elements(self, mesh):
        return self.pairs, jnp.minimum(mesh.vertex_area[self.pairs[:, 0]], mesh.vertex_area[self.pairs[:, 1]])

    def element_energy(self, xe, area, params):
        pen = jnp.maximum(self.thickness_m - safe_norm(xe[0] - xe[1]), 0.0)
        return 0.5 * self.stiffness_n_per_m3 * area * pen * pen


class SelfContact(Effect):
    name: str = eqx.field(static=True, default="self_contact")
    label = "self-contact of neighbouring folds"

    def n_params(self):
        return 1

    def prior_std(self):
        return np.array([0.005])

    def lower_bound(self):
        return np.array([0.0])  # a thickness

    def terms(self, mesh, theta):
        return (SelfContactTerm(thickness_m=theta[0], pairs=jnp.asarray(candidate_pairs(mesh))),)

    def describe(self, theta):
        return {"contact_thickness_mm": float(theta[0]) * 1e3}

    def signature(self, evidence):
        """Fold walls held apart change the number and depth of folds: half the rim residual's share
        in harmonics 3 and up."""
        return 0.5 * evidence.high_harmonic_fraction

    def where(self, values):
        return "between the walls of neighbouring folds"
