"""Anisotropic nonlinear membrane (stretch and shear) energy of seed 001.

Each triangle's deformation gradient $F = [x_1-x_0, x_2-x_0] D_m^{-1}$ stretches the warp,
weft and the two bias directions by $\\lambda_d = |F a_d|$; with strain
$\\epsilon = \\lambda - 1$ each direction stores
$\\psi(\\epsilon) = \\int_0^\\epsilon \\alpha e^{\\beta s} s\\,ds$ per unit area, so the tangent
stiffness is $k(l) = \\alpha e^{\\beta(l/l_0-1)}$ at small strain (Baraff–Witkin-style springs
with the exponential law). The law is fitted to tensile tests; in compression its force
$\\alpha e^{\\beta\\epsilon}\\epsilon$ peaks at $\\epsilon = -1/\\beta$ and would fall beyond, so the
membrane holds the peak force there (``peak_compression``): a stiffening fabric's elements then
cannot collapse.

``Membrane(buckling=True)`` caps the compressive force of every direction at the Euler load
$N_c = \\pi^2 k_1 / h^2$ of the shortest fold the element can carry (half-wavelength $h$, the
edge of the equilateral triangle of the element's rest area; $k_1$ the bending rigidity along
that direction): beyond it the energy continues linearly, a constant force, as a sheet that
buckles below the mesh scale. A coarse triangle mesh cannot bend into folds narrower than a
few elements without straining them, so soft fabrics, whose folds are narrow, lock: "light"
(bending length 13 mm) forms 2-5 folds at 10-20 mm spacing where 5 mm gives 9-11
(``experiments/cusick_convergence.py --buckling``). The cap grows as $h^{-2}$, so it vanishes
under refinement (on uniform 5 mm it moved the drape coefficient of "mid" and "heavy" by 0.02 or
less). It serves meshes that resolve the bend over the disc edge, such as the graded fit mesh,
where it brings soft fabrics to the 5 mm drape; uniform coarse meshes already droop at that
edge, and with the cap they droop further (``docs/results/2026-11-29-compression-cap.md``). Off by
default.
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ._base import AbstractEnergy, safe_norm

_S = 0.5**0.5
DIRECTIONS = np.array([[1.0, 0.0], [0.0, 1.0], [_S, _S], [_S, -_S]])
"""Material directions (u, v): warp, weft, bias +45°, bias -45°."""


def exp_law_energy(eps, alpha, beta):
    """$\\alpha[e^{\\beta\\epsilon}(\\beta\\epsilon - 1) + 1]/\\beta^2$, exact series near βε = 0."""
    be = beta * eps
    small = jnp.abs(be) < 1e-3
    b_safe = jnp.where(small, 1.0, beta)
    be_safe = jnp.where(small, 0.0, be)
    exact = (jnp.exp(be_safe) * (be_safe - 1.0) + 1.0) / (b_safe * b_safe)
    series = eps * eps * (0.5 + be / 3.0 + be * be / 8.0)
    return alpha * jnp.where(small, series, exact)


def capped_law_energy(eps, alpha, beta, eps_c):
    """``exp_law_energy`` down to a compression of ``eps_c`` (> 0), then linear: a constant force."""
    beyond = eps < -eps_c
    psi = exp_law_energy(jnp.where(beyond, -eps_c, eps), alpha, beta)
    e_c = jnp.where(beyond, eps_c, 0.0)  # 0 where unused: a huge eps_c with β < 0 would overflow
    force = -alpha * jnp.exp(-beta * e_c) * e_c  # dψ/dε at ε = -eps_c
    return psi + force * jnp.minimum(eps + eps_c, 0.0)


def peak_compression(beta):
    """Compression 1/β at which the exponential law's compressive force α e^{βε} ε is largest (β > 0).

    Beyond it the law's force falls as the compression grows, a negative stiffness (the energy is
    concave there, ψ'' = α e^{βε}(1 + βε) < 0) that no fabric has: Eq. (1) of the seed paper is
    fitted to tensile tests, and a compressed fabric buckles or its yarns jam, so its compressive
    force does not fall. Elements of a stiffening fabric (β of 10-15 puts the peak at 7-10 %
    compression) would collapse there and never come to rest. The membrane continues the law past
    this point at its peak force (``capped_law_energy``), which is C² there (ψ'' = 0 on both sides)
    and leaves every state with less compression unchanged. β ≤ 0 (no peak): 1e6, no limit."""
    return jnp.where(beta > 1e-6, 1.0 / jnp.where(beta > 1e-6, beta, 1.0), 1e6)


def stretches(xe, dm_inv):
    """Stretch ratios (4,) along warp, weft, bias± of a triangle (3,3) m."""
    ds = jnp.stack([xe[1] - xe[0], xe[2] - xe[0]], -1)  # (3,2)
    f = ds @ dm_inv
    return safe_norm(DIRECTIONS @ f.T)


class Membrane(AbstractEnergy):
    """Stretching and shear of the cloth (triangle elements); ``buckling`` caps compression at the
    element's Euler load (module docstring)."""

    buckling: bool = eqx.field(default=False, static=True)
    element_instability = True

    def coarse_level(self):
        """The capped membrane: a coarse level that does not lock in compression hands the
        finer levels a start whose folds are theirs (the light fabrics' rest states lie below
        the uncapped coarse drape's energy and drape coefficient:
        ``docs/results/2026-12-05-indefinite-steps.md``)."""
        return self if self.buckling else Membrane(buckling=True)

    def elements(self, mesh):
        return mesh.faces, (mesh.dm_inv, mesh.area)

    def element_energy(self, xe, data, params):
        dm_inv, area = data
        eps = stretches(xe, dm_inv) - 1.0
        alpha = jnp.stack([params.stretch_alpha_warp, params.stretch_alpha_weft,
                           params.stretch_alpha_bias, params.stretch_alpha_bias])
        beta = jnp.stack([params.stretch_beta_warp, params.stretch_beta_weft,
                          params.stretch_beta_bias, params.stretch_beta_bias])
        eps_c = peak_compression(beta)
        if self.buckling:
            k1 = jnp.stack([params.bend_k1_warp, params.bend_k1_weft, params.bend_k1_bias, params.bend_k1_bias])
            h2 = 4.0 * area / 3.0**0.5
            eps_c = jnp.minimum(eps_c, np.pi**2 * k1 / (h2 * alpha))
        return area * jnp.sum(capped_law_energy(eps, alpha, beta, eps_c))
