"""Spatially varying material: bending rigidity scaled by $\\exp(\\sum_j\\theta_j\\phi_j)$ across the specimen.

Basis: first and second angular harmonics of the material polar angle (cos ψ, sin ψ, cos 2ψ,
sin 2ψ), the smoothest variations a cut specimen shows from place to place in the roll.
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ..energy.bending import bending_density
from ._base import CurvatureTerm, Effect


class StiffnessFieldTerm(CurvatureTerm):
    theta: jnp.ndarray  # (4,)

    def vertex_data(self, mesh):
        uv = mesh.uv[mesh.curv_verts]
        psi = jnp.arctan2(uv[:, 1], uv[:, 0])
        return jnp.stack([jnp.cos(psi), jnp.sin(psi), jnp.cos(2 * psi), jnp.sin(2 * psi)], -1)

    def density(self, K, phi, params):
        return (jnp.exp(jnp.dot(phi, self.theta)) - 1.0) * bending_density(K, params)


class Heterogeneity(Effect):
    name: str = eqx.field(static=True, default="heterogeneity")

    def n_params(self):
        return 4

    def prior_std(self):
        return np.full(4, 0.5)

    def terms(self, mesh, theta):
        return (StiffnessFieldTerm(theta=jnp.asarray(theta[:4])),)

    def describe(self, theta):
        t = np.asarray(theta, float)
        return {"log_rigidity_harmonic1": float(np.hypot(t[0], t[1])),
                "log_rigidity_harmonic2": float(np.hypot(t[2], t[3]))}
