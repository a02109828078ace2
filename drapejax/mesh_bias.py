"""The estimators' stiffness bias against converged drapes, calibrated, and its removal.

The fit mesh (20 mm graded to 3 mm on the disc edge, ``refine.fit_mesh``) is not mesh-converged:
where a fabric folds finely, its drape lies lower than the converged drape (``drapejax simulate``'s
nested meshes) at equal bending stiffness, so a fit on it reads k1 too stiff, the more so the
shorter the bending length (``docs/results/2026-12-05-converged-refit.md``). The packaged networks,
trained on coarse drapes, read a converged drape 1.4× to 4× too stiff. Fitting on a converged mesh
removes the fit's bias (``estimate --converged-mm``) but costs minutes per capture.

This module removes each estimator's bias on average instead, from a calibration of drapejax
against itself: captures made by ``drapejax simulate`` at its converged default for fabrics across
the 618-fabric table (Feng et al. 2022), fitted as ``drapejax estimate`` fits them and read by each
packaged network (``experiments/converged_fit.py --converged-mm 0``). Per estimator, the log ratio
of the estimated to the true overall rigidity is regressed on ``x = log(ℓ / ℓ_ref)``, ``ℓ`` the
estimated overall bending length, by a polynomial of the degree (0 to 2) that predicts left-out
fabrics best (``experiments/mesh_bias_fit.py``):

    log(k1_est / k1_true) = c0 + c1 x + c2 x²

The coefficients, the residual std (what one capture's fold state and the regression leave
unexplained) and the leave-one-out errors live in ``drapejax/data/mesh_bias.json``, keyed
"fit_mesh" or by the packaged checkpoint's file stem. ``correct`` divides every k1 and k2 by the
factor (k2/k1 ratios kept) and widens each k1 std in quadrature by the per-direction scatter: for
the refined fit, the maximum-likelihood scatter of each direction's corrected log k1 about the
truth beyond its Laplace std, with the factor made without that fabric (0.36 in log, against 0.17
for the overall rigidity, because one drape splits its rigidity between warp, weft and bias
loosely); for the networks, the residual std. Outside the
calibrated bending lengths the nearest end's factor is used, and the caller is told.

A calibration holds for the estimator it was made of: the fit's covers the default fit mesh, its
prior and start and its step budget together, so a fit on any other fit mesh, with the capped
membrane (``--buckling``) or continued on a converged mesh gets no correction, nor does a network
checkpoint not in the file.
"""

from __future__ import annotations

import functools
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .material import G

CALIBRATION = Path(__file__).resolve().parent / "data" / "mesh_bias.json"


@dataclass(frozen=True)
class MeshBias:
    """``log(k1_est / k1_true) = Σ coef[i] xⁱ``, ``x = log(ℓ / ℓ_ref)``, of one estimator (the fit on
    the mesh ``spacing_m``/``rim_spacing_m``, or a packaged network, whose mesh is its training
    drapes'), calibrated for bending lengths ``range_mm``; ``std_log``: the regression's residual std
    (of the overall rigidity); ``std_log_direction``: for a refined fit, the scatter of each
    direction's k1 that its Laplace std leaves out (None: ``std_log`` stands for it);
    ``capped_start``: a refined fit's start was the 3DH model trained on capped-membrane drapes
    (``refine.estimate``'s ``capped_start``), which lands on other values than the default start."""

    coef: tuple[float, ...]
    ref_mm: float
    range_mm: tuple[float, float]
    std_log: float
    spacing_m: float | None = None
    rim_spacing_m: float | None = None
    std_log_direction: float | None = None
    capped_start: bool = False

    @classmethod
    def load(cls, key: str = "fit_mesh", path: str | Path = CALIBRATION) -> MeshBias | None:
        """The calibration of estimator ``key`` ("fit_mesh", or a packaged checkpoint's file stem such
        as "inverse_2ds"); None where the file holds none for it."""
        d = json.loads(Path(path).read_text()).get(key)
        return None if d is None else cls.from_record(d)

    @classmethod
    def from_record(cls, d: dict) -> MeshBias:
        """One estimator's record of the calibration file (``experiments/mesh_bias_fit.py --write``)."""
        return cls(coef=tuple(float(c) for c in d["coef"]), ref_mm=float(d["ref_mm"]),
                   range_mm=(float(d["range_mm"][0]), float(d["range_mm"][1])), std_log=float(d["std_log"]),
                   spacing_m=d.get("spacing_m"), rim_spacing_m=d.get("rim_spacing_m"),
                   std_log_direction=d.get("std_log_direction"), capped_start=bool(d.get("capped_start", False)))

    @property
    def widen_log(self) -> float:
        """What each direction's k1 std is widened by in quadrature (log): the per-direction scatter
        where calibrated, else the overall residual std."""
        return self.std_log if self.std_log_direction is None else self.std_log_direction

    def applies(self, spacing_m: float, rim_spacing_m: float | None, buckling: bool,
                capped_start: bool = False) -> bool:
        """Whether a fit on this mesh, from this start, is the calibrated one."""
        return (not buckling and capped_start == self.capped_start
                and None not in (rim_spacing_m, self.spacing_m, self.rim_spacing_m)
                and bool(np.isclose(spacing_m, self.spacing_m)) and bool(np.isclose(rim_spacing_m, self.rim_spacing_m)))

    def log_factor(self, bending_length_mm: float) -> tuple[float, bool]:
        """log(k1_est / k1_true) at the estimated bending length, and whether that length lies inside
        the calibrated range (outside it the nearest end's factor is returned)."""
        lo, hi = self.range_mm
        inside = lo <= bending_length_mm <= hi
        ell = float(np.clip(bending_length_mm, lo, hi))
        x = np.log(ell / self.ref_mm)
        return float(sum(c * x**i for i, c in enumerate(self.coef))), inside


def overall_k1(params: dict) -> float:
    """Geometric mean of k1 over warp, weft and bias of a reported parameter dict (SI keys, N·m, or
    per-density keys, k1/ρ)."""
    return float(np.exp(np.mean(np.log([v for n, v in params.items() if n.startswith("bend_k1_")]))))


def bending_length_mm(params: dict) -> float:
    """Overall bending length (k̄1 / (ρ g))^(1/3) of a reported parameter dict, mm, k̄1 = ``overall_k1``:
    SI keys with ``density``, or per-density keys (k1/ρ, no ``density`` key)."""
    return float((overall_k1(params) / params.get("density", 1.0) / G) ** (1 / 3) * 1e3)


@functools.cache
def default_bias(key: str = "fit_mesh") -> MeshBias | None:
    """The packaged calibration of estimator ``key`` (``MeshBias.load``)."""
    return MeshBias.load(key)


def correct(params: dict, std: dict | None, bending_length_mm: float, bias: MeshBias) -> tuple[dict, dict | None, dict]:
    """(params, std, record) with k1 and k2 divided by the estimator's factor at ``bending_length_mm``
    (the estimated overall bending length) and each k1 std widened in quadrature by the calibration's
    per-direction scatter (``std_log_direction``, else ``std_log``). Works on SI and per-density keys
    alike. ``record``: the factor, its log std, the per-direction scatter, the bending length it was
    read at and whether that lay inside the calibrated range."""
    log_f, inside = bias.log_factor(bending_length_mm)
    f = float(np.exp(log_f))
    out = dict(params)
    out_std = None if std is None else dict(std)
    for name, val in params.items():
        if name.startswith(("bend_k1_", "bend_k2_")):
            out[name] = val / f
        if out_std is not None and name.startswith("bend_k1_") and std.get(name) is not None:
            sd_log = std[name] / val
            out_std[name] = out[name] * float(np.hypot(sd_log, bias.widen_log))
    record = {"factor": f, "std_log": bias.std_log, "std_log_direction": bias.widen_log,
              "bending_length_mm": bending_length_mm,
              "inside_calibration": inside, "range_mm": list(bias.range_mm)}
    return out, out_std, record
