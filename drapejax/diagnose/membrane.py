"""The membrane stiffness a baseline holds, checked on fresh drops before any effect is tried.

A drape fit moves k1 only; the tensile and shear stiffness α come from the fabric tag or, where
no tag gives them, from the network's estimate, which a drape informs poorly. Where the drape
still depends on α (light fabrics on the fit mesh: a softer membrane lets the skirt stretch and
sag, and takes up the circumferential excess in-plane rather than in folds), a held α far from
the fabric's leaves a baseline that no k1 can bring to the captures, and any candidate that moves
the drape then "explains" the difference. On clean virtual-lab captures of the "light" example
fabric (80 g/m², α 600/400/80 N/m) the network gave α 169/104/25 N/m; three drops of the true
fabric with that α alone scored 30.5 (½χ²) on the captures where the true α scored 2.0, and the
effect search selected a weightless hem band.

So the baseline's overall membrane scale is scanned like its k1 scale (``select.Rescale``):
each factor of ``MembraneScan.factors`` multiplies α along every direction
(``material.scale_stretch``, β kept), is dropped at a few seeds and scored on every capture
(``select.selection_misfits``), so that fold placement is averaged rather than fitted. When a
factor other than 1 scores best, the baseline fit, that factor's best drop and a k1 refit from it
(``trials.held_refit``) are compared over further drops and the lowest misfit is kept
(``select.scale_scan``, which the k1 rescale uses too), with the fit context's fabric
(``refine.FitContext.init``) rescaled to match; every later problem of the diagnosis is posed on it.
Each factor is a new fabric and compiles its own drop.

The scan is off by default (``diagnose(membrane=MembraneScan())``, ``drapejax diagnose
--membrane-scan`` turn it on), because a membrane scale is itself a look-alike: on "mid" captures
with a hidden heavier hem (θ = 2) the scan chose a membrane four times softer, whose sagging skirt
mimics the heavier rim, and the search then selected bending saturation instead of the hem. With
it, six clean cases of "light", "mid" and "heavy" selected nothing, the two "light" cases that
select a weightless hem without it among them (``docs/results/2026-12-06-membrane-scan.md``).
A membrane scale weighed against the effects, as one more candidate with a tensile test as its
separating measurement, would let the search choose between them.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from .. import refine
from ..io import Measurement
from ..material import scale_stretch
from ..refine import FitContext
from . import select


@dataclasses.dataclass(frozen=True)
class MembraneScan(select.Rescale):
    """Settings of the scan of the baseline's overall membrane stiffness (module docstring): those of
    the k1 rescale (``select.Rescale``), with factors of α and seeds of its own.

    Attributes:
        factors: overall α factors around the fit context's fabric; 1 must be among them, so the
            baseline is kept unless another factor beats it.
        seeds: drops per factor (seeds ``seed``, ``seed`` + 1, …).
        seed: first drop seed of the scan; the comparison uses ``seed`` + 100, … (neither is a
            seed of ``select.Screen``, ``select.Rescale`` or ``select.EXPECTED_SEEDS``).
        compare: drops at which the baseline fit, the best factor's drop and the k1 refit from it
            are compared, the lowest misfit kept.
        widen: times the scan may be extended by a factor of 2 beyond its end while the best
            factor is at that end.
    """

    factors: tuple[float, ...] = (0.5, 1.0, 2.0, 4.0)
    seed: int = 6000
    widen: int = 1


def membrane_baseline(measurements: Sequence[Measurement], base_fit: refine.FitResult, *, ctx: FitContext,
                      scan: MembraneScan = MembraneScan()) -> tuple[refine.FitResult, FitContext, dict]:
    """The best of ``base_fit`` (fit context ``ctx``), the best membrane factor of ``scan`` at the fit's
    k1 and a k1 refit from that factor's best drop (module docstring).

    Returns (the fit kept, its fit context: ``ctx`` or ``ctx`` with α rescaled, {"factors",
    "misfits" (per factor, mean over its drops), "best_factor", "kept", "factor" (the membrane
    factor of the fit kept), "compare": {model: misfit} or None}).
    """
    theta = np.asarray(base_fit.theta, float)[:3]
    fit, factor, fit_ctx, record = select.scale_scan(
        measurements, base_fit, theta_at=lambda f: theta, factors=scan.factors, scan_seeds=scan.scan_seeds(),
        context_at=lambda f: ctx if f == 1.0 else dataclasses.replace(ctx, init=scale_stretch(ctx.init, f)),
        compare_seeds=scan.compare_seeds(), widen=scan.widen, desc="membrane scale scan",
        refit_label="k1 refit at the scan's best factor")
    return fit, fit_ctx, {**record, "factor": factor}


__all__ = ["MembraneScan", "membrane_baseline"]
