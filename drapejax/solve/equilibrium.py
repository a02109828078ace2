"""Differentiable rest shapes: the implicit function theorem at the static equilibrium.

``equilibrium`` hands a converged rest state to ``optimistix.minimise`` as the minimum of the
total energy, with ``optimistix.ImplicitAdjoint``: gradients of anything computed from the rest
shape, with respect to the material parameters (and any float field of the energy terms, e.g.
an effect's strength), come from one linear solve with the equilibrium Hessian
($\\partial x^*/\\partial p = -H^{-1}\\,\\partial_p\\nabla_x E$), never from unrolling the drop.
The Hessian solve is a sparse direct factorisation of the exact equilibrium Hessian on CPU
(``linear_solver="direct"``) or conjugate gradients in block-Jacobi-scaled coordinates ("cg",
for devices; it needs many iterations because membrane and bending stiffness differ by
orders of magnitude).
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
from ._sparse import SparseDirect, hessian_coo
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
        coo = hessian_coo(terms, x_ref, mesh, p0, jnp.zeros(mesh.n_verts, x_ref.dtype), project=False,
                          exact=True)
        solver = SparseDirect(coo[0], coo[1], jax.lax.stop_gradient(coo[2]))
        scale = jnp.broadcast_to(jnp.eye(3, dtype=x_ref.dtype), (mesh.n_verts, 3, 3))
    elif linear_solver == "cg":
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


def _scaling(terms, mesh, params, x):
    """Inverse square root of the block-Jacobi preconditioner: makes the adjoint CG well-scaled."""
    pinv = preconditioner(terms, mesh, params, x, 1e-6 * params.density * mesh.vertex_area)
    w, q = jnp.linalg.eigh(pinv)
    return jnp.einsum("nij,nj,nkj->nik", q, jnp.sqrt(jnp.maximum(w, 0.0)), q)
