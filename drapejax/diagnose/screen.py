"""The fresh-drop screen's settings (``Screen``) and the probe-grid helpers only it uses.

A model's prediction is what a fresh drop does, not what a continuation from a fitted rest state
keeps, so by default the selection (``select``) screens candidates on fresh drops; this module
holds what configures that screen and how its probe grid is built and widened.

By default (``Screen``) each step SCREENS the candidates on fresh drops instead of refitting by
continuation. A baseline fitted without the effect drifts to mimic it (a hidden heavy hem: every
k1 at 0.3× the truth, a soft fabric still holding a stiffer one's folds), and a continuation
from that rest state keeps the mimicry; letting Levenberg–Marquardt continue from a good fresh
drop undid it too (hem +2 → +0.009, 25 mm virtual lab). A model's prediction is what a drop
does, so that is what is scored (``docs/results/2026-11-24-redrop-vs-continuation.md``,
``redrop_vs_continuation.py``), by the rows of ``selection_misfits``: the fit's rows with the skirt's
height profile in place of its two rings (``refine.Misfit(profile=True)``), so that an effect that
reshapes the skirt where k1 cannot follow shows beyond fold noise:

* every candidate is dropped afresh at a few strengths (±1, ±2 prior stds from null; an offset
  also along the scans' mean centroid, ``centroid_probes``) times a few overall k1 factors around
  the current fit, each with the same seed; while its best drop is the
  farthest probe on its side, the grid is widened by a probe twice as far out (``Screen.widen``
  times at most; without it a hidden edge curl of 3.6 prior stds was selected at the grid's
  edge, 2 stds). Its lowest ½χ² on the fitted capture is compared with that of the current model
  dropped at the same k1 factors with as many seeds as the largest candidate grid can have
  points, so that no effect gets more chances of a lucky fold placement than no effect;
* the ``Screen.top`` candidates with the lowest best drop are then re-dropped, with the best
  null point, at ``Screen.confirm`` further seeds (a candidate's best drop in each of its
  ``Screen.directions`` best probe directions, the lowest confirmed misfit kept: one seed
  settles an effect's direction no better than fold placement does), and the misfit over
  captures (their median, ``over_captures``) averaged over those drops must fall by more than
  half the BIC-like penalty below: a lucky fold placement does not survive other seeds, a real
  effect does. (The best drop on one capture only ranks; requiring it to beat the best null
  drop too refused a hidden edge curl whose fold-averaged gain, at the true k1, is 14 noise
  units: the best of 27 null drops beat the best of 12 curl drops on the fitted capture);
* nor may it raise the error ratio (the veto below) over those drops and captures (the same way),
  paired drop by drop beyond fold noise (``ratio_rises``);
  among the accepted, the lowest confirmed misfit wins. Its best drop is then refitted in k1
  alone, the effect held (``refit_k1``): the baseline is such a fit, so the errors before and
  after differ by the effect, not by how the model was fitted (a single screened drop, left
  as it is, scored worse than the baseline fit in the demo while finding the right effect);
* that refit, the model that would be reported, must itself beat over drops at
  ``Screen.validate`` further seeds on every capture, by the same margin and without raising
  the error ratio (``validate_step``), the better of the current model and the same k1 refit
  of the best null drop (``validation_bar``: what the refit gains without the effect is not
  the effect's); if it does not, the screened drop itself (the confirmed model) is validated
  the same way with twice the margin, and if neither passes, the next accepted candidate is
  refitted and validated. The first to pass is the new model around which the next step screens,
  unless the best point of a scan of its newest effect's strength (with a few k1 factors) is
  lower over drops at ``Screen.polish`` further seeds (``polish_step``): the screen places an
  effect on its probe grid, and the remainder of a probe short of the truth (an offset at
  15 mm for 20) otherwise goes to the next step's candidates.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np

from ._common import _at_least, _positive_with_one


@dataclasses.dataclass(frozen=True)
class Screen:
    """Fresh-drop screen of the candidates at every step (see module docstring).

    Attributes:
        k_factors: overall k1 factors around the current fit, tried with every probe. Softer
            ones too: with the baseline at its k1-only optimum (``Rescale``), an effect that
            mimics stiffness (edge curl) needs a softer k1 beside it, one that mimics
            softness (a heavy hem, a compliant clamp) a stiffer one. (Above the rescaled
            baseline only, (1, 1.4, 2), the hidden edge curl's best drop was at 1.4× and failed
            confirmation, 7.5 against the null's 5.7.)
        steps: probe offsets of a one-parameter effect from null, in prior stds.
        vector_steps: the same along each axis of a vector effect.
        seed: drop seed of every candidate grid point; the null grid drops seeds seed, seed+1, …
            at each k1 factor, as many as the largest candidate grid has probes plus one, so no
            effect is tried more often than no effect.
        confirm: further drop seeds at which the best candidate and null points are re-dropped
            and scored on every capture (the fold-placement average that decides).
        top: candidates confirmed (lowest screened misfit first).
        directions: probe directions (axis and sign) of a candidate confirmed, the best drop of
            each, lowest screened misfit first: one seed's drop settles a direction no better
            than fold placement does (a demo run screened an offset hidden along +x
            best along −y, and the three confirmation seeds ranked +x first). Keeping the
            best of several confirmed directions favours the candidate over the null model;
            the validation drops, at further seeds, judge the kept one alone.
        validate: further drop seeds at which the accepted candidate, once its k1 are refitted,
            and the models it must beat are dropped and scored on every capture: the model that
            would be reported must itself beat the one it replaces (``validate_step``).
        widen: times a candidate's grid may be widened: while its best drop is the farthest probe
            on its side of its axis, a probe twice as far from null is dropped at every k1 factor
            (``_outward``), so an effect stronger than the grid is bracketed rather than capped.
        k_widen: times a candidate's k1 grid may be widened: while its best drop is at the
            softest (stiffest) k1 factor, every probe is dropped once more at that factor times
            the ratio of the two softest (stiffest) factors. A setup effect a baseline has
            absorbed into its k1 can need a k1 far outside ``k_factors``: with a hidden 20 mm
            offset of "mid" a baseline came out 2.2-4.8 times too stiff, and the offset's best
            probe sat at the softest factor, 0.71, its loss above the null's; the truth's k1 were
            0.21-0.46 times the fit's. The null is widened the same way while its own best
            drop is at an edge (``null_grid``), so that a candidate does not win by a k1 alone.
            0 keeps the grid.
        polish: drops at which a validated model and the best point of its strength scan
            (``polish_step``) are compared, the lower kept; 0: no scan, the validated model is
            kept with its newest effect at the probe value.
        polish_strengths: factors on the newest effect's displacement from null in that scan
            (1, the validated strength, must be among them).
        polish_k_factors: overall k1 factors tried with every strength (1 must be among them).
        polish_drops: drops per scanned point.
        centroid_factors: probes of an effect whose θ is the specimen's offset
            (``Effect.seeded_by_centroid``) at these multiples of the scans' mean centroid,
            beside the axis probes, where the centroid test is significant (``centroid_probes``).
    """

    k_factors: tuple[float, ...] = (0.71, 1.0, 1.41, 2.0)
    steps: tuple[float, ...] = (-2.0, -1.0, 1.0, 2.0)
    vector_steps: tuple[float, ...] = (-1.5, 1.5)
    seed: int = 100
    confirm: int = 3
    top: int = 3
    directions: int = 3
    validate: int = 3
    widen: int = 2
    k_widen: int = 3
    polish: int = 3
    polish_strengths: tuple[float, ...] = (0.5, 0.71, 1.0, 1.41, 2.0)
    polish_k_factors: tuple[float, ...] = (0.84, 1.0, 1.19)
    polish_drops: int = 2
    centroid_factors: tuple[float, ...] = (1.0, 2.0)

    def __post_init__(self):
        if not self.k_factors or min(self.k_factors) <= 0:
            raise ValueError(f"Screen.k_factors must be positive and not empty, got {self.k_factors}")
        _positive_with_one(self, "polish_strengths", "polish_k_factors")
        if any(f <= 0 for f in self.centroid_factors):
            raise ValueError(f"Screen.centroid_factors must be positive, got {self.centroid_factors}")
        _at_least(self, 0, "widen", "k_widen", "polish")
        _at_least(self, 1, "polish_drops", "confirm", "top", "directions", "validate")

    def confirm_seeds(self) -> list[int]:
        return [self.seed + 1000 + i for i in range(self.confirm)]

    def validation_seeds(self) -> list[int]:
        return [self.seed + 3000 + i for i in range(self.validate)]

    def polish_scan_seeds(self) -> list[int]:
        return [self.seed + 4000 + i for i in range(self.polish_drops)]

    def polish_seeds(self) -> list[int]:
        return [self.seed + 4100 + i for i in range(self.polish)]


def _by_direction(effect, drops: Sequence[dict], n_theta: int) -> list[dict]:
    """The best of ``drops`` for each probe direction (the axis moved from null and its sign),
    lowest ½χ² first; ``n_theta``: length of θ before the effect's parameters."""
    t0, best = effect.theta0(), {}
    for d in drops:
        moved = d["theta"][n_theta:] - t0
        key = tuple(np.sign(moved))
        if key not in best or d["loss"] < best[key]["loss"]:
            best[key] = d
    return sorted(best.values(), key=lambda d: d["loss"])


def widened_grid(effect, screen: Screen, theta: np.ndarray, probes: list, drop, lowest
                 ) -> tuple[dict | None, list, int]:
    """A candidate's probes dropped at every k1 factor around the fit θ (whose first three
    components are log k1), then widened while that lowers the best loss: ``Screen.widen`` times a
    probe twice as far out while the best drop is the farthest on its side (``_outward``), then
    ``Screen.k_widen`` times every probe at a k1 factor one step beyond the grid while the best
    drop sits at its softest (stiffest) factor, the step being the log ratio of the grid's two
    softest (stiffest) factors. ``probes`` is extended in place; ``drop(points)`` scores (θ, seed)
    points and ``lowest`` picks the best of them. Returns (best point, scored points, drops tried)."""
    grid = [math.log(k) for k in screen.k_factors]
    at = lambda ths, ks: [(np.concatenate([theta[:3] + k, theta[3:], th]), screen.seed) for th in ths for k in ks]
    scored = drop(at(probes, grid))
    best, drops = lowest(scored), len(grid) * len(probes)

    def further(points) -> bool:
        nonlocal best, drops
        new = drop(points)
        drops += len(points)
        scored.extend(new)
        wider = lowest(new)
        if wider is None or wider["loss"] >= best["loss"]:
            return False
        best = wider
        return True

    for _ in range(screen.widen):
        th = None if best is None else _outward(effect, best["theta"][len(theta):], probes)
        if th is None:
            break
        probes.append(th)
        if not further(at([th], grid)):
            break
    widen_k(screen, theta[0], lambda: best, lambda k: further(at(probes, [k])))
    return best, scored, drops


def widen_k(screen: Screen, log_k0: float, best, further) -> None:
    """``Screen.k_widen`` times, while the best point (``best()``, a dict with "theta") sits at the
    grid's softest (stiffest) k1 factor, ``further(log k)`` drops at one step beyond it, the step
    the log ratio of the grid's two softest (stiffest) factors; stops when ``further`` returns
    False (no lower loss). ``log_k0``: the fit's first log k1, the grid's factor 1."""
    logs = sorted(math.log(k) for k in screen.k_factors)
    lo, hi = logs[0], logs[-1]
    for _ in range(screen.k_widen if len(logs) > 1 else 0):
        b = best()
        side = math.nan if b is None else float(b["theta"][0] - log_k0)
        if side <= lo + 1e-9:
            lo += logs[0] - logs[1]
            k = lo
        elif side >= hi - 1e-9:
            hi += logs[-1] - logs[-2]
            k = hi
        else:
            break
        if not further(k):
            break


def null_grid(screen: Screen, theta: np.ndarray, n_null: int, best_of) -> tuple[dict | None, int]:
    """The current model dropped at every k1 factor around the fit θ at ``n_null`` seeds each, and,
    as a candidate's grid is (``widened_grid``), at factors beyond the grid while its best drop sits
    at an edge (``widen_k``): the null is offered every k1 a candidate may use, at as many drops.
    ``best_of(points)`` is the best scored (θ, seed) point or None. Returns (best, drops tried)."""
    at = lambda k: [(np.concatenate([theta[:3] + k, theta[3:]]), screen.seed + i) for i in range(n_null)]
    points = [p for k in screen.k_factors for p in at(math.log(k))]
    best, drops = best_of(points), len(points)

    def further(k) -> bool:
        nonlocal best, drops
        drops += n_null
        new = best_of(at(k))
        if new is None or (best is not None and new["loss"] >= best["loss"]):
            return False
        best = new
        return True

    widen_k(screen, theta[0], lambda: best, further)
    return best, drops


def _outward(effect, theta: np.ndarray, tried: Sequence[np.ndarray]) -> np.ndarray | None:
    """The probe twice as far from null as ``theta`` in its direction, clipped to the lower bound,
    when ``theta`` is the farthest of the ``tried`` probes in that direction (along one axis, or
    along a seeded direction such as those of ``centroid_probes``); else None."""
    t0, lo = effect.theta0(), effect.lower_bound()
    d = np.asarray(theta, float) - t0
    norm = float(np.linalg.norm(d))
    if norm == 0.0:
        return None
    along = [float(np.linalg.norm(p - t0)) for p in tried
             if float(np.dot(p - t0, d)) >= (1.0 - 1e-9) * float(np.linalg.norm(p - t0)) * norm > 0.0]
    if norm < max(along, default=0.0):
        return None
    out = np.maximum(t0 + 2.0 * d, lo)
    return None if np.array_equal(out, theta) or any(np.array_equal(out, p) for p in tried) else out


def _with_seeded(probes: list[np.ndarray], seeded: Sequence[np.ndarray]) -> list[np.ndarray]:
    """``probes`` and then those of ``seeded`` not among them."""
    out = list(probes)
    for th in seeded:
        th = np.asarray(th, float)
        if not any(np.array_equal(th, p) for p in out):
            out.append(th)
    return out


__all__ = ["Screen"]
