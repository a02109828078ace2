"""Edge curl (knits, seed 001 Fig. 11a): a spontaneous radial curvature κ0 near the cut edge.

The band weight decays as $e^{-(R - r)/w}$ from the hem inward; the rest curvature is
$K_0 = \\kappa_0\\, e_r e_r^\\top$ (the edge rolls about the tangent; κ0 > 0 rolls upward).
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ._base import CurvatureTerm, Effect, radial_coords, rest_curvature_density


class EdgeCurlTerm(CurvatureTerm):
    kappa0_per_m: jnp.ndarray
    band_m: float = eqx.field(static=True, default=0.01)

    def vertex_data(self, mesh):
        r, e = radial_coords(mesh, mesh.curv_verts)
        w = jnp.exp(-(mesh.info.specimen_radius_m - r) / self.band_m)
        return w[:, None, None] * e[:, :, None] * e[:, None, :]  # (c, 2, 2): w e e^T

    def density(self, K, wee, params):
        return rest_curvature_density(K, self.kappa0_per_m * wee, params)


class EdgeCurl(Effect):
    name: str = eqx.field(static=True, default="edge_curl")

    def n_params(self):
        return 1

    def prior_std(self):
        return np.array([50.0])

    def terms(self, mesh, theta):
        return (EdgeCurlTerm(kappa0_per_m=theta[0]),)

    def describe(self, theta):
        return {"rest_curvature_at_edge_1_per_m": float(theta[0]), "band_m": 0.01}
