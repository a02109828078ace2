"""Contact with the support disc (top face, rim, underside) and the floor, as vertex penalties.

The disc is a solid cylinder of radius R (top at z = 0, thickness T) with rounded edges; a
vertex closer than ``offset_m`` to it (or below the floor plus the offset) pays
$\\tfrac12 k A_i (\\delta - d_i)_+^2$ with $k$ in N/m³. Clamped vertices are exempt.
"""

import equinox as eqx
import jax.numpy as jnp

from ._base import AbstractEnergy, safe_norm


def disk_sdf(p, radius_m: float, thickness_m: float, round_m: float):
    """Signed distance (m) from points (..., 3) to a rounded solid disc under z = 0."""
    r = safe_norm(p[..., :2])
    zc = p[..., 2] + 0.5 * thickness_m
    qx = r - (radius_m - round_m)
    qz = jnp.abs(zc) - (0.5 * thickness_m - round_m)
    outside = safe_norm(jnp.stack([jnp.maximum(qx, 0.0), jnp.maximum(qz, 0.0)], -1))
    inside = jnp.minimum(jnp.maximum(qx, qz), 0.0)
    return outside + inside - round_m


class DiskContact(AbstractEnergy):
    """Penalty contact with the support disc."""

    radius_m: float = eqx.field(static=True, default=0.09)
    thickness_m: float = eqx.field(static=True, default=0.005)
    round_m: float = eqx.field(static=True, default=0.001)
    offset_m: float = eqx.field(static=True, default=0.001)
    stiffness_n_per_m3: float = eqx.field(static=True, default=1e7)

    def elements(self, mesh):
        w = jnp.where(mesh.clamped, 0.0, mesh.vertex_area)
        return jnp.arange(mesh.n_verts)[:, None], w

    def element_energy(self, xe, w, params):
        d = disk_sdf(xe[0], self.radius_m, self.thickness_m, self.round_m)
        pen = jnp.maximum(self.offset_m - d, 0.0)
        return 0.5 * self.stiffness_n_per_m3 * w * pen * pen


class FloorContact(AbstractEnergy):
    """Penalty contact with the floor plane z = ``floor_z_m``."""

    floor_z_m: float = eqx.field(static=True, default=-0.2)
    offset_m: float = eqx.field(static=True, default=0.001)
    stiffness_n_per_m3: float = eqx.field(static=True, default=1e7)

    def elements(self, mesh):
        return jnp.arange(mesh.n_verts)[:, None], mesh.vertex_area

    def element_energy(self, xe, w, params):
        pen = jnp.maximum(self.floor_z_m + self.offset_m - xe[0, 2], 0.0)
        return 0.5 * self.stiffness_n_per_m3 * w * pen * pen
