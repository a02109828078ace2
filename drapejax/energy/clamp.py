"""Clamp: a stiff spring holding each clamped vertex at its rest position (Cusick top clamp)."""

import equinox as eqx
import jax.numpy as jnp

from ._base import AbstractEnergy


class Clamp(AbstractEnergy):
    """$E = \\tfrac12 k \\sum_{i\\in C} |x_i - X_i|^2$; ``stiffness_n_per_m`` per clamped vertex."""

    stiffness_n_per_m: float = eqx.field(static=True, default=1e4)

    def elements(self, mesh):
        w = jnp.where(mesh.clamped, 1.0, 0.0)
        return jnp.arange(mesh.n_verts)[:, None], (mesh.rest, w)

    def element_energy(self, xe, data, params):
        x0, w = data
        d = xe[0] - x0
        return 0.5 * self.stiffness_n_per_m * w * jnp.sum(d * d)
