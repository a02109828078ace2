"""Solvers: dynamic drop, static equilibrium, implicit derivatives, batched runs, the linear solver
types (``linear``) and the solver presets (``presets``). ``term_hessian_coo`` (one energy term's
Hessian as sparse triplets) is re-exported from the private ``_sparse`` for the experiments."""

from ._newton import NewtonConfig
from ._sparse import term_hessian_coo
from .batch import drape_batch
from .drop import (AT_REST, INVALID_PARAMS, NONFINITE, NOT_EQUILIBRIUM, STATUS_NAMES, STEP_BUDGET, DrapeResult,
                   SolverConfig, drape, perturbation, quick_config, static_solve)
from .equilibrium import equilibrium
from .linear import CG, AbstractNewtonSolve, Direct
from .multilevel import (DEFAULT_FINEST_SPACING_M, FINE_ABSOLUTE_ABOVE, FINE_CONFIG, LOCKING_NUMBER_MAX,
                         MultilevelResult, coarsest_spacing_m, drape_multilevel, finest_spacing_m, locking_number,
                         polished_status)
from .presets import CONTINUATION_CONFIG, EXACT_CONFIG, SOLVERS

__all__ = ["NewtonConfig", "SolverConfig", "DrapeResult", "drape", "drape_batch", "static_solve", "equilibrium",
           "quick_config", "perturbation", "drape_multilevel", "MultilevelResult", "coarsest_spacing_m",
           "FINE_ABSOLUTE_ABOVE", "FINE_CONFIG", "polished_status", "finest_spacing_m", "locking_number",
           "DEFAULT_FINEST_SPACING_M", "LOCKING_NUMBER_MAX",
           "STATUS_NAMES", "AT_REST", "STEP_BUDGET", "NONFINITE", "INVALID_PARAMS",
           "NOT_EQUILIBRIUM", "AbstractNewtonSolve", "Direct", "CG", "CONTINUATION_CONFIG", "EXACT_CONFIG",
           "SOLVERS", "term_hessian_coo"]
