"""drapejax: differentiable cloth drape simulation and fabric parameter estimation in JAX.

Data flow: ``mesh`` (host-built topology) → ``material`` (parameter pytrees, SI units) →
``energy`` (one module per physical term) → ``solve`` (dynamic drop, static equilibrium,
implicit adjoint) → ``observe`` (renderers, descriptors, metrics) → ``inverse`` (prior,
networks) and ``refine`` (optimistix fits) → ``diagnose`` (residuals, effect search, reports).
``io`` reads and writes measurement folders; ``cli`` only parses arguments.
"""

from . import compile_cache
from ._lazy import lazy_exports

__version__ = "0.1.0"

_names, __getattr__, __dir__ = lazy_exports(__name__, {
    "material": ("FabricParams", "ParameterError", "example_params", "load_params"),
    "mesh": ("ClothMesh", "cusick_mesh", "from_trimesh", "specimen_mesh", "square_mesh", "strip_mesh"),
    "solve": ("DrapeResult", "SolverConfig", "drape", "drape_batch", "equilibrium", "quick_config", "static_solve"),
}, globals())
"""The top-level names are imported on first use (``_lazy``): ``import drapejax`` does not load the solver."""

__all__ = ["compile_cache", *_names]
