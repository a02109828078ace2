"""drapejax: differentiable cloth drape simulation and fabric parameter estimation in JAX.

Data flow: ``mesh`` (host-built topology) → ``material`` (parameter pytrees, SI units) →
``energy`` (one module per physical term) → ``solve`` (dynamic drop, static equilibrium,
implicit adjoint) → ``observe`` (renderers, descriptors, metrics) → ``inverse`` (prior,
networks) and ``refine`` (optimistix fits) → ``diagnose`` (residuals, effect search, reports).
``io`` reads and writes measurement folders; ``cli`` only parses arguments.
"""

from . import compile_cache
from .material import FabricParams, ParameterError, example_params, load_params
from .mesh import ClothMesh, cusick_mesh, from_trimesh, specimen_mesh, square_mesh, strip_mesh
from .solve import DrapeResult, SolverConfig, drape, drape_batch, equilibrium, quick_config, static_solve

__version__ = "0.1.0"

__all__ = ["compile_cache", "FabricParams", "ParameterError", "example_params", "load_params", "ClothMesh",
           "cusick_mesh", "from_trimesh", "specimen_mesh", "square_mesh", "strip_mesh", "DrapeResult", "SolverConfig",
           "drape", "drape_batch", "equilibrium", "quick_config", "static_solve"]
