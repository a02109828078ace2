"""Drape to rest: a dynamic drop from the flat state, then a static equilibrium.

The drop integrates implicit Euler (each step minimises the incremental potential
$E(x) + \\tfrac{1}{2h^2}\\|x - x_n - h v_n\\|_M^2$ with Newton-PCG), starting from the flat
specimen with a seeded, smooth symmetry-breaking perturbation, and grows the step as the
motion settles, until the largest vertex speed is below ``rest_speed_m_s``. A step's few Newton
iterations start from the inertial prediction or from the current position, whichever has the
lower incremental potential, so that a step that does not converge cannot raise the potential
energy above the total (potential plus kinetic) energy it started with. A final static
Newton solve lands exactly on the equilibrium whose implicit derivative ``equilibrium``
provides.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from ..energy import AbstractEnergy, default_energies, total_energy
from ..material import G, FabricParams, PARAM_KEYS, example_params, validity
from ..mesh import ClothMesh
from ._newton import NewtonConfig, newton_minimise
from .linear import AbstractNewtonSolve, check_linear_solver, newton_solve

AT_REST, STEP_BUDGET, NONFINITE, INVALID_PARAMS, NOT_EQUILIBRIUM = 0, 1, 2, 3, 4
STATUS_NAMES = {AT_REST: "at_rest", STEP_BUDGET: "step_budget_exhausted", NONFINITE: "non_finite",
                INVALID_PARAMS: "invalid_parameters", NOT_EQUILIBRIUM: "static_solve_not_converged"}


class SolverConfig(eqx.Module):
    """Drop and equilibrium settings (static).

    Attributes:
        dt0_s: first time step, s.
        dt_max_s: largest time step once the drape settles, s.
        dt_growth: step growth factor after an easy step.
        rest_speed_m_s: rest criterion on the largest vertex speed, m/s.
        force_tol: the static solve stops when every residual force is below 0.1 × this
            fraction of the mean vertex weight.
        step_force_tol: a time step's Newton solve stops when every residual force is below
            this fraction of the mean vertex weight. Looser than the static tolerance: the drop
            only has to carry the specimen into its rest basin (the static solve polishes), and
            a step that does not converge halves the time step, so too tight a tolerance keeps
            the drop at ``dt0_s`` for hundreds of steps.
        max_steps: time-step budget.
        max_drop_time_s: end the dynamic phase after this simulated time even if still
            moving, and let the static solve finish (``quick_config`` uses 0.3 s); the
            status then reports the static solve's convergence, not the speed.
        perturb_m: amplitude of the seeded symmetry-breaking perturbation, m.
        linear_solver: "direct" (``linear.Direct``: Newton with a sparse Cholesky on the host,
            fast on CPU), "cg" (``linear.CG``: matrix-free block-Jacobi PCG, stays on the device,
            for GPUs), "auto" (direct on CPU, cg elsewhere), or an ``AbstractNewtonSolve``
            itself, used as given (``shifted_steps`` then plays no part). Any other value raises
            ``ValueError`` on construction. ``newton_solve()`` gives the resolved type. The PCG
            solves of both the time steps and the static solve take ``static``'s ``cg_iters``
            and ``cg_rtol``.
        exact_step_hessian: time steps use the exact Hessian wherever it is positive definite
            and the PSD-projected one elsewhere (``linear.AbstractNewtonSolve``; the CG solver
            tests for negative curvature met by PCG instead of a failed Cholesky).
            False: projected Hessians only, which converge linearly (mid fabric, Cusick, seed
            0: 199 steps and 1452 Newton iterations to rest at 10 mm, against 105 and 715; at
            5 mm the projected drop used up its 200 steps).
        exact_static_hessian: the same for the static solve. False (projected only) suits
            warm-started continuation in the parameters (``refine``), where the big exact steps
            can carry the shape to another fold pattern.
        shifted_steps: direct solver by name only (``linear.Direct.shifted``): exact steps use
            every term's exact element Hessian (not a term's own PSD approximation), and where
            that Hessian is indefinite the least diagonal shift of a ladder that makes it
            positive definite comes before the projected fallback. Fewer Newton iterations
            (5 mm: -12 %), and static solves that converge where the projected fallback stalls
            (a saturation drape). ``diagnose``'s model drops with the virtual lab's solver
            (``select.MODEL_CONFIG``): with the lab alone on shifted steps, clean captures had
            selected a clamp hinge. False: the exact-or-projected rule.
        absolute_above: direct solver by name only (``linear.Direct.absolute_above``): where the
            exact Hessian needs a diagonal shift above this multiple of the mean diagonal, the
            membrane's element Hessians are taken with their eigenvalues' magnitudes first (a
            few compressed elements then no longer slow every mode). None: the shift ladder
            alone. ``drape_multilevel``'s finer levels use 1e-5 by default.
        newton: Newton settings inside one time step (few iterations: the next step goes on).
        static: Newton settings of the final static equilibrium solve.
    """

    dt0_s: float = eqx.field(static=True, default=0.01)
    dt_max_s: float = eqx.field(static=True, default=0.5)
    max_drop_time_s: float = eqx.field(static=True, default=float("inf"))
    dt_growth: float = eqx.field(static=True, default=1.4)
    rest_speed_m_s: float = eqx.field(static=True, default=1e-3)
    force_tol: float = eqx.field(static=True, default=1e-4)
    step_force_tol: float = eqx.field(static=True, default=1e-2)
    max_steps: int = eqx.field(static=True, default=200)
    perturb_m: float = eqx.field(static=True, default=5e-4)
    linear_solver: str | AbstractNewtonSolve = eqx.field(static=True, default="auto")
    exact_step_hessian: bool = eqx.field(static=True, default=True)
    exact_static_hessian: bool = eqx.field(static=True, default=True)
    shifted_steps: bool = eqx.field(static=True, default=True)
    absolute_above: float | None = eqx.field(static=True, default=None)
    newton: NewtonConfig = NewtonConfig(max_iters=8, step_tol_m=1e-6)
    static: NewtonConfig = NewtonConfig(max_iters=200, step_tol_m=1e-9)

    def __check_init__(self):
        check_linear_solver(self.linear_solver)

    def newton_solve(self) -> AbstractNewtonSolve:
        """The linear solver as a type: ``linear_solver`` if it is one, else ``Direct(shifted_steps)``
        for "direct", ``CG()`` for "cg", and for "auto" the first on CPU, the second elsewhere
        (resolved when called, on the default backend), with ``absolute_above`` where given."""
        return newton_solve(self.linear_solver, self.shifted_steps, self.absolute_above)


class DrapeResult(eqx.Module):
    """Rest state of one drape (or a batch: leading axis on every field).

    Attributes:
        x: rest positions (n, 3), m.
        status: 0 at rest (the final static solve converged: a static equilibrium, whether the
            drop ended by its speed criterion, its time limit or its step budget), 1 step budget
            exhausted and the static solve from there did not converge, 2 non-finite, 3 invalid
            parameters, 4 the drop ended but the final static solve did not converge (not an
            equilibrium, so its implicit gradients would be wrong).
        steps: time steps taken.
        max_speed_m_s: largest vertex speed at the last step, m/s (0 once the static solve
            converged).
        energy_j: total energy at rest, J.
        newton_iters: Newton iterations over the whole run (drop and static solve).
        cg_iters: conjugate-gradient iterations (Hessian-vector products) over the whole run.
    """

    x: Float[Array, "*b n 3"]
    status: Int[Array, "*b"]
    steps: Int[Array, "*b"]
    max_speed_m_s: Float[Array, "*b"]
    energy_j: Float[Array, "*b"]
    newton_iters: Int[Array, "*b"]
    cg_iters: Int[Array, "*b"]


def perturbation(mesh: ClothMesh, key, amplitude_m: float) -> Float[Array, "n 3"]:
    """Smooth random vertical bumps (wavelengths 2-10 cm) on the free vertices."""
    k1, k2, k3 = jax.random.split(key, 3)
    n_modes = 16
    ang = jax.random.uniform(k1, (n_modes,), maxval=2 * jnp.pi)
    wl = jax.random.uniform(k2, (n_modes,), minval=0.02, maxval=0.10)
    ph = jax.random.uniform(k3, (n_modes,), maxval=2 * jnp.pi)
    kvec = (2 * jnp.pi / wl)[:, None] * jnp.stack([jnp.cos(ang), jnp.sin(ang)], 1)
    z = jnp.sum(jnp.sin(mesh.rest[:, :2] @ kvec.T + ph[None]), 1) / jnp.sqrt(n_modes)
    z = jnp.where(mesh.clamped, 0.0, amplitude_m * z)
    return jnp.zeros_like(mesh.rest).at[:, 2].set(z)


def _safe_params(params: FabricParams):
    ok = validity(params)
    safe = example_params("mid").astype(params.density.dtype)
    fixed = FabricParams(**{k: jnp.where(ok, getattr(params, k), getattr(safe, k)) for k in PARAM_KEYS})
    return fixed, ok


def require_float64(where: str) -> None:
    """Raise one clear error when JAX runs in float32: the solver's force tolerances lie below
    float32's resolution, so every drape would end short of rest (status NOT_EQUILIBRIUM)."""
    if not jax.config.jax_enable_x64:
        raise ValueError(f"{where}: the drape solver needs float64; call "
                         f"jax.config.update('jax_enable_x64', True) before using it")


def drape(mesh: ClothMesh, params: FabricParams, seed, *, terms: tuple[AbstractEnergy, ...] | None = None,
          config: SolverConfig = SolverConfig(), x0: Float[Array, "n 3"] | None = None) -> DrapeResult:
    """Drop a flat specimen and let it come to rest (jit- and vmap-compatible; a failing fabric
    gets a status, never an exception).

    Args:
        mesh: specimen mesh.
        params: one fabric (scalar fields).
        seed: int or uint32 key seed for the symmetry-breaking perturbation.
        terms: energy terms (default: ``default_energies(mesh.info.test)``). The time steps
            use those with ``in_drop``; the final static solve and the reported energy use all.
        config: solver settings.
        x0: optional start positions (default: flat rest shape plus perturbation).

    Raises:
        ValueError: when JAX is not in float64 mode (``require_float64``).
    """
    require_float64("drape")
    terms = default_energies(mesh.info.test) if terms is None else terms
    p, valid = _safe_params(params)
    key = jax.random.PRNGKey(seed) if jnp.ndim(seed) == 0 else seed
    x_start = mesh.rest + perturbation(mesh, key, config.perturb_m) if x0 is None else x0
    mass = p.density * mesh.vertex_area
    ftol = config.step_force_tol * G * jnp.mean(mass)
    energy = lambda x: total_energy(terms, x, mesh, p)
    stepped = tuple(t for t in terms if t.in_drop)
    free = ~mesh.clamped

    def step_cond(s):
        x, v, h, k, done, speed, nit, ncg, t = s
        return (k < config.max_steps) & ~done & (t < config.max_drop_time_s)

    def step_body(s):
        x, v, h, k, done, speed, nit, ncg, t = s
        xt = x + h * v
        inertia = mass / (h * h)
        phi = lambda y: total_energy(stepped, y, mesh, p) + 0.5 * jnp.sum(inertia[:, None] * (y - xt) ** 2)
        # Newton starts from the inertial prediction xt unless the current position x has the lower
        # incremental potential (φ(x) = E(x) + kinetic energy): then φ(x_new) ≤ E(x) + ½|v|²_M even
        # when the few Newton iterations of a step do not converge, so the potential energy can
        # never climb above the total energy, however far the prediction overshoots.
        y0 = jnp.where(phi(x) < phi(xt), x, xt)
        x_new, iters, cgi, conv = newton_minimise(phi, y0, _direction(phi, stepped, mesh, p, inertia, config,
                                                                      config.exact_step_hessian), config.newton, ftol)
        v_new = (x_new - x) / h
        speed_new = jnp.max(jnp.where(free, jnp.linalg.norm(v_new, axis=1), 0.0))
        bad = ~jnp.all(jnp.isfinite(x_new))
        easy = conv & (iters < config.newton.max_iters)
        h_new = jnp.where(easy, jnp.minimum(h * config.dt_growth, config.dt_max_s), jnp.maximum(0.5 * h, config.dt0_s))
        rest = speed_new < config.rest_speed_m_s
        return (jnp.where(bad, x, x_new), jnp.where(bad, 0.0, v_new), h_new, k + 1, rest | bad,
                jnp.where(bad, jnp.inf, speed_new), nit + iters, ncg + cgi, t + h)

    init = (x_start, jnp.zeros_like(x_start), jnp.asarray(config.dt0_s, x_start.dtype), 0, False,
            jnp.asarray(jnp.inf, x_start.dtype), 0, 0, 0.0)
    x, v, h, steps, _, speed, nit, ncg, t = jax.lax.while_loop(step_cond, step_body, init)
    x_eq, nit2, ncg2, static_conv = _static(mesh, p, x, terms, config)
    # The static solve's convergence decides the status: a drop that used up its steps while
    # still creeping (a light fabric settles slowly) has handed the static solve a state in its
    # rest basin whenever that solve converges, and the result is then an equilibrium like any other.
    ended = (t >= config.max_drop_time_s) | (speed < config.rest_speed_m_s) | static_conv
    speed = jnp.where(static_conv, 0.0, speed)
    finite = jnp.all(jnp.isfinite(x_eq))
    x_eq = jnp.where(finite, x_eq, x)
    status = jnp.where(~valid, INVALID_PARAMS,
                       jnp.where(~finite | ~jnp.isfinite(speed), NONFINITE,
                                 jnp.where(~ended, STEP_BUDGET, jnp.where(static_conv, AT_REST, NOT_EQUILIBRIUM))))
    return DrapeResult(x=x_eq, status=status.astype(jnp.int32), steps=jnp.asarray(steps, jnp.int32),
                       max_speed_m_s=speed, energy_j=energy(x_eq), newton_iters=jnp.asarray(nit + nit2, jnp.int32),
                       cg_iters=jnp.asarray(ncg + ncg2, jnp.int32))


def linear_solver(config: SolverConfig) -> str:
    """The name of ``config``'s resolved solver type ("direct" or "cg"; "auto" resolved by backend)."""
    return config.newton_solve().name


def _direction(f, terms, mesh, params, diag, config: SolverConfig, exact_first: bool = False):
    """Newton-direction rule of ``config``'s solver type (``diag``: mass/h² added to the Hessian;
    ``exact_first``: exact steps where the Hessian allows, see ``linear.AbstractNewtonSolve``)."""
    return config.newton_solve().direction(f, terms, mesh, params, diag, exact_first, config.static)


def static_solve(mesh: ClothMesh, params: FabricParams, x0: Float[Array, "n 3"], *,
                 terms: tuple[AbstractEnergy, ...] | None = None, config: SolverConfig = SolverConfig()) -> DrapeResult:
    """Static equilibrium near ``x0`` by Newton on the energy alone (not differentiated; jit- and
    vmap-compatible, never raises).

    Converges when residual forces fall below ``0.1 * config.force_tol`` of the mean vertex
    weight (set ``force_tol=0`` to iterate to ``config.static.step_tol_m``). The status is
    ``drape``'s: AT_REST when converged, NOT_EQUILIBRIUM when the iterations ran out first (its
    implicit gradients would be wrong), NONFINITE (``x0`` returned), INVALID_PARAMS (solved with
    a safe stand-in fabric, as ``drape`` does). ``steps`` is 0 and ``max_speed_m_s`` 0.
    Raises ``ValueError`` when JAX is not in float64 mode.
    """
    require_float64("static_solve")
    terms = default_energies(mesh.info.test) if terms is None else terms
    p, valid = _safe_params(params)
    x, nit, ncg, conv = _static(mesh, p, x0, terms, config)
    finite = jnp.all(jnp.isfinite(x))
    x = jnp.where(finite, x, x0)
    status = jnp.where(~valid, INVALID_PARAMS, jnp.where(~finite, NONFINITE, jnp.where(conv, AT_REST, NOT_EQUILIBRIUM)))
    zero = jnp.zeros((), x.dtype)
    return DrapeResult(x=x, status=status.astype(jnp.int32), steps=jnp.asarray(0, jnp.int32), max_speed_m_s=zero,
                       energy_j=total_energy(terms, x, mesh, p), newton_iters=jnp.asarray(nit, jnp.int32),
                       cg_iters=jnp.asarray(ncg, jnp.int32))


def quick_config(**kw) -> SolverConfig:
    """A short physical drop (0.3 s) then the static equilibrium: ~5x cheaper, for datasets and fits."""
    return SolverConfig(max_drop_time_s=0.3, dt_max_s=0.05, **kw)


def _static(mesh, params, x0, terms, config: SolverConfig):
    energy = lambda x: total_energy(terms, x, mesh, params)
    mass = params.density * mesh.vertex_area
    ftol = 0.1 * config.force_tol * G * jnp.mean(mass)
    return newton_minimise(energy, x0, _direction(energy, terms, mesh, params, 1e-6 * mass, config,
                                                      config.exact_static_hessian),
                           config.static, ftol)
