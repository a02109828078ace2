"""The two-piece anisotropic bending law of seed 001 (Ju et al. 2024), an alternative to ``Bending``.

Seed 001 makes the bending stiffness a piecewise-constant function of the bending angle: $k^0$
up to 15° and $k^1 = s_b k^0$ beyond, per warp, weft and bias, interpolated by bending
direction. Here the tangent stiffness switches at the curvature $\\kappa_s = \\theta_s / h$
that gives a 15° dihedral angle between neighbouring elements of size $h$ (the mesh spacing),
so the moment $M(\\kappa)$ is continuous: $M = k^0\\kappa$ below $\\kappa_s$ and
$M = k^0\\kappa_s + s_b k^0(\\kappa - \\kappa_s)$ above. Direction interpolation uses the
curvature tensor K of ``bending.curvature_tensor`` with
$k(\\phi) = k_u c^4 + k_v s^4 + (4k_h - k_u - k_v)c^2s^2$ evaluated on $K/|K|$.
"""

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from ._base import AbstractEnergy
from .bending import arc_corrected, curvature_tensor


def _directional(K, kw, kf, kb):
    """$k_w K_{uu}^2 + k_f K_{vv}^2 + (4k_b - k_w - k_f) K_{uv}^2$ (= k(φ)κ² for a cylinder)."""
    return kw * K[0, 0] ** 2 + kf * K[1, 1] ** 2 + (4.0 * kb - kw - kf) * K[0, 1] ** 2


class TwoPieceBending(AbstractEnergy):
    """Seed 001's bending law; use it in place of ``Bending`` in the energy terms.

    Attributes:
        k0_warp, k0_weft, k0_bias: small-angle bending stiffness, N·m.
        scale_warp, scale_weft, scale_bias: s_b, stiffness ratio beyond the switch angle.
        switch_deg: switch angle θ_s (seed 001: 15°).
    """

    k0_warp: Float[Array, ""]
    k0_weft: Float[Array, ""]
    k0_bias: Float[Array, ""]
    scale_warp: Float[Array, ""]
    scale_weft: Float[Array, ""]
    scale_bias: Float[Array, ""]
    switch_deg: float = eqx.field(static=True, default=15.0)

    def elements(self, mesh):
        idx = jnp.concatenate([mesh.curv_verts[:, None], mesh.nbr], 1)
        kappa_s = jnp.full(mesh.curv_verts.shape, jnp.deg2rad(self.switch_deg) / mesh.info.spacing_m)
        return idx, (mesh.fit, mesh.curv_area, kappa_s, mesh.curv_quartic)

    def element_energy(self, xe, data, params):
        fit, area, ks, quartic = data
        K = arc_corrected(curvature_tensor(xe, fit), quartic)  # the curvature ``Bending`` uses
        r2 = K[0, 0] ** 2 + K[1, 1] ** 2 + 2.0 * K[0, 1] ** 2
        ok = r2 > 1e-30
        r = jnp.where(ok, jnp.sqrt(jnp.where(ok, r2, 1.0)), 0.0)
        q0 = _directional(K, self.k0_warp, self.k0_weft, self.k0_bias)  # k0(φ) r²
        qs = _directional(K, self.k0_warp * self.scale_warp, self.k0_weft * self.scale_weft,
                          self.k0_bias * self.scale_bias)  # s_b k0(φ) r²
        big = r > ks
        rs = jnp.where(big, r, 1.0)
        u = jnp.where(big, ks / rs, 1.0)  # κs/κ
        # Above the switch: ½k0κs² + k0κs(κ-κs) + ½ s k0 (κ-κs)², written with q = k(φ)κ².
        above = 0.5 * q0 * u * u + q0 * u * (1.0 - u) + 0.5 * qs * (1.0 - u) ** 2
        return area * jnp.where(big, above, 0.5 * q0)
