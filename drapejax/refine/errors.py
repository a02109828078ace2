"""The refinement's error: a measurement or argument the fit cannot use (``RefineError``).

In a module of its own so that every stage of the refinement (observables, prior, fit,
uncertainty) raises the same error without importing the others.
"""

from __future__ import annotations


class RefineError(ValueError):
    """A measurement or argument the refinement cannot use; the message names it."""
