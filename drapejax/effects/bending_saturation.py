r"""Bending that saturates at large curvature: the moment stops growing as fast beyond κ_s.

Real fabrics soften (613 of the 618 measured have k2 < 0), but the fitted law
$M = k_1\kappa + k_2\kappa^2$ comes from curvatures below 50 m⁻¹ and continues linearly beyond,
while the bend over a Cusick disc edge goes well past that (the real scans drop 25–55° within
5 mm of the edge). The term removes a fraction $f = 0.7\,(1 - e^{-\theta})$ of the bending
energy density where the curvature is large:
$\Delta W(K) = -f\, W(K)\, |K|^2 / (|K|^2 + \kappa_s^2)$, $\kappa_s$ = ``KAPPA_RANGE`` = 50 m⁻¹ ($|K|$ the
Frobenius norm). θ > 0 softens, θ < 0 stiffens. f stays below ``F_MAX`` = 0.7 for every θ, which
keeps the energy density convex in K for the example fabrics: it stops being so at f = 0.73-0.75
with their k2 softening (0.79-0.80 on the linear law, where at f = 0.8 the moment along one
direction stops growing with κ). Beyond that the material would kink, a physically impossible
law; a fabric that softens faster than the examples could still reach it at large θ.
"""

import equinox as eqx
import jax.numpy as jnp

from ..energy.bending import bending_density, curvature_tensor
from ..material import KAPPA_RANGE
from ._base import CurvatureTerm, Effect, scaled_bending_hessian


F_MAX = 0.7
"""Largest fraction of the bending energy the term removes (θ → ∞)."""


def removed_fraction(theta):
    """f(θ) = ``F_MAX`` (1 − e^{−θ})."""
    return F_MAX * (1.0 - jnp.exp(-theta))


class BendingSaturationTerm(CurvatureTerm):
    theta: jnp.ndarray
    kappa_s_per_m: float = eqx.field(static=True, default=KAPPA_RANGE)

    has_psd_hessian = True
    in_preconditioner = False

    def vertex_data(self, mesh):
        return jnp.zeros(mesh.curv_verts.shape[0])

    def _fraction(self, K):
        """Fraction of the bending energy density removed at curvature K."""
        r2 = jnp.sum(K * K)
        return removed_fraction(self.theta) * r2 / (r2 + self.kappa_s_per_m**2)

    def density(self, K, _, params):
        return -self._fraction(K) * bending_density(K, params)

    def psd_element_hessian(self, xe, data, params):
        """The removed fraction at the current curvature times the base element's projected
        Hessian (its change with K left out, as in Gauss–Newton)."""
        fit, area, _ = data
        return scaled_bending_hessian(-self._fraction(curvature_tensor(xe, fit)), xe, fit, area, params)


class BendingSaturation(Effect):
    name: str = eqx.field(static=True, default="bending_saturation")
    label = "bending that saturates at large curvature"

    def n_params(self):
        return 1

    def terms(self, mesh, theta):
        return (BendingSaturationTerm(theta=theta[0]),)

    def strip_terms(self, mesh, theta):
        """A property of the fabric: a strip cut from it feels it too."""
        return self.terms(mesh, theta)

    def describe(self, theta):
        return {"energy_fraction_removed_at_large_curvature": float(removed_fraction(theta[0])),
                "kappa_s_per_m": KAPPA_RANGE}

    def signature(self, evidence):
        """None: no residual pattern is assigned to it (softening at large curvature acts over the
        disc edge and in every fold crest alike), so it ranks with score 0 and the screen's drops
        alone weigh it."""
        return None

    def where(self, values):
        return "where the fabric bends sharply (curvature beyond about 50 1/m: over the disc edge)"
