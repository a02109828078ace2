"""The fit carried onto the converged model: a two-grid fit of a Cusick capture.

The fit mesh (``meshing.FIT_SPACING_M``, 20 mm graded from 3 mm at the disc edge) is not
mesh-converged: its drape folds less finely than the fabric does, so the k1 it fits come out
stiffer than those of a converged drape that matches the same capture. A fit whose every
Levenberg–Marquardt step drops afresh on a 5 mm mesh would cost minutes per step. Here the
coarse fit finds the parameters' basin and a fold pattern cheaply; one nested-mesh drape
(``solve.drape_multilevel``, the drape ``drapejax simulate`` runs) carries its parameters onto the
finest level; and the fit goes on there from that rest state (``lm.fit`` with ``start``), each
step a warm-started static solve and implicit derivatives on the finest mesh. This is nested
iteration (Deuflhard 1996) applied to the fit as well as to the state: the coarse level supplies
the start, the fine level the answer, and the fine level's prior stays the coarse fit's (the
network's estimate), so the Laplace covariance is that of the converged model.
"""

from __future__ import annotations

import dataclasses

import jax
import numpy as np

from ..energy import default_energies
from ..io import Measurement
from ..material import FabricParams
from ..mesh import ClothMesh, cusick_hierarchy
from ..solve import (DEFAULT_FINEST_SPACING_M, FINE_CONFIG, STATUS_NAMES, SolverConfig, coarsest_spacing_m,
                     drape_multilevel)
from ..solve._reuse import Same, reuse
from .errors import RefineError
from .lm import FitResult, fit

CONVERGED_SPACING_M = DEFAULT_FINEST_SPACING_M
"""Finest level of the converged refit by default: ``drapejax simulate``'s default resolution for most
fabrics (``solve.DEFAULT_FINEST_SPACING_M``), whose drape coefficient is within a few thousandths of
the 2.5 mm drape's on the same fold pattern (``docs/results/2026-12-05-default-resolution.md``). The
refit does not refine it for a light, soft fabric as ``solve.finest_spacing_m`` does."""


def converged_hierarchy(m: Measurement, params: FabricParams, spacing_m: float = CONVERGED_SPACING_M):
    """The nested meshes of ``m``'s Cusick specimen, support disc and warp angle, finest level
    ``spacing_m``, coarsest as coarse as ``params``' folds allow (``solve.coarsest_spacing_m``)."""
    if m.test != "cusick":
        raise RefineError(f"the converged refit drapes on nested Cusick meshes; this capture is a {m.test} test")
    return cusick_hierarchy(spacing_m, coarsest_spacing_m=coarsest_spacing_m(params),
                            warp_angle_deg=m.warp_angle_deg or 0.0, radius_m=m.specimen_radius_m,
                            disk_radius_m=m.disk_radius_m)


def _nested_drape(meshes: tuple[ClothMesh, ...], prolongs, terms):
    """The jitted nested drape on these meshes (one compiled program per hierarchy and terms)."""
    return reuse(("converged_drape", Same(meshes[-1]), terms),
                 lambda: jax.jit(lambda p, s: drape_multilevel(meshes, prolongs, p, s, terms=terms)))


def converged_refit(m: Measurement, coarse: FitResult, init: FabricParams, *,
                    spacing_m: float = CONVERGED_SPACING_M, seed: int = 0, max_steps: int = 4,
                    config: SolverConfig = FINE_CONFIG, buckling: bool = False) -> tuple[FitResult, ClothMesh, dict]:
    """Continue ``coarse`` (a fit of ``m`` from ``init``) on the finest level of nested meshes.

    Args:
        m: the Cusick capture ``coarse`` fitted.
        coarse: its fit on the coarse mesh (``lm.fit``); θ starts at ``coarse.theta``.
        init: the coarse fit's initial parameters: θ is relative to them and the prior is centred
            on them.
        spacing_m: the finest level's interior spacing, m.
        seed: the nested drape's drop seed.
        max_steps: Levenberg–Marquardt steps on the finest level.
        config: the finest level's static solves (``solve.FINE_CONFIG``: the thresholded
            absolute-eigenvalue rule and 500 Newton iterations, as ``drape_multilevel``'s finer levels).
        buckling: the compression cap on every level (as the coarse fit's).

    Returns:
        (the fit on the finest level, that mesh, ``{"spacing_m", "levels", "drape_status",
        "loss_coarse_model"}``): the nested drape's levels (spacing, vertices, Newton iterations,
        status) and the loss of the coarse fit's parameters scored on the finest level (the fine
        fit's ``loss_start``), so the refit's gain is that of the converged model alone.

    Raises:
        RefineError: when ``m`` is not a Cusick capture.
    """
    meshes, prolongs = converged_hierarchy(m, coarse.params, spacing_m)
    terms = default_energies("cusick", buckling=buckling)
    multi = _nested_drape(meshes, prolongs, terms)(coarse.params, seed)
    start = dataclasses.replace(coarse, x=np.asarray(multi.finest.x))
    fine = fit(m, init=init, spacing_m=spacing_m, max_steps=max_steps, mesh=meshes[-1], start=start, config=config,
               buckling=buckling)
    info = {"spacing_m": spacing_m, "levels": multi.level_records(meshes),
            "drape_status": STATUS_NAMES[int(multi.finest.status)],
            "loss_coarse_model": fine.loss_start}
    return fine, meshes[-1], info


__all__ = ["converged_refit", "converged_hierarchy", "CONVERGED_SPACING_M"]
