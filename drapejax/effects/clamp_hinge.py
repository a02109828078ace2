r"""A compliant clamp edge: the fabric hinges at the rim of the support disc.

The base model clamps the specimen with a built-in edge: the clamp line resists bending with the
fabric's full rigidity, so the skirt leaves the disc smoothly. The real Cusick scans kink there
instead (2.7–8.6 mm down within 5 mm of the edge, against 0.5–1.1 mm for the fits,
``experiments/edge_profile.py``), as a rounded or padded rim, or fabric crushed by the clamp,
would make it.

The term puts a rotational spring of compliance length $\ell$ in series with the built-in edge:
the clamp line resists a hinge rotation φ with $B\varphi^2/(2\ell)$ per metre, B the fabric's
rigidity across the line, so $\ell$ is the extra root rotation per unit root moment times B (a
cantilever of length L then droops $\ell/(2L)\,\Gamma$ further than built-in, Γ = ρgL³/B). On
the mesh the clamp line already acts as a spring $B/w$: from the curvature its fit reports for a
unit hinge (``ClothMesh.hinge_curv``), w = B_nn k_nn / (2 w_lin(K_unit)), about h/2. Removing the
fraction $\ell/(\ell + w)$ of the clamp-line vertices' bending energy leaves $B/(\ell + w)$, the
two springs in series, which converges to $B/\ell$ as the mesh is refined. The hourglass control
(``energy.hourglass``) charges a kink too, as a parallel spring that stiffens with refinement (an
eighth to a quarter of $B/\ell$ for ℓ = 25 mm at 5-1.25 mm), so the term removes the same series
fraction of it on the stencils that reach the clamp line, with w half the local spacing.
A strip (Γ = 0.1, ℓ = L/4) droops the analytic Γℓ/(2L) further within 4.4 % at 5 mm and 1.4 % at
2.5 mm (``tests/test_cantilever.py``). Without the hourglass share and with w = h/2 it reached
52-73 %, less on finer meshes: the unremoved springs moved the bend one ring outward.

θ = ℓ / c in bending lengths $c = (\sqrt{k_{1,warp} k_{1,weft}}/\rho g)^{1/3}$, the scale on
which a hinge changes a drape; θ ≥ 0, since a built-in edge is the stiffest a clamp line can be,
and its prior std is 1. Unlike ``bending_saturation`` it leaves the fold crests alone.
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ..energy.bending import bending_density, linear_density
from ..energy.hourglass import HourglassControl
from ..material import G
from ._base import CurvatureTerm, Effect, scaled_bending_hessian


def hinge_length_m(theta, params):
    """Compliance length ℓ (m) of the clamp hinge: θ bending lengths."""
    c = (jnp.sqrt(params.bend_k1_warp * params.bend_k1_weft) / (params.density * G)) ** (1.0 / 3.0)
    return theta * c


def _series_fraction(theta, width, params):
    ell = hinge_length_m(theta, params)
    return ell / (ell + width)


class ClampHingeTerm(CurvatureTerm):
    """Removes the series fraction ℓ/(ℓ + w) of the clamp-line vertices' bending energy."""

    theta: jnp.ndarray
    has_psd_hessian = True
    in_preconditioner = False

    def elements(self, mesh):
        rows = mesh.hinge_rows
        idx = jnp.concatenate([mesh.curv_verts[rows, None], mesh.nbr[rows]], 1)
        return idx, (mesh.fit[rows], mesh.curv_area[rows], self.vertex_data(mesh))

    def vertex_data(self, mesh):
        return mesh.hinge_curv, mesh.hinge_normal

    def _fraction(self, hinge, params):
        """ℓ/(ℓ + w), w = B_nn k_nn / (2 w_lin(K_unit)) the width of the line's discrete hinge."""
        k, n = hinge
        k_unit = jnp.stack([jnp.stack([k[0], k[1]]), jnp.stack([k[1], k[2]])])
        k_nn = n @ k_unit @ n
        width = linear_density(jnp.outer(n, n), params) * k_nn / linear_density(k_unit, params)
        return _series_fraction(self.theta, width, params)

    def density(self, K, hinge, params):
        return -self._fraction(hinge, params) * bending_density(K, params)

    def psd_element_hessian(self, xe, data, params):
        fit, area, hinge = data
        return scaled_bending_hessian(-self._fraction(hinge, params), xe, fit, area, params)


class ClampHingeHourglass(HourglassControl):
    """Removes the series fraction ℓ/(ℓ + w) of the hourglass energy of stencils reaching the
    clamp, w half the local spacing; its Gauss–Newton Hessian is −f times the base one's."""

    theta: jnp.ndarray = 0.0
    in_preconditioner = False

    def elements(self, mesh):
        rows = mesh.hg_hinge_rows
        width = 0.5 * jnp.sqrt(2.0 * mesh.vertex_area[mesh.hg_nbr[rows, 0]])
        return mesh.hg_nbr[rows], (mesh.hg_res[rows], mesh.hg_tan[rows], mesh.hg_weight[rows], width)

    def element_energy(self, xe, data, params):
        *base, width = data
        return -_series_fraction(self.theta, width, params) * super().element_energy(xe, tuple(base), params)

    def element_hessian(self, xe, data, params):
        *base, width = data
        return -_series_fraction(self.theta, width, params) * super().element_hessian(xe, tuple(base), params)

    def psd_element_hessian(self, xe, data, params):
        *base, width = data
        return -_series_fraction(self.theta, width, params) * super().psd_element_hessian(xe, tuple(base), params)


class ClampHinge(Effect):
    name: str = eqx.field(static=True, default="clamp_hinge")
    label = "compliant clamp edge (the fabric hinges at the disc rim)"

    def n_params(self):
        return 1

    def prior_std(self):
        return np.ones(1)

    def lower_bound(self):
        return np.zeros(1)

    def terms(self, mesh, theta):
        return ClampHingeTerm(theta=theta[0]), ClampHingeHourglass(theta=theta[0])

    def describe(self, theta):
        return {"clamp_hinge_length_in_bending_lengths": float(theta[0])}

    def signature(self, evidence):
        """A hinge at the rim drops the skirt right next to the disc: the near-disc band's share of
        the height residual where the measured skirt hangs lower there, 0 where higher."""
        return evidence.band_share("near_disc") * (1.0 if evidence.band_lower("near_disc") else 0.0)

    def where(self, values):
        return "at the rim of the support disc"
