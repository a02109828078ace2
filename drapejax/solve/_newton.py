"""Newton's method with block-Jacobi preconditioned, truncated conjugate gradients.

Used for every minimisation in drapejax: implicit-Euler time steps (incremental potential)
and static equilibria. Hessian-vector products are ``jvp(grad)``; the preconditioner is the
per-vertex 3x3 Hessian diagonal, made positive definite.
"""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float


class NewtonConfig(eqx.Module):
    """Inner-solver settings (static).

    Attributes:
        max_iters: Newton iterations per solve.
        cg_iters: conjugate-gradient iterations per Newton iteration.
        cg_rtol: relative residual at which CG stops (inexact Newton).
        step_tol_m: converged when the largest vertex move of a full step is below this, m.
        max_halvings: backtracking line-search halvings.
    """

    max_iters: int = eqx.field(static=True, default=30)
    cg_iters: int = eqx.field(static=True, default=300)
    cg_rtol: float = eqx.field(static=True, default=1e-3)
    step_tol_m: float = eqx.field(static=True, default=1e-7)
    max_halvings: int = eqx.field(static=True, default=12)


def spd_block_inverse(blocks: Float[Array, "n 3 3"], floor: Float[Array, " n"]) -> Float[Array, "n 3 3"]:
    """Inverse of symmetric 3x3 blocks with eigenvalues clamped from below by ``floor``."""
    w, q = jnp.linalg.eigh(0.5 * (blocks + jnp.swapaxes(blocks, -1, -2)))
    w = jnp.maximum(w, floor[:, None])
    return jnp.einsum("nij,nj,nkj->nik", q, 1.0 / w, q)


def pcg(hvp: Callable, g: Array, pinv: Array, iters: int, rtol: float, active=True) -> tuple[Array, Array, Array]:
    """Approximately solve H d = -g; stops at negative curvature (Steihaug).

    Returns a descent direction, the number of iterations used, and whether negative
    curvature was met (the direction is then a truncated one). ``active=False`` returns at
    once (zero iterations): under ``vmap`` a member that needs no solve then does not keep the
    batch's loop going."""
    apply_p = lambda r: jnp.einsum("nij,nj->ni", pinv, r)
    r0 = -g
    z0 = apply_p(r0)
    gnorm = jnp.sqrt(jnp.vdot(g, g))

    def cond(s):
        i, d, r, z, p, rz, done, neg_hit = s
        return (i < iters) & ~done

    def body(s):
        i, d, r, z, p, rz, done, neg_hit = s
        hp = hvp(p)
        php = jnp.vdot(p, hp)
        neg = php <= 0.0
        a = rz / jnp.where(neg, 1.0, php)
        # On negative curvature keep the current iterate, or the preconditioned gradient at i = 0.
        d_neg = jnp.where(i == 0, z0, d)
        d_new = jnp.where(neg, d_neg, d + a * p)
        r_new = r - a * hp
        z_new = apply_p(r_new)
        rz_new = jnp.vdot(r_new, z_new)
        p_new = z_new + (rz_new / jnp.where(rz == 0, 1.0, rz)) * p
        conv = jnp.sqrt(jnp.vdot(r_new, r_new)) <= rtol * gnorm
        return i + 1, d_new, r_new, z_new, p_new, rz_new, neg | conv, neg

    init = (0, jnp.zeros_like(g), r0, z0, z0, jnp.vdot(r0, z0), (gnorm == 0) | ~jnp.asarray(active), False)
    i, d, *_, neg_hit = jax.lax.while_loop(cond, body, init)
    return d, i, neg_hit


def cg_direction(f: Callable, make_pinv: Callable, projected_hvp: Callable, cfg: NewtonConfig,
                 exact_first: bool = True) -> Callable:
    """Newton direction by matrix-free PCG; ``make_pinv(x)`` gives (n,3,3) preconditioner blocks.

    ``projected_hvp(x)`` returns the product with the PSD-projected Hessian at x. The
    direction comes from the exact Hessian wherever PCG meets no negative curvature (the
    CG analogue of the direct solver's positive-definiteness test: quadratic convergence near
    a minimum) and is solved again with the projected Hessian where it does (a full descent
    step instead of a truncated one); ``exact_first=False`` uses the projected Hessian only.
    """
    grad = jax.grad(f)

    def direction(x, g, exact=True, shift=0.0):
        pinv = make_pinv(x)
        zero = jnp.zeros((), g.dtype)

        def projected(k0, active=True):
            d, k, _ = pcg(projected_hvp(x), g, pinv, cfg.cg_iters, cfg.cg_rtol, active)
            return d, k0 + k, jnp.asarray(False), zero

        if not exact_first:
            return projected(0)
        d, k, neg = pcg(lambda v: jax.jvp(grad, (x,), (v,))[1], g, pinv, cfg.cg_iters, cfg.cg_rtol, exact)
        fall = neg | ~exact
        # Under vmap the cond runs both branches for every member; ``active`` keeps the members
        # that keep their exact step from lengthening the projected solve's loop.
        return jax.lax.cond(fall, lambda: projected(k, fall), lambda: (d, k, jnp.asarray(True), zero))

    return direction


def newton_minimise(f: Callable, x0: Array, direction: Callable, cfg: NewtonConfig, force_tol=0.0):
    """Minimise ``f`` from ``x0`` by line-searched Newton steps.

    ``direction(x, g, exact, shift)`` returns (step, linear-solver iterations, whether the step
    came from the exact Hessian, the diagonal shift it needed); ``exact=False`` asks for the
    PSD-projected one, ``shift`` is the shift the previous step needed (the direct solver's
    ladder starts below it, see ``_sparse.sparse_solve_shifted``). Converged when the
    largest gradient entry (a force, N) is below ``force_tol`` or a full step moves less than
    ``cfg.step_tol_m``. An exact step whose line search fails is retried once with the projected
    Hessian instead of ending the solve: a positive definite but nearly singular Hessian (a soft
    hem mode) gives exact steps of metres that no backtracking rescues, while the projected
    step still descends. Returns (x, Newton iterations, linear-solver iterations, converged).
    """
    grad = jax.grad(f)

    def cond(s):
        x, it, ncg, done, conv, fx, exact, shift = s
        return (it < cfg.max_iters) & ~done

    def body(s):
        x, it, ncg, done, conv, fx, exact, shift = s
        g = grad(x)
        small = jnp.max(jnp.abs(g)) < force_tol
        d, k, used_exact, shift = direction(x, g, exact, shift)
        d = jnp.where(jnp.isfinite(d), d, 0.0)
        slope = jnp.vdot(g, d)
        d = jnp.where(slope < 0, d, -g)
        slope = jnp.where(slope < 0, slope, -jnp.vdot(g, g))

        def ls_cond(t):
            a, fa, k = t
            return (k < cfg.max_halvings) & ~(fa <= fx + 1e-4 * a * slope)

        def ls_body(t):
            a, fa, k = t
            a = 0.5 * a
            return a, f(x + a * d), k + 1

        a, fa, _ = jax.lax.while_loop(ls_cond, ls_body, (1.0, f(x + d), 0))
        ok = jnp.isfinite(fa) & (fa <= fx)
        x_new = jnp.where(ok, x + a * d, x)
        move = jnp.max(jnp.abs(d))
        x_new = jnp.where(small, x, x_new)
        conv = (move < cfg.step_tol_m) | small
        retry = ~ok & used_exact & ~conv
        return x_new, it + 1, ncg + k, conv | (~ok & ~retry), conv, jnp.where(ok, fa, fx), ~retry, shift

    init = (x0, 0, 0, False, False, f(x0), jnp.asarray(True), jnp.zeros((), x0.dtype))
    x, it, ncg, _, conv, _, _, _ = jax.lax.while_loop(cond, body, init)
    return x, it, ncg, conv
