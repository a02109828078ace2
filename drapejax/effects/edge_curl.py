"""Edge curl (knits, seed 001 Fig. 11a): a spontaneous radial curvature κ0 near the cut edge.

The band weight decays as $e^{-(R - r)/w}$ from the hem inward; the rest curvature is
$K_0 = \\kappa_0\\, e_r e_r^\\top$ (the edge rolls about the tangent; κ0 > 0 rolls upward).
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ._base import CurvatureTerm, Effect, band_width_text, radial_coords, rest_curvature_density


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
    label = "edge curl"

    def n_params(self):
        return 1

    def prior_std(self):
        return np.array([50.0])

    def terms(self, mesh, theta):
        return (EdgeCurlTerm(kappa0_per_m=theta[0]),)

    def describe(self, theta):
        return {"rest_curvature_at_edge_1_per_m": float(theta[0]), "band_m": 0.01}

    def signature(self, evidence):
        """A rolled edge changes the hem's height and the rim's reach: the mean of the hem band's
        share of the height residual and the rim's mean shift over its rms, weighted 1 where the
        measured hem sits higher than simulated and ½ where lower (the heavy hem's opposite)."""
        lower = 1.0 if evidence.band_lower("hem") else 0.5
        return 0.5 * (evidence.band_share("hem") + evidence.mean_share) * (1.5 - lower)

    def where(self, values):
        return f"near the cut edge (decaying over {band_width_text(values) or 'a band'} inwards)"
