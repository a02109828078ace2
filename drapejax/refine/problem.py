"""The fit problem of one capture: whitened residuals r(θ), their Jacobian and the prior (``Problem``).

θ (log space) is ``log k1`` along warp, weft and bias (``material.from_log_theta``: k2 scaled with k1), then
the effects' parameters. ``Problem`` adds to ``Misfit`` the rest state at θ (a warm-started
static solve from the last accepted state, held on the host; the jitted drop, solve and soft
features are shared by every problem of the same mesh, effects and solver, whatever its fabric), the
Gaussian prior rows (``prior_sqrt_information``) and the Jacobian of the soft features through
``equilibrium`` (implicit function theorem, never unrolled).
"""

from __future__ import annotations

import functools
import math
import operator
from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..energy import AbstractEnergy, default_energies
from ..material import FabricParams, from_log_theta, validity
from ..mesh import ClothMesh
from ..solve import SolverConfig, drape, equilibrium, static_solve
from ..solve._reuse import Same, reuse
from ..solve.threads import run_side_by_side
from .errors import RefineError
from .misfit import Misfit
from .observables import N_HARMONICS, Targets, _F, _soft_features
from .presets import CONTINUATION_CONFIG

K_PRIOR_STD = (math.log(3.0), 0.25)
"""Default log-space prior stds of the overall k1 scale and of the k1 direction ratios (``fit``)."""

Effect = Callable[[ClothMesh, Float[Array, " e"]], tuple[AbstractEnergy, ...]]


class Problem(Misfit):
    """Whitened residuals r(θ) of one measurement, with a warm-started host-side rest-state cache.

    Args:
        mesh: simulation mesh (its warp angle is the measured one, or 0 when unknown).
        targets: measured observables.
        init: initial parameters (density = nominal when unknown).
        effects: callables ``effect(mesh, theta_e) -> tuple[AbstractEnergy, ...]``.
        theta0: prior mean of θ: 3 log-k1 scales then the effect vector (every effect receives
            the whole effect vector θ[3:]).
        prior_std: (overall k1 scale, direction ratios, effects...) prior stds, see
            ``prior_sqrt_information``.
        spacing_m: mesh spacing, m.
        lower: smallest allowed θ (default: unbounded), e.g. the physical limits of effects.
        profile: score the height profile (``Misfit``); for evaluating drops only, not for fitting.
        config: solver of the drops and warm-started static solves (``CONTINUATION_CONFIG`` or
            ``EXACT_CONFIG``).
        buckling: the base model's membrane caps compression at the element scale
            (``energy.Membrane``).

    Attributes:
        split: the map θ -> (fabric at θ, the base energies followed by the effects' terms at
            θ) that the problem's drops and solves use; public because the experiments evaluate
            the model at θ themselves (e.g. its energy terms).
    """

    def __init__(self, mesh: ClothMesh, targets: Targets, init: FabricParams, effects: Sequence[Effect],
                 theta0: np.ndarray, prior_std: np.ndarray, spacing_m: float, lower: np.ndarray | None = None,
                 profile: bool = False, config: SolverConfig = CONTINUATION_CONFIG, buckling: bool = False):
        super().__init__(mesh, targets, profile)
        self.init, self.effects = init, tuple(effects)
        self.theta0, self.spacing_m = np.asarray(theta0, float), spacing_m
        self.lower = np.full(len(self.theta0), -np.inf) if lower is None else np.asarray(lower, float)
        self.prior_sqrt_info = prior_sqrt_information(np.asarray(prior_std, float), len(self.theta0))
        self.max_step = np.concatenate([np.ones(3), 2.0 / np.diag(self.prior_sqrt_info)[3:]])
        self.base = default_energies(mesh.info.test, buckling=buckling)
        self.config = config
        own = self.own_observations
        key = ("problem", Same(mesh), self.effects, config, float(spacing_m), buckling) + ((own,) if own else ())
        functions = reuse(key, lambda: _problem_functions(mesh, self.base, self.effects, config, spacing_m, own))
        fabric = _fabric_argument(init)
        self.split, self._drape, self._static, self._soft, self._soft_jac = (
            functools.partial(f, fabric) for f in functions)
        self.x = None

    def rest(self, theta: np.ndarray, seed: int) -> np.ndarray:
        """Rest state at θ: warm-started static solve from the cached state, else a quick drape.

        NaN where θ gives impossible parameters (``material.validity``, e.g. a bias rigidity no
        positive-definite plate has): the drape would otherwise return the rest state of the
        safe stand-in material it drops such a member with, and the static solve a state of a
        non-convex one, either scored as if it were θ's. The warm-started solve's status is not
        checked: with ``CONTINUATION_CONFIG`` most stop short of the equilibrium by design (the
        lag keeps the fit on one fold pattern), and with ``EXACT_CONFIG`` all 99 of four
        virtual-lab diagnoses converged (``docs/results/2026-11-26-effect-recovery-shared-solver.md``)."""
        th, seed = jnp.asarray(theta), operator.index(seed)  # a numpy seed would be another program's argument
        if not bool(validity(from_log_theta(self.init, th[:3]))):
            return np.full(np.shape(self.mesh.rest), np.nan)
        if self.x is None:
            return np.asarray(self._drape(th, seed).x)
        return np.asarray(self._static(th, jnp.asarray(self.x)).x)

    def programs(self, *, drop: bool = True, solves: bool = True) -> list[tuple]:
        """This problem's programs as (jitted function, example arguments), for ``prepare_programs``:
        the fresh drop (with ``drop``), and (with ``solves``) the warm-started static solve and the
        soft features with their Jacobian, which a fit runs from its second evaluation on. The
        arguments have the shapes and types ``rest`` and ``evaluate`` call them with."""
        th, x = jnp.asarray(np.asarray(self.theta0, float)), jnp.asarray(np.asarray(self.mesh.rest, float))
        out = [(self._drape, (th, 0))] if drop else []
        if solves:
            out += [(self._static, (th, x)), (self._soft, (th, x)), (self._soft_jac, (th, x))]
        return [(f.func, (*f.args, *args)) for f, args in out]

    def drop(self, theta: np.ndarray, seed: int) -> np.ndarray:
        """Rest state of a fresh drop at θ (the cached state is dropped, not warm-started from)."""
        self.x = None
        return self.rest(theta, seed)

    def params(self, theta: np.ndarray) -> FabricParams:
        """The fabric at θ: ``init`` with its k1 and k2 per direction scaled by exp(θ[:3])."""
        return jax.tree.map(lambda a: jnp.asarray(a), from_log_theta(self.init, jnp.asarray(np.asarray(theta)[:3])))

    def prior_residual(self, theta):
        return self.prior_sqrt_info @ (np.asarray(theta) - self.theta0)

    def evaluate(self, theta: np.ndarray, x: np.ndarray, jacobian: bool):
        """(whitened residuals incl. prior, Jacobian or None) at θ with rest state x."""
        r = np.concatenate([self.whiten(self.hard(x)), self.prior_residual(theta)])
        if not jacobian:
            return r, None
        if self.profile:
            raise RefineError("Problem.evaluate: the height-profile rows have no Jacobian; fit with profile=False")
        jf = np.asarray(self._soft_jac(jnp.asarray(theta), jnp.asarray(x)))
        self._last_soft = np.asarray(self._soft(jnp.asarray(theta), jnp.asarray(x)))
        self._last_amp = self._last_soft[_F["amp"]:_F["amp"] + N_HARMONICS]
        j = np.concatenate([self._whiten_jac(jf), self.prior_sqrt_info])
        return r, j


def _fabric_argument(init: FabricParams) -> FabricParams:
    """``init`` as float arrays of the default float type: the argument every problem function
    takes first, so that one compiled program serves every fabric (same avals, same program text)."""
    return jax.tree.map(lambda a: jnp.asarray(a, dtype=jnp.result_type(float)), init)


def _problem_functions(mesh: ClothMesh, base: tuple, effects: tuple, config: SolverConfig, spacing_m: float,
                       observations: tuple = ()):
    """``Problem``'s split, jitted drop, warm-started static solve and soft features (with their
    Jacobian in θ), each taking the starting fabric first; shared by every problem of the same mesh,
    effects, solver and observation types with features of their own (``Misfit.own_observations``,
    whose soft features follow the shared ones) (``reuse``).

    The fabric is an argument, not a constant of the program: a drop program closing over it
    would be another program for every fabric, compiled again (20-60 s on two cores) by every
    fit of a new capture, even with the persistent compilation cache on (``compile_cache``)."""
    n_k = 3

    def split(init, theta):
        return from_log_theta(init, theta[:n_k]), base + tuple(t for e in effects for t in e(mesh, theta[n_k:]))

    def soft(init, theta, x_rest):
        p, terms = split(init, theta)
        x = equilibrium(mesh, p, x_rest, terms=terms)
        if not observations:
            return _soft_features(x, mesh, spacing_m)
        return jnp.concatenate([_soft_features(x, mesh, spacing_m)]
                               + [jnp.ravel(o.soft_features(x, mesh, spacing_m)) for o in observations])

    def drop(init, theta, seed):
        p, terms = split(init, theta)
        return drape(mesh, p, seed, terms=terms, config=config)

    def solve(init, theta, x0):
        p, terms = split(init, theta)
        return static_solve(mesh, p, x0, terms=terms, config=config)

    return split, jax.jit(drop), jax.jit(solve), jax.jit(soft), jax.jit(jax.jacfwd(soft, argnums=1))


def prepare_programs(programs: Sequence[tuple], *, threads: int | None = None) -> None:
    """Compile the (jitted function, example arguments) ``programs`` (``Problem.programs``) side by
    side, before their first call (``solve.threads.run_side_by_side``, one per CPU by default).
    A function listed twice (problems that share their programs) is compiled once, with its first
    arguments: a problem's functions fix the shapes and types of theirs. One already compiled
    costs nothing more.

    A program compiles on about one core (20-60 s on the fit mesh for a drop with its effects)
    and, called lazily, keeps a run's other threads waiting: a fit compiles its drop, static
    solve and soft-feature Jacobian one after another, and a diagnosis's screen each candidate's
    drop in turn. Compiled ahead, they share the cores. They are traced one after another
    first: traced at once, their text (so their key in the persistent cache) would vary from
    run to run. JAX keeps the compiled program for the jitted function's later calls with
    arguments of the same shapes and types (and writes it to the persistent cache,
    ``compile_cache``), so nothing is computed twice and nothing changes in the results."""
    unique: dict = {}
    for fn, args in programs:
        unique.setdefault(id(fn), (fn, args))
    # Traced one after another: programs traced at once from several threads interleave their shared
    # traces, and the program text (so the persistent cache's key) then varies from run to run.
    lowered = [fn.lower(*args) for fn, args in unique.values()]
    if lowered:
        run_side_by_side(lambda i: lowered[i].compile(), len(lowered), threads=threads, desc="compiling",
                         unit="program")


def prior_sqrt_information(prior_std: np.ndarray, n: int) -> np.ndarray:
    """Square root L of the prior precision of θ, in (overall scale, ratio) coordinates.

    The drape pins the overall bending stiffness (geometric mean of the three k1) far better
    than the split between directions (warp and weft trade off nearly freely on coarse
    meshes), so the prior is loose on the scale and tight on the ratios warp/weft and
    bias/√(warp·weft), which then stay near the network's. ``prior_std`` = (scale std, ratio
    std, effect stds...), all in log space.
    """
    s = np.broadcast_to(prior_std, (n - 1,)) if np.ndim(prior_std) == 0 else np.asarray(prior_std)
    if s.shape != (n - 1,):
        raise RefineError(f"prior_std: expected {n - 1} values (scale, ratio, {n - 3} effect), got {s.shape[0]}")
    a = np.zeros((n, n))
    a[0, :3] = np.array([1.0, 1.0, 1.0]) / 3.0 / s[0]
    a[1, :3] = np.array([1.0, -1.0, 0.0]) / s[1]
    a[2, :3] = np.array([-0.5, -0.5, 1.0]) / s[1]
    for i in range(3, n):
        a[i, i] = 1.0 / s[i - 1]
    return a
