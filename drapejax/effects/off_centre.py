"""Specimen off-centre on the disc: the specimen centre displaced by s = (dx, dy) metres.

The material point X then lies at X + s in the world, and the clamp (a disc of radius R at the
origin) holds the material inside $|X + s| \\le R$ at X + s: the overhang is longer on one side
(a first-harmonic residual), not a rigid translation. Energy only, no new mesh: the term
replaces the base clamp's springs by $\\tfrac12 k \\sum_i [w_i(s)|x_i - X_i - s|^2 - c_i|x_i - X_i|^2]$,
c the base clamp mask and $w_i = c_i\\,\\mathrm{ramp}(|X_i+s|; R, R+h_i) + (1-c_i)\\,\\mathrm{ramp}(|X_i+s|; R-h_i, R)$:
linear ramps from 1 to 0 over the local mesh spacing $h_i$, from the vertex's lumped area
$A_i = \\tfrac{\\sqrt3}{2}h_i^2$, so w(0) = c exactly and w is piecewise linear in s. A ramp as
wide as a graded mesh's nominal spacing holds released material half-clamped beyond the
support's edge (on the default fit mesh, 20 mm graded from 3 mm, the long overhang of a 13 mm
offset stood out 9 mm too far). Released material that was deep inside the clamp carries no
bending stencil (``ClothMesh.curv_verts``), so shifts beyond one mesh spacing are only approximate.
"""

import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ..energy import AbstractEnergy, Clamp, safe_norm
from ._base import Effect, is_number


class ClampShiftTerm(AbstractEnergy):
    shift_m: jnp.ndarray  # (2,)
    stiffness_n_per_m: float = eqx.field(static=True, default=Clamp().stiffness_n_per_m)

    def elements(self, mesh):
        c = jnp.where(mesh.clamped, 1.0, 0.0)
        big_r = mesh.info.disk_radius_m
        h = jnp.sqrt(2.0 * mesh.vertex_area / math.sqrt(3.0))
        r = safe_norm(mesh.rest[:, :2] + self.shift_m[None, :])
        w = c * jnp.clip((big_r + h - r) / h, 0.0, 1.0) + (1.0 - c) * jnp.clip((big_r - r) / h, 0.0, 1.0)
        target = mesh.rest + jnp.concatenate([self.shift_m, jnp.zeros(1)])[None, :]
        return jnp.arange(mesh.n_verts)[:, None], (mesh.rest, target, c, w)

    def element_energy(self, xe, data, params):
        x0, target, c, w = data
        d, d0 = xe[0] - target, xe[0] - x0
        return 0.5 * self.stiffness_n_per_m * (w * jnp.sum(d * d) - c * jnp.sum(d0 * d0))


class OffCentre(Effect):
    name: str = eqx.field(static=True, default="off_centre")
    label = "specimen off-centre on the disc"
    seeded_by_centroid = True

    def n_params(self):
        return 2

    def prior_std(self):
        return np.array([0.01, 0.01])

    def terms(self, mesh, theta):
        return (ClampShiftTerm(shift_m=jnp.asarray(theta[:2])),)

    def describe(self, theta):
        return {"specimen_centre_dx_mm": float(theta[0]) * 1e3, "specimen_centre_dy_mm": float(theta[1]) * 1e3}

    def signature(self, evidence):
        """An offset that stays put in the world frame over the captures (the offset test,
        ``Evidence.offset_significant``) scores 1 − p; without it, the rim residual's first-harmonic
        share times its odd share (a shifted centre adds d·cos(φ − φ0) to the rim). It is scored only
        while the effect is not yet in the model, whose rims are then centred in expectation."""
        if evidence.offset_significant:
            return 1.0 - evidence.offset_pvalue
        return evidence.first_harmonic_fraction * evidence.symmetry["odd_fraction"]

    def inadmissible(self, evidence):
        """An off-centre specimen shifts the skirt in the world frame by the same offset in every
        capture, so its rims carry a first harmonic, and its scan's centroid moves, beyond fold noise
        (``Evidence.offset_significant``). Without either, an offset found by a fit mimics a change
        in the skirt's shape instead (a hidden heavy hem was taken for a 15 mm offset when selection
        scored the height profile), so it is not tried."""
        if evidence.offset_significant:
            return None
        return (f"no world-frame first harmonic beyond fold noise in the measured rims, nor a shifted "
                f"scan centroid (p = {evidence.offset_pvalue:.2g})")

    def where(self, values):
        dx, dy = values.get("specimen_centre_dx_mm"), values.get("specimen_centre_dy_mm")
        if not (is_number(dx) and is_number(dy)):
            return None
        dx, dy = float(dx), float(dy)
        return (f"the specimen centre sits {math.hypot(dx, dy):.1f} mm from the disc centre, at "
                f"{math.degrees(math.atan2(dy, dx)):.0f}° from the simulation's x axis")
