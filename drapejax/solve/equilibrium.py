"""Differentiable rest shapes: the implicit function theorem at the static equilibrium.

``equilibrium`` returns a converged rest state whose derivatives with respect to the material
parameters (and any float field of the energy terms, e.g. an effect's strength) come from one
linear solve with the equilibrium Hessian ($\\partial x^*/\\partial p = -H^{-1}\\,\\partial_p\\nabla_x
E$), never from unrolling the drop.

On CPU (``linear_solver="direct"``) the tangent is a ``jax.custom_jvp`` whose solve is
``jax.lax.custom_linear_solve`` around a sparse direct factorisation of the exact equilibrium
Hessian on the host (symmetric, so the same solve serves reverse mode). It holds no host
callback, so programs that differentiate a rest state go into JAX's persistent compilation
cache. Elsewhere ("cg") the rest state is handed to ``optimistix.minimise`` as the minimum of
the total energy with ``optimistix.ImplicitAdjoint`` and conjugate gradients in
block-Jacobi-scaled coordinates (it stays on the device, and needs many iterations because
membrane and bending stiffness differ by orders of magnitude).
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import optimistix as optx

from ..energy import default_energies, total_energy
from ..material import FabricParams
from ..mesh import ClothMesh
from ._sparse import hessian_coo, sparse_solve
from .drop import require_float64
from .linear import preconditioner


class _AtMinimum(optx.AbstractMinimiser):
    """A minimiser for an already-converged point: it takes no step (the forward solve was done)."""

    rtol: float = 0.0
    atol: float = 0.0
    norm: Any = optx.max_norm

    def init(self, fn, y, args, options, f_struct, aux_struct, tags):
        return None

    def step(self, fn, y, args, options, state, tags):
        return y, state, None

    def terminate(self, fn, y, args, options, state, tags):
        return jnp.array(True), optx.RESULTS.successful

    def postprocess(self, fn, y, aux, args, options, state, tags, result):
        return y, aux, {}


def equilibrium(mesh: ClothMesh, params: FabricParams, x_rest, *, terms=None, linear_solver: str = "direct",
                cg_rtol: float = 1e-10, cg_max_steps: int = 20000):
    """Rest positions (n,3) equal to ``x_rest`` with implicit derivatives w.r.t. params and terms.

    Args:
        mesh: the specimen mesh.
        params: material parameters (differentiable).
        x_rest: a converged rest state (e.g. ``drape(...).x``); it is treated as a constant.
        terms: energy terms (default: the base model); their float fields are differentiable.
        linear_solver: "direct" (host sparse LU, also used from a GPU via a callback), "cg"
            (stays on the device; may exhaust its budget on stiff membranes) or "auto" (direct
            on CPU, cg elsewhere), for the adjoint solve.
        cg_rtol, cg_max_steps: tolerance and budget of the adjoint CG solve.

    Raises:
        ValueError: when JAX is not in float64 mode.
    """
    require_float64("equilibrium")
    terms = default_energies(mesh.info.test) if terms is None else terms
    x_ref = jax.lax.stop_gradient(x_rest)
    if linear_solver == "auto":
        linear_solver = "direct" if jax.default_backend() == "cpu" else "cg"
    if linear_solver == "direct":
        p0 = jax.lax.stop_gradient(params)
        rows, cols, vals = hessian_coo(terms, x_ref, mesh, p0, jnp.zeros(mesh.n_verts, x_ref.dtype), project=False,
                                       exact=True)
        return _implicit_direct(terms, mesh, x_ref, (rows, cols, jax.lax.stop_gradient(vals)), params)
    if linear_solver == "cg":
        solver = lx.CG(rtol=cg_rtol, atol=0.0, max_steps=cg_max_steps)
        scale = jax.lax.stop_gradient(_scaling(terms, mesh, params, x_ref))
    else:
        raise ValueError(f"unknown linear_solver {linear_solver!r}: expected 'direct', 'cg' or 'auto'")

    def fn(y, args):
        p, t = args
        return total_energy(t, x_ref + jnp.einsum("nij,nj->ni", scale, y), mesh, p)

    adjoint = optx.ImplicitAdjoint(linear_solver=solver)
    dynamic, static = eqx.partition(terms, eqx.is_array)
    sol = optx.minimise(lambda y, a: fn(y, (a[0], eqx.combine(a[1], static))), _AtMinimum(), jnp.zeros_like(x_ref),
                        (params, dynamic), adjoint=adjoint, throw=False, max_steps=1,
                        tags=frozenset({lx.symmetric_tag, lx.positive_semidefinite_tag}))
    return x_ref + jnp.einsum("nij,nj->ni", scale, sol.value)


def _implicit_direct(terms, mesh: ClothMesh, x_ref, coo, params):
    """``x_ref`` with the implicit tangent $-H^{-1}\\,\\partial_{(p, t)}\\nabla_x E$, H the COO Hessian ``coo``
    factorised on the host (``_sparse.sparse_solve``); t are the float fields of ``terms``."""
    rows, cols, vals = coo
    dynamic, static = eqx.partition(terms, eqx.is_inexact_array)
    n = x_ref.size

    def force(p, dyn):
        return jax.grad(lambda y: total_energy(eqx.combine(dyn, static), y, mesh, p))(x_ref).reshape(-1)

    @jax.custom_jvp
    def rest(p, dyn):
        return x_ref

    @rest.defjvp
    def rest_jvp(primals, tangents):
        _, dforce = jax.jvp(force, primals, tangents)
        matvec = lambda v: jax.ops.segment_sum(vals * v[cols], rows, num_segments=n)
        dx = jax.lax.custom_linear_solve(matvec, -dforce, lambda _, b: sparse_solve(rows, cols, vals, b),
                                         symmetric=True)
        return x_ref, dx.reshape(x_ref.shape)

    return rest(params, dynamic)


def _scaling(terms, mesh, params, x):
    """Inverse square root of the block-Jacobi preconditioner: makes the adjoint CG well-scaled."""
    pinv = preconditioner(terms, mesh, params, x, 1e-6 * params.density * mesh.vertex_area)
    w, q = jnp.linalg.eigh(pinv)
    return jnp.einsum("nij,nj,nkj->nik", q, jnp.sqrt(jnp.maximum(w, 0.0)), q)
