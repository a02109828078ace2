r"""A compliant clamp edge: the fabric hinges at the rim of the support disc.

The base model clamps the specimen with a built-in edge: the clamp line resists bending with the
fabric's full rigidity, so the skirt leaves the disc smoothly. The real Cusick scans kink there
instead (2.7–8.6 mm down within 5 mm of the edge, against 0.5–1.1 mm for the fits,
``experiments/edge_profile.py``), as a rounded or padded rim, or fabric crushed by the clamp,
would make it. The term removes a fraction $f = 1 - e^{-\theta}$ of the bending energy of the
vertices on the clamp line only (their bending area is the built-in edge's hinge,
``mesh._curvature_fit``); θ > 0 makes the edge a softer hinge, θ < 0 a stiffer one. Unlike
``bending_saturation`` it leaves the fold crests alone.

θ ≥ 0: a built-in edge is already the stiffest the clamp line can be, so fits only soften it.
Its prior std is 3, so that a nearly free hinge (θ = 3 removes 95 %) costs the fit ½ in ½χ²:
on the real scans a hinge held at θ = 3 halved the held-out misfit of all 13 fabrics while the
unit prior kept free fits near null (experiments/README.md, ``pooled_real.py --hold``).
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ..energy.bending import bending_density
from ._base import CurvatureTerm, Effect


class ClampHingeTerm(CurvatureTerm):
    theta: jnp.ndarray

    def vertex_data(self, mesh):
        return mesh.clamped[mesh.curv_verts].astype(mesh.rest.dtype)

    def density(self, K, on_line, params):
        return -(1.0 - jnp.exp(-self.theta)) * on_line * bending_density(K, params)


class ClampHinge(Effect):
    name: str = eqx.field(static=True, default="clamp_hinge")

    def n_params(self):
        return 1

    def prior_std(self):
        return np.full(1, 3.0)

    def lower_bound(self):
        return np.zeros(1)

    def terms(self, mesh, theta):
        return (ClampHingeTerm(theta=theta[0]),)

    def describe(self, theta):
        return {"clamp_line_bending_fraction_removed": float(1.0 - np.exp(-float(theta[0])))}
