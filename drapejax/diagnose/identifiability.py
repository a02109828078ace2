r"""Can the captures at hand tell each candidate effect from a change of k1? (Fisher information.)

For every candidate effect this computes the Fisher information of z = (θ of the effect in units
of its prior std, log k1 along warp, weft and bias) at the fitted baseline, from the rows the
selection scores drops by (``selection_misfits``: ``refine.Misfit(profile=True)``, with the skirt's
height profile when the capture has heights), less the height profile's world-frame first
harmonic: differenced along the state derivatives, its rows broke the exact identity that a
candidate collinear with the membrane stiffness must meet (by 12 % on the test lab), so the
stage leaves them to the screen's fresh drops. Those rows are already whitened by the
drop-to-drop noise floors (``refine.SIGMA_*``: fold placement and capture-to-capture spread), so
with J = ∂r/∂z the information of one capture is $F = J^\top J$, and of n independent captures
of one specimen $nJ^\top J$ (each re-drop folds afresh). By the Cramér–Rao bound (Rao 1945; Kay
1993, *Fundamentals of Statistical Signal Processing: Estimation Theory*, ch. 3) no unbiased
estimate of θ has a smaller std than:

* ``std_conditional``: $\sqrt{[(F_{\theta\theta})^{-1}]_{ii}}$, k1 known ($1/\sqrt{F_{\theta\theta}}$ for one θ);
* ``std_marginal``: $\sqrt{[(F + P)^{-1}]_{ii}}$, the k1 free under a weak prior P on log k1
  (std ``Identifiability.k1_prior_std`` = 1, a factor e, so that it stays finite; with P this is
  the bound's Bayesian form, Van Trees 1968);
* ``k1_confounding`` = 1 − std_conditional² / std_marginal² (0: k1 takes none of its variance,
  1: the data cannot tell it from a change of k1).

An effect is ``identifiable`` when its std_marginal is below ``Identifiability.threshold`` = 0.5
prior stds in every component (one prior std then stands out at 2σ); a vector θ reports its
worst component. A very weak prior on θ (``BLIND_STD`` prior stds) keeps F invertible where the
rows do not respond to the effect at all (one acting only beyond its null, as a contact
thickness at zero).

The areal density has no column: when measured it is known, and when not the fit estimates k/ρ,
and a change of ρ moves the drape as the opposite change of every stiffness, i.e. of the overall
log-k1 scale (to within the stretching stiffness a drape barely loads): the k1 columns carry it.

When an effect is not identifiable, the measurements below are tried in order of cost, each
adding its information to F, and the first that brings std_marginal below the threshold is
named (``separated_by``; None when none does): another capture of the same specimen (J again);
another capture with the observations this one lacks (a height map or scan, the warp direction:
their rows are differentiated too, from the rest state, since a row's derivative does not depend
on what was measured); a cantilever strip along warp, weft or bias, then the sets of
``STRIP_SETS`` (both biases, warp/weft/bias, all four cuts); a pure bending test (KES-FB2) of
such strips, in the same order. A strip test measures its log k1 with std
σ = ``Identifiability.cantilever_std`` = ``io.READING_STD`` = 0.05 (the bending model reproduces the heavy-elastica
cantilever master curve of Romero et al. 2021 within a few per cent in droop,
``validate.TOLERANCE``, and a strip test's own repeatability is of a few per cent), but an effect
of the fabric itself (``Effect.strip_terms``) moves the strip as well: its rows are simulated at
the fitted fabric (``diagnose.strip``), so a strip test separates such an effect only as far as it
responds to it differently from the drape. A strip whose solve does not converge is recorded as
None in ``with_measurement`` and not counted.

The membrane (tensile and shear stiffness α) is held at the start's in every fit, and a light
fabric's drape on the fit mesh depends on it (a membrane held four times too soft was
"explained" by a weightless hem band: ``docs/results/2026-12-06-membrane-scan.md``). So z is
also taken with one more column, the overall log α scale, under a prior of std
``Identifiability.membrane_prior_std`` (the tag's or network's α; ``membrane_std`` when tensile
readings set it): ``std_membrane_free``. An effect identifiable against k1 whose std with the
membrane free reaches the threshold is told apart only with the membrane known, and a strip
tensile test (``TENSILE_TEST``) is named to fix it (``membrane_separated_by``).

J is the derivative of the mean observation over fold placement (the noise the rows are whitened
by). At one rest state the response also carries how that state's own folds move (an offset
moves the drape coefficient there, which symmetry forbids on average), so J is averaged over the
fit's state and ``Identifiability.drops`` fresh drops of the fitted fabric. The fold-specific
part shrinks only as one over the root of the number of states: on a clean "mid" capture an
offset's k1_confounding ranged 0.02–0.81 over single states and was 0.20 and 0.38 (x, y) over
eight, while its std_marginal, which decides identifiability, stayed within 0.2–0.45.

At each state x, J is computed by the implicit function theorem, as ``solve.equilibrium``
differentiates a rest state: the equilibrium Hessian H of the base model at x is factorised once
(every effect vanishes at ``theta0()``, so it is the whole model's), a column's state derivative is
$\partial x/\partial z = -H^{-1}\,\partial_z \nabla_x E$, the force derivative by a central
difference of the energy gradient (0.3 prior std in θ, one-sided above a ``lower_bound`` at
null; 0.1 in log k1), and J's column is the central difference of the rendered rows along that
direction (a step of the same size, shortened so that no vertex moves more than
``max_displacement_m``). Differences of warm-started static solves would compile a solve per
effect (15–35 s each at the default fit mesh on two cores), and at those steps they jump to
other fold states (vertices 0.14 m apart between ±0.1 in log bias k1 on a "mid" capture).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .. import refine
from ..energy import default_energies, total_energy
from ..io import K1_OF_CUT, READING_STD, Measurement
from ..material import DIRECTIONS, FabricParams, from_log_theta, scale_stretch
from ..mesh import ClothMesh
from ..progress import bar
from ..solve._sparse import hessian_coo
from ..solve._reuse import Same, reuse
from ._common import _at_least, _positive
from .strip import KES_CURVATURES_PER_M, KES_UNLOADING_CURVATURES_PER_M, BenchResponse, theta_steps
from .trials import combine, effect_problem, fresh_drops

BLIND_STD = 1000.0
"""Prior std of θ (in its prior stds) that keeps F invertible where the rows do not respond to it."""

_and = lambda ks: "{} and {:g}".format(", ".join(f"{k:g}" for k in ks[:-1]), ks[-1])
_KES = (f"(KES-FB2: moments at {_and(KES_CURVATURES_PER_M)} 1/m loading, "
        f"{_and(KES_UNLOADING_CURVATURES_PER_M)} 1/m unloading)")
BENCH_TESTS = {"cantilever": ("a cantilever strip cut", "cantilever strips cut"),
               "pure_bending": (f"a pure bending test {_KES} of a strip cut",
                                f"pure bending tests {_KES} of strips cut")}
"""The bench tests on strips tried after further captures, cheapest first (``strip.BenchResponse``)."""

STRIP_SETS = (("both biases (45° and 135°)", ("bias", "counter_bias")),
              ("warp, weft and bias", ("warp", "weft", "bias")),
              ("warp, weft and both biases", ("warp", "weft", "bias", "counter_bias")))
"""Sets of strips tried after the single cuts, fewest strips first: the pair of biases is what
tells an effect on one bias (``effects.bias_asymmetry``) from the base model's one bias k1."""

TENSILE_TEST = "a strip tensile test (KES-FB1) along warp, weft and bias"
"""The measurement that fixes the membrane an effect trades against (``refine.tensile``)."""

ADDED_OBSERVATIONS = {"height_map": "a height map or 3D scan of the drape",
                      "warp_harmonic": "the warp direction recorded"}
"""How an observation type (``observe.types.REGISTRY`` name) a capture lacks is asked for, in words."""


@dataclasses.dataclass(frozen=True)
class Identifiability:
    """Settings of the identifiability analysis (see module docstring).

    Attributes:
        threshold: largest std_marginal, in prior stds of the effect, that counts as identifiable.
        k1_prior_std: std of the weak prior on each log k1 that keeps std_marginal finite.
        cantilever_std: precision of a cantilever strip test, as a std of log k1 along its cut.
        theta_step: force-difference step in θ, prior stds.
        k1_step: force-difference step in log k1.
        max_displacement_m: largest vertex displacement of the row differences, m.
        drops: fresh drops of the fitted fabric whose states J is averaged over with the fit's.
        seed: drop seed of the first of them (seed, seed + 1, …; none of the selection's seeds).
        membrane_prior_std: std of the overall log α the fit holds when no tensile reading set it
            (1: a factor e; the network's α for the "light" fabric was 3.5 times the truth's
            inverse).
    """

    threshold: float = 0.5
    k1_prior_std: float = 1.0
    cantilever_std: float = READING_STD
    theta_step: float = 0.3
    k1_step: float = 0.1
    max_displacement_m: float = 0.005
    drops: int = 3
    seed: int = 6000
    membrane_prior_std: float = 1.0

    def __post_init__(self):
        _positive(self, "threshold", "k1_prior_std", "cantilever_std", "theta_step", "k1_step", "max_displacement_m",
                  "membrane_prior_std")
        _at_least(self, 0, "drops")

    def drop_seeds(self) -> list[int]:
        return [self.seed + i for i in range(self.drops)]


def _hessian(mesh: ClothMesh, terms: tuple):
    """Jitted exact Hessian triplets of ``terms`` at (x, params) (``solve._sparse.hessian_coo``, as
    ``solve.equilibrium`` assembles it), shared by equal meshes and terms."""
    build = lambda: jax.jit(lambda x, p: hessian_coo(terms, x, mesh, p, jnp.zeros(mesh.n_verts, x.dtype),
                                                     project=False, exact=True))
    return reuse(("identifiability hessian", Same(mesh), terms), build)


def _gradient(mesh: ClothMesh, key, terms_at):
    """Jitted ∇ₓ of the energy of ``terms_at(a)`` at (x, params, a)."""
    build = lambda: jax.jit(lambda x, p, a: jax.grad(lambda y: total_energy(terms_at(a), y, mesh, p))(x))
    return reuse(("identifiability gradient", Same(mesh), key), build)


def _with_every_observation(targets: refine.Targets) -> refine.Targets:
    """``targets`` with the heights and warp-frame harmonics it lacks filled in (zeros): a row's
    derivative does not depend on the measured value, so their rows can be differentiated."""
    fill = dict(hem_m=0.0, rings_m=np.zeros(len(refine.RING_RADII_M)), profile_m=np.zeros(len(refine.PROFILE_RADII_M)),
                aniso_m=0.0, shear_m=0.0)
    fill = {k: v for k, v in fill.items() if getattr(targets, k) is None}
    return dataclasses.replace(targets, **fill) if fill else targets


class _Response:
    """Row derivatives averaged over rest states xs: state derivatives by each state's factorised
    Hessian, then central differences of each misfit's whitened rows along them."""

    def __init__(self, mesh, params, xs, terms, misfits, settings):
        self.xs, self.misfits, self.settings = xs, misfits, settings
        coo = [tuple(np.asarray(a) for a in _hessian(mesh, terms)(jnp.asarray(x), params)) for x in xs]
        self.lus = [spla.splu(sp.csc_matrix((v, (r, c)), shape=(x.size,) * 2), permc_spec="MMD_AT_PLUS_A")
                    for x, (r, c, v) in zip(xs, coo)]

    def columns(self, dforce, step: float) -> list[np.ndarray]:
        """Each misfit's row derivative, averaged over the states, for the force derivative per
        unit z ``dforce(x)`` (n, 3) at a state x."""
        out = [np.zeros(mf.n_rows) for mf in self.misfits]
        for x, lu in zip(self.xs, self.lus):
            v = -lu.solve(np.asarray(dforce(x), float).ravel()).reshape(x.shape)
            peak = float(np.max(np.abs(v)))
            if not (peak > 0 and math.isfinite(peak)):
                out = [o + (0.0 if peak == 0 else np.nan) for o in out]
                continue
            h = min(step, self.settings.max_displacement_m / peak)
            rows = lambda mf, y: mf.whiten(mf.hard(y))
            out = [o + (rows(mf, x + h * v) - rows(mf, x - h * v)) / (2.0 * h) for o, mf in zip(out, self.misfits)]
        return [o / len(self.xs) for o in out]


def theta_stds(f: np.ndarray, n: int, k1_prior_std: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """(std_conditional, std_marginal) of each of the first ``n`` components of z (θ in prior
    stds) from the information ``f`` on z = (θ, log k1 per direction); see module docstring."""
    blind = np.eye(n) / BLIND_STD**2
    cond = np.sqrt(np.diag(np.linalg.inv(f[:n, :n] + blind)))
    prior = np.zeros_like(f)
    prior[:n, :n], prior[n:, n:] = blind, np.eye(f.shape[0] - n) / k1_prior_std**2
    return cond, np.sqrt(np.diag(np.linalg.inv(f + prior))[:n])


def _measurements(j_own: np.ndarray, j_full: np.ndarray | None, added: Sequence[str], bench
                  ) -> list[tuple[str, np.ndarray]]:
    """(the measurement in words, the information it adds on z), cheapest first (module docstring).
    ``bench(test, cut)`` gives the information of a strip test cut along ``cut`` (simulated on first
    use and kept)."""
    yield "another capture of the same specimen", j_own.T @ j_own
    if j_full is not None and added:
        yield "another capture with " + " and ".join(added), j_full.T @ j_full
    for test, (one, many) in BENCH_TESTS.items():
        yield from ((f"{one} along the {d}", bench(test, d)) for d in DIRECTIONS)
        for label, cuts in STRIP_SETS:
            yield f"{many} along {label}", sum(bench(test, d) for d in cuts)


def strip_information(n: int, direction: str, std: float = Identifiability.cantilever_std,
                      shift: np.ndarray | None = None) -> np.ndarray:
    """The information on z = (θ with ``n`` components, log k1 per direction) of a strip test cut
    along ``direction`` (``io.CUT_ANGLES_DEG``): Σ v vᵀ over its rows, v = (a, e_d) / std, e_d the
    k1 the cut measures (``io.K1_OF_CUT``: both biases the one bias k1), a a
    row of ``shift`` (rows, n): the apparent log k1 shift per prior std of θ
    (``strip.BenchResponse.shift``). Default one row of zeros, an effect the strip does not feel:
    1/std² on that log k1 alone."""
    a = np.zeros((1, n)) if shift is None else np.atleast_2d(np.asarray(shift, float))
    e = np.broadcast_to(np.eye(len(DIRECTIONS))[DIRECTIONS.index(K1_OF_CUT[direction])], (a.shape[0], len(DIRECTIONS)))
    v = np.concatenate([a, e], 1) / std
    return v.T @ v


def _verdict(cond: float, marg: float, identifiable: bool, by: str | None, after: float | None, limit: float,
             membrane: float | None = None) -> str:
    stds = f"std {cond:.2g} prior stds with k1 known, {marg:.2g} with k1 free"
    if identifiable:
        if membrane is not None and membrane >= limit:
            return (f"identifiable from these captures only with the membrane stiffness known ({stds}, {membrane:.2g} "
                    f"with the membrane free as well); {TENSILE_TEST} would fix it")
        return f"identifiable from these captures ({stds})"
    head = (f"cannot be told apart from a change of k1 with these captures ({stds})" if cond < limit
            else f"too weak to see in these captures even with k1 known ({stds})")
    return f"{head}; " + (f"{by} would separate it (std {after:.2g})" if by else
                          "none of the measurements tried would separate it")


def analyse_identifiability(mesh: ClothMesh, params: FabricParams, x: np.ndarray, targets: refine.Targets,
                            candidates: Sequence, *, captures: int = 1, terms: Sequence | None = None,
                            buckling: bool = False, settings: Identifiability = Identifiability(),
                            membrane_std: float | None = None) -> dict:
    """The identifiability of every candidate effect at the fitted rest state (module docstring).

    Args:
        mesh, params, x: the fit mesh, the fitted fabric and its rest state (m), or several rest
            states of it (fold states: J is averaged over them).
        targets: the fitted capture's targets (``refine.measured_targets``).
        candidates: ``drapejax.effects.Effect`` objects, each neutral at ``theta0()``.
        captures: captures of the specimen at hand (independent fold noise each).
        terms: the base model's energy terms (default ``energy.default_energies`` with ``buckling``).
        settings: thresholds and steps.
        membrane_std: std of the overall log α the fits hold (tensile readings set it); None:
            ``settings.membrane_prior_std``.

    Returns:
        {effect name: {"std_conditional", "std_marginal", "k1_confounding" (of the component with
        the largest std_marginal), "identifiable", "separated_by" (the cheapest measurement that
        would make it identifiable, in words; None if it is or none would), "with_measurement"
        ({measurement tried: std_marginal with it}), "std_membrane_free" (std_marginal with the
        overall membrane stiffness free too, under ``membrane_std``), "membrane_separated_by"
        (``TENSILE_TEST`` when the effect is identifiable but not with the membrane free, else
        None), "verdict" (in words), "per_parameter" (the three per component), "columns" (names
        of z), "fisher" (F on z), "rows", "captures"}}.
    """
    base = default_energies(mesh.info.test, buckling=buckling) if terms is None else tuple(terms)
    xs = [np.asarray(x, float)] if np.ndim(x) == 2 else [np.asarray(a, float) for a in x]
    targets = dataclasses.replace(targets, height_c1_m=None)
    own = refine.Misfit(mesh, targets, profile=True)
    filled = _with_every_observation(targets)
    full = None if filled is targets else refine.Misfit(mesh, filled, profile=True)
    names = {obs.name for obs, _ in own.observations}
    added = [ADDED_OBSERVATIONS.get(o.name, f"the {o.name.replace('_', ' ')} observation")
             for o, _ in (full.observations if full is not None else ()) if o.name not in names]
    resp = _Response(mesh, params, xs, base, [own] + ([full] if added else []), settings)
    grad_k = _gradient(mesh, ("k1", base), lambda a: base)
    k1_cols = []
    for k in range(len(DIRECTIONS)):
        z = np.zeros(len(DIRECTIONS))
        z[k] = settings.k1_step
        g = lambda x, s: np.asarray(grad_k(jnp.asarray(x), from_log_theta(params, jnp.asarray(s * z)), jnp.zeros(0)))
        k1_cols.append(resp.columns(lambda x: (g(x, 1.0) - g(x, -1.0)) / (2.0 * settings.k1_step), settings.k1_step))
    ga = lambda x, s: np.asarray(grad_k(jnp.asarray(x), scale_stretch(params, math.exp(s * settings.k1_step)),
                                        jnp.zeros(0)))
    membrane_col = resp.columns(lambda x: (ga(x, 1.0) - ga(x, -1.0)) / (2.0 * settings.k1_step), settings.k1_step)
    membrane_std = settings.membrane_prior_std if membrane_std is None else float(membrane_std)
    bench = BenchResponse(params, k1_step=settings.k1_step)
    out = {}
    for effect in bar(candidates, desc="identifiability", unit="effect"):
        n = effect.n_params()
        sd = np.asarray(effect.prior_std(), float)
        grad_e = _gradient(mesh, ("effect", effect), lambda th, e=effect: combine([e])(mesh, th))
        g = lambda x, th: np.asarray(grad_e(jnp.asarray(x), params, jnp.asarray(th)))
        cols = []
        for i in range(n):
            up, dn = theta_steps(effect, i, settings.theta_step)
            cols.append(resp.columns(lambda x: (g(x, up) - g(x, dn)) / (up[i] - dn[i]) * sd[i], settings.theta_step))
        js = [np.stack([c[m] for c in cols + k1_cols], 1) for m in range(len(resp.misfits))]
        f = captures * js[0].T @ js[0]
        cond, marg = theta_stds(f, n, settings.k1_prior_std)
        worst = int(np.argmax(marg))
        identifiable = bool(np.all(marg < settings.threshold))
        j_m = np.concatenate([js[0], membrane_col[0][:, None]], 1)
        f_m = captures * j_m.T @ j_m
        f_m[-1, -1] += 1.0 / membrane_std**2 - 1.0 / settings.k1_prior_std**2  # theta_stds adds the k1 prior to it
        free_m = float(np.max(theta_stds(f_m, n, settings.k1_prior_std)[1]))
        by_tensile = TENSILE_TEST if identifiable and free_m >= settings.threshold else None
        tried, separated_by = {}, None
        if not identifiable:
            tests = functools.cache(lambda test, cut, e=effect, n=n: strip_information(
                n, cut, settings.cantilever_std, bench.shift(e, test, cut, settings.theta_step)))
            for label, info in _measurements(js[0], js[1] if added else None, added, tests):
                if not np.all(np.isfinite(info)):
                    tried[label] = None  # a strip solve that did not converge: unknown, not tried
                    continue
                tried[label] = float(np.max(theta_stds(f + info, n, settings.k1_prior_std)[1]))
                if tried[label] < settings.threshold:
                    separated_by = label
                    break
        confounding = np.clip(1.0 - cond**2 / marg**2, 0.0, 1.0)
        out[effect.name] = {
            "std_conditional": float(cond[worst]), "std_marginal": float(marg[worst]),
            "k1_confounding": float(confounding[worst]), "identifiable": identifiable, "separated_by": separated_by,
            "with_measurement": tried, "std_membrane_free": free_m, "membrane_separated_by": by_tensile,
            "verdict": _verdict(float(cond[worst]), float(marg[worst]), identifiable, separated_by,
                                tried.get(separated_by), settings.threshold, free_m),
            "per_parameter": {"std_conditional": cond.tolist(), "std_marginal": marg.tolist(),
                              "k1_confounding": confounding.tolist()},
            "columns": [f"theta[{i}]" for i in range(n)] + [f"log_k1_{d}" for d in DIRECTIONS],
            "fisher": f.tolist(), "rows": int(js[0].shape[0]), "captures": int(captures)}
    return out


def identifiability_at_fit(measurements: Sequence[Measurement], fit: refine.FitResult, candidates: Sequence, *,
                           ctx: refine.FitContext, settings: Identifiability = Identifiability(),
                           membrane_std: float | None = None) -> dict:
    """``analyse_identifiability`` at a k1-only fit of ``measurements[0]`` in the fit context
    ``ctx`` (θ = 3 log-k1 scales relative to ``ctx.init``), over its rest state and
    ``settings.drops`` fresh drops of the fitted fabric (the fold states J is averaged over), with
    ``len(measurements)`` captures at hand and the membrane known to ``membrane_std``."""
    theta = np.asarray(fit.theta, float)[:3]
    targets = refine.measured_targets(measurements[0])
    prob = effect_problem(targets, [], **ctx.problem_keywords())
    drops = fresh_drops(prob, [(theta, s) for s in settings.drop_seeds()], desc="fold states")
    return analyse_identifiability(ctx.mesh, prob.params(theta), [fit.x] + [x for x in drops if x is not None],
                                   targets, candidates, captures=len(measurements), buckling=ctx.buckling,
                                   settings=settings, membrane_std=membrane_std)


__all__ = ["Identifiability", "analyse_identifiability", "identifiability_at_fit", "theta_stds", "strip_information",
           "ADDED_OBSERVATIONS", "BENCH_TESTS", "BLIND_STD", "STRIP_SETS", "TENSILE_TEST"]
