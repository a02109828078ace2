"""Library of candidate effects the base drape model lacks (issue: close the loop)."""

from ._base import CurvatureTerm, Effect
from .bending_saturation import BendingSaturation
from .bias_asymmetry import BiasAsymmetry
from .clamp_hinge import ClampHinge
from .edge_curl import EdgeCurl
from .heavy_hem import HeavyHem
from .heterogeneity import Heterogeneity
from .off_centre import OffCentre
from .plastic_set import PlasticSet
from .self_contact import SelfContact


def candidate_effects() -> list[Effect]:
    """Every candidate effect, each neutral at ``theta0()``."""
    return [EdgeCurl(), BiasAsymmetry(), PlasticSet(), HeavyHem(), OffCentre(), SelfContact(), Heterogeneity(),
            BendingSaturation(), ClampHinge()]


REGISTRY = {e.name: e for e in candidate_effects()}

__all__ = ["Effect", "CurvatureTerm", "EdgeCurl", "BiasAsymmetry", "PlasticSet", "HeavyHem", "OffCentre", "SelfContact",
           "Heterogeneity", "BendingSaturation", "ClampHinge", "candidate_effects", "REGISTRY"]
