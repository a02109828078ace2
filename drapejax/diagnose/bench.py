r"""What the bench readings a folder holds say about each candidate effect (cantilever strips, KES-FB2).

The identifiability analysis (``identifiability``) names the bench test that would tell an effect
from a change of k1; when the folders hold such readings (``io.BenchRecord``), this module uses
them. Each reading is simulated at the baseline fit (``strip.ReadingResponse``) and written as an
apparent log k1 along its cut: $y_r = (\log m_r - \log s_r(\hat p)) / (\partial \log s_r/\partial
\log k1_{d_r})$, whitened by ``BenchFit.std`` (the precision of a strip test as a log k1, as in
``Identifiability.cantilever_std``). On z = (θ of the effect in prior stds, log k1 along warp,
weft and bias relative to the fit) a reading's row is $v_r = (a_r, e_{d_r})/\sigma$, with $a_r$
the apparent shift per prior std of θ (a difference of strips simulated with the effect, taken
again at every Gauss–Newton step).

The captures enter through their Fisher information F on the same z at the fit (the identifiability
record's ``fisher``): the baseline fit is the captures' optimum in k1 with the effect absent, and
their misfit is taken to rise by $z^\top F z$ (in the units of the readings' $\chi^2$) away from
it. That keeps their curvature and drops their first-order pull on θ, which the fit's residual has
(it is not an optimum in θ): what the captures say about θ on their own is the effect search's to
judge, and this stage asks what the readings add. Two models are fitted to readings and captures
together by Gauss–Newton on the simulated readings (every objective is that of strips simulated at
the point, not of a linearisation): k1 alone (θ = 0) and k1 with the effect (θ under its own prior,
N(0, 1) in prior stds, and above its ``lower_bound``). The effect is taken as found when

* the objective falls by more than the χ² quantile ``BenchFit.level`` with θ's components as
  degrees of freedom (a likelihood-ratio test, Wilks 1938), and
* θ's std at the fit (Gauss–Newton covariance with the captures and the prior) is below
  ``BenchFit.threshold`` prior stds: it is identifiable, the criterion of ``identifiability``, and
* it explains the readings better than every other candidate a strip feels by ``BenchFit.margin``
  in the objective (2 ln 10: "strong" evidence on the scale of Kass & Raftery 1995). Two effects
  of the fabric can bend a strip alike: on pure bending readings of "mid" with a bending saturation
  hidden (half the energy removed at large curvature), whose own std there is above the threshold,
  a frictional couple explained them almost as well (objective falls 7.5 and 6.7) and would
  otherwise have been named.

The error before and after is the RMS apparent log k1 of the readings: at the baseline fit, with
k1 refitted alone, and with the effect.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np
from scipy import stats
from scipy.optimize import lsq_linear

from ..io import READING_STD
from ..material import DIRECTIONS, FabricParams
from ..progress import bar
from ._common import _positive
from .strip import ReadingResponse


@dataclasses.dataclass(frozen=True)
class BenchFit:
    """Settings of the bench-reading test (module docstring).

    Attributes:
        std: precision of one reading as a log k1 along its cut.
        level: χ² quantile the objective must fall by for the effect to count as found.
        threshold: largest std of θ with the readings, prior stds, for the effect to count as identifiable.
        k1_prior_std: weak prior on each log k1 (as ``Identifiability.k1_prior_std``).
        theta_step, k1_step: steps of the central differences, prior stds and log k1.
        iterations: most Gauss–Newton steps of each fit.
        margin: how much lower the chosen effect's objective must be than every other felt candidate's.
    """

    std: float = READING_STD
    level: float = 0.99
    threshold: float = 0.5
    k1_prior_std: float = 1.0
    theta_step: float = 0.3
    k1_step: float = 0.1
    iterations: int = 6
    margin: float = 2.0 * math.log(10.0)

    def __post_init__(self):
        _positive(self, "std", "threshold", "k1_prior_std", "theta_step", "k1_step")
        if not 0 < self.level < 1:
            raise ValueError(f"BenchFit.level must be in (0, 1), got {self.level}")


class _Model:
    """The readings of one candidate on z = (θ in prior stds from ``theta0``, log k1 along warp,
    weft and bias relative to the fit), in apparent log k1 units g(z) = log reading / s with s the
    fitted fabric's slope along the reading's cut (``ReadingResponse.slope``), and the objective
    Φ(z) = ‖(m/s − g(z))/σ‖² + zᵀ(F + P)z: readings, captures (F) and priors (P: θ ~ N(0, 1), each
    log k1 ~ N(0, ``k1_prior_std``²))."""

    def __init__(self, resp: ReadingResponse, effect, fisher: np.ndarray, settings: BenchFit):
        self.resp, self.effect, self.settings = resp, effect, settings
        self.t0, self.sd, lo = (np.asarray(f(), float) for f in (effect.theta0, effect.prior_std, effect.lower_bound))
        self.n = n = len(self.t0)
        prior = np.zeros_like(fisher)
        prior[:n, :n], prior[n:, n:] = np.eye(n), np.eye(len(DIRECTIONS)) / settings.k1_prior_std**2
        self.info = fisher + prior
        self.root = np.linalg.cholesky(self.info + 1e-12 * np.eye(len(self.info))).T
        self.lower = np.concatenate([(lo - self.t0) / self.sd, np.full(len(DIRECTIONS), -np.inf)])
        self.scale = resp.slope()
        self.target = resp.measured() / self.scale

    def params(self, z: np.ndarray) -> tuple[FabricParams, tuple]:
        """The fabric at z and the effect's (effect, θ) pair (none at θ = theta0)."""
        theta = self.t0 + z[: self.n] * self.sd
        moved = _moved(self.resp.params, z[self.n:])
        return moved, (((self.effect, theta),) if np.any(z[: self.n]) else ())

    def g(self, z: np.ndarray) -> np.ndarray:
        return self.resp.values(*self.params(z)) / self.scale

    def objective(self, z: np.ndarray, g: np.ndarray) -> float:
        return float(np.sum(((self.target - g) / self.settings.std) ** 2) + z @ self.info @ z)

    def jacobian(self, z: np.ndarray, g: np.ndarray, free: np.ndarray) -> np.ndarray:
        """∂g/∂z on the free components (central differences; forward at θ's lower bound)."""
        cols = []
        for i in np.flatnonzero(free):
            h = self.settings.theta_step if i < self.n else self.settings.k1_step
            up, dn = z.copy(), z.copy()
            up[i] += h
            dn[i] -= h
            if dn[i] < self.lower[i]:
                cols.append((self.g(up) - g) / h)
            else:
                cols.append((self.g(up) - self.g(dn)) / (2 * h))
        return np.stack(cols, 1)

    def fit(self, effect: bool) -> dict:
        """Gauss–Newton on Φ from z = 0 (the baseline fit), θ held at 0 unless ``effect``, each
        step halved until Φ falls (at most ``BenchFit.iterations`` steps)."""
        free = np.ones(len(self.info), bool)
        free[: self.n] = effect
        z = np.zeros(len(self.info))
        g = self.g(z)
        phi = self.objective(z, g)
        jac = None
        for _ in range(self.settings.iterations):
            if not np.all(np.isfinite(g)):
                break
            jac = self.jacobian(z, g, free)
            rows = np.concatenate([jac / self.settings.std, self.root[:, free]])
            rhs = np.concatenate([(self.target - g + jac @ z[free]) / self.settings.std, np.zeros(len(self.info))])
            new = z.copy()
            new[free] = lsq_linear(rows, rhs, bounds=(self.lower[free], np.full(free.sum(), np.inf))).x
            for _ in range(4):
                g_new = self.g(new)
                phi_new = self.objective(new, g_new)
                if phi_new < phi:
                    break
                new = 0.5 * (z + new)
            else:
                break
            done = phi - phi_new < 1e-3 * max(phi_new, 1.0)
            z, g, phi = new, g_new, phi_new
            if done:
                break
        std = None
        if effect and jac is not None:
            a = jac / self.settings.std
            std = np.sqrt(np.diag(np.linalg.inv(a.T @ a + self.info))[: self.n])
        return {"z": z, "g": g, "objective": phi, "theta_std": std}


def _moved(params: FabricParams, z_k1: np.ndarray) -> FabricParams:
    return dataclasses.replace(params, **{f"bend_k1_{d}": getattr(params, f"bend_k1_{d}") * math.exp(float(k))
                                          for d, k in zip(DIRECTIONS, z_k1)})


def _rms(v: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(v)))) if np.all(np.isfinite(v)) else math.nan


def bench_evidence(records: Sequence, params: FabricParams, candidates: Sequence, *, fisher: dict | None = None,
                   settings: BenchFit = BenchFit()) -> dict:
    """Test every candidate effect on the bench readings ``records`` (module docstring).

    Args:
        records: ``io.BenchRecord`` readings on strips of the specimen's fabric.
        params: the baseline fit's fabric.
        candidates: ``drapejax.effects.Effect`` objects.
        fisher: {effect name: the captures' information on z} (an ``identifiability`` record's
            "fisher"); an effect missing from it gets none (the readings alone).
        settings: see ``BenchFit``.

    Returns:
        {"readings": [reading with "simulated" (the baseline's value) and "residual_log_k1"],
        "error_before": RMS apparent log k1 of the baseline, "selected": the effect found or
        None, "ambiguous": the felt candidates within ``margin`` of the best one's objective when
        there are several (then none is selected), "effects": {name: {"felt" (does
        a strip feel it), and where felt: "theta" (physical), "theta_prior_stds",
        "theta_std_prior_stds", "chi2_drop", "chi2_needed", "log_k1_shift" (per direction, with
        the effect), "error_baseline_refit" (k1 refitted without it), "error_after" (with it; RMS
        apparent log k1), "found", "why"}}}.
    """
    resp = ReadingResponse(records, params, k1_step=settings.k1_step)
    y_log = resp.residual()
    out = {"readings": [{**r.to_json(), "simulated": float(math.exp(b)) if math.isfinite(b) else None,
                         "residual_log_k1": float(v) if math.isfinite(v) else None}
                        for r, b, v in zip(records, resp.base(), y_log)],
           "error_before": _rms(y_log), "selected": None, "effects": {}}
    if not np.all(np.isfinite(y_log)) or not np.all(np.isfinite(resp.slope())):
        out["why"] = "a reading's strip did not come to rest at the baseline fit; the readings were not used"
        return out
    for effect in bar(candidates, desc="bench readings", unit="effect"):
        t0, sd = np.asarray(effect.theta0(), float), np.asarray(effect.prior_std(), float)
        if not any(effect.strip_terms(t.mesh(), t0 + sd) for t in resp.tests):
            out["effects"][effect.name] = {"felt": False, "found": False, "why": "a strip does not feel it"}
            continue
        n = len(t0)
        f = np.zeros((n + len(DIRECTIONS),) * 2) if fisher is None or effect.name not in fisher \
            else np.asarray(fisher[effect.name], float)
        model = _Model(resp, effect, f, settings)
        null, alt = model.fit(effect=False), model.fit(effect=True)
        z = alt["z"]
        rec = {"felt": True, "theta": effect.describe(t0 + z[:n] * sd), "theta_prior_stds": z[:n].tolist(),
               "theta_std_prior_stds": None if alt["theta_std"] is None else alt["theta_std"].tolist(),
               "chi2_drop": null["objective"] - alt["objective"],
               "chi2_needed": float(stats.chi2.ppf(settings.level, n)),
               "log_k1_shift": dict(zip(DIRECTIONS, z[n:].tolist())),
               "error_baseline_refit": _rms(model.target - null["g"]), "error_after": _rms(model.target - alt["g"])}
        std = np.inf if alt["theta_std"] is None else float(np.max(alt["theta_std"]))
        checks = {"the objective falls by less than the χ² bound": not rec["chi2_drop"] > rec["chi2_needed"],
                  "θ is not identifiable from the readings": not std < settings.threshold}
        failed = [k for k, v in checks.items() if v]
        rec["found"] = not failed
        rec["why"] = "; ".join(failed) if failed else "the readings ask for it"
        out["effects"][effect.name] = rec
    felt = {k: v for k, v in out["effects"].items() if v["felt"]}
    if felt:
        best = max(felt, key=lambda k: felt[k]["chi2_drop"])
        close = sorted(k for k, v in felt.items() if v["chi2_drop"] > felt[best]["chi2_drop"] - settings.margin)
        out["ambiguous"] = close if len(close) > 1 else None
        for k, v in felt.items():
            if v["found"] and k != best:
                v["found"], v["why"] = False, f"{best} explains the readings better"
        if felt[best]["found"] and len(close) > 1:
            felt[best]["found"] = False
            felt[best]["why"] = ("the readings ask for an effect of the fabric but cannot say which: "
                                 + ", ".join(close) + " explain them about as well")
        out["selected"] = best if felt[best]["found"] else None
    return out


__all__ = ["BenchFit", "bench_evidence"]
