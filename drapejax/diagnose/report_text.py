"""How the diagnosis report writes numbers, units and effects in words.

The page is read by people, so every number on it passes through ``_fmt`` (about three
significant figures, no exponent in the usual ranges, "—" for a missing value), every unit
through ``_unit`` (µN·m, not uN*m), and an effect's ``describe`` values are labelled with the unit
read from their key's suffix. ``_where`` says where on the specimen each effect acts. The
conclusion and the tables in ``report`` share these rules, so a value reads the same wherever it
appears.
"""

from __future__ import annotations

import html
import math
from collections.abc import Mapping, Sequence

import numpy as np

_METRICS = (("iou", "outline IoU (aligned)", "", "≥"), ("dc_abs", "|ΔDC| drape coefficient", "", "≤"),
            ("spectral_mm", "rim spectral distance", "mm", "≤"), ("scan_mm", "scan distance", "mm", "≤"))
"""Error metric key, label, unit, and the side of the floor that is inside it."""

EFFECT_TEXT = {
    "off_centre": "specimen off-centre on the disc",
    "clamp_hinge": "compliant clamp edge (the fabric hinges at the disc rim)",
    "heavy_hem": "heavier hem band",
    "edge_curl": "edge curl",
    "bias_asymmetry": "unequal left/right bias rigidity",
    "bending_saturation": "bending that saturates at large curvature",
    "plastic_set": "plastic set creases from storage",
    "heterogeneity": "bending rigidity varying across the specimen",
    "self_contact": "self-contact of neighbouring folds",
}
"""Effect name -> what it is, in words (``drapejax.effects``)."""


def _is_num(v) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool) and math.isfinite(v)


def _fmt(v, digits: int = 3) -> str:
    """A number for reading: about ``digits`` significant figures, no exponent in the usual
    ranges; "—" for None, NaN or a non-number."""
    if not _is_num(v):
        return "—"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    v = float(v)
    a = abs(v)
    if a == 0.0:
        return "0"
    if a >= 10 ** digits or a < 1e-3:
        return f"{v:.{digits}g}" if a < 1e-3 else f"{v:.0f}"
    decimals = max(digits - 1 - int(math.floor(math.log10(a))), 0)
    return f"{v:.{decimals}f}"


def _unit(u: str) -> str:
    """A ``drapejax.units`` name as printed: g*mm^2/s^2 -> g·mm²/s², uN*m -> µN·m."""
    return u.replace("uN", "µN").replace("*", "·").replace("^2", "²").replace("^3", "³")


def _yes_no(v) -> str:
    return "—" if v is None else ("yes" if v else "no")


def _e(v) -> str:
    return html.escape("" if v is None else str(v))


def _quantity(key: str, value) -> tuple[str, str, str]:
    """(label, value, unit) of one entry of an effect's ``describe`` dict, the unit read from the
    key's suffix (``specimen_centre_dx_mm`` -> mm; ``band_m`` -> shown in mm; ``*_per_m`` -> 1/m)."""
    vals = [float(x) for x in np.ravel(value)] if isinstance(value, (list, tuple, np.ndarray)) else [value]
    label, unit, scale, mm = key, "", 1.0, False
    for suffix, u, s in (("_1_per_m", "1/m", 1.0), ("_per_m", "1/m", 1.0), ("_mm", "mm", 1.0), ("_m", "mm", 1e3),
                         ("_in_bending_lengths", "bending lengths", 1.0)):
        if key.endswith(suffix):
            label, unit, scale, mm = key[:-len(suffix)], u, s, u == "mm"
            break
    text = ", ".join((f"{x * scale:.1f}" if mm else _fmt(x * scale)) if _is_num(x) else _e(x) for x in vals)
    return label.replace("_", " "), text, unit


def _effect_values(values: Mapping | None) -> list[tuple[str, str, str]]:
    if not isinstance(values, Mapping):
        return []
    return [_quantity(k, v) for k, v in values.items() if k != "theta"]


def _strength(values: Mapping | None) -> str:
    parts = [f"{label} {v}" + (f" {u}" if u else "") for label, v, u in _effect_values(values)]
    return "; ".join(parts) if parts else "no physical values recorded"


def _where(name: str, values: Mapping | None) -> str | None:
    """Where on the specimen the effect acts, in words; None when it has no location."""
    v = values if isinstance(values, Mapping) else {}
    band = v.get("band_m")
    band_mm = f"{float(band) * 1e3:.0f} mm" if _is_num(band) else None
    if name == "off_centre" and _is_num(v.get("specimen_centre_dx_mm")) and _is_num(v.get("specimen_centre_dy_mm")):
        dx, dy = float(v["specimen_centre_dx_mm"]), float(v["specimen_centre_dy_mm"])
        return (f"the specimen centre sits {math.hypot(dx, dy):.1f} mm from the disc centre, at "
                f"{math.degrees(math.atan2(dy, dx)):.0f}° from the simulation's x axis")
    return {
        "heavy_hem": f"the band within {band_mm or 'a hem width'} of the cut edge",
        "edge_curl": f"near the cut edge (decaying over {band_mm or 'a band'} inwards)",
        "plastic_set": "along the warp and weft lines through the specimen centre"
                       + (f" (bands {band_mm} wide)" if band_mm else ""),
        "clamp_hinge": "at the rim of the support disc",
        "bias_asymmetry": "everywhere, along the +45° bias direction",
        "bending_saturation": "where the fabric bends sharply (curvature beyond about 50 1/m: over the disc edge)",
        "heterogeneity": "across the specimen (angular harmonics of the rigidity)",
        "self_contact": "between the walls of neighbouring folds",
    }.get(name)


def _mean_errors(errors: Sequence | None) -> dict:
    """Mean of each metric over held-out captures' error dicts (None where no capture has it)."""
    out = {}
    for k, *_ in _METRICS:
        vals = [float(e[k]) for e in (errors or []) if isinstance(e, Mapping) and _is_num(e.get(k))]
        out[k] = float(np.mean(vals)) if vals else None
    return out
