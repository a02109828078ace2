"""Residual signatures: which candidate effects the residual of a fit points to, before any drop.

Scoring a candidate by its signature costs no simulation, so the selection (``select``) uses it
to order the candidates it then tries, and a model-free test can rule a candidate out before it
is tried.

This module reads the residual's features once (``Evidence``: rim-spectrum shares, symmetries,
the radial bands' height residuals, the rim's mean shift, and the offset test below), and each
effect turns them into its own score and admissibility (``Effect.signature``,
``Effect.inadmissible`` in ``drapejax.effects``), so no effect is named here. Candidates are
RANKED by that score (cheap, no simulation) and the top ``max_refits`` (default: all) are then
tried and chosen by evidence.

The offset test is the one hard, model-free signature: a world-frame first harmonic of the
measured rims beyond the drop-to-drop noise (χ² test over all captures), or the same test on the
scans' centroids (``offset_pvalue``). A specimen displaced on the disc must show it, and without
it a fitted offset mimics a reshaped skirt instead; where the centroid alone is significant, it
also points to the offset's size (``centroid_probes``).
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import cached_property

import numpy as np
from scipy import stats

from .. import effects as effect_library
from .. import refine
from ..observe.descriptors import fold_count
from ..observe.metrics import triangle_areas
from .residuals import ResidualReport, Views


def _frac(a: float, b: float) -> float:
    return float(a / b) if b > 0 else 0.0


FIRST_HARMONIC_ALPHA = 0.01
"""Significance level of the offset test (``offset_pvalue``): below it the captures show a
world-frame offset of the specimen (``Evidence.offset_significant``)."""


def first_harmonic_pvalue(residuals: Sequence[ResidualReport]) -> float:
    """p-value of "centred specimen" from the measured rims of captures of one specimen.

    A centred specimen of any material the base model has puts no world-frame first harmonic
    into its rim r(φ) except fold-placement noise, ``refine.SIGMA_C1_M`` per component and
    independent from drop to drop. The mean measured (Re, Im) over the N captures therefore has
    variance σ²/N per component and its squared norm over that is χ² with 2 degrees of freedom;
    a real offset stays put in the world frame while the fold noise averages out. (The
    measured rim is used, not the residual: the rotation that aligns the simulation to the
    measurement also turns the simulation's own fold-noise harmonic towards the measured one.)
    """
    c1 = np.array([refine.first_harmonic(r.rim_measured) for r in residuals])
    return _centred_pvalue(c1.mean(axis=0), refine.SIGMA_C1_M, len(c1))


def _centred_pvalue(mean: np.ndarray, sigma: float, n: int) -> float:
    """p-value of a zero 2-vector given the ``mean`` of ``n`` captures with noise ``sigma`` per
    component: χ² with 2 degrees of freedom of |mean|² over σ²/n."""
    return float(stats.chi2.sf(float(np.sum(mean**2)) / (sigma**2 / n), 2))


SIGMA_CENTROID_M = 0.0006
"""Capture-to-capture spread of each world-frame component of the draped specimen's area-weighted
centroid (``scan_centroid``), m: 0.60 mm pooled within fabrics over the 48 real scans of 13
fabrics in ``shared/data/real_cusick`` (hand placement and fold placement), 0.55 mm rms over 24
captures of 8 centred virtual labs of "mid" (20 mm fit mesh graded from 3 mm, capped membrane;
fold placement alone, one lab's heterogeneity included). It is ten times quieter than the rim's
first harmonic (``refine.SIGMA_C1_M``): folds move the outline, not the cloth's mass."""


def scan_centroid(views: Views) -> np.ndarray | None:
    """(x, y) of the area-weighted centroid of a measured scan mesh in the world frame, m (None
    without one). A centred specimen of any material that is the same under a half turn has it on
    the disc axis up to fold noise, and the skirt's outline may hide an offset that this shows: on
    the capped lab a 20 mm offset put the centroid at +8 to +17 mm in all three captures, while the
    rims' first harmonics pointed −13, +10 and −3 mm along it."""
    if views.verts is None or views.faces is None or not len(views.faces):
        return None
    t = np.asarray(views.verts, float)[np.asarray(views.faces)]
    area = triangle_areas(t)
    if not area.sum() > 0:
        return None
    return (area[:, None] * t.mean(axis=1)[:, :2]).sum(axis=0) / area.sum()


def _mean_scan_centroid(residuals: Sequence[ResidualReport]) -> np.ndarray | None:
    """Mean ``scan_centroid`` over the captures; None when a capture has no scan mesh."""
    c = [scan_centroid(r.measured) for r in residuals]
    return None if not c or any(v is None for v in c) else np.mean(c, axis=0)


def centroid_pvalue(residuals: Sequence[ResidualReport]) -> float | None:
    """p-value of "centred specimen" from the scan centroids of captures of one specimen (None when
    a capture has no scan mesh): χ² with 2 degrees of freedom of their mean over
    ``SIGMA_CENTROID_M``²/N, as ``first_harmonic_pvalue`` for the rims."""
    mean = _mean_scan_centroid(residuals)
    return None if mean is None else _centred_pvalue(mean, SIGMA_CENTROID_M, len(residuals))


def offset_pvalue(residuals: Sequence[ResidualReport]) -> float:
    """p-value of "centred specimen": the rims' first harmonic (``first_harmonic_pvalue``) and, where
    every capture has a scan mesh, its centroid (``centroid_pvalue``), the smaller of the two
    doubled (Bonferroni), so that two tests do not double the false alarms."""
    p1, p2 = first_harmonic_pvalue(residuals), centroid_pvalue(residuals)
    return p1 if p2 is None else min(1.0, 2.0 * min(p1, p2))


def centroid_probes(residuals: Sequence[ResidualReport], factors: Sequence[float]) -> list[np.ndarray]:
    """Offsets (dx, dy, m) along the captures' mean scan centroid at ``factors`` times its length,
    when the centroid test alone is significant (``centroid_pvalue`` doubled, as in ``offset_pvalue``,
    below ``FIRST_HARMONIC_ALPHA``); none otherwise: the θ the screen adds for an effect whose θ is
    that offset (``Effect.seeded_by_centroid``). The axis probes of the screen (±1.5 prior stds,
    15 mm) are ten times the 1.3–2.0 mm centroids of the real scans that admit an offset, so an
    offset of that size would be screened only far beyond it; these probes try it at the size the
    data point to. The skirt hangs nearer the disc on the long side, so the centroid moves less than
    the specimen (0.4–0.8× on the capped lab)."""
    mean = _mean_scan_centroid(residuals)
    if mean is None or not 2.0 * _centred_pvalue(mean, SIGMA_CENTROID_M, len(residuals)) < FIRST_HARMONIC_ALPHA:
        return []
    return [f * mean for f in factors]


class Evidence:
    """The features of a fit's residual that the effects' signatures and admissibility read
    (``Effect.signature``, ``Effect.inadmissible``), each computed when first asked for.

    ``report``: the residual of the fitted capture; ``others``: those of further captures of the
    same specimen, which sharpen the offset test. Shares are 0..1 (0 where their total is 0).
    """

    def __init__(self, report: ResidualReport, others: Sequence[ResidualReport] = ()):
        self.report = report
        self.others = tuple(others)

    @cached_property
    def _spectrum(self) -> tuple[np.ndarray, float]:
        spec = self.report.rim_residual_spectrum[1:] ** 2
        return spec, float(spec.sum())

    @property
    def first_harmonic_fraction(self) -> float:
        """Share of the rim residual's energy (harmonics k ≥ 1) in harmonic 1."""
        spec, total = self._spectrum
        return _frac(spec[0], total)

    @property
    def high_harmonic_fraction(self) -> float:
        """Share of the rim residual's energy (harmonics k ≥ 1) in harmonics 3 and up."""
        spec, total = self._spectrum
        return _frac(spec[2:].sum(), total)

    @cached_property
    def fold_excess(self) -> int:
        """Folds of the measured rim minus folds of the simulated one (``observe.fold_count``)."""
        return fold_count(self.report.rim_measured) - fold_count(self.report.rim_simulated)

    @property
    def symmetry(self) -> dict:
        """The rim residual's symmetry shares (``ResidualReport.symmetry``): "odd_fraction",
        "mirror_antisymmetric_fraction", "low_fraction" (harmonics 1–2)."""
        return self.report.symmetry

    @cached_property
    def _band_heights(self) -> dict[str, float]:
        return {k: abs(v.get("height_mm", 0.0)) for k, v in self.report.bands.items()}

    def band_share(self, band: str) -> float:
        """Share of the radial bands' mean |height residual| in ``band`` ("near_disc", "mid" or
        "hem", ``residuals.BANDS``)."""
        h = self._band_heights
        return _frac(h[band], sum(h.values()))

    def band_lower(self, band: str) -> bool:
        """The measured skirt hangs lower than the simulated one in ``band`` (its mean signed height
        residual, measured − simulated, is negative)."""
        return self.report.bands[band].get("height_mm", 0.0) < 0

    @property
    def mean_share(self) -> float:
        """The rim residual's mean (harmonic 0, the rim drawn in or let out all round) over its rms."""
        rim_rms = float(np.sqrt(np.mean(self.report.rim_residual**2))) * 1e3
        return _frac(abs(self.report.rim_mean_mm), rim_rms)

    @cached_property
    def offset_pvalue(self) -> float:
        """p-value of "centred specimen" over all the captures (``offset_pvalue``)."""
        return offset_pvalue([self.report, *self.others])

    @property
    def offset_significant(self) -> bool:
        """The captures show a world-frame offset of the specimen: ``offset_pvalue`` below
        ``FIRST_HARMONIC_ALPHA``."""
        return bool(self.offset_pvalue < FIRST_HARMONIC_ALPHA)


def inadmissible(effect, residuals: Sequence[ResidualReport]) -> str | None:
    """Why ``effect`` cannot explain these captures (None when it can): its ``Effect.inadmissible``
    on their ``Evidence``, the first capture's residual with the others'. ``effect`` is an
    ``Effect`` or a registered effect's name (``drapejax.effects.REGISTRY``); an unregistered name
    is never ruled out.
    """
    if isinstance(effect, str):
        effect = effect_library.registered(effect)
        if effect is None:
            return None
    residuals = list(residuals)
    return effect.inadmissible(Evidence(residuals[0], residuals[1:]))


def signature_scores(report: ResidualReport, others: Sequence[ResidualReport] = (),
                     effects: Sequence | None = None) -> dict[str, float]:
    """How well each effect's expected residual signature matches ``report`` (0..1, larger = better).

    Each of ``effects`` (default: every registered effect, ``drapejax.effects.candidate_effects``)
    scores the residual's ``Evidence`` by its ``Effect.signature``. ``others``: residual reports of
    further captures of the same specimen; they sharpen the offset test (``offset_pvalue``). Keys
    are the effects' names; an effect without a signature is left out (``select.rank`` scores it 0).
    """
    evidence = Evidence(report, others)
    scores = {}
    for effect in effect_library.candidate_effects() if effects is None else effects:
        score = effect.signature(evidence)
        if score is not None:
            scores[effect.name] = float(score)
    return scores


__all__ = ["Evidence", "signature_scores", "inadmissible", "first_harmonic_pvalue", "FIRST_HARMONIC_ALPHA",
           "SIGMA_CENTROID_M", "scan_centroid", "centroid_pvalue", "offset_pvalue", "centroid_probes"]
