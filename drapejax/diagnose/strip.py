r"""What bench tests on strips (cantilever, pure bending) tell about a candidate effect and k1.

Peirce's (1930) cantilever test (BS 3356, ASTM D1388) slides a strip cut along one direction d of
the fabric over a clamp edge until its overhang is about ℓ = 2c, with c = (k1/ρg)^(1/3) the
bending length. For an elastic fabric the strip's droop depends on the gravito-bending number
Γ = ρgℓ³/k1_d alone (the heavy-elastica master curve, Romero et al. 2021), so the test measures
log k1_d. A strip along either bias (``io.CUT_ANGLES_DEG``: +45°, or the counter bias at 135°)
measures the one bias k1 of the base model (``io.K1_OF_CUT``). Here the strips share the overhang
ℓ = 2c̄ of the fabric's mean bending length.
An effect that acts on any piece cut from the fabric (``Effect.strip_terms``:
a frictional couple, softening at large curvature, unequal bias rigidities) moves the strip's droop
too, and the strip is then no longer a pure k1 measurement: a stiffer k1 and a frictional couple both
lift it. This module measures how much, by simulating the strip.

At the fitted fabric a row y (the strip's log droop ratio H/W) is expressed as an apparent log
k1_d, $y/s$ with $s = \partial y/\partial \log k1_d$ (at fixed density), so that its derivative in
log k1_d is 1 and in $\theta_i$ is $a_i$, the shift of the apparent log k1_d that one prior std of
$\theta_i$ causes. Whitened by the test's std as a log k1 (``Identifiability.cantilever_std``, σ),
the row on z = (θ in prior stds, log k1 along warp, weft, bias) is $(a, e_d)/\sigma$, with $e_d$
the unit vector of the k1 its cut measures, and its information $vv^\top$. An effect a strip does
not feel has a = 0, and the test pins log k1_d alone.
Both derivatives are central differences (one-sided where θ sits on its lower bound) of static
strip solves (``validate.strip_droop``) on a strip of width ℓ/2 meshed at ℓ/16.

A cantilever at Peirce's overhang bends its strip over the same range of curvatures as a Cusick
drape's folds, so an effect that stiffens the fabric at every curvature looks like a stiffer k1 to
both. The pure bending test (Kawabata 1980, KES-FB2) imposes a uniform curvature and reads the
moment; its rows are the log moment per unit width on the loading branch at the curvatures of
``KES_CURVATURES_PER_M`` (∂w/∂κ of the bending energy of the strip wrapped onto a cylinder). An
elastic k1 scales every row alike. A frictional couple adds a constant moment, whose share falls
as 1/κ and keeps rising towards small curvature; a bending that saturates
(``effects.bending_saturation``) takes its share away above its κ_s = 50 1/m and leaves the
smallest curvature's moment elastic. So the 50 and 150 1/m rows take a saturation for a stiffer
k1, and a row well below κ_s tells it apart. Against a frictional couple the loading branch helps
less: over 10-150 1/m the two soften the moment per curvature in nearly the same proportions (on
pure bending of three cuts of a saturated "mid" the couple explained the readings within the bench
stage's margin in two seeds of three: docs/results/2026-12-06-bias-pair-and-low-curvature.md).
The unloading branch separates them: the tester bends the strip to its largest curvature and back,
and a frictional couple then resists the other way (``Effect.unloading_strip_terms``: the moment
drops by the hysteresis 2HB), where an elastic softening gives back what it took. So a pure
bending test's rows are both branches, the unloading one at ``KES_UNLOADING_CURVATURES_PER_M``.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..energy import Bending, HourglassControl, total_energy
from ..io import CUT_ANGLES_DEG, K1_OF_CUT
from ..material import G, FabricParams, bending_length, strip_rigidity
from ..mesh import build_mesh, strip_mesh
from ..solve._reuse import by_value

PEIRCE_GAMMA = 8.0
"""Γ of a strip at Peirce's overhang ℓ = 2c (ρgℓ³/k1 = 2³)."""

SPACINGS_PER_OVERHANG = 16
"""Mesh spacing ℓ/16 (the bending zone at Γ = 8 is the whole overhang)."""

KES_CURVATURES_PER_M = (10.0, 50.0, 150.0)
"""Curvatures (1/m) of the pure bending test's rows: the KES-FB2 tester records its moment over
±2.5 cm⁻¹ and reads the bending rigidity as its slope between 0.5 and 1.5 cm⁻¹ (Kawabata 1980);
the loading branch at 0.1 cm⁻¹ as well is what separates a saturating bending from a stiffer k1
(module docstring). On "mid", one weft strip's information with its k1 free gives the saturation
a std of 0.13 prior stds with the 0.1 cm⁻¹ row and 1.08 without it, and the saturation and a
frictional couple fitted jointly on three cuts 0.42 and 0.24 against 1.02 and 0.46 (std 0.05 per
row as a log k1)."""
KES_UNLOADING_CURVATURES_PER_M = (50.0, 150.0)
"""Curvatures (1/m) of the unloading branch's rows: KES-FB2 reads the hysteresis 2HB at 0.5 and
1.5 cm⁻¹ (Kawabata 1980). Below them the unloading moment of a fabric with a large frictional
couple can change sign, which a log reading cannot hold."""
UNLOADING_TEST = "pure_bending_unloading"
"""The bench test (``io.BENCH_FIELDS``) of the unloading branch."""


def strip_terms(effect, test: str, mesh, theta) -> tuple:
    """The effect's energy terms on a strip in ``test``: the unloading branch's for
    ``UNLOADING_TEST`` (``Effect.unloading_strip_terms``), else the loading one's."""
    return (effect.unloading_strip_terms if test == UNLOADING_TEST else effect.strip_terms)(mesh, theta)


@dataclasses.dataclass(frozen=True)
class StripTest:
    """One strip cut along ``direction`` of a fabric, at Peirce's overhang for that fabric, or at
    the given ``overhang`` and ``width`` (m; the width defaults to half the overhang)."""

    params: FabricParams
    direction: str
    gamma: float = PEIRCE_GAMMA
    overhang: float | None = None
    width: float | None = None

    def __post_init__(self):
        if self.direction not in CUT_ANGLES_DEG:
            raise ValueError(f"strip direction must be one of {tuple(CUT_ANGLES_DEG)}, got {self.direction!r}")

    @property
    def overhang_m(self) -> float:
        """Peirce's overhang for the fabric's mean bending length, shared by the three directions
        (Γ along d is then 8 k̄1/k1_d), so that their strips share one mesh and one compiled solve."""
        if self.overhang is not None:
            return float(self.overhang)
        return self.gamma ** (1.0 / 3.0) * float(bending_length(self.params, "mean"))

    @property
    def width_m(self) -> float:
        return self.overhang_m / 2 if self.width is None else float(self.width)

    @property
    def angle_deg(self) -> float:
        return CUT_ANGLES_DEG[self.direction]

    def cut_mesh(self):
        """The strip's mesh as cut (clamped at x <= 0, the cut angle in ``info``)."""
        ell = self.overhang_m
        return strip_mesh(ell, self.width_m, ell / SPACINGS_PER_OVERHANG, angle_deg=self.angle_deg)

    @functools.cached_property
    def _mesh(self):
        return _angle_free(self.cut_mesh())

    def mesh(self):
        """The strip's mesh; the cut angle lives in its material-frame arrays, and its static copy
        in ``info`` is zeroed so that the three directions share compiled programs."""
        return self._mesh

    def _rest(self, params: FabricParams | None, extra_terms: tuple):
        from ..validate import strip_droop

        p = self.params if params is None else params
        ell = self.overhang_m
        gamma = float(p.density) * G * ell**3 / float(strip_rigidity(p, self.angle_deg))
        return strip_droop(gamma, self.angle_deg, ell / SPACINGS_PER_OVERHANG, params_aniso=p, length_m=ell,
                           width_m=self.width_m, extra_terms=tuple(extra_terms), linear=False)

    def log_droop(self, params: FabricParams | None = None, extra_terms: tuple = ()) -> tuple[float, bool]:
        """(log H/W, converged) of this strip (its overhang fixed by ``self.params``) made of
        ``params`` (default ``self.params``) with ``extra_terms`` added, at ``params``' density."""
        from ..validate import droop_ratio

        mesh, x, ok = self._rest(params, extra_terms)
        hw = droop_ratio(mesh, x)
        return (math.log(hw) if hw > 0 else math.nan), ok

    def log_tip_drop(self, params: FabricParams | None = None, extra_terms: tuple = ()) -> tuple[float, bool]:
        """(log of the free end's mean drop below the clamp (m), converged), as ``log_droop``: the
        reading of a cantilever tester at a fixed overhang (``io.BenchRecord``)."""
        from ..validate import tip_drop

        mesh, x, ok = self._rest(params, extra_terms)
        drop = tip_drop(mesh, x)
        return (math.log(drop) if drop > 0 else math.nan), ok


@dataclasses.dataclass(frozen=True)
class PureBendingTest:
    """A pure bending test (KES-FB2, Kawabata 1980) of a strip cut along ``direction``: the
    moment per unit width at an imposed uniform curvature, the loading branch. For the model it is
    ∂w/∂κ of the bending energy of the strip wrapped onto a cylinder (no membrane strain, no
    gravity), per unit rest area."""

    params: FabricParams
    direction: str

    @functools.cached_property
    def _mesh(self):
        m = StripTest(self.params, self.direction).cut_mesh()
        free = build_mesh(np.asarray(m.rest)[:, :2], np.asarray(m.faces), np.zeros(m.n_verts, bool), m.info)
        return _angle_free(free)

    def mesh(self):
        """The cantilever strip's triangulation with nothing clamped: the tester holds the strip's
        ends, and the whole strip bends uniformly."""
        return self._mesh

    def log_moment(self, kappa: float, params: FabricParams | None = None, extra_terms: tuple = ()) -> float:
        """log of the moment per unit width (N·m/m) at curvature ``kappa`` (1/m) of the strip made of
        ``params`` (default ``self.params``) with ``extra_terms`` added to the bending."""
        p = self.params if params is None else params
        mesh = self.mesh()
        moment = float(_moment((Bending(), HourglassControl(), *extra_terms), mesh, p, jnp.asarray(float(kappa))))
        return math.log(moment) if moment > 0 else math.nan


def _angle_free(mesh):
    """``mesh`` with the static copy of its cut angle zeroed (the angle stays in its arrays)."""
    return dataclasses.replace(mesh, info=dataclasses.replace(mesh.info, warp_angle_deg=0.0))


def wrap_onto_cylinder(rest, kappa):
    """A flat strip along +x (rest positions, m) bent isometrically to curvature ``kappa`` (1/m,
    nonzero) about an axis along y."""
    x, y = rest[:, 0], rest[:, 1]
    return jnp.stack([jnp.sin(kappa * x) / kappa, y, (1.0 - jnp.cos(kappa * x)) / kappa], 1)


@eqx.filter_jit
def _moment(terms, mesh, params, kappa):
    """dE/dκ of ``terms`` on ``mesh`` wrapped to curvature κ, per unit rest area."""
    energy = lambda k: total_energy(terms, wrap_onto_cylinder(mesh.rest, k), mesh, params)
    return jax.grad(energy)(kappa) / jnp.sum(mesh.area)


def theta_steps(effect, i: int, theta_step: float) -> tuple[np.ndarray, np.ndarray]:
    """(up, down): the effect's θ moved from ``theta0`` by ± ``theta_step`` prior stds in component
    ``i``, down left at ``theta0`` where it would pass ``lower_bound`` (a one-sided difference)."""
    t0, sd, lo = (np.asarray(f(), float) for f in (effect.theta0, effect.prior_std, effect.lower_bound))
    step = theta_step * sd[i] * np.eye(len(t0))[i]
    return t0 + step, (t0 if t0[i] - step[i] < lo[i] else t0 - step)


def k1_of_cut_scaled(params: FabricParams, cut: str, log_factor: float) -> FabricParams:
    """``params`` with the k1 a strip cut along ``cut`` measures (``io.K1_OF_CUT``) times
    e^``log_factor``: the step of a strip row's slope in that k1."""
    key = f"bend_k1_{K1_OF_CUT[cut]}"
    return dataclasses.replace(params, **{key: getattr(params, key) * math.exp(log_factor)})


def _value(result: tuple[float, bool]) -> float:
    """log H/W of a strip solve, NaN where its Newton solve did not converge (the row is then
    unknown rather than wrong; ``identifiability`` skips a measurement whose information is not finite)."""
    y, ok = result
    return y if ok else math.nan


class BenchResponse:
    """The rows of bench tests on strips of a fitted fabric, as apparent log k1 shifts (module
    docstring): per direction, the cantilever strip's log H/W (``"cantilever"``) and the pure
    bending test's log moment at each of ``KES_CURVATURES_PER_M`` on loading, then at each of
    ``KES_UNLOADING_CURVATURES_PER_M`` on unloading (``"pure_bending"``). The base
    values and k1 slopes are computed once and shared by every effect."""

    TESTS = ("cantilever", "pure_bending")

    def __init__(self, params: FabricParams, *, k1_step: float = 0.1, gamma: float = PEIRCE_GAMMA):
        self.params, self.k1_step = params, k1_step
        self.strips = {d: StripTest(params, d, gamma) for d in CUT_ANGLES_DEG}
        self.kes = {d: PureBendingTest(params, d) for d in CUT_ANGLES_DEG}
        self._cache: dict = {}

    def _rows(self, test: str, direction: str, params: FabricParams, effect=None, theta=None) -> np.ndarray:
        """The test's rows for ``params``, with ``effect`` at ``theta`` where given: a pure bending
        test's loading rows, then its unloading rows (``KES_UNLOADING_CURVATURES_PER_M``)."""
        mesh = self.strips[direction].mesh()
        terms = lambda branch: () if effect is None else tuple(strip_terms(effect, branch, mesh, theta))
        if test == "cantilever":
            return np.array([_value(self.strips[direction].log_droop(params, terms(test)))])
        t = self.kes[direction]
        return np.array([t.log_moment(k, params, terms("pure_bending")) for k in KES_CURVATURES_PER_M]
                        + [t.log_moment(k, params, terms(UNLOADING_TEST)) for k in KES_UNLOADING_CURVATURES_PER_M])

    def _once(self, key, make):
        if key not in self._cache:
            self._cache[key] = make()
        return self._cache[key]

    def base(self, test: str, direction: str) -> np.ndarray:
        return self._once(("base", test, direction), lambda: self._rows(test, direction, self.params))

    def slope(self, test: str, direction: str) -> np.ndarray:
        """∂ row / ∂ log k1 of the cut ``direction`` (``io.K1_OF_CUT``) at fixed density (central difference)."""
        h = self.k1_step
        at = lambda s: k1_of_cut_scaled(self.params, direction, s * h)
        return self._once(("slope", test, direction),
                          lambda: (self._rows(test, direction, at(1.0)) - self._rows(test, direction, at(-1.0)))
                          / (2.0 * h))

    def shift(self, effect, test: str, direction: str, theta_step: float) -> np.ndarray:
        """(rows, n): the apparent log k1 shift of each row per prior std of each component of the
        effect's θ (central difference of ``theta_step`` prior stds, one-sided at its lower bound);
        zeros for an effect a strip does not feel (``Effect.strip_terms``)."""
        mesh = self.strips[direction].mesh()
        t0, sd = np.asarray(effect.theta0(), float), np.asarray(effect.prior_std(), float)
        n, rows = len(t0), (1 if test == "cantilever" else
                            len(KES_CURVATURES_PER_M) + len(KES_UNLOADING_CURVATURES_PER_M))
        if not effect.strip_terms(mesh, t0 + sd):
            return np.zeros((rows, n))
        out = np.zeros((rows, n))
        for i in range(n):
            up, dn = theta_steps(effect, i, theta_step)
            val = lambda th: self._rows(test, direction, self.params, effect, th)
            y_dn = self.base(test, direction) if np.array_equal(dn, t0) else val(dn)
            out[:, i] = (val(up) - y_dn) / (up[i] - dn[i]) * sd[i] / self.slope(test, direction)
        return out


class ReadingResponse:
    """Bench readings a folder holds (``io.BenchRecord``: cantilever tip drops at their own
    overhang, pure bending moments at their own curvature), simulated for a fitted fabric and
    written as apparent log k1 along their cut, as ``BenchResponse`` does for the tests it
    proposes: ``residual`` is (log measured − log simulated) / s with s = ∂ log reading / ∂ log k1_d
    at fixed density. A reading simulated once for a fabric and effects is kept: the fits of
    ``diagnose.bench`` ask again for the same points (the baseline, the k1-only fit of every
    candidate)."""

    def __init__(self, records, params: FabricParams, *, k1_step: float = 0.1):
        self.records, self.params, self.k1_step = tuple(records), params, k1_step
        self.tests = [StripTest(params, r.direction, overhang=r.values["overhang_m"], width=r.values["width_m"])
                      if r.test == "cantilever" else PureBendingTest(params, r.direction) for r in self.records]
        self._base: list | None = None
        self._slope: list | None = None
        self._seen: dict = {}  # (reading, fabric, effects) -> simulated log reading

    def value(self, i: int, params: FabricParams, effects=()) -> float:
        """log of reading ``i`` simulated for ``params`` with ``effects`` ((effect, θ), ...) added
        where a strip feels them; NaN where the strip's solve did not converge."""
        key = (i, by_value(params), tuple((id(e), np.asarray(th, float).tobytes()) for e, th in effects))
        if key not in self._seen:
            self._seen[key] = self._simulate(i, params, effects)
        return self._seen[key]

    def _simulate(self, i: int, params: FabricParams, effects) -> float:
        test, rec = self.tests[i], self.records[i]
        mesh = test.mesh()
        extra = tuple(t for e, th in effects for t in strip_terms(e, rec.test, mesh, jnp.asarray(th, float)))
        if rec.test == "cantilever":
            return _value(test.log_tip_drop(params, extra))
        return test.log_moment(rec.values["curvature_per_m"], params, extra)

    def values(self, params: FabricParams, effects=()) -> np.ndarray:
        return np.array([self.value(i, params, effects) for i in range(len(self.records))])

    def base(self) -> np.ndarray:
        if self._base is None:
            self._base = self.values(self.params)
        return self._base

    def slope(self) -> np.ndarray:
        """∂ log reading / ∂ log k1 along each reading's cut, at fixed density (central difference)."""
        if self._slope is None:
            h, out = self.k1_step, []
            for i, rec in enumerate(self.records):
                at = lambda s: k1_of_cut_scaled(self.params, rec.direction, s * h)
                out.append((self.value(i, at(1.0)) - self.value(i, at(-1.0))) / (2.0 * h))
            self._slope = np.array(out)
        return self._slope

    def measured(self) -> np.ndarray:
        return np.log([r.measured for r in self.records])

    def residual(self) -> np.ndarray:
        """Apparent log k1 by which each reading is above the fitted fabric's simulation."""
        return (self.measured() - self.base()) / self.slope()


__all__ = ["StripTest", "PureBendingTest", "BenchResponse", "ReadingResponse", "theta_steps", "wrap_onto_cylinder",
           "PEIRCE_GAMMA", "CUT_ANGLES_DEG", "SPACINGS_PER_OVERHANG", "KES_CURVATURES_PER_M",
           "KES_UNLOADING_CURVATURES_PER_M", "UNLOADING_TEST", "strip_terms"]
