"""Heavier hem band (a sewn or folded edge): extra areal mass within ``band_m`` of the cut edge."""

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ..energy import AbstractEnergy
from ..material import G
from ._base import Effect, band_width_text, radial_coords

HEM_BAND_M = 0.01
"""Width of the heavier band along the cut edge, m (a sewn or folded hem)."""


class HemMassTerm(AbstractEnergy):
    relative_extra_density: jnp.ndarray
    band_m: float = eqx.field(static=True, default=HEM_BAND_M)

    def elements(self, mesh):
        r, _ = radial_coords(mesh)
        w = jnp.where(r > mesh.info.specimen_radius_m - self.band_m, mesh.vertex_area, 0.0)
        return jnp.arange(mesh.n_verts)[:, None], w

    def element_energy(self, xe, w, params):
        return self.relative_extra_density * params.density * w * G * xe[0, 2]


class HeavyHem(Effect):
    name: str = eqx.field(static=True, default="heavy_hem")
    label = "heavier hem band"

    def n_params(self):
        return 1

    def prior_std(self):
        return np.array([1.0])

    def lower_bound(self):
        return np.array([-1.0])  # the band's areal mass cannot be negative

    def terms(self, mesh, theta):
        return (HemMassTerm(relative_extra_density=theta[0]),)

    def describe(self, theta):
        return {"hem_band_extra_density_ratio": float(theta[0]), "band_m": HEM_BAND_M}

    def signature(self, evidence):
        """A heavier edge pulls the skirt down at the hem and draws the rim in: the height residual
        concentrated in the hem band (weighted 1 where the measured hem hangs lower, ½ where
        higher) averaged with the rim's mean shift over its rms."""
        lower = 1.0 if evidence.band_lower("hem") else 0.5
        return 0.5 * (evidence.band_share("hem") * lower + evidence.mean_share)

    def where(self, values):
        return f"the band within {band_width_text(values) or 'a hem width'} of the cut edge"
