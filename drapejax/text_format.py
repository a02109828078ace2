"""Plain-text number and line formatting shared by the command summaries (``drapejax.summary``)
and anything else that prints results for people: significant digits, percentages, seconds,
millimetres, wrapped warnings. Pure Python, no imports beyond the standard library."""

from __future__ import annotations

import math
import textwrap
from collections.abc import Mapping

WIDTH = 100
"""Lines longer than this are wrapped (warnings, reasons) or shortened (generic values)."""


def num(x, sig: int = 3) -> str:
    """``x`` with ``sig`` significant digits: fixed-point between 1e-3 and 1e6, else exponent;
    "n/a" for None or something that is not a number."""
    if isinstance(x, bool):
        return "yes" if x else "no"
    try:
        v = float(x)
    except (TypeError, ValueError):
        return "n/a" if x is None else str(x)
    if math.isnan(v):
        return "nan"
    if math.isinf(v):
        return "inf" if v > 0 else "-inf"
    if v == 0.0:
        return "0"
    a = abs(v)
    if 1e-3 <= a < 1e6:
        decimals = max(0, sig - 1 - math.floor(math.log10(a)))
        text = f"{round(v, decimals):.{decimals}f}"
        return text.rstrip("0").rstrip(".") if "." in text else text
    mant, exp = f"{v:.{sig - 1}e}".split("e")
    return (mant.rstrip("0").rstrip(".") if "." in mant else mant) + "e" + exp


def pct(x, sig: int = 2) -> str:
    """A fraction as a percentage."""
    try:
        return f"{num(100.0 * float(x), sig)} %"
    except (TypeError, ValueError):
        return "n/a"


def yes_no(x) -> str:
    return "n/a" if x is None else ("yes" if x else "no")


def get(d, *keys, default=None):
    """``d[k0][k1]...``, or ``default`` where a key is missing or a level is not a mapping."""
    for k in keys:
        if not isinstance(d, Mapping) or k not in d:
            return default
        d = d[k]
    return default if d is None else d


def is_num(x) -> bool:
    if isinstance(x, bool):
        return False
    try:
        float(x)
    except (TypeError, ValueError):
        return False
    return True


def wrap(text: str, indent: str = "  ", max_lines: int = 3) -> list[str]:
    return textwrap.wrap(str(text), width=WIDTH, initial_indent=indent, subsequent_indent=indent + "  ",
                         max_lines=max_lines, placeholder=" ...", break_on_hyphens=False)


def short(text: str, width: int = WIDTH) -> str:
    text = " ".join(str(text).split())
    return text if len(text) <= width else text[:width - 3] + "..."


def seconds(x) -> str:
    if not is_num(x):
        return "n/a"
    s = float(x)
    if s < 120:
        return f"{num(s, 3)} s"
    return f"{num(s, 4)} s ({s / 60.0:.1f} min)"


def mm(x_m) -> str:
    return "n/a" if not is_num(x_m) else f"{num(float(x_m) * 1e3, 3)} mm"
