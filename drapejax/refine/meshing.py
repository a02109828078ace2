"""The fit's simulation mesh: its default (``FIT_SPACING_M``, ``FIT_RIM_SPACING_M``), how it is
built for a capture (``fit_mesh``) and when it is too coarse for the fabric (``mesh_warnings``).

A mesh a fit can afford does not converge the drape, so the fitted values belong to the mesh
they were fitted on, and a soft fabric locks on a coarse one.
"""

from __future__ import annotations

from ..io import Measurement
from ..material import FabricParams, bending_length
from ..mesh import ClothMesh, cusick_mesh, square_mesh

FIT_SPACING_M = 0.02
FIT_RIM_SPACING_M = 0.003
"""Default fit mesh of ``estimate`` and ``diagnose``: 20 mm, its rings graded from 3 mm at the
disc edge (487 vertices). The uniform 20 mm mesh droops too far at the disc edge and its fits
came out 2.0-2.5x stiffer than at 5 mm on three real fabrics; this one 1.3x, in about the same
time as uniform 10 mm (``docs/results/2026-11-23-refine-real.md``)."""

MIN_BENDING_LENGTH_M = 0.016
"""Below this bending length (``bending_length_m``) the fit meshes coarser than 5 mm lock: the
skirt cannot form the fabric's short folds and stands out, so fitted k1 are unreliable (a
"light" capture simulated at 5 mm was fitted 1.5-1.7x too stiff, on another fold branch). On the
default fit mesh the drape coefficient against uniform 5 mm was −0.03 at 17.9 mm ("mid"), +0.05
at 15.1 mm, +0.20 at 12.7 mm ("mid" with k1 × 0.6 and × 0.35) and +0.33 at 13.1 mm ("light");
10 mm graded from 2 mm locked too ("light": +0.28). ``estimate`` warns below it
(``experiments/cusick_convergence.py --k-scale``)."""

MIN_BENDING_LENGTH_BUCKLING_M = 0.0125
"""With the compression cap (``buckling``) the default fit mesh folds like uniform 5 mm down to
the softest fabrics checked, "light" (13.1 mm) and "mid" with k1 × 0.35 (12.7 mm); ``estimate``
warns below this."""


def fit_mesh(m: Measurement, spacing_m: float, rim_spacing_m: float | None = None) -> ClothMesh:
    """The simulation mesh of a measurement's specimen and support disc at its warp angle (0 when
    not recorded): ``cusick_mesh`` with its rings graded from ``rim_spacing_m`` at the disc edge,
    or a uniform ``square_mesh``."""
    angle = m.warp_angle_deg or 0.0
    if m.test == "square":
        return square_mesh(spacing_m, half_side_m=m.specimen_radius_m, disk_radius_m=m.disk_radius_m,
                           warp_angle_deg=angle)
    return cusick_mesh(spacing_m, radius_m=m.specimen_radius_m, disk_radius_m=m.disk_radius_m, warp_angle_deg=angle,
                       rim_spacing_m=rim_spacing_m)


def bending_length_m(params: FabricParams) -> float:
    """``material.bending_length(params, "mean")`` as a float, m: depends on k/ρ only."""
    return float(bending_length(params, "mean"))


def mesh_warnings(params: FabricParams, spacing_m: float, buckling: bool = False) -> list[str]:
    """Warnings about the fit mesh for these parameters (see ``MIN_BENDING_LENGTH_M``); with
    ``buckling`` (``energy.Membrane``) only below ``MIN_BENDING_LENGTH_BUCKLING_M``."""
    lb = bending_length_m(params)
    limit = MIN_BENDING_LENGTH_BUCKLING_M if buckling else MIN_BENDING_LENGTH_M
    if spacing_m <= 0.005 or lb >= limit:
        return []
    refit = "on a 5 mm mesh (spacing_m=0.005, CLI --spacing-mm 5; slow)"
    if buckling:
        return [f"bending length {lb * 1e3:.1f} mm is below {limit * 1e3:g} mm: the compression cap that lets soft "
                f"fabrics fold on a coarse mesh was not checked on a fabric this soft; refit {refit}"]
    return [f"bending length {lb * 1e3:.1f} mm is below {limit * 1e3:.0f} mm: on a fit mesh coarser than 5 mm (here "
            f"{spacing_m * 1e3:g} mm) such a soft fabric cannot form its folds, so the fitted k1 are unreliable; fit "
            f"with the compression cap (buckling=True, CLI --buckling) or {refit}"]
