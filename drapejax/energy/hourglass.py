r"""Hourglass control: a penalty on the mesh-scale curvature the bending fit cannot see.

``Bending`` fits a quadratic to each vertex's 1-ring. On a refined unstructured mesh that fit
has soft non-smooth (hourglass) modes: zig-zags with little fitted curvature, which let a
cantilever droop 3-5 % past the master curve at 1.25-1.75 mm (while the same energy restricted
to smooth shapes is slightly stiff, as a consistent discretisation should be). This term fits a
cubic to each free vertex's 2-ring and charges the part of the offsets' normal components no
cubic explains:

$E = \beta \sum_v \frac{A_v}{k_v} \sum_j D(e_j)\,(r_{vj}/\ell_{vj}^2)^2$,

with $r_v = (I - \Phi\Phi^+)\,(\Delta x_v\cdot n_v)$ the residual of the fit, $D(e)$ the
plate's rigidity along offset direction $e$ and $\ell$ the offset length. The penalty vanishes
for every cubic surface, so it adds no stiffness to smooth bending at any resolution (a 1-ring
residual would: it is the bend's cubic part), and it only stiffens the modes the bending
energy misses. With β = 3 every cantilever with Γ ≤ 10 (widths 7.5-30 mm, spacings 5-1.25 mm,
cut at 0° and 45°) is within 3 % of the master curve, about +1 % at 1.25 mm where it was
+2-5 % (``experiments/cantilever_convergence.py``).

The 2-ring stencil couples vertices four rings apart in the Hessian: inside every time step of
a drop it made a Cusick drop 4.6x slower (mid fabric, 20 mm graded mesh: 46.7 s against 10.1 s),
so the drop leaves it out (``in_drop``) and the static solve that ends each drape adds it
(2-15 s on meshes of 20 to 5 mm). Newton steps use its Gauss–Newton Hessian, which is exact at
a flat state (exact steps use the exact one with ``SolverConfig.shifted_steps``);
``equilibrium`` uses the exact one.
"""

import jax
import jax.numpy as jnp
from jax.scipy.linalg import block_diag

from ._base import AbstractEnergy, normalize
from .bending import plate_terms

HOURGLASS_BETA = 3.0
"""Default penalty weight (dimensionless)."""


def _unit_normal(t):
    """Unit normal of the fitted tangent plane from the tangents t (2, 3): ∂u x, ∂v x."""
    return normalize(jnp.cross(t[0], t[1]))


def _rigidity_weights(weight, params):
    d11, d12, d22, d66 = plate_terms(params)
    return weight @ jnp.stack([d11, d12 + 2.0 * d66, d22])


class HourglassControl(AbstractEnergy):
    """Penalty on the non-cubic part of each free vertex's 2-ring (J); ``beta`` dimensionless."""

    beta: float = HOURGLASS_BETA
    in_drop = False

    def elements(self, mesh):
        return mesh.hg_nbr, (mesh.hg_res, mesh.hg_tan, mesh.hg_weight)

    def _normal_and_rows(self, xe, data):
        res, tan, _ = data
        off = xe[1:] - xe[:1]
        return _unit_normal(tan @ off), res, off

    def _gauss_newton_rows(self, xe, data, params):
        """Normal n, residual rows over the stencil (k, k+1; self first) and their weights (k,)."""
        n, res, _ = self._normal_and_rows(xe, data)
        rt = jnp.concatenate([-jnp.sum(res, 1, keepdims=True), res], 1)
        return n, rt, 2.0 * self.beta * _rigidity_weights(data[2], params)

    def element_energy(self, xe, data, params):
        n, res, off = self._normal_and_rows(xe, data)
        r = res @ (off @ n)
        return self.beta * jnp.sum(_rigidity_weights(data[2], params) * r * r)

    def element_hessian(self, xe, data, params):
        r"""Exact Hessian in closed form, one product $U^\top C U$ per stencil.

        With $s = \mathrm{off}\,n$ and $c = M s$, $M = R^\top W R$, the Hessian is
        $2\beta\,(J^\top M J + \sum_i c_i \nabla^2 s_i)$; the second part is the normal's
        first derivative (in the six fitted tangent components) paired with the offsets, and its
        second derivative weighted by $\mathrm{off}^\top c$. Only the normal is differentiated by
        autodiff (the generic Hessian differentiates through all 3(k+1) stencil coordinates)."""
        res, tan, weight = data[:3]
        k2, dt = res.shape[0], xe.dtype
        off = xe[1:] - xe[:1]
        t = tan @ off
        n, dn = _unit_normal(t), jax.jacfwd(_unit_normal)(t)  # (3,), (3, 2, 3)
        m = res.T @ (_rigidity_weights(weight, params)[:, None] * res)
        c = m @ (off @ n)
        hn = jax.hessian(lambda t: (off.T @ c) @ _unit_normal(t))(t).reshape(6, 6)
        a = jnp.concatenate([-jnp.ones((k2, 1), dt), jnp.eye(k2, dtype=dt)], 1)  # off = a @ xe
        tx = tan @ a  # t = tx @ xe
        eye = jnp.eye(3, dtype=dt)
        jac = (a[:, :, None] * n[None, None] + jnp.einsum("ic,cmb,mp->ipb", off, dn, tx)).reshape(k2, -1)  # ds/dxe
        lift = jnp.einsum("mp,ab->mapb", tx, eye).reshape(6, -1)  # dt/dxe
        pair = jnp.einsum("p,ab->apb", a.T @ c, eye).reshape(3, -1)
        dnx = jnp.einsum("amb,mq->aqb", dn, tx).reshape(3, -1)  # dn/dxe
        u = jnp.concatenate([jac, lift, pair, dnx])
        z3 = jnp.zeros((3, 3), dt)
        cmat = block_diag(m, hn, jnp.block([[z3, eye], [eye, z3]]))
        return 2.0 * self.beta * (u.T @ (cmat @ u))

    has_psd_hessian = True

    def psd_element_hessian(self, xe, data, params):
        r"""Gauss–Newton Hessian $2\beta\,R^\top W R \otimes n n^\top$ (the normal held fixed): PSD."""
        n, rt, w = self._gauss_newton_rows(xe, data, params)
        m = rt.T @ (w[:, None] * rt)
        k1 = m.shape[0]
        return (m[:, None, :, None] * jnp.outer(n, n)[None, :, None, :]).reshape(3 * k1, 3 * k1)

    def hessian_blocks(self, x, mesh, params):
        """The diagonal 3x3 blocks of ``psd_element_hessian``, summed per vertex."""
        idx, data = self.elements(mesh)

        def blocks(xe, d):
            n, rt, w = self._gauss_newton_rows(xe, d, params)
            return (w @ (rt * rt))[:, None, None] * jnp.outer(n, n)[None]

        b = jax.vmap(blocks)(x[idx], data)
        return jnp.zeros((x.shape[0], 3, 3), x.dtype).at[idx.reshape(-1)].add(b.reshape(-1, 3, 3))
