"""Spatially varying material: bending rigidity scaled by $\\exp(\\sum_j\\theta_j\\phi_j)$ across the specimen.

Basis: the angular harmonics 1 … ``harmonics`` of the material polar angle ψ (cos ψ, sin ψ,
cos 2ψ, sin 2ψ, …), the smoothest variations a cut specimen shows from place to place in the
roll. The library's candidate takes harmonics 1 and 2 (four parameters); ``harmonics=1`` is a
rigidity gradient across the specimen alone (two), which on the capped virtual lab did not get
through the screen where the four-parameter field did (``docs/results/2026-11-29-effect-recovery-capped-lab.md``,
``effect_recovery.py``: the two-parameter heterogeneity).
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ..energy.bending import bending_density
from ._base import CurvatureTerm, Effect


class StiffnessFieldTerm(CurvatureTerm):
    theta: jnp.ndarray  # (2 · harmonics,): cos and sin amplitudes of log rigidity per harmonic

    def vertex_data(self, mesh):
        uv = mesh.uv[mesh.curv_verts]
        psi = jnp.arctan2(uv[:, 1], uv[:, 0])
        angle = psi[:, None] * jnp.arange(1, self.theta.shape[0] // 2 + 1)[None, :]
        return jnp.stack([jnp.cos(angle), jnp.sin(angle)], -1).reshape(psi.shape[0], -1)

    def density(self, K, phi, params):
        return (jnp.exp(jnp.dot(phi, self.theta)) - 1.0) * bending_density(K, params)


class Heterogeneity(Effect):
    """θ = (cos, sin) amplitudes of log rigidity for harmonics 1 … ``harmonics`` (dimensionless)."""

    name: str = eqx.field(static=True, default="heterogeneity")
    harmonics: int = eqx.field(static=True, default=2)
    label = "bending rigidity varying across the specimen"

    def __post_init__(self):
        if not (isinstance(self.harmonics, int) and self.harmonics >= 1):
            raise ValueError(f"Heterogeneity.harmonics must be an integer >= 1, got {self.harmonics!r}")

    def n_params(self):
        return 2 * self.harmonics

    def prior_std(self):
        return np.full(self.n_params(), 0.5)

    def terms(self, mesh, theta):
        return (StiffnessFieldTerm(theta=jnp.asarray(theta[:self.n_params()])),)

    def describe(self, theta):
        t = np.asarray(theta, float)
        return {f"log_rigidity_harmonic{k + 1}": float(np.hypot(t[2 * k], t[2 * k + 1])) for k in range(self.harmonics)}

    def signature(self, evidence):
        """A smooth rigidity field reshapes the rim at low order: the rim residual's share in
        harmonics 1–2, discounted by half its first-harmonic share (which an offset leaves too)."""
        return evidence.symmetry["low_fraction"] * (1.0 - 0.5 * evidence.first_harmonic_fraction)

    def where(self, values):
        return "across the specimen (angular harmonics of the rigidity)"
