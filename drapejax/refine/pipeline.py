"""The whole estimate of one capture (``estimate``), as the CLI's ``estimate`` command runs it.

Load the capture, start from the network's estimate (``_initial_guess``), fit it through the
simulator on the fit mesh, and report in the ``drapejax estimate --json`` schema: values and
stds (``reported_params``), how the fitted drape matches the capture (``compare``), what the
drape identified, and warnings when the mesh or the data leave the values unreliable.
"""

from __future__ import annotations

import time
from pathlib import Path

import jax
import numpy as np
from jaxtyping import Float

from .. import observe
from ..energy import default_energies
from ..io import Measurement, load_measurement
from ..material import DIRECTIONS, PER_DENSITY_SUFFIX, FabricParams, from_per_density, to_per_density
from ..mesh import hierarchy_rim_spacing
from ..mesh_bias import correct, default_bias
from ..solve import SolverConfig, drape
from .converged import converged_refit
from .errors import RefineError
from .lm import fit
from .meshing import FIT_RIM_SPACING_M, FIT_SPACING_M, bending_length_m, fit_mesh, mesh_warnings
from .observables import EXTENT_M, measured_targets
from .presets import EXACT_CONFIG
from .quality import fit_quality, fit_warnings
from .uncertainty import identified


def reported_params(p: FabricParams, density_known: bool, sd_log: np.ndarray | None = None) -> tuple[dict, dict]:
    """(params, std) of ``p`` in the ``drapejax estimate`` schema: SI keys (``FabricParams.to_dict``),
    or k/ρ keys (``material.to_per_density``, no density) when the density is unknown; ``std`` is
    k1 × the log-space std ``sd_log`` per direction (warp, weft, bias), null for parameters not refined."""
    params = p.to_dict() if density_known else to_per_density(p)
    std = {}
    for name, val in params.items():
        std[name] = None
        if sd_log is not None and name.startswith("bend_k1_"):
            d = name.removeprefix("bend_k1_").removesuffix(PER_DENSITY_SUFFIX)
            std[name] = val * float(sd_log[DIRECTIONS.index(d)])
    return params, std


def _initial_guess(m: Measurement, buckling: bool = False) -> tuple[dict, str, dict | None]:
    """Network estimate (SI or density-normalised dict), its source name and the record of the
    membrane the capture's tensile readings set (None without any); ``buckling``: by the packaged
    models that go with the capped membrane (``InverseModel.for_measurement``)."""
    from ..inverse.estimate import InverseModel

    out = InverseModel.for_measurement(m, buckling=buckling).estimate_no_refine(m, mesh_bias=False)
    return out["params"], "network", out["membrane"]


def to_fabric(params: dict, density: float | None, nominal_density: float) -> FabricParams:
    """The fabric of an estimate's dict: SI keys when ``density`` is known, else per-density keys
    made absolute at ``nominal_density`` (``material.from_per_density``). ``estimate``'s start;
    public because the experiments start fits from estimates of models they choose."""
    if density is not None:
        return FabricParams.from_dict(params, source="initial estimate")
    return FabricParams.from_dict(from_per_density(params, nominal_density, source="initial estimate"),
                                  source="initial estimate")


def compare(x: Float[np.ndarray, "n 3"], faces, m: Measurement) -> dict:
    """Simulated rest mesh vs a measurement: DCs, fold counts, rotation/mirror-aligned IoU, scan distance (mm)."""
    targets = measured_targets(m)
    sil = observe.silhouette(np.asarray(x), np.asarray(faces), n=256, extent_m=EXTENT_M)
    dc_sim = observe.drape_coefficient(sil, EXTENT_M, specimen_radius_m=m.specimen_radius_m, test=m.test,
                                       disk_radius_m=m.disk_radius_m)
    folds = [observe.fold_count(observe.rim_profile(s, EXTENT_M)) for s in (sil, targets.silhouette)]
    iou = observe.aligned_iou(sil, targets.silhouette, mirror=True)[0]
    scan_mm = None
    if m.scan_vertices is not None:  # a point cloud is measured through its alpha-shape mesh
        sv, sf = ((np.asarray(m.scan_vertices, float), np.asarray(m.scan_faces)) if m.has_scan_mesh
                  else observe.point_cloud_mesh(m.scan_vertices))
        scan_mm = float(observe.scan_distance_mm(np.asarray(x), np.asarray(faces), sv, sf))
    return {"dc_measured": targets.dc, "dc_simulated": float(dc_sim), "iou": float(iou), "scan_mm": scan_mm,
            "folds_measured": int(folds[1]), "folds_simulated": int(folds[0])}


def estimate(folder_or_measurement: str | Path | Measurement, *, refine: bool = True,
             spacing_m: float = FIT_SPACING_M, rim_spacing_m: float | None = FIT_RIM_SPACING_M, seed: int = 0,
             max_steps: int = 8, nominal_density: float = 0.2, config: SolverConfig = EXACT_CONFIG,
             buckling: bool = False, converged_spacing_m: float | None = None, mesh_bias: bool = True,
             capped_start: bool | None = None) -> dict:
    """Network estimate refined through the simulator, in the ``drapejax estimate --json`` schema.

    ``config`` is the fit's solver (``EXACT_CONFIG``: exact Newton, every rest state at equilibrium).
    ``buckling`` fits with the membrane's compression capped at the element scale
    (``energy.Membrane``), which lets a soft fabric fold on the coarse fit mesh, and starts a scan
    from the 3DH models trained on such drapes (``InverseModel.for_measurement``).
    ``capped_start`` starts a scan from those 3DH models whatever ``buckling`` is (None: as
    ``buckling``); a fit started so is corrected only by a calibration made from that start
    (``MeshBias.applies``), which the packaged one is not.
    ``converged_spacing_m`` (a Cusick capture, with ``refine``): the fit then goes on on nested
    meshes down to this spacing (``converged.converged_refit``: the converged model, a few
    minutes more), and the reported values, stds, fit and mesh are that level's.
    ``mesh_bias`` (a refined fit on the default fit mesh without ``buckling``, no converged refit):
    the reported k1 and k2 are the fit mesh's divided by its calibrated stiffness bias at the fitted
    bending length (``mesh_bias.correct``: values for a converged simulator), their stds widened by
    the calibration's scatter; the fit mesh's own values stay in ``params_fit_mesh``.

    Returns:
        ``{"params", "std", "identified", "density_normalized", "fit": {"dc_measured",
        "dc_simulated", "iou", "scan_mm"}, "fit_quality", "status", "init", "spacing_m", "rim_spacing_m",
        "buckling", "converged", "membrane", "mesh_bias", "params_fit_mesh", "bending_length_mm", "warnings",
        "seconds"}`` (``mesh_bias``: null, or ``mesh_bias.correct``'s record; ``converged``: null, or the
        converged refit's ``spacing_m``, nested ``levels``, ``drape_status``, ``loss_coarse_model``,
        ``loss``, ``status`` and the coarse fit's ``params_coarse``); ``warnings`` lists reasons to distrust
        the estimate (first, when ``fit_quality`` is not ``within_floor``, that the fitted drape misses
        its own capture by more than two specimens of one fabric differ; ``mesh_warnings`` of the
        softer of the initial and the fitted parameters: a locked fit can come out too stiff; k1
        directions the drape hardly informed). ``fit_quality`` is ``quality.fit_quality`` of ``fit``
        (``dc_error``, ``iou``, their bounds, ``within_floor``, ``reasons``); ``status`` is the
        solver's alone and says nothing about how well the drape was reproduced.
        ``identified`` (null without refinement) is ``identified`` of the fit keyed by the k1
        names: ``combination_log`` (weights of the best-determined log-k1 combination),
        ``std_log`` (its data-only std) and ``data_share`` per direction.
        ``params``/``std`` hold k/ρ keys (``*_per_density``) when the density is unknown;
        ``std`` covers the fitted k1 (Laplace) and is null for parameters that are not refined
        (stretching, k2 ratio: prior values). ``membrane`` is null when the folder holds no tensile
        reading; otherwise the network read the drape at, and the fit held, the tensile stiffness α
        the readings imply (``tensile.membrane_of_captures``: its record, α per direction and its
        factor on the tag's or prior's). ``spacing_m``/``rim_spacing_m`` describe the fit
        mesh (``fit_mesh``: a square mesh is uniform): the drape is not mesh-converged, and on three real fabrics the
        default mesh's k1 came out 1.3× the uniform 5 mm fits' (``docs/results/2026-11-23-refine-real.md``).
    """
    t0 = time.perf_counter()
    converged = None
    m = folder_or_measurement if isinstance(folder_or_measurement, Measurement) else load_measurement(
        folder_or_measurement)
    if converged_spacing_m is not None and refine and m.test != "cusick":
        raise RefineError(f"estimate: converged_spacing_m needs a Cusick capture (nested meshes), not a {m.test} test")
    rho = m.areal_density_kg_m2
    capped_start = buckling if capped_start is None else capped_start
    guess, source, membrane = _initial_guess(m, capped_start)
    init = to_fabric(guess, rho, nominal_density)
    mesh = fit_mesh(m, spacing_m, rim_spacing_m)
    if refine:
        res = fit(m, init=init, spacing_m=spacing_m, max_steps=max_steps, seed=seed, mesh=mesh, config=config,
                  buckling=buckling)
        if converged_spacing_m is not None:
            coarse_params = res.params
            res, mesh, conv = converged_refit(m, res, init, spacing_m=converged_spacing_m, seed=seed, buckling=buckling)
            spacing_m, rim_spacing_m = converged_spacing_m, hierarchy_rim_spacing(converged_spacing_m)
            converged = {**conv, "loss": res.loss, "status": res.status,
                         "params_coarse": reported_params(coarse_params, rho is not None)[0]}
        p, x, status = res.params, res.x, res.status
        sd_log = np.sqrt(np.diag(res.cov))[:3]
        ident = identified(res.cov)
    else:
        p = init
        terms = default_energies(mesh.info.test, buckling=buckling)
        x = np.asarray(jax.jit(lambda q: drape(mesh, q, seed, terms=terms, config=config))(init).x)
        status, sd_log, ident = "not_refined", None, None
    params, std = reported_params(p, rho is not None, sd_log)
    params_fit_mesh, bias_record, ell_mm = None, None, bending_length_m(p) * 1e3
    bias = default_bias()
    if (mesh_bias and refine and converged is None and bias is not None
            and bias.applies(spacing_m, rim_spacing_m, buckling, capped_start)):
        params_fit_mesh = params
        params, std, bias_record = correct(params, std, ell_mm, bias)
        ell_mm /= bias_record["factor"] ** (1 / 3)
    fit_block = compare(x, np.asarray(mesh.faces), m)
    quality = fit_quality(fit_block)
    # first: the CLI's summary shows the first three warnings, and a poor fit outweighs the others
    warnings = fit_warnings(quality) + mesh_warnings(min(p, init, key=bending_length_m), spacing_m, buckling)
    if bias_record is not None and not bias_record["inside_calibration"]:
        lo, hi = bias_record["range_mm"]
        warnings.append(f"the fitted bending length {bias_record['bending_length_mm']:.1f} mm lies outside the "
                        f"{lo:.1f}-{hi:.1f} mm the fit mesh's bias was calibrated on; the nearest end's factor "
                        f"(÷{bias_record['factor']:.2f}) was used")
    if membrane is not None and "ignored" in membrane:
        warnings.append(f"tensile readings not used: {membrane['ignored']}")
    if m.test != "cusick":
        warnings.append(f"the network was trained on Cusick drapes: its start for a {m.test} specimen is an "
                        "extrapolation, and only the refinement fitted this drape")
    ident_block = None
    if ident is not None:
        names = [next(n for n in params if n.startswith(f"bend_k1_{d}")) for d in DIRECTIONS]
        ident_block = {"combination_log": dict(zip(names, ident["weights"].tolist())), "std_log": ident["std_log"],
                       "data_share": dict(zip(names, ident["data_share"].tolist()))}
        loose = [n for n, sh in zip(names, ident["data_share"]) if sh < 0.5]
        if loose:
            warnings.append(f"{', '.join(loose)}: the drape supplied under half of the precision, so these mostly "
                            "restate the network's direction ratios; the capture pins the log-k1 combination in "
                            "'identified' (std_log)")
    return {"params": params, "std": std, "identified": ident_block, "density_normalized": rho is None,
            "fit": {k: fit_block[k] for k in ("dc_measured", "dc_simulated", "iou", "scan_mm")},
            "fit_quality": quality, "status": status, "init": source, "spacing_m": spacing_m,
            "rim_spacing_m": rim_spacing_m, "buckling": buckling, "converged": converged, "membrane": membrane,
            "mesh_bias": bias_record, "params_fit_mesh": params_fit_mesh, "bending_length_mm": ell_mm,
            "warnings": warnings, "seconds": time.perf_counter() - t0}
