"""The fit's solver presets, kept importable here: they live in ``drapejax.solve.presets``."""

from __future__ import annotations

from ..solve.presets import CONTINUATION_CONFIG, EXACT_CONFIG, SOLVERS

__all__ = ["CONTINUATION_CONFIG", "EXACT_CONFIG", "SOLVERS"]
