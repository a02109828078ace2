"""Residual signatures: which candidate effects the residual of a fit points to, before any drop.

Scoring a candidate by its signature costs no simulation, so the selection (``select``) uses it
to order the candidates it then tries, and the one model-free test (the offset test) decides
whether off-centre is tried at all.

Candidates are first RANKED by their residual signature (cheap, no simulation): a world-frame
first harmonic of the measured rims beyond the drop-to-drop noise (χ² test over all captures) →
off-centre specimen, refitted first as the rigid two-parameter explanation; harmonic 1 / odd
harmonics → off-centre specimen; a residual antisymmetric under the warp mirror → unequal
bias rigidities; harmonics 1–2 → heterogeneity; a residual concentrated in the hem band → edge
curl or heavy hem; the skirt lower than simulated next to the disc → a compliant clamp edge
(clamp hinge); high harmonics away from the hem → creases or fold self-contact. The top
``max_refits`` (default: all) are then tried and chosen by evidence. Off-centre is tried only
when that offset test, or the same test on the scans' centroids, is significant (``offset_pvalue``,
``inadmissible``): it is the one effect with a hard, model-free signature, and without it a fitted
offset mimics a reshaped skirt instead.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy import stats

from .. import refine
from ..observe.metrics import triangle_areas
from .residuals import ResidualReport, Views


def _frac(a: float, b: float) -> float:
    return float(a / b) if b > 0 else 0.0


FIRST_HARMONIC_ALPHA = 0.01
"""Significance level of the offset test (``offset_pvalue``) that puts the off-centre candidate first."""


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
    """Off-centre θ (dx, dy, m) along the captures' mean scan centroid at ``factors`` times its length,
    when the centroid test alone is significant (``centroid_pvalue`` doubled, as in ``offset_pvalue``,
    below ``FIRST_HARMONIC_ALPHA``); none otherwise. The axis probes of the screen (±1.5 prior stds,
    15 mm) are ten times the 1.3–2.0 mm centroids of the real scans that admit off-centre, so an
    offset of that size would be screened only far beyond it; these probes try it at the size the
    data point to. The skirt hangs nearer the disc on the long side, so the centroid moves less than
    the specimen (0.4–0.8× on the capped lab)."""
    mean = _mean_scan_centroid(residuals)
    if mean is None or not 2.0 * _centred_pvalue(mean, SIGMA_CENTROID_M, len(residuals)) < FIRST_HARMONIC_ALPHA:
        return []
    return [f * mean for f in factors]


def inadmissible(name: str, residuals: Sequence[ResidualReport]) -> str | None:
    """Why effect ``name`` cannot explain these captures (None when it can).

    An off-centre specimen shifts the skirt in the world frame by the same offset in every
    capture, so its rims carry a first harmonic, and its scan's centroid moves, beyond fold noise
    (``offset_pvalue`` below ``FIRST_HARMONIC_ALPHA``). Without either, an offset found by a fit
    mimics a change in the skirt's shape instead (a hidden heavy hem was taken for a 15 mm offset
    when selection scored the height profile), so it is not tried.
    """
    if name == "off_centre":
        p1 = offset_pvalue(residuals)
        if not p1 < FIRST_HARMONIC_ALPHA:
            return (f"no world-frame first harmonic beyond fold noise in the measured rims, nor a shifted "
                    f"scan centroid (p = {p1:.2g})")
    return None


def signature_scores(report: ResidualReport, others: Sequence[ResidualReport] = ()) -> dict[str, float]:
    """How well each effect's expected residual signature matches ``report`` (0..1, larger = better).

    ``others``: residual reports of further captures of the same specimen; they sharpen the
    offset test (``offset_pvalue``), which, when significant at
    ``FIRST_HARMONIC_ALPHA``, scores off-centre 1 − p (off-centre is only scored while it is not
    yet in the model, whose rims are then centred in expectation). Keys are the effect names of
    ``drapejax.effects``; an effect without a signature is scored 0.
    """
    spec = report.rim_residual_spectrum[1:] ** 2
    total = float(spec.sum())
    sym = report.symmetry
    h1 = _frac(spec[0], total)
    high = _frac(spec[2:].sum(), total)
    bands = report.bands
    h_abs = {k: abs(v.get("height_mm", 0.0)) for k, v in bands.items()}
    hem_share = _frac(h_abs["hem"], sum(h_abs.values()))
    rim_rms = float(np.sqrt(np.mean(report.rim_residual**2))) * 1e3
    mean_share = _frac(abs(report.rim_mean_mm), rim_rms)
    hem_lower = 1.0 if bands["hem"].get("height_mm", 0.0) < 0 else 0.5
    near_share = _frac(h_abs["near_disc"], sum(h_abs.values()))
    near_lower = 1.0 if bands["near_disc"].get("height_mm", 0.0) < 0 else 0.0
    p1 = offset_pvalue([report, *others])
    return {
        "off_centre": 1.0 - p1 if p1 < FIRST_HARMONIC_ALPHA else h1 * sym["odd_fraction"],
        "heterogeneity": sym["low_fraction"] * (1.0 - 0.5 * h1),
        "bias_asymmetry": sym["mirror_antisymmetric_fraction"] * (1.0 - sym["odd_fraction"]),
        "heavy_hem": 0.5 * (hem_share * hem_lower + mean_share),
        "edge_curl": 0.5 * (hem_share + mean_share) * (1.5 - hem_lower),
        "plastic_set": high * (1.0 - hem_share),
        "self_contact": 0.5 * high,
        "clamp_hinge": near_share * near_lower,
    }


__all__ = ["signature_scores", "inadmissible", "first_harmonic_pvalue", "FIRST_HARMONIC_ALPHA", "SIGMA_CENTROID_M",
           "scan_centroid", "centroid_pvalue", "offset_pvalue", "centroid_probes"]
