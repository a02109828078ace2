"""Drape on a hierarchy of nested meshes: drop on the coarsest, polish on each finer level.

The coarsest level runs ``drape`` (the dynamic drop that chooses the fold pattern, then its
static solve); each finer level starts from the previous level's rest shape carried over by its
``mesh.Prolongation`` (exact on nested meshes: the coarse shape is a fine shape, with no added
membrane strain) and runs ``static_solve`` there. The drop, which dominates a drape's Newton
iterations, then runs on the mesh with the fewest vertices; what is left to the fine levels is
the difference between the levels' equilibria (a cascadic, or nested-iteration, scheme: Deuflhard
1996, "Cascadic conjugate gradient methods for elliptic partial differential equations"; Bornemann
and Deuflhard 1996).

The coarse drop runs each term's ``coarse_level()`` (the membrane with its compression cap): an
uncapped coarse mesh cannot fold as finely as the fabric and locks, and the finer levels then
start from a state with too few folds that their static solves, which cannot move folds far,
keep. The finer levels solve the terms as given, so the finest rest state is their equilibrium.

How well this pays depends on how close the coarse level's equilibrium already is to the fine
one: the fine static solve's iterations are reported per level (``MultilevelResult``) so that
``experiments/multilevel_drape.py`` can measure it. The finest level's state is a static
equilibrium (status ``AT_REST``) only when its own static solve converged, so ``equilibrium``'s
implicit gradients apply to it as to any ``drape`` result on that mesh.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Int

from ..energy import AbstractEnergy, coarse_level, default_energies
from ..material import G, FabricParams, bending_length
from ..mesh import COARSEST_SPACING_M, CUSICK_RADIUS_M, DISK_RADIUS_M, ClothMesh, Prolongation
from ._newton import NewtonConfig
from .drop import AT_REST, INVALID_PARAMS, NONFINITE, STATUS_NAMES, DrapeResult, SolverConfig, drape, static_solve


COARSEST_OVER_BENDING_LENGTH = 0.75
"""Largest coarsest-level spacing, in bending lengths, at which the drop still chooses the fold
pattern of the fine levels: the static solves on finer levels keep the coarse drape's number of
folds, and a Cusick fold's wavelength scales with the bending length (about five of them for the
mid fabric)."""


FINE_ABSOLUTE_ABOVE = 1e-5
"""The finer levels' ``SolverConfig.absolute_above`` by default: where their static solve's exact
Hessian needs a shift above 1e-5 of its mean diagonal, a few compressed membrane elements are
the cause, and their absolute-eigenvalue Hessians take the shift's place. On the lightest
table fabric (15 g/m²) the shift ladder alone needed 1e-4 to 1e-3 and stopped short of rest
after 500 iterations; with the threshold and a capped coarsest level it came to rest in 370, and
"mid" in 190 (``docs/results/2026-12-05-indefinite-steps.md``)."""

FINE_CONFIG = SolverConfig(absolute_above=FINE_ABSOLUTE_ABOVE, static=NewtonConfig(max_iters=500, step_tol_m=1e-9))
"""The finer levels' static solves by default: ``FINE_ABSOLUTE_ABOVE``, and 500 Newton iterations
(the lightest table fabric needs 370 at 5 mm; "mid" about 190)."""


def _hard(status):
    """Statuses that no finer level can mend: invalid parameters, a non-finite state."""
    return (status == INVALID_PARAMS) | (status == NONFINITE)


def polished_status(drop_status, polish_status):
    """Status of a drop's rest state solved again with the terms as given (a single-level drape's
    last solve): the second solve's, unless the drop had invalid parameters or a non-finite
    state, which no later solve mends."""
    return jnp.where(_hard(drop_status), drop_status, polish_status).astype(jnp.int32)


def coarsest_spacing_m(params: FabricParams) -> float:
    """The coarsest level's largest spacing for ``params`` (one fabric, concrete values): the
    smaller of ``mesh.COARSEST_SPACING_M`` and ``COARSEST_OVER_BENDING_LENGTH`` times its overall
    bending length (k1/(ρ g))^(1/3), k1 the geometric mean over warp, weft and bias. Parameters
    without a finite, positive bending length (outside the model's range: their drape reports
    ``invalid_parameters``) get ``mesh.COARSEST_SPACING_M``."""
    length = float(bending_length(params, "mean"))
    if not (np.isfinite(length) and length > 0):
        return COARSEST_SPACING_M
    return min(COARSEST_SPACING_M, COARSEST_OVER_BENDING_LENGTH * length)


DEFAULT_FINEST_SPACING_M = 0.005
"""The finest level's interior spacing for most fabrics (``finest_spacing_m``): on it the Cusick drape
coefficient of fabrics across the 618-fabric table is within a few thousandths of the 2.5 mm
level's on the same drops (``docs/results/2026-12-08-default-resolution-cascades.md``)."""

CUSICK_OVERHANG_M = CUSICK_RADIUS_M - DISK_RADIUS_M
"""The Cusick specimen's overhang beyond its support: 150 mm radius less the 90 mm disc."""

LOCKING_NUMBER_MAX = 3000.0
"""Largest ``locking_number`` of a default finest level. Measured at 5 mm on rows of the 618-fabric
table, the seed mean of five drops against the same drops carried to 2.5 mm: Π = 485 (its 25 %
quantile of bending length) −0.0006, 3 223 (its softest row) +0.006, 5 260 (its lightest row,
15 g/m²) +0.072 (``docs/results/2026-12-08-light-fabric-locking.md``)."""


def locking_number(params: FabricParams, spacing_m: float, overhang_m: float = CUSICK_OVERHANG_M) -> float:
    """How far flat triangles of size ``spacing_m`` stiffen a drape of ``params``: Π = ᾱ h² / (ρ g L c²).

    A fold of curvature about 1/c (c the overall bending length (k1/(ρ g))^(1/3)) drawn with flat
    elements of size h cannot bend without stretching: the chords strain by about (h/c)², a spurious
    membrane stress ᾱ (h/c)² (ᾱ the tensile stiffness, mean of warp and weft), which locks the
    fold (membrane locking: Stolarski and Belytschko 1982) when it is not small beside the tension
    gravity puts into the overhang of length L, ρ g L. Two fabrics of the table with nearly the same
    bending length (14.9 and 16.2 mm) differ thirteenfold in density, so in Π; at 5 mm the heavier
    one's drape is converged and the lighter one's is not. Parameters without finite, positive
    density, bending length and ᾱ give NaN (``finest_spacing_m`` then keeps its default)."""
    c = float(bending_length(params, "mean"))
    alpha = 0.5 * (float(params.stretch_alpha_warp) + float(params.stretch_alpha_weft))
    rho = float(params.density)
    if not all(np.isfinite(v) and v > 0 for v in (c, alpha, rho)):
        return float("nan")
    return alpha * spacing_m**2 / (rho * G * overhang_m * c**2)


def finest_spacing_m(params: FabricParams, default_m: float = DEFAULT_FINEST_SPACING_M,
                     overhang_m: float = CUSICK_OVERHANG_M) -> float:
    """The finest level's interior spacing of a converged Cusick drape of ``params`` (one fabric,
    concrete values): ``default_m``, or finer where that would lock the fabric's folds, so that
    ``locking_number`` stays at most ``LOCKING_NUMBER_MAX``, rounded down to 0.1 mm. Of the 618
    fabrics of Feng et al. (2022), 27 light, soft ones drape finer than 5 mm, down to 3.4 mm."""
    pi = locking_number(params, default_m, overhang_m)
    if not (np.isfinite(pi) and pi > LOCKING_NUMBER_MAX):
        return default_m
    return float(np.floor(default_m * np.sqrt(LOCKING_NUMBER_MAX / pi) * 1e4) / 1e4)


class MultilevelResult(eqx.Module):
    """The finest level's rest state, and where the work went.

    Attributes:
        finest: the finest level's ``DrapeResult``. Its ``status`` is the finest level's own
            (``AT_REST`` when its static solve converged: the state is a static equilibrium of
            the terms as given, as ``drape``'s status says of its final static solve, whatever
            the coarser levels reached), unless a level had invalid parameters or a non-finite
            state, whose status it then takes. ``steps`` are the coarse drop's;
            ``newton_iters`` and ``cg_iters`` sum all levels.
        level_newton_iters: (levels,) Newton iterations on each level, coarsest first.
        level_status: (levels,) each level's own status (a coarse drop whose own static solve
            did not converge says so here; a single level's is that of its solve with the
            terms as given).
        coarse_x: the coarsest level's rest positions (its fold pattern), m.
    """

    finest: DrapeResult
    level_newton_iters: Int[Array, "*b levels"]
    level_status: Int[Array, "*b levels"]
    coarse_x: Array

    def level_records(self, meshes: tuple[ClothMesh, ...]) -> list[dict]:
        """One fabric's levels as JSON-able records, coarsest first: spacing (m), vertices, Newton
        iterations and status name (``meshes``: the hierarchy this result was draped on)."""
        return [{"spacing_m": float(m.info.spacing_m), "verts": int(m.n_verts), "newton_iters": int(it),
                 "status": STATUS_NAMES[int(st)]}
                for m, it, st in zip(meshes, self.level_newton_iters.tolist(), self.level_status.tolist())]


def drape_multilevel(meshes: tuple[ClothMesh, ...], prolongations: tuple[Prolongation, ...], params: FabricParams,
                     seed, *, terms: tuple[AbstractEnergy, ...] | None = None,
                     coarse_terms: tuple[AbstractEnergy, ...] | None = None,
                     config: SolverConfig | None = None, coarse_config: SolverConfig | None = None
                     ) -> MultilevelResult:
    """Drape ``params`` on nested ``meshes`` (coarsest first, e.g. ``mesh.nested_cusick_meshes``).

    jit- and vmap-compatible, never raises for one fabric (as ``drape``).

    Args:
        meshes: the levels, coarsest first; ``meshes[i + 1]`` is ``prolongations[i]``'s fine mesh.
        prolongations: the maps between consecutive levels (``len(meshes) - 1`` of them).
        params: one fabric.
        seed: the coarse drop's perturbation seed.
        terms: the finer levels' energy terms (default: ``default_energies`` of the test); the
            finest level's rest state is their equilibrium.
        coarse_terms: the coarse drop's terms (default: each of ``terms`` as its
            ``coarse_level()``: the membrane with its compression cap, so that the coarse level
            does not lock in compression).
        config: the fine levels' static solves (and the coarse drop's unless ``coarse_config``);
            default: ``FINE_CONFIG`` for the fine levels and ``SolverConfig()`` for the coarse
            drop. With a single level, the coarse drop's rest state is solved again with
            ``terms`` and ``config`` when ``coarse_terms`` are other objects, so the result is always the
            equilibrium of ``terms``.
        coarse_config: the coarse drop's settings.
    """
    if len(prolongations) != len(meshes) - 1:
        raise ValueError(f"drape_multilevel: {len(meshes)} meshes need {len(meshes) - 1} prolongations, "
                         f"got {len(prolongations)}")
    terms = default_energies(meshes[0].info.test) if terms is None else terms
    coarse_terms = coarse_level(terms) if coarse_terms is None else coarse_terms
    if coarse_config is None:
        coarse_config = SolverConfig() if config is None else config
    if config is None:
        config = FINE_CONFIG
    r = drape(meshes[0], params, seed, terms=coarse_terms, config=coarse_config)
    coarse_x, steps = r.x, r.steps
    iters, statuses, ncg = [r.newton_iters], [r.status], r.cg_iters
    same = len(coarse_terms) == len(terms) and all(c is t for c, t in zip(coarse_terms, terms))
    if len(meshes) == 1 and not same:  # the coarsest level is the finest
        polish = static_solve(meshes[0], params, r.x, terms=terms, config=config)
        iters = [r.newton_iters + polish.newton_iters]
        statuses = [polished_status(r.status, polish.status)]
        ncg = ncg + polish.cg_iters
        r = polish
    for mesh, prolong in zip(meshes[1:], prolongations):
        r = static_solve(mesh, params, prolong(r.x, mesh), terms=terms, config=config)
        iters.append(r.newton_iters)
        statuses.append(r.status)
        ncg = ncg + r.cg_iters
    level_iters, level_status = jnp.stack(iters), jnp.stack(statuses)
    hard = _hard(level_status)
    status = jnp.where(jnp.any(hard), level_status[jnp.argmax(hard)], level_status[-1]).astype(jnp.int32)
    speed = jnp.where(status == AT_REST, jnp.zeros_like(r.max_speed_m_s), jnp.inf)
    finest = DrapeResult(x=r.x, status=status, steps=steps, max_speed_m_s=speed, energy_j=r.energy_j,
                         newton_iters=jnp.sum(level_iters).astype(jnp.int32), cg_iters=ncg)
    return MultilevelResult(finest=finest, level_newton_iters=level_iters, level_status=level_status,
                            coarse_x=coarse_x)
