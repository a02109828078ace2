"""The settings that every fit, drop and refit of one specimen shares (``FitContext``)."""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

from ..material import FabricParams
from ..mesh import ClothMesh
from ..solve import SolverConfig
from .presets import EXACT_CONFIG

if TYPE_CHECKING:
    from ..diagnose.residuals import NoiseFloor


@dataclasses.dataclass(frozen=True, eq=False)
class FitContext:
    """The settings of one fit that every problem built on it must share, as one object.

    A diagnosis fits a baseline and then scans its scale, screens, confirms, validates and refits
    effects on top of it; every one of those problems has to be posed on the same mesh, from the
    same start, with the same solver and base membrane, or two models would differ by more than
    their physics. The entry point (``diagnose``, ``diagnose.select.search``) builds this once and
    passes it down whole, so the settings stay equal by construction. Frozen; compared by
    identity (the mesh and fabric hold arrays).

    Attributes:
        init: the fabric the fits start from and the prior mean of every refit (θ = 0).
        mesh: the simulation mesh of every fit and drop.
        spacing_m: its spacing, m.
        config: the solver of every drop, static solve and refit (default ``EXACT_CONFIG``, the
            diagnosis's ``MODEL_CONFIG``).
        buckling: the base membrane caps compression at the element scale (``energy.Membrane``).
        max_steps: Levenberg–Marquardt steps per fit or refit.
        noise_floor: the capture-to-capture floor of the errors that models are scored in
            (``diagnose.NoiseFloor``); None where nothing is scored against one (a fit alone).
    """

    init: FabricParams
    mesh: ClothMesh
    spacing_m: float
    config: SolverConfig = EXACT_CONFIG
    buckling: bool = False
    max_steps: int = 8
    noise_floor: NoiseFloor | None = None

    def fit_keywords(self) -> dict:
        """The keywords of ``fit`` (and of the diagnosis's refits built on it) that this context sets."""
        return dict(init=self.init, spacing_m=self.spacing_m, mesh=self.mesh, max_steps=self.max_steps,
                    config=self.config, buckling=self.buckling)

    def problem_keywords(self) -> dict:
        """The keywords of ``Problem`` (and of the diagnosis's ``effect_problem``) that this context sets."""
        return dict(init=self.init, mesh=self.mesh, spacing_m=self.spacing_m, config=self.config,
                    buckling=self.buckling)


__all__ = ["FitContext"]
