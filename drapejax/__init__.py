"""drapejax: differentiable cloth drape simulation and fabric parameter estimation in JAX."""

from .material import FabricParams, ParameterError, example_params, load_params
from .mesh import ClothMesh, cusick_mesh, square_mesh, strip_mesh, from_trimesh, specimen_mesh

__version__ = "0.1.0"
