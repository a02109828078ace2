"""Library of candidate effects the base drape model lacks (issue: close the loop).

Each effect is one module: its energy terms, prior, residual signature, admissibility and report
text live on its ``Effect`` subclass. ``REGISTRY`` lists the effects the diagnosis considers; a new
effect is its module plus one entry there, and nothing in ``drapejax.diagnose`` names it.
"""

from ._base import CurvatureTerm, Effect
from .bending_friction import BendingFriction
from .bending_saturation import BendingSaturation
from .bias_asymmetry import BiasAsymmetry
from .clamp_hinge import ClampHinge
from .edge_curl import EdgeCurl
from .heavy_hem import HeavyHem
from .heterogeneity import Heterogeneity
from .off_centre import OffCentre
from .plastic_set import PlasticSet
from .self_contact import SelfContact

REGISTRY: dict[str, Effect] = {e.name: e for e in (
    EdgeCurl(),
    BiasAsymmetry(),
    PlasticSet(),
    HeavyHem(),
    OffCentre(),
    SelfContact(),
    Heterogeneity(),
    BendingSaturation(),
    ClampHinge(),
    BendingFriction(),
)}
"""Every candidate effect by name, each neutral at ``theta0()``. Its order is the order in which
the search ranks candidates of equal signature score."""


def candidate_effects() -> list[Effect]:
    """Every registered candidate effect (``REGISTRY``, in its order), each neutral at ``theta0()``."""
    return list(REGISTRY.values())


def registered(name: str) -> Effect | None:
    """The registered effect called ``name``, or None: how a result file's effect names, which
    carry no class, find their effect's hooks (the report's label and place)."""
    return REGISTRY.get(name)


__all__ = ["Effect", "CurvatureTerm", "EdgeCurl", "BiasAsymmetry", "PlasticSet", "HeavyHem", "OffCentre", "SelfContact",
           "Heterogeneity", "BendingSaturation", "ClampHinge", "BendingFriction", "candidate_effects", "registered",
           "REGISTRY"]
