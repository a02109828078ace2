"""Validation of the diagnosis's settings dataclasses (``Screen``, ``Rescale``, ``Identifiability``,
``BenchFit``), shared by all."""

from __future__ import annotations


def _at_least(settings, minimum: int, *names: str) -> None:
    """Raise a ValueError naming the first of the ``settings`` fields ``names`` below ``minimum``."""
    for name in names:
        if getattr(settings, name) < minimum:
            raise ValueError(f"{type(settings).__name__}.{name} must be at least {minimum}, "
                             f"got {getattr(settings, name)}")


def _positive(settings, *names: str) -> None:
    """Raise a ValueError naming the first of the ``settings`` fields ``names`` that is not above 0
    (NaN included)."""
    for name in names:
        if not getattr(settings, name) > 0:
            raise ValueError(f"{type(settings).__name__}.{name} must be positive, got {getattr(settings, name)}")


def _positive_with_one(settings, *names: str) -> None:
    """Raise a ValueError naming the first of the ``settings`` factor tuples ``names`` that is
    empty, has a factor ≤ 0 or lacks 1.0 (the scanned model's own value)."""
    for name in names:
        factors = getattr(settings, name)
        if not factors or min(factors) <= 0 or 1.0 not in factors:
            raise ValueError(f"{type(settings).__name__}.{name} must be positive and include 1.0, got {factors}")
