"""Conversions between SI and the units of fabric-testing tools (units-and-ranges.md).

Every material quantity inside drapejax is SI: bending rigidity per width in N·m, the
quadratic bending coefficient in N·m², stretch and shear stiffness per width in N/m, areal
density in kg/m². This module is the one place where the units of CLO3D, KES-F, FAST,
BS 3356 / ASTM D1388 and the 618-fabric bending file are turned into SI and back.

Units defined through a weight (gram-force, the milligram of a BS 3356 flexural rigidity)
use standard gravity 9.80665 m/s², the definition of the gram-force; the spec table rounds
the resulting factors to 9.807e-5 and 9.807e-8. Physical helpers (bending length,
cantilever rigidity) use the simulator's gravity ``drapejax.material.G``.
"""

from __future__ import annotations

import csv
import dataclasses
import math
import os
import re
from pathlib import Path

import numpy as np
from jaxtyping import ArrayLike, Float

from .material import G

STANDARD_GRAVITY = 9.80665
"""Standard gravity, m/s²: 1 gf = 1e-3 kg × STANDARD_GRAVITY (exact by definition)."""

CANTILEVER_GAMMA = 8.004
"""Gravito-bending number ρ g L³ / k1 at which a heavy elastica's tip chord reaches 41.5°.

The ASTM D1388 / BS 3356 cantilever test slides the strip out until its tip touches the
41.5° line; the exact heavy-elastica solution puts that at Γ = 8.004 (units-and-ranges.md),
i.e. bending length c = overhang / 2 to 0.02%."""


@dataclasses.dataclass(frozen=True)
class Unit:
    """A non-SI unit: ``scale`` is the SI value of 1 unit, in ``si``."""

    scale: float
    si: str
    quantity: str


UNITS: dict[str, Unit] = {
    "N*m": Unit(1.0, "N*m", "bending rigidity per width k1 (SI)"),
    "N*m^2": Unit(1.0, "N*m^2", "quadratic bending coefficient k2 (SI)"),
    "N/m": Unit(1.0, "N/m", "stretch or shear stiffness per width (SI)"),
    "kg/m^2": Unit(1.0, "kg/m^2", "areal density (SI)"),
    "g*mm^2/s^2": Unit(1e-9, "N*m", "CLO3D bending stiffness"),
    "gf*cm^2/cm": Unit(1e-3 * STANDARD_GRAVITY * 1e-2, "N*m", "KES-F bending rigidity B"),
    "mg*cm": Unit(1e-6 * STANDARD_GRAVITY * 1e-2, "N*m",
                  "BS 3356 / ASTM D1388 flexural rigidity G = W c^3"),
    "uN*m": Unit(1e-6, "N*m", "FAST bending rigidity"),
    "g/s^2": Unit(1e-3, "N/m", "CLO3D stretch and shear stiffness"),
    "g/m^2": Unit(1e-3, "kg/m^2", "areal density (gsm)"),
    # 1 dyn·cm²/cm = 1e-5 N × 1e-4 m² / 1e-2 m; 1 mg/cm² = 1e-6 kg / 1e-4 m².
    "dyn*cm^2/cm": Unit(1e-7, "N*m", "CGS bending rigidity per width (Browzwear VStitcher Bend)"),
    "mg/cm^2": Unit(1e-2, "kg/m^2", "KES-F fabric weight W"),
    "gf/cm/deg": Unit(1e-3 * STANDARD_GRAVITY / 1e-2 * 180.0 / math.pi, "N/m",
                      "KES-F shear stiffness G: force per width per degree of shear angle"),
    "fabrics618_linear": Unit(1e-9, "N*m", "linear columns of fabrics_618_bending.csv (k1)"),
    "fabrics618_nonlinear": Unit(1e-12, "N*m^2",
                                 "nonlinear columns of fabrics_618_bending.csv (k2)"),
}
"""Named units. Lookups also accept the typographic spellings (µ, ·, ², spaces) and ALIASES."""

ALIASES: dict[str, str] = {
    "gsm": "g/m^2",
    "clo_bending": "g*mm^2/s^2",
    "clo_stretch": "g/s^2",
    "kes_bending": "gf*cm^2/cm",
    "bs3356": "mg*cm",
    "astm_d1388": "mg*cm",
    "fast": "uN*m",
}

_SPELLINGS = str.maketrans({"·": "*", "⋅": "*", "×": "*", "µ": "u", "μ": "u", "²": "^2"})


def get_unit(name: str) -> Unit:
    """Look up a unit by name; raises ValueError naming the unit and the known ones."""
    if not isinstance(name, str):
        raise ValueError(f"unit must be a string, got {name!r}")
    key = re.sub(r"\s+", "*", re.sub(r"\s*([*/^])\s*", r"\1", name.translate(_SPELLINGS).strip()))
    key = ALIASES.get(key.lower(), key)
    if key not in UNITS:
        raise ValueError(f"unknown unit {name!r}; known units: {sorted(UNITS)} "
                         f"and aliases {sorted(ALIASES)}")
    return UNITS[key]


def _array(value):
    return np.asarray(value, float) if isinstance(value, (list, tuple)) else value


def to_si(value: ArrayLike, unit: str):
    """Convert ``value`` given in ``unit`` to SI (``get_unit(unit).si``); keeps array type."""
    return _array(value) * get_unit(unit).scale


def from_si(value_si: ArrayLike, unit: str):
    """Convert an SI value to ``unit``; keeps array type."""
    return _array(value_si) / get_unit(unit).scale


def bending_length_m(k1: ArrayLike, density: ArrayLike):
    """Peirce bending length c = (k1 / (ρ g))^(1/3), m.

    Args:
        k1: bending rigidity per width, N·m.
        density: areal density ρ, kg/m².
    """
    return (k1 / (density * G)) ** (1.0 / 3.0)


def cantilever_k1_from_overhang(overhang_m: ArrayLike, density: ArrayLike):
    """Bending rigidity (N·m) from the 41.5° cantilever test: k1 = ρ g L³ / 8.004.

    Args:
        overhang_m: strip length L beyond the platform edge when the tip meets the 41.5°
            line, m.
        density: areal density ρ, kg/m².
    """
    return density * G * overhang_m**3 / CANTILEVER_GAMMA


FABRICS_618_COLUMNS = {
    "density": ("density", "kg/m^2"),
    "linear warp": ("k1_warp", "fabrics618_linear"),
    "linear weft": ("k1_weft", "fabrics618_linear"),
    "linear diag": ("k1_bias", "fabrics618_linear"),
    "nonlinear warp": ("k2_warp", "fabrics618_nonlinear"),
    "nonlinear weft": ("k2_weft", "fabrics618_nonlinear"),
    "nonlinear diag": ("k2_bias", "fabrics618_nonlinear"),
}
"""Header name in ``fabrics_618_bending.csv`` (before the ``[unit]``) -> (key, unit)."""


def load_fabrics_618(path: str | os.PathLike) -> dict[str, Float[np.ndarray, " n"]]:
    """Read the 618-fabric bending file (Feng et al. 2022) into SI arrays.

    Returns a dict with ``density`` (kg/m²), ``k1_warp``, ``k1_weft``, ``k1_bias`` (N·m) and
    ``k2_warp``, ``k2_weft``, ``k2_bias`` (N·m², moment per width M = k1 κ + k2 κ²). The
    file's "diag" columns are the bias direction.

    Raises:
        ValueError: naming the file and the column or line that is missing or malformed.
    """
    path = Path(path)
    try:
        with path.open(newline="") as f:
            rows = list(csv.reader(f))
    except (OSError, UnicodeDecodeError) as e:
        raise ValueError(f"{path}: cannot read the 618-fabric bending file ({e})") from None
    if not rows:
        raise ValueError(f"{path}: empty file, expected a header line")
    names = [re.sub(r"\s+", " ", h.split("[", 1)[0]).strip().lower() for h in rows[0]]
    index = {}
    for name in FABRICS_618_COLUMNS:
        if names.count(name) != 1:
            raise ValueError(f"{path}: header must contain exactly one column '{name}', "
                             f"found columns {rows[0]}")
        index[name] = names.index(name)
    body = [(i, r) for i, r in enumerate(rows[1:], start=2) if any(c.strip() for c in r)]
    values = np.empty((len(body), len(FABRICS_618_COLUMNS)))
    for j, (line, r) in enumerate(body):
        for k, name in enumerate(FABRICS_618_COLUMNS):
            try:
                values[j, k] = float(r[index[name]])
            except (IndexError, ValueError):
                raise ValueError(f"{path}: line {line}: column '{name}' is missing or not "
                                 f"a number") from None
    if not np.all(np.isfinite(values)):
        line, k = np.argwhere(~np.isfinite(values))[0]
        raise ValueError(f"{path}: line {body[line][0]}: column "
                         f"'{list(FABRICS_618_COLUMNS)[k]}' is not finite")
    return {key: to_si(values[:, k], unit) for k, (key, unit) in enumerate(FABRICS_618_COLUMNS.values())}


__all__ = [
    "STANDARD_GRAVITY", "CANTILEVER_GAMMA", "Unit", "UNITS", "ALIASES", "get_unit", "to_si",
    "from_si", "bending_length_m", "cantilever_k1_from_overhang", "FABRICS_618_COLUMNS",
    "load_fabrics_618",
]
