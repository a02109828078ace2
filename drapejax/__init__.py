"""drapejax: differentiable cloth drape simulation and fabric parameter estimation in JAX.

Data flow: ``mesh`` (host-built topology) → ``material`` (parameter pytrees, SI units) →
``energy`` (one module per physical term) → ``solve`` (dynamic drop, static equilibrium,
implicit adjoint) → ``observe`` (renderers, descriptors, metrics) → ``inverse`` (prior,
networks) and ``refine`` (optimistix fits) → ``diagnose`` (residuals, effect search, reports).
``io`` reads and writes measurement folders; ``cli`` only parses arguments.
"""

import importlib

from . import compile_cache

_EXPORTS = {
    "material": ("FabricParams", "ParameterError", "example_params", "load_params"),
    "mesh": ("ClothMesh", "cusick_mesh", "from_trimesh", "specimen_mesh", "square_mesh", "strip_mesh"),
    "solve": ("DrapeResult", "SolverConfig", "drape", "drape_batch", "equilibrium", "quick_config", "static_solve"),
}
"""Where each top-level name lives. They are imported on first use (PEP 562), so that a command which only
reads a measurement and runs a network does not pay for the solver's imports at start-up."""

_HOME = {name: module for module, names in _EXPORTS.items() for name in names}

__version__ = "0.1.0"

__all__ = ["compile_cache", *_HOME]


def __getattr__(name: str):
    if name in _HOME:
        value = getattr(importlib.import_module(f".{_HOME[name]}", __name__), name)
        globals()[name] = value
        return value
    try:
        return importlib.import_module(f".{name}", __name__)
    except ModuleNotFoundError as e:
        if e.name != f"{__name__}.{name}":
            raise
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}") from None


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
