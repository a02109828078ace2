"""Solver presets (``SOLVERS``): how a fit's drops and warm-started static solves run.

Beside the solver because modules that only choose a solver need nothing of the fit: the
virtual lab drops its synthetic captures with ``EXACT_CONFIG``, the diagnosis's model is that
solver too, and the CLI offers ``SOLVERS`` by name (``drapejax.refine`` re-exports all three).
"""

from __future__ import annotations

from .drop import quick_config
from .linear import Direct

CONTINUATION_CONFIG = quick_config(exact_step_hessian=False, exact_static_hessian=False, linear_solver=Direct())
"""Solver of ``fit`` by default: projected Newton only. Its warm-started static solves lag
behind θ (after 200 iterations most are not yet at equilibrium), and the lag keeps the
continuation on one fold pattern. With exact steps the 25 mm "mid" fit of all k1 ×2
(``tests/test_refine.py``) stalls at ½χ² 9.4: on the line to the truth the loss stays at
9.2-9.6 until the drape changes fold pattern 90 % of the way, and the truth then scores 7.5.
A direct host solve on every backend: a fit drapes one member at a time, where the matrix-free
CG path ("auto" on a GPU) only adds inexact steps (it stops short of equilibrium on a thin strip, see
``validate``)."""
EXACT_CONFIG = quick_config(linear_solver=Direct(shifted=True))
"""Exact Newton wherever the Hessian is positive definite (shifted steps where it is not): every
rest state at equilibrium, and 4-7x faster than ``CONTINUATION_CONFIG`` (a warm-started static
solve in 9-24 iterations against 200 unconverged ones); ``estimate``'s default
(``docs/results/2026-11-23-refine-real.md``)."""
SOLVERS = {"continuation": CONTINUATION_CONFIG, "exact": EXACT_CONFIG}

__all__ = ["CONTINUATION_CONFIG", "EXACT_CONFIG", "SOLVERS"]
