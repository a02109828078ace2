"""How the diagnosis report writes numbers, units and effects in words.

The page is read by people, so every number on it passes through ``_fmt`` (about three
significant figures, no exponent in the usual ranges, "—" for a missing value), every unit
through ``_unit`` (µN·m, not uN*m), and an effect's ``describe`` values are labelled with the unit
read from their key's suffix. Each effect's own ``label`` and ``where`` (``drapejax.effects``)
say what it is and where on the specimen it acts (``effect_label``, ``_where``). The
conclusion and the tables in ``report`` share these rules, so a value reads the same wherever it
appears.
"""

from __future__ import annotations

import html
import math
from collections.abc import Mapping, Sequence

import numpy as np

from .. import effects as effect_library

_METRICS = (("iou", "outline IoU (aligned)", "", "≥"), ("dc_abs", "|ΔDC| drape coefficient", "", "≤"),
            ("spectral_mm", "rim spectral distance", "mm", "≤"), ("scan_mm", "scan distance", "mm", "≤"))
"""Error metric key, label, unit, and the side of the floor that is inside it."""


def effect_label(name: str) -> str | None:
    """What the registered effect ``name`` is, in words (its ``Effect.label``); None for an
    unregistered name or an effect without one."""
    effect = effect_library.registered(name)
    return None if effect is None else effect.label


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
    """Where on the specimen the registered effect ``name`` acts, in words (its ``Effect.where`` of
    the recorded ``values``); None for an unregistered name or an effect without a location."""
    effect = effect_library.registered(name)
    return None if effect is None else effect.where(values if isinstance(values, Mapping) else {})


def _mean_errors(errors: Sequence | None) -> dict:
    """Mean of each metric over held-out captures' error dicts (None where no capture has it)."""
    out = {}
    for k, *_ in _METRICS:
        vals = [float(e[k]) for e in (errors or []) if isinstance(e, Mapping) and _is_num(e.get(k))]
        out[k] = float(np.mean(vals)) if vals else None
    return out
