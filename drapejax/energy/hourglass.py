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

from ._base import AbstractEnergy, normalize
from .bending import over_stencil, plate_terms

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
        rt = over_stencil(res, 1)
        return n, rt, 2.0 * self.beta * _rigidity_weights(data[2], params)

    def element_energy(self, xe, data, params):
        n, res, off = self._normal_and_rows(xe, data)
        r = res @ (off @ n)
        return self.beta * jnp.sum(_rigidity_weights(data[2], params) * r * r)

    def element_hessian(self, xe, data, params):
        r"""Exact Hessian in closed form, assembled as 3x3 blocks per stencil vertex pair.

        With $s = \mathrm{off}\,n$, $c = M s$, $M = R^\top W R$, offsets $\mathrm{off} = A x$
        and fitted tangents $t = T x$ ($T$ = ``tan`` $A$, 2 per vertex), the Hessian is
        $2\beta\,(J^\top M J + \sum_i c_i \nabla^2 s_i)$ with
        $\partial s_i/\partial x_a = A_{ia} n + \sum_m T_{ma} L_{im}$, $L_{im} = \mathrm{off}_i^\top
        \partial n/\partial t_m$. Every block is then a sum of small products: $(A^\top M A)_{ab}\,n n^\top$,
        $n$ against $\sum_m T_{mb} (A^\top M L)_{am}$ and its mirror, $\sum_{mm'} T_{ma} T_{m'b}
        (L^\top M L + \nabla_t^2[(\mathrm{off}^\top c)\cdot n])_{mm'}$, and the normal's first
        derivative weighted by $A^\top c$. Only the normal is differentiated by autodiff, and the
        blocks are written as broadcast products, which XLA fuses into one loop over the
        (k+1)² x 9 entries, not as batched small matrix products, which it runs slowly on a CPU."""
        res, tan, weight = data[:3]
        off = xe[1:] - xe[:1]
        t = tan @ off
        n, dn = _unit_normal(t), jax.jacfwd(_unit_normal)(t)  # (3,), (3, 2, 3)
        m = res.T @ (_rigidity_weights(weight, params)[:, None] * res)
        c = m @ (off @ n)
        hn = jax.hessian(lambda t: (off.T @ c) @ _unit_normal(t))(t)  # (2, 3, 2, 3)
        tx = over_stencil(tan, 1)  # (2, k): t = tx @ xe
        lo = jnp.einsum("ip,pmq->imq", off, dn)  # ∂s_i/∂t_m
        p = over_stencil(over_stencil(m, 1), 0)  # a^T m a, with a = [-1 | I]
        r = over_stencil(jnp.einsum("ij,jmq->imq", m, lo), 0)  # a^T m lo
        x = r[:, None, 0] * tx[0][None, :, None] + r[:, None, 1] * tx[1][None, :, None]  # (k, k, 3)
        sm = jnp.einsum("imq,ij,jnr->mqnr", lo, m, lo) + hn
        d = jnp.einsum("pmq,mb->bpq", dn, tx)
        w = over_stencil(c, 0)
        ta, tb = tx[:, :, None, None, None], tx[:, None, :, None, None]
        blocks = (p[:, :, None, None] * jnp.outer(n, n)[None, None]
                  + n[None, None, :, None] * x[:, :, None, :]
                  + jnp.swapaxes(x, 0, 1)[:, :, :, None] * n[None, None, None, :]
                  + sum(ta[i] * tb[j] * sm[None, None, i, :, j, :] for i in range(2) for j in range(2))
                  + w[:, None, None, None] * d[None] + w[None, :, None, None] * jnp.swapaxes(d, 1, 2)[:, None])
        k = tx.shape[1]
        return 2.0 * self.beta * blocks.transpose(0, 2, 1, 3).reshape(3 * k, 3 * k)

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
