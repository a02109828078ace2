"""Progress bars for the long Python-level loops of ``estimate`` and ``diagnose``.

A fit or a diagnosis runs for minutes, most of it in drops and refits that the library loops
over in Python (Levenberg–Marquardt iterations, the screen's fresh drops, confirmation and
validation drops, scans of a scale or a strength). ``bar`` wraps such a loop in a
``tqdm.auto.tqdm`` on stderr, so that the command line shows where the time goes while stdout
keeps only the result (``--json`` stays machine-readable).

A bar shows only when stderr is a terminal (tqdm's ``disable=None``), so library calls from
scripts, pipes and tests stay quiet and the command line needs no option of its own. The
environment variable ``DRAPEJAX_PROGRESS`` overrides that: ``1`` forces bars on (a log file
of a batch job, say), ``0`` forces them off; any other value, or none, leaves it to the terminal.

A bar only counts and reports values the loop has already computed, so it changes neither
results nor the order of computation; loops inside jitted code (the drop's own solver
iterations) have none. Bars opened inside another bar's loop are cleared when they end
(``leave=None``: only the outermost bar stays on screen).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Iterable

from tqdm.auto import tqdm

ENV_VAR = "DRAPEJAX_PROGRESS"
"""Environment variable that forces bars on (``1``) or off (``0``)."""


def _disable() -> bool | None:
    """tqdm's ``disable`` from ``DRAPEJAX_PROGRESS``: False (on), True (off) or None (on a terminal)."""
    flag = os.environ.get(ENV_VAR, "").strip()
    return {"1": False, "0": True}.get(flag)


def bar(iterable: Iterable | None = None, *, total: int | None = None, desc: str, **kwargs) -> tqdm:
    """A ``tqdm`` bar on stderr over ``iterable`` (or updated by hand up to ``total``), labelled ``desc``.

    Shown on a terminal or with ``DRAPEJAX_PROGRESS=1``, silent otherwise or with ``=0`` (module
    docstring). ``kwargs`` go to ``tqdm`` (``unit``, say). A disabled bar still iterates,
    updates and takes postfixes, as no-ops, so callers need no branch of their own.
    """
    kwargs.setdefault("leave", None)
    return tqdm(iterable, total=total, desc=desc, file=sys.stderr, disable=_disable(), **kwargs)


__all__ = ["bar", "ENV_VAR"]
