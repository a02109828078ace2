"""Gravity: $E = \\sum_i m_i g z_i$ with lumped masses $m_i = \\rho A_i$."""

import jax.numpy as jnp

from ..material import G
from ._base import AbstractEnergy


class Gravity(AbstractEnergy):
    """Uniform gravity along -z (g = 9.81 m/s²)."""

    def elements(self, mesh):
        return jnp.arange(mesh.n_verts)[:, None], mesh.vertex_area

    def element_energy(self, xe, area, params):
        return params.density * area * G * xe[0, 2]
