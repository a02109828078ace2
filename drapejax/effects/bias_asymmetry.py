"""Unequal left/right bias rigidity (seed 001 Fig. 11b): extra stiffness along the +45° bias.

Energy per area $\\tfrac12\\,\\delta\\,k_{1,\\mathrm{bias}}\\,K_{++}^2$ with
$K_{++} = (K_{uu} + K_{vv})/2 + K_{uv}$ the curvature along +45°; δ < 0 softens it. This
breaks the warp-mirror symmetry every base-model drape has.
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ._base import CurvatureTerm, Effect


class BiasAsymmetryTerm(CurvatureTerm):
    delta: jnp.ndarray

    def vertex_data(self, mesh):
        return jnp.zeros(mesh.curv_verts.shape)

    def density(self, K, d, params):
        kpp = 0.5 * (K[0, 0] + K[1, 1]) + K[0, 1]
        return 0.5 * self.delta * params.bend_k1_bias * kpp * kpp


class BiasAsymmetry(Effect):
    name: str = eqx.field(static=True, default="bias_asymmetry")
    label = "unequal left/right bias rigidity"

    def n_params(self):
        return 1

    def prior_std(self):
        return np.array([0.5])

    def terms(self, mesh, theta):
        return (BiasAsymmetryTerm(delta=theta[0]),)

    def strip_terms(self, mesh, theta):
        """A property of the fabric: a strip cut from it feels it too."""
        return self.terms(mesh, theta)

    def describe(self, theta):
        return {"plus45_over_minus45_rigidity": float(1.0 + theta[0])}

    def signature(self, evidence):
        """The rim residual's share antisymmetric under the warp mirror, which every base-model
        drape keeps, times its share in even harmonics (the effect keeps the half-turn symmetry)."""
        sym = evidence.symmetry
        return sym["mirror_antisymmetric_fraction"] * (1.0 - sym["odd_fraction"])

    def where(self, values):
        return "everywhere, along the +45° bias direction"
