"""Energy terms. Each physical effect is one small module; forces are ``-jax.grad``."""

from ._base import AbstractEnergy, normalize, safe_norm
from .bending import Bending, bending_density, curvature_tensor
from .bending_twopiece import TwoPieceBending
from .clamp import Clamp
from .contact import DiskContact, FloorContact, disk_sdf
from .gravity import Gravity
from .hourglass import HourglassControl
from .membrane import Membrane
from .shape_operator import CurvatureJumpControl, ShapeOperatorBending


def default_energies(test: str = "cusick", buckling: bool = False) -> tuple[AbstractEnergy, ...]:
    """The base model for a test: membrane, bending with hourglass control, gravity, clamp, and contact;
    ``buckling`` caps the membrane's compression at the element scale (``Membrane``)."""
    terms = (Membrane(buckling=buckling), Bending(), HourglassControl(), Gravity(), Clamp())
    if test in ("cusick", "square", "mesh"):
        terms = terms + (DiskContact(), FloorContact())
    return terms


def shape_operator_energies(test: str = "cusick", buckling: bool = False, jump: bool = True
                            ) -> tuple[AbstractEnergy, ...]:
    """``default_energies`` with the bending on per-triangle hinge shape operators
    (``ShapeOperatorBending``, a 6-vertex stencil) and their curvature-jump control (8 vertices)
    in place of the vertex fit and its hourglass control (22); the same constitutive law and
    parameters. ``jump=False`` leaves the jump control out (the cantilever then droops 4-6 % too far
    at any spacing; with it the folds of a coarse Cusick drape stiffen: see
    ``energy.shape_operator.CurvatureJumpControl``)."""
    swap = {Bending: ShapeOperatorBending(), HourglassControl: CurvatureJumpControl() if jump else None}
    return tuple(t for t in (swap.get(type(u), u) for u in default_energies(test, buckling)) if t is not None)


def coarse_level(terms) -> tuple[AbstractEnergy, ...]:
    """Each term as the coarsest level of a multilevel drape uses it (``AbstractEnergy.coarse_level``)."""
    return tuple(t.coarse_level() for t in terms)


def total_energy(terms, x, mesh, params):
    """Sum of all terms (J)."""
    return sum(t(x, mesh, params) for t in terms)


__all__ = ["AbstractEnergy", "Bending", "TwoPieceBending", "Clamp", "DiskContact", "FloorContact", "Gravity",
           "HourglassControl", "Membrane", "ShapeOperatorBending", "CurvatureJumpControl", "shape_operator_energies",
           "default_energies", "coarse_level", "total_energy", "bending_density", "curvature_tensor", "disk_sdf",
           "safe_norm", "normalize"]
