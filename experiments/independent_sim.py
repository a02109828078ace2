"""Estimation on drapes made by an independent simulator: Newton's SolverStyle3D (NVIDIA warp).

Every other synthetic check of the estimator uses drapejax's own simulator for the data, so a
shared modelling error cannot show there. Here each truth is draped in Style3D instead
(``drapejax.bench.newton_peer``: projective-dynamics implicit Euler, Bergou hinge bending
calibrated to the truth's strip rigidities, contact with a support cylinder and a ground plane),
observed like a capture (silhouette, height map, scan) and estimated by ``drapejax.refine.estimate``
(the packaged inverse model, then refinement) exactly as ``drapejax estimate DIR`` does. Style3D
bends linearly and stretches without stiffening, so the truths are linear: k2 = 0 and β = 0.

Per case the script reports the simulator gap (drapejax's own drop of the truth on the Newton
mesh against the Style3D drape: DC, IoU, scan distance) next to the estimation error (k1 ratio
estimated / truth per direction: the packaged 2DS network alone, the packaged 3DH scan model that
``InverseModel.for_measurement`` picks alone (the oriented one, since these captures record their
warp angle; it is also the refinement's start), the 3DH model trained on capped-membrane drapes
that ``drapejax estimate --no-refine`` reads a scan with (``InverseModel.amortised_checkpoint_for``),
and refined; each corrected for its calibrated stiffness bias against converged drapes,
``drapejax.mesh_bias``, and uncorrected), so an error can be told apart from the two simulators
disagreeing about the same fabric. ``--no-refine`` stops after the amortised estimates.

``--diagnose`` then runs ``drapejax diagnose`` on each fabric's captures. Nothing is hidden in
them, so what the loop selects, if anything, stands for a way Style3D's drape differs from
drapejax's model: the effect no list declared.

``--hidden off_centre=0.013,0`` or ``--hidden heavy_hem=2`` makes a setup effect inside the
Style3D scene instead (``drapejax.bench.newton_peer.hidden_effect_scene``: a specimen meshed off
the support's centre, or a hem band of heavier vertices), and ``--diagnose-only`` runs the loop on
those captures alone (no per-capture estimates, no simulator gap): is the effect found on drapes
drapejax did not make? ``--bench`` adds bench readings of the fabric to every capture folder.

Usage: python -m experiments.independent_sim [--fabrics light,mid,heavy] [--prior N]
       [--captures 2] [--spacing-mm 7] [--converged-mm 5] [--no-gap] [--out OUT.jsonl]
       [--workdir DIR [--reuse]] [--diagnose | --diagnose-only | --no-refine]
       [--hidden NAME=THETA] [--candidates A,B] [--max-effects N] [--no-rescale] [--k-widen N]
       [--bench TEST:DIRECTION]
Needs ``pip install 'drapejax[newton]'``.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
import tempfile
import time
from pathlib import Path

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

from drapejax import refine, virtual_lab  # noqa: E402
from drapejax.bench.newton_peer import SCENE_EFFECTS, hidden_effect_scene, newton_rest_state  # noqa: E402
from drapejax.diagnose import Screen, recovery  # noqa: E402
from drapejax.effects import REGISTRY  # noqa: E402
from drapejax.inverse.estimate import InverseModel  # noqa: E402
from drapejax.inverse.prior import default_prior  # noqa: E402
from drapejax.io import load_measurement, load_truth  # noqa: E402
from drapejax.material import FabricParams, example_params, unstack  # noqa: E402
from drapejax.mesh import cusick_mesh  # noqa: E402
from drapejax.solve import drape  # noqa: E402

if __package__:  # python -m experiments.independent_sim
    from .common import emit, parse_bench_tests, parse_candidates, parse_hidden
else:  # python experiments/independent_sim.py
    from common import emit, parse_bench_tests, parse_candidates, parse_hidden

DIRS = refine.DIRECTIONS


def linear(p: FabricParams) -> FabricParams:
    """The fabric with the parts Style3D cannot represent removed: k2 = 0, β = 0."""
    d = p.to_dict()
    for k in d:
        if k.startswith(("bend_k2_", "stretch_beta_")):
            d[k] = 0.0
    return FabricParams.from_dict(d)


def truths(fabrics: list[str], n_prior: int):
    """The example fabrics, then prior draws (seed 777, in order, at most 20 per wanted truth);
    the caller counts a prior draw only once Style3D could represent it."""
    yield from ((f, linear(example_params(f))) for f in fabrics)
    if n_prior:
        draws = unstack(default_prior().sample(20 * n_prior, seed=777))
        yield from ((f"prior{i}", linear(p)) for i, p in enumerate(draws))


def write_capture(folder: Path, q: np.ndarray, faces: np.ndarray, truth: FabricParams, info: dict,
                  hidden: dict | None = None, bench=()) -> Path:
    """A Style3D rest state (m) as a measurement folder with its truth (and the ``hidden`` effects
    made in the scene), warp along +x, density known, with ``bench`` readings beside it."""
    return virtual_lab.write_capture(folder, q, faces,
                                     truth={"params": truth.to_dict(), "effects": virtual_lab.truth_effects(hidden),
                                            "mesh": {"simulator": "newton.Style3D", **info}},
                                     areal_density_kg_m2=float(truth.density), warp_angle_deg=0.0,
                                     extra={"source": "newton SolverStyle3D (benchmarks/newton_peer.py)"},
                                     bench=bench)


def reused_drape(folder: Path, truth: FabricParams) -> dict:
    """The Style3D run recorded in ``folder/truth.json`` (``--reuse``), refused when its fabric is
    not ``truth``: another ``--fabrics``/``--prior`` than the run that wrote it."""
    recorded = load_truth(folder)
    if recorded.get("params") != truth.to_dict():
        raise SystemExit(f"{folder / 'truth.json'}: 'params' differ from this run's truth; --reuse needs the "
                         "--fabrics and --prior of the run that wrote the folder")
    return recorded["mesh"]


def k1(p: dict | FabricParams) -> np.ndarray:
    """(warp, weft, bias) k1 in N·m of a flat SI parameter dict or a fabric."""
    d = p if isinstance(p, dict) else p.to_dict()
    return np.array([float(d[f"bend_k1_{x}"]) for x in DIRS])


def diagnosis(name: str, folders: list[Path], truth: FabricParams, work: Path, a, hidden: dict) -> dict:
    """``drapejax diagnose`` on one fabric's Style3D captures (the command line's defaults, or the
    candidates, effect count, rescale and k1 widening given): without ``hidden`` effects, an effect
    it selects stands for a way the two simulators differ; with them, ``recovery`` says whether the
    hidden one was found."""
    from drapejax.diagnose import Rescale, diagnose

    t0 = time.perf_counter()
    res = diagnose(folders, report=work / f"{name}_report.html",
                   candidates=[REGISTRY[n] for n in a.candidates] if a.candidates else None,
                   max_effects=a.max_effects, rescale=None if a.no_rescale else Rescale(),
                   screen=Screen(k_widen=a.k_widen))
    pick = lambda model: {k: res[model][k] for k in ("error", "error_ratio", "heldout_misfit", "expected")
                          if k in res[model]}
    k1_ratio = lambda model: (k1(res[model]["params"]) / k1(truth)).tolist()
    return {"fabric": name, "diagnose": True, "captures": len(folders), "hidden": hidden,
            **(recovery(res, hidden) if hidden else {}), "candidates": a.candidates, "max_effects": a.max_effects,
            "rescale": not a.no_rescale, "k_widen": a.k_widen, "bench_tests": a.bench, "selected": res["selected"],
            "selected_values": res.get("selected_values"), "within_noise_floor": res["within_noise_floor"],
            "baseline_within_noise_floor": res.get("baseline_within_noise_floor"),
            "baseline": pick("baseline"), "final": pick("final"),
            "baseline_k1_ratio": k1_ratio("baseline"), "final_k1_ratio": k1_ratio("final"),
            "effects_tested": [{k: t.get(k) for k in ("name", "screen_loss", "accepted", "reason")}
                               for t in res["effects_tested"]],
            "seconds": time.perf_counter() - t0}


def main(a) -> None:
    work = Path(a.workdir or tempfile.mkdtemp())
    out = Path(a.out) if a.out else None
    mesh = cusick_mesh(a.spacing_mm * 1e-3)
    xy, faces, clamped = np.asarray(mesh.rest)[:, :2], np.asarray(mesh.faces), np.asarray(mesh.clamped)
    mass_scale = None
    if a.hidden:  # the scene the captures are draped in; the centred mesh stays drapejax's own (the gap)
        xy, faces, clamped, mass_scale = hidden_effect_scene(xy, faces, clamped, a.hidden,
                                                             spacing_m=a.spacing_mm * 1e-3)
    own = jax.jit(lambda p, s: drape(mesh, p, s, config=refine.EXACT_CONFIG))
    net = InverseModel.load_default()
    rows, prior_done, prior_skipped = [], 0, 0
    folders: dict[str, list[Path]] = {}
    for name, truth in truths(a.fabrics.split(",") if a.fabrics else [], a.prior):
        if name.startswith("prior") and prior_done == a.prior:
            break
        for c in range(a.captures):
            row = {"fabric": name, "capture": c, "truth_k1": k1(truth).tolist(), "density": float(truth.density)}
            folder = work / f"{name}_{c}"
            if a.reuse and (folder / "truth.json").exists():
                row["newton"] = {**reused_drape(folder, truth), "reused": True}
            else:
                t0 = time.perf_counter()
                try:
                    with contextlib.redirect_stdout(sys.stderr):
                        q, info = newton_rest_state(xy, faces, clamped, truth.to_dict(), seed=c,
                                                    mass_scale=mass_scale)
                except ValueError as e:  # a directional law Style3D cannot represent
                    emit({**row, "skipped": str(e)}, out)
                    prior_skipped += name.startswith("prior")
                    break
                row["newton"] = {**info, "seconds": time.perf_counter() - t0}
                bench = virtual_lab.virtual_bench(truth, {}, a.bench_tests, seed=c) if a.bench_tests else ()
                write_capture(folder, q, faces, truth, info, a.hidden, bench)
            folders.setdefault(name, []).append(folder)
            if a.diagnose_only:
                emit({**row, "hidden": a.hidden}, out)
                continue
            m = load_measurement(folder)
            scan_model = InverseModel.for_measurement(m)
            scan = scan_model.estimate_no_refine(m)
            capped = InverseModel.load(InverseModel.amortised_checkpoint_for(m))  # what --no-refine reads it with
            for key, amortised in (("network", net.estimate_no_refine(m)), ("scan_model", scan),
                                   ("capped_scan_model", capped.estimate_no_refine(m))):
                ratio = k1(amortised["params"]) / k1(truth)  # corrected; × the divided factor: the network's own
                factor = (amortised["mesh_bias"] or {"factor": 1.0})["factor"]
                row[f"{key}_k1_ratio"] = ratio.tolist()
                row[f"{key}_k1_ratio_uncorrected"] = (ratio * factor).tolist()
            row["scan_model_phase_harmonics"] = int(scan_model.meta["phase_harmonics"])
            row["scan_model_outside_training_range"] = scan["outside_training_range"]
            if a.no_refine:
                rows.append(row)
                emit(row, out)
                continue
            if not (a.no_gap or a.hidden):  # drapejax's own drop is of the centred specimen
                row["simulator_gap"] = refine.compare(np.asarray(own(truth, c).x), faces, m)
            est = refine.estimate(folder, seed=c, converged_spacing_m=a.converged_mm * 1e-3 if a.converged_mm else None)
            row["refined_k1_ratio"] = (k1(est["params"]) / k1(truth)).tolist()
            if est.get("params_fit_mesh"):  # before the fit mesh's calibrated bias was divided out
                row["refined_k1_ratio_uncorrected"] = (k1(est["params_fit_mesh"]) / k1(truth)).tolist()
                row["mesh_bias_factor"] = est["mesh_bias"]["factor"]
            row["refined_k2"] = [float(est["params"][f"bend_k2_{x}"]) for x in DIRS]  # the fit is not told k2 = 0
            row["refined_std_log"] = (np.array([est["std"][f"bend_k1_{x}"] for x in DIRS]) / k1(est["params"])).tolist()
            row.update(fit=est["fit"], status=est["status"], estimate_seconds=est["seconds"])
            rows.append(row)
            emit(row, out)
        else:
            prior_done += name.startswith("prior")
            if (a.diagnose or a.diagnose_only) and len(folders.get(name, [])) >= 2:
                emit(diagnosis(name, folders[name], truth, work, a, a.hidden), out)
    if not rows:
        return
    emit({**summary(rows, a), "n_verts": int(mesh.n_verts), "prior_draws_style3d_cannot_represent": prior_skipped,
          "workdir": str(work)}, out)


def summary(rows: list[dict], a) -> dict:
    """Medians over the cases: per-direction |log k1 error| of each method, the overall rigidity's
    relative error (geometric mean of k1 over warp, weft and bias: ``material.mean_k1``), and, refined,
    the share of per-direction k1 inside the estimate's reported 2σ (Laplace std of log k1)."""
    err = lambda key: np.abs(np.log([r[key] for r in rows]))
    overall = lambda key: np.abs(np.exp(np.mean(np.log([r[key] for r in rows]), axis=1)) - 1.0)
    out = {"summary": True, "n": len(rows), "spacing_mm": a.spacing_mm, "converged_mm": a.converged_mm}
    for name, key in (("network", "network_k1_ratio"), ("scan_model", "scan_model_k1_ratio"),
                      ("refined", "refined_k1_ratio"), ("network_uncorrected", "network_k1_ratio_uncorrected"),
                      ("scan_model_uncorrected", "scan_model_k1_ratio_uncorrected"),
                      ("refined_uncorrected", "refined_k1_ratio_uncorrected"),
                      ("capped_scan_model", "capped_scan_model_k1_ratio"),
                      ("capped_scan_model_uncorrected", "capped_scan_model_k1_ratio_uncorrected")):
        if all(key in r for r in rows):
            out[f"median_abs_log_k1_error_{name}"] = np.median(err(key), 0).tolist()
            out[f"median_overall_rel_error_{name}"] = float(np.median(overall(key)))
    if all("refined_k1_ratio" in r for r in rows):
        z = err("refined_k1_ratio") / np.array([r["refined_std_log"] for r in rows])
        out["refined_inside_2sigma"] = float(np.mean(z <= 2.0))
        out["median_refined_k1_ratio"] = np.median([r["refined_k1_ratio"] for r in rows], 0).tolist()
        out["median_fit_dc_abs"] = float(np.median([abs(r["fit"]["dc_simulated"] - r["fit"]["dc_measured"])
                                                    for r in rows]))
    gaps = [r["simulator_gap"] for r in rows if "simulator_gap" in r]
    if gaps:
        out["median_simulator_gap"] = {"dc_abs": float(np.median([abs(g["dc_simulated"] - g["dc_measured"])
                                                                   for g in gaps])),
                                       "iou": float(np.median([g["iou"] for g in gaps])),
                                       "scan_mm": float(np.median([g["scan_mm"] for g in gaps]))}
    return out


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fabrics", default="light,mid,heavy", help="example fabrics (linearised), comma-separated")
    ap.add_argument("--prior", type=int, default=0, help="further truths drawn from the 618-fabric prior")
    ap.add_argument("--captures", type=int, default=2, help="Style3D drapes per fabric (seeded start heights)")
    ap.add_argument("--spacing-mm", type=float, default=7.0, help="mesh spacing of the Style3D drape, mm")
    ap.add_argument("--out", help="append the JSON lines here")
    ap.add_argument("--workdir", help="where the measurement folders go (default: a fresh temporary folder)")
    ap.add_argument("--converged-mm", type=float, default=None, metavar="MM",
                    help="continue each refined fit on nested meshes down to MM (drapejax estimate --converged-mm)")
    ap.add_argument("--no-gap", action="store_true",
                    help="skip drapejax's own drop of each truth on the Style3D mesh (the simulator gap)")
    ap.add_argument("--reuse", action="store_true",
                    help="estimate the Style3D drapes already in --workdir again instead of draping them anew")
    mode = ap.add_mutually_exclusive_group()
    mode.add_argument("--diagnose", action="store_true",
                      help="also run drapejax diagnose on each fabric's captures (needs --captures 2 or more)")
    mode.add_argument("--diagnose-only", action="store_true",
                      help="drape the captures and run drapejax diagnose on them, without the per-capture estimates")
    mode.add_argument("--no-refine", action="store_true", help="only the two amortised estimates (minutes)")
    ap.add_argument("--hidden", action="append", default=[], metavar="NAME=THETA",
                    help=f"an effect made in the Style3D scene ({', '.join(SCENE_EFFECTS)}; θ as in drapejax.effects, "
                    "e.g. off_centre=0.013,0 in m), repeatable")
    ap.add_argument("--candidates", default=None, help="comma list of the effects diagnose may select "
                    "(default: diagnose's own)")
    ap.add_argument("--max-effects", type=int, default=2, help="effects diagnose may add (diagnose's default 2)")
    ap.add_argument("--no-rescale", action="store_true", help="diagnose without the baseline's k1 rescale scan")
    ap.add_argument("--k-widen", type=int, default=Screen().k_widen, help="diagnose's Screen.k_widen")
    ap.add_argument("--bench", action="append", default=[], metavar="TEST:DIRECTION",
                    help="bench readings of the truth fabric written beside each capture, repeatable")
    args = ap.parse_args()
    args.hidden = parse_hidden(args.hidden, ap)
    if set(args.hidden) - set(SCENE_EFFECTS):
        ap.error(f"--hidden: the Style3D scene makes only {', '.join(SCENE_EFFECTS)}")
    args.candidates = parse_candidates(args.candidates, ap) if args.candidates else None
    args.bench_tests = parse_bench_tests("--bench", args.bench, ap)
    main(args)
