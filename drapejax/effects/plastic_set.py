"""Plastic set from storage (hysteresis, seed 000 limitation 1): creases along the fold lines.

A specimen stored folded in four keeps a rest curvature κ0 across the warp and weft lines
through its centre (Gaussian bands of width ``band_m``); the rest curvature is
$K_0 = \\kappa_0 g(d)\\, n n^\\top$ with n normal to the crease.
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ._base import CurvatureTerm, Effect, band_width_text, rest_curvature_density


class CreaseTerm(CurvatureTerm):
    kappa0_per_m: jnp.ndarray
    band_m: float = eqx.field(static=True, default=0.008)

    def vertex_data(self, mesh):
        uv = mesh.uv[mesh.curv_verts]
        return jnp.exp(-0.5 * (uv / self.band_m) ** 2)  # (c, 2): near the v-axis, near the u-axis

    def density(self, K, g, params):
        K0 = self.kappa0_per_m * (g[0] * jnp.diag(jnp.array([1.0, 0.0])) + g[1] * jnp.diag(jnp.array([0.0, 1.0])))
        return rest_curvature_density(K, K0, params)


class PlasticSet(Effect):
    name: str = eqx.field(static=True, default="plastic_set")
    label = "plastic set creases from storage"

    def n_params(self):
        return 1

    def prior_std(self):
        return np.array([50.0])

    def terms(self, mesh, theta):
        return (CreaseTerm(kappa0_per_m=theta[0]),)

    def describe(self, theta):
        return {"crease_rest_curvature_1_per_m": float(theta[0]), "band_m": 0.008}

    def signature(self, evidence):
        """Creases pin folds to the fold lines: the rim residual's share in harmonics 3 and up,
        times the share of the height residual away from the hem band."""
        return evidence.high_harmonic_fraction * (1.0 - evidence.band_share("hem"))

    def where(self, values):
        band = band_width_text(values)
        return "along the warp and weft lines through the specimen centre" + (f" (bands {band} wide)" if band else "")
