"""The linear solve inside each Newton step, as a type: ``Direct`` or ``CG``.

A Newton step of the drop and of the static solve needs a direction from the Hessian of energy
(plus inertia ``diag``, mass/h²), and each solver has its own rule for where the exact Hessian
is used and what replaces it where it is indefinite. ``Direct`` factorises a sparse Hessian on
the host (fast on CPU; from a GPU through a callback); ``CG`` runs matrix-free block-Jacobi PCG
and stays on the device (for GPUs). ``auto`` picks one by backend. ``SolverConfig`` still takes
the solver by name (``linear_solver="direct"``, ``shifted_steps=...``) and resolves it to one of
these types with ``SolverConfig.newton_solve``; new code may pass the type itself.
"""

from __future__ import annotations

import abc
from collections.abc import Callable
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp

from ..material import FabricParams
from ..mesh import ClothMesh
from ._newton import NewtonConfig, cg_direction, spd_block_inverse
from ._sparse import element_hessians, hessian_coo, sparse_solve, sparse_solve_shifted, term_hessian_coo, with_diagonal

LINEAR_SOLVER_NAMES = ("direct", "cg", "auto")
"""The names ``SolverConfig.linear_solver`` accepts."""


def preconditioner(terms, mesh: ClothMesh, params: FabricParams, x, mass_over_h2):
    """Block-Jacobi inverse of the Hessian of energy + inertia at x."""
    blocks = sum(t.hessian_blocks(x, mesh, params) for t in terms if t.in_preconditioner)
    blocks = blocks + mass_over_h2[:, None, None] * jnp.eye(3)[None]
    floor = jnp.maximum(mass_over_h2, 1e-6 * jnp.max(jnp.abs(blocks)))
    return spd_block_inverse(blocks, floor)


class AbstractNewtonSolve(eqx.Module):
    """How a Newton step gets its direction (a static setting: hashable, compared by value).

    ``exact_first`` (from ``SolverConfig.exact_step_hessian`` / ``exact_static_hessian``): take
    the exact Newton step wherever the exact Hessian (plus ``diag``) is positive definite.
    Positive definiteness, not mere descent, is the test: an exact step on an indefinite Hessian
    can be a descent direction that still heads for a saddle, and the static solve then stops on
    one (seen on 16 prior fabrics at 15 mm). ``exact_first=False``: the PSD-projected Hessian
    only. Projecting element Hessians discards the compressive part of the membrane Hessian that
    buckling lives on, so projected Newton converges only linearly.
    """

    name: ClassVar[str]
    """The ``SolverConfig.linear_solver`` name of this solver."""

    @abc.abstractmethod
    def direction(self, f: Callable, terms, mesh: ClothMesh, params: FabricParams, diag, exact_first: bool,
                  pcg: NewtonConfig) -> Callable:
        """The ``direction(x, g, exact, shift)`` rule ``newton_minimise`` calls for minimising
        ``f`` (the energy of ``terms``, plus the inertia ``diag`` (n,) added to the Hessian).
        ``pcg``: settings of the conjugate-gradient solves (``cg_iters``, ``cg_rtol``)."""


class Direct(AbstractNewtonSolve):
    """Newton with a sparse Cholesky factorisation on the host (fast on CPU).

    The factorisation shows at no extra cost whether the exact Hessian is positive definite.
    Where it is not, the step falls back to the PSD-projected Hessian; with ``shifted`` it
    first shifts the exact Hessian's diagonal by the least shift of a ladder that makes it
    positive definite (a Levenberg-type step that keeps the exact curvature of every stable mode;
    the ladder starts a tenth below the previous step's shift), and exact steps use every term's
    exact element Hessian (not a term's own PSD approximation). A 10 mm saturation drape's
    static solve was still 2e6 times above its force tolerance after 60 projected iterations (it
    used up 200), and converged in 94 shifted ones from the same state; at 5 mm shifted steps
    take 12 % fewer Newton iterations.

    Attributes:
        shifted: the shift ladder and exact element Hessians before the projected fallback
            (``SolverConfig.shifted_steps``). False: the exact-or-projected rule.
        absolute: where the exact Hessian is indefinite, first replace the element Hessians of
            the terms with ``element_instability`` (the membrane) by their absolute-eigenvalue
            projections (Longva et al. 2023, "Pitfalls of projection") and keep every other
            term exact; the shift ladder then starts from that matrix. A few compressed
            membrane elements (modes on 2-40 vertices) otherwise force a shift of 1e-4 to 1e-3
            of the mean diagonal that slows every fold-scale mode a thousandfold. Off by default
            (``docs/results/2026-12-05-indefinite-steps.md``).
        absolute_above: with ``absolute``, the largest shift (a multiple of the mean diagonal)
            the ladder may put on the exact Hessian before the absolute-eigenvalue membrane takes
            over; 0: at the first indefinite factorisation. A threshold keeps the exact curvature
            where a small shift suffices (a fold forming) and turns to the absolute rule only where
            a few elements would otherwise slow every mode.
    """

    shifted: bool = eqx.field(static=True, default=True)
    absolute: bool = eqx.field(static=True, default=False)
    absolute_above: float = eqx.field(static=True, default=0.0)
    name: ClassVar[str] = "direct"

    def direction(self, f, terms, mesh, params, diag, exact_first, pcg):
        shifted_steps, absolute, above = self.shifted, self.absolute, self.absolute_above

        def coo(x, project):
            return hessian_coo(terms, x, mesh, params, diag, project=project, exact=shifted_steps and not project)

        def projected(x, g):
            return sparse_solve(*coo(x, True), -g.reshape(-1)).reshape(g.shape)

        def direction(x, g, exact=True, shift=0.0):
            zero = jnp.zeros((), g.dtype)
            if not exact_first:
                return projected(x, g), 1, jnp.asarray(False), zero

            def shifted():
                if not absolute:
                    d, mu = sparse_solve_shifted(*coo(x, False), -g.reshape(-1), shift, shifted_steps)
                    return d.reshape(g.shape), mu
                # The exact terms' triplets serve both matrices; only the flagged terms are projected.
                parts = [term_hessian_coo(t, x, mesh, params, False, shifted_steps) for t in terms]
                d, mu = sparse_solve_shifted(*with_diagonal(parts, diag), -g.reshape(-1), shift,
                                             shifted_steps and above > 0, above)
                absolute_parts = lambda: [
                    term_hessian_coo(t, x, mesh, params, True, True, True) if t.element_instability
                    else part if shifted_steps else term_hessian_coo(t, x, mesh, params, False, True)
                    for t, part in zip(terms, parts)]
                d, mu = jax.lax.cond(jnp.isfinite(mu), lambda: (d, mu), lambda: sparse_solve_shifted(
                    *with_diagonal(absolute_parts(), diag), -g.reshape(-1), shift, True))
                return d.reshape(g.shape), mu

            d, mu = jax.lax.cond(exact, shifted, lambda: (jnp.full_like(g, jnp.nan), jnp.asarray(jnp.inf, g.dtype)))
            ok = jnp.isfinite(mu) & jnp.all(jnp.isfinite(d)) & (jnp.vdot(g, d) < 0)
            return jax.lax.cond(ok, lambda: d, lambda: projected(x, g)), 1, ok, jnp.where(ok, mu, zero)
        return direction


class CG(AbstractNewtonSolve):
    """Matrix-free Newton-PCG with block-Jacobi preconditioning (stays on the device, for GPUs).

    Instead of a factorisation's positive-definiteness test it checks whether PCG on the exact
    Hessian meets negative curvature, and then solves again with the projected Hessian (a
    matrix-free product over element Hessians). There is no shift ladder.
    """

    name: ClassVar[str] = "cg"

    def direction(self, f, terms, mesh, params, diag, exact_first, pcg):
        def projected_hvp(x):
            parts = [element_hessians(t, x, mesh, params, project=True) for t in terms]

            def hvp(v):
                out = diag[:, None] * v
                for idx, h in parts:
                    e, k = idx.shape
                    he = jnp.einsum("eij,ej->ei", h, v[idx].reshape(e, 3 * k)).reshape(e, k, 3)
                    out = out.at[idx].add(he)
                return out
            return hvp

        return cg_direction(f, lambda x: preconditioner(terms, mesh, params, x, diag), projected_hvp, pcg, exact_first)


def _direct(shifted: bool, absolute_above: float | None) -> Direct:
    if absolute_above is None:
        return Direct(shifted=shifted)
    return Direct(shifted=shifted, absolute=True, absolute_above=float(absolute_above))


def auto(shifted: bool = True, absolute_above: float | None = None) -> AbstractNewtonSolve:
    """``Direct(shifted)`` (with the absolute membrane rule above ``absolute_above``) on CPU,
    ``CG()`` on any other backend (resolved when called)."""
    return _direct(shifted, absolute_above) if jax.default_backend() == "cpu" else CG()


def check_linear_solver(value) -> None:
    """Raise a ``ValueError`` naming ``linear_solver`` unless ``value`` is one of
    ``LINEAR_SOLVER_NAMES`` or an ``AbstractNewtonSolve``."""
    if isinstance(value, AbstractNewtonSolve) or (isinstance(value, str) and value in LINEAR_SOLVER_NAMES):
        return
    raise ValueError(f"unknown linear_solver {value!r}: expected one of {', '.join(map(repr, LINEAR_SOLVER_NAMES))} "
                     f"or a drapejax.solve.linear.AbstractNewtonSolve (Direct(), CG())")


def newton_solve(linear_solver: str | AbstractNewtonSolve, shifted: bool = True,
                 absolute_above: float | None = None) -> AbstractNewtonSolve:
    """The solver type for a ``linear_solver`` name ("direct", "cg" or "auto") or type (returned
    as is); ``shifted`` is ``Direct.shifted`` and ``absolute_above`` (None: off)
    ``Direct.absolute_above`` for the names that give ``Direct``."""
    check_linear_solver(linear_solver)
    if isinstance(linear_solver, AbstractNewtonSolve):
        return linear_solver
    if linear_solver == "auto":
        return auto(shifted, absolute_above)
    return _direct(shifted, absolute_above) if linear_solver == "direct" else CG()


__all__ = ["AbstractNewtonSolve", "Direct", "CG", "auto", "newton_solve", "check_linear_solver",
           "LINEAR_SOLVER_NAMES", "preconditioner"]
