"""The fit: Levenberg–Marquardt on a ``Problem`` (``run_lm``) and its entry for one capture (``fit``).

The loop is Python around jitted (residual, Jacobian) evaluations, because every evaluation
warm-starts the forward solve from the previous accepted rest state, a host-side cache that
optimistix' pure loop cannot hold; the damped normal equations are solved with ``lineax``.
Steps that give NaN or a higher loss are rejected, so a fit never ends worse than it started,
and it ends with the Laplace (Gauss–Newton) covariance ``(JᵀJ)⁻¹`` of θ, prior rows included.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import jax.numpy as jnp
import lineax as lx
import numpy as np

from ..io import Measurement
from ..material import FabricParams
from ..mesh import ClothMesh
from ..progress import bar
from ..solve import SolverConfig
from .errors import RefineError
from .meshing import fit_mesh
from .observables import measured_targets
from .presets import CONTINUATION_CONFIG
from .problem import K_PRIOR_STD, Effect, Problem, prepare_programs


@dataclass
class FitResult:
    """Outcome of ``fit``: best parameters, θ, its covariance, rest state, losses and status."""

    params: FabricParams
    theta: np.ndarray
    cov: np.ndarray
    x: np.ndarray
    loss_start: float
    loss: float
    steps: int
    status: str
    history: list
    n_residuals: int = 0


LAPLACE_STATUSES = ("converged", "max_steps", "no_improvement_returned_start")
"""``FitResult.status`` values whose ``cov`` is the Laplace one at the fit's end point (``run_lm``;
"nan_returned_start" carries the prior's covariance instead)."""


def _lm_step(j: np.ndarray, r: np.ndarray, lam: float) -> np.ndarray:
    """Levenberg–Marquardt step: solve (JᵀJ + λ diag(JᵀJ)) δ = -Jᵀr with lineax."""
    a = j.T @ j
    a = a + lam * np.diag(np.diag(a))
    op = lx.MatrixLinearOperator(jnp.asarray(a), lx.positive_semidefinite_tag)
    return np.asarray(lx.linear_solve(op, jnp.asarray(-j.T @ r), lx.Cholesky()).value)


def fit(measurement: Measurement, *, init: FabricParams, spacing_m: float = 0.02, effects: Sequence[Effect] = (),
        theta_effects0: np.ndarray | None = None, prior_std: np.ndarray | None = None,
        max_steps: int = 8, seed: int = 0, mesh: ClothMesh | None = None, start: FitResult | None = None,
        lower_effects: np.ndarray | None = None, config: SolverConfig = CONTINUATION_CONFIG,
        buckling: bool = False, resolve_start: bool = False) -> FitResult:
    """Refine the bending rigidities (and effect parameters) of ``init`` against ``measurement``.

    Args:
        measurement: a Cusick or square measurement (any of its observations).
        init: initial parameters; scalar fields (density = nominal value when unknown).
        spacing_m: simulation mesh spacing, m.
        effects: extra energy terms as functions of their parameter vector θ_e.
        theta_effects0: initial/prior-mean θ_e (required when ``effects`` is given).
        prior_std: log-space prior stds (overall k1 scale, k1 direction ratios, effects...);
            default (log 3, 0.25, 1 per effect).
        max_steps: Levenberg–Marquardt iterations.
        seed: drop seed of the first forward solve (unused with ``start``).
        mesh: optional pre-built mesh (default ``fit_mesh(measurement, spacing_m)``).
        start: an earlier fit of this measurement on ``mesh`` to continue from instead of dropping
            afresh: θ starts at ``start.theta`` (its k1 scales and effects, which must lead
            ``effects``), extended by ``theta_effects0`` for the added effects, and the rest state
            at ``start.x``; the prior mean stays (init, ``theta_effects0``). With the added effects
            at null and the same prior as ``start``, the refit is nested in it (same fold pattern,
            loss never above its), so a gain measures the effects, not a new fold pattern.
        resolve_start: the added effects start away from null, so ``start.x`` is not the rest state
            at the starting θ: solve it first, warm-started from ``start.x`` (same fold pattern).
        lower_effects: smallest allowed θ_e (e.g. ``Effect.lower_bound()``; default unbounded).
        config: the solver (``Problem``).
        buckling: cap the membrane's compression at the element scale (``energy.Membrane``), so
            that a soft fabric can fold on a coarse fit mesh.

    Returns:
        ``FitResult``; ``status`` is "converged", "max_steps", "nan_returned_start" (the start
        was not finite) or "no_improvement_returned_start" (no step lowered the loss).
    """
    if effects and theta_effects0 is None:
        raise RefineError("fit: theta_effects0 is required when effects are given")
    th_e = np.zeros(0) if theta_effects0 is None else np.asarray(theta_effects0, float).ravel()
    theta0 = np.concatenate([np.zeros(3), th_e])
    pstd = np.concatenate([K_PRIOR_STD, np.ones(len(th_e))]) if prior_std is None else prior_std
    th_start = theta0 if start is None else np.asarray(start.theta, float)
    if len(th_start) > len(theta0):
        raise RefineError(f"fit: start has {len(th_start)} parameters, more than the {len(theta0)} of this fit")
    if mesh is None:
        mesh = fit_mesh(measurement, spacing_m)
    lower = None if lower_effects is None else np.concatenate([np.full(3, -np.inf), np.ravel(lower_effects)])
    prob = Problem(mesh, measured_targets(measurement), init, effects, theta0, pstd, spacing_m, lower, config=config,
                   buckling=buckling)
    x0 = None if start is None else np.asarray(start.x)
    theta_start = np.concatenate([th_start, theta0[len(th_start):]])
    if x0 is not None and resolve_start:
        prob.x, x0 = x0, None  # ``run_lm``'s first solve is then warm-started from it
    prepare_programs(prob.programs(drop=start is None))  # compiled side by side, not one after another
    return run_lm(prob, theta_start, max_steps=max_steps, seed=seed, x0=x0)


def run_lm(prob: Problem, theta0: np.ndarray, *, max_steps: int, seed: int = 0, lam0: float = 1e-2,
           tol: float = 1e-3, x0: np.ndarray | None = None) -> FitResult:
    """Levenberg–Marquardt from θ0 with rejection of NaN/worse steps; never ends worse than θ0.
    Steps are projected onto θ ≥ ``prob.lower``. A progress bar (``drapejax.progress``) counts
    the iterations and shows the ½χ² and damping reached. ``x0``: the rest state θ0 is known to
    have (a nested refit's start, ``fit(start=...)``), scored as it is rather than solved again: the
    fit's warm-started static solves lag behind equilibrium by design (``CONTINUATION_CONFIG``),
    so a second solve from it would move on and the refit would not start at its start's loss."""
    theta = np.asarray(theta0, float)
    with bar(total=max_steps, desc="LM fit", unit="step") as steps_bar:
        steps_bar.set_postfix_str("first drop")
        x = prob.rest(theta, seed) if x0 is None else x0
        r, j = prob.evaluate(theta, x, jacobian=True)
        loss0 = loss = 0.5 * float(r @ r)
        history = [loss]
        if not (np.isfinite(loss) and np.all(np.isfinite(j))):
            steps_bar.set_postfix_str("start not finite")
            cov = np.linalg.inv(prob.prior_sqrt_info.T @ prob.prior_sqrt_info)
            return FitResult(prob.params(theta), theta, cov, x, loss0, loss0, 0, "nan_returned_start", history,
                             len(r) - len(theta))
        prob.x = x
        lam, status, steps, improved = lam0, "max_steps", 0, False
        steps_bar.set_postfix(loss=f"{loss:.4g}", lam=f"{lam:.0e}")
        for steps in range(1, max_steps + 1):
            delta = _lm_step(j, r, lam)
            cand = np.maximum(theta + np.clip(delta, -prob.max_step, prob.max_step), prob.lower)
            try:
                xc = prob.rest(cand, seed)
                lc = np.nan
                if np.all(np.isfinite(xc)):
                    rc, _ = prob.evaluate(cand, xc, jacobian=False)
                    lc = 0.5 * float(rc @ rc)
            except (FloatingPointError, ValueError):
                lc = np.nan
            if np.isfinite(lc) and lc < loss:
                gain = loss - lc
                theta, x, loss, improved = cand, xc, lc, True
                prob.x = x
                r, j = prob.evaluate(theta, x, jacobian=True)
                lam = max(lam / 3.0, 1e-6)
                history.append(loss)
                done = gain < tol * max(loss, 1.0) or np.max(np.abs(delta) / prob.max_step) < 1e-3
                if done:
                    status = "converged"
            else:
                lam *= 10.0
                history.append(loss)
                done = lam > 1e4
                if done:
                    status = "converged" if improved else "no_improvement_returned_start"
            steps_bar.update()
            steps_bar.set_postfix(loss=f"{loss:.4g}", lam=f"{lam:.0e}", **({"status": status} if done else {}))
            if done:
                break
    cov = np.linalg.inv(j.T @ j)
    return FitResult(prob.params(theta), theta, cov, x, loss0, loss, steps, status, history, len(r) - len(theta))
