"""Diagnosis after a fit: residual analysis → effect search → refit → report.

``diagnose`` fits the baseline model to the first capture, analyses the residual (maps,
rim-profile spectrum, symmetries, radial bands, noise floor), searches the candidate effects
(``drapejax.effects``) and writes a self-contained HTML report. ``demo`` runs it on a virtual-lab
measurement with a hidden effect, needing no downloaded data.

Its stages (baseline fit, k1 scale scan, identifiability, effect search, bench readings, fabric
estimates) and the loops within them (refit iterations, fresh drops, candidates screened, confirmed and
validated) show progress bars on stderr at a terminal (``drapejax.progress``), since a diagnosis
runs for minutes. The identifiability stage (``identifiability``) says, from the Fisher
information of the captures at hand, which candidates they cannot tell from a change of k1 and
which measurement would; when the folders hold bench readings on strips of the fabric (cantilever,
pure bending: ``io.BenchRecord``), the bench stage (``bench``) tests each candidate on them.
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from .. import refine
from ..io import BENDING_TESTS, Measurement, load_measurement, load_truth
from ..material import FabricParams
from ..progress import bar
from ..solve import SolverConfig
from .bench import BenchFit, bench_evidence
from .identifiability import Identifiability, identifiability_at_fit
from .membrane import MembraneScan, membrane_baseline
from .report import render_html, write_report
from .residuals import (DiagnoseError, NoiseFloor, ResidualReport, Views, analyse, analyse_views, measured_views,
                        simulated_views)
from .select import (EXPECTED_SEEDS, MODEL_CONFIG, Rescale, Screen, Selection, _search, expected_error,
                     evaluate_baseline, expected_within_noise, fabric_estimate, held_refit, rank, ratio_rises,
                     rescale_baseline, search, signature_scores)
from .trials import Trial, _trial


NOMINAL_DENSITY = 0.2
"""Areal density, kg/m², at which a capture without one is fitted (k/ρ is what it identifies)."""


def initial_params(measurement: Measurement, *, nominal_density: float = NOMINAL_DENSITY,
                   buckling: bool = False) -> FabricParams:
    """Amortised estimate of the parameters by the packaged model that suits the measurement
    (``InverseModel.for_measurement``, with ``buckling`` the models that go with the capped
    membrane; density = ``nominal_density`` kg/m² when unknown): ``refine.estimate``'s start."""
    return _network_start(measurement, nominal_density, buckling)[0]


def _network_start(measurement: Measurement, nominal_density: float,
                   buckling: bool) -> tuple[FabricParams, dict | None]:
    """``initial_params`` and the record of the membrane the capture's tensile readings set in it."""
    guess, _, membrane = refine._initial_guess(measurement, buckling)
    return refine.to_fabric(guess, measurement.areal_density_kg_m2, nominal_density), membrane


def _load(folders: Sequence[str | os.PathLike]) -> list[Measurement]:
    if not folders:
        raise DiagnoseError("diagnose needs at least one measurement folder")
    ms = [load_measurement(f) for f in folders]
    for f, m in zip(folders, ms):
        if m.test != "cusick":
            raise DiagnoseError(f"{f}: diagnose supports test 'cusick', got {m.test!r}")
        geometry = (m.specimen_radius_m, m.disk_radius_m)
        if geometry != (ms[0].specimen_radius_m, ms[0].disk_radius_m):
            raise DiagnoseError(f"{f}: specimen radius {geometry[0]:g} m on a {geometry[1]:g} m disc, but "
                                f"{folders[0]} has {ms[0].specimen_radius_m:g} m on {ms[0].disk_radius_m:g} m: "
                                "the captures must be of one test geometry (they share one fit mesh)")
    return ms


def _bench_readings(ms: Sequence[Measurement]) -> tuple:
    """The bending readings of all folders (cantilever, pure bending), each once (captures of one
    specimen may repeat them). Tensile readings set the membrane instead (``refine.tensile``)."""
    out = {}
    for m in ms:
        for r in (r for r in m.bench if r.test in BENDING_TESTS):
            out.setdefault(json.dumps(r.to_json(), sort_keys=True), r)
    return tuple(out.values())


def bench_refused(name: str, before: dict | None, after: dict | None) -> str | None:
    """Why the captures refuse the model with an effect the bench readings found, or None: its error
    ratio on fresh drops rises against the captures' final model's at the same drops
    (``select.ratio_rises``, the test the search puts its own candidates to). The readings are
    independent evidence, so a misfit that moves within the drops' scatter does not refuse them;
    a rise on every drop does (pure bending readings of a softening fabric "found" a bias asymmetry
    whose refit raised the error ratio on each of three drops, 1.18 to 1.79 on average:
    ``docs/results/2026-12-06-hidden-effects-readings.md``). None also when either has no
    expected errors."""
    if before is None or after is None or not ratio_rises(before, after):
        return None
    return (f"{name}: with it the captures' error ratio on fresh drops rises ({before['error_ratio']:.2f} -> "
            f"{after['error_ratio']:.2f}, paired over the same drops; expected misfit {before['misfit']:.2f} -> "
            f"{after['misfit']:.2f})")


def bench_refit(measurements: Sequence[Measurement], sel: Selection, effect, theta: np.ndarray, *,
                ctx: refine.FitContext) -> tuple[list, Trial, dict | None]:
    """The captures' model with an effect the bench readings found: ``effect`` added to the effects the
    search selected, held at the readings' ``theta``, and the k1 refitted to the first capture
    (``held_refit``, continuation from the captures' final fit), scored like every model of the search
    (held-out errors, and the expected misfit over fresh drops when the search computed the baseline's).

    The readings fix θ, which the captures could not; the captures then set k1 with it, so the error on
    held-out captures before and after the effect is compared on the same footing as a selection by the
    captures. Returns (effects, trial, expected)."""
    effects = [*sel.selected, effect]
    th_e = np.concatenate([np.asarray(sel.final.fit.theta, float)[3:], np.asarray(theta, float)])
    res = held_refit(measurements[0], sel.final.fit, effects, th_e, **ctx.fit_keywords())
    trial = _trial(measurements, [e.name for e in effects], res, ctx.mesh, ctx.noise_floor)
    expected = None if sel.expected is None else expected_error(measurements, effects, res.theta, ctx=ctx,
                                                                seeds=EXPECTED_SEEDS)
    return effects, trial, expected


class _Stages:
    """The ``diagnose`` stage bar and the wall seconds of each stage, by name, in order."""

    def __init__(self, bar_, first: str):
        self.bar, self.name, self.t0, self.seconds = bar_, first, time.perf_counter(), {}
        bar_.set_postfix_str(first)

    def next(self, name: str) -> None:
        """Count the stage just finished (and its seconds) and name the one starting."""
        now = time.perf_counter()
        self.seconds[self.name] = self.seconds.get(self.name, 0.0) + now - self.t0
        self.bar.update()
        self.bar.set_postfix_str(name)
        self.name, self.t0 = name, now


def diagnose(folders: Sequence[str | os.PathLike], *, report: str | os.PathLike | None = None,
             spacing_m: float = refine.FIT_SPACING_M, rim_spacing_m: float | None = refine.FIT_RIM_SPACING_M,
             candidates: Sequence | None = None, seed: int = 0, init: FabricParams | None = None,
             max_effects: int = 2, max_refits: int | None = None, max_steps: int = 8, min_gain: float = 0.0,
             screen: Screen | None = Screen(), rescale: Rescale | None = Rescale(),
             membrane: MembraneScan | None = None, config: SolverConfig = MODEL_CONFIG,
             buckling: bool = False,
             identifiability: Identifiability | None = Identifiability(), bench: BenchFit = BenchFit()) -> dict:
    """Fit → residual → effect search → refit on captures of one specimen; optionally write the report.

    Args:
        folders: measurement folders, captures of one specimen; the first is fitted, the others
            give held-out evidence and the capture-to-capture noise floor.
        report: HTML report path, or None for no report.
        spacing_m: simulation mesh spacing, m.
        rim_spacing_m: spacing on the disc edge of a rim-graded mesh (``cusick_mesh``), m;
            None for a uniform mesh.
        candidates: ``drapejax.effects.Effect`` objects (default ``candidate_effects()``).
        seed: drop seed.
        init: initial parameters (default: the network estimate of the first capture, by the
            packaged model that goes with ``buckling``, at the membrane its tensile readings set).
            A given ``init`` gets the membrane the folders' tensile readings set.
        max_effects, max_refits, max_steps, min_gain, screen: see ``select.search``.
        rescale: the scan of the baseline's overall k1 scale over fresh drops that may replace
            the baseline fit by a better scale or a k1 refit from it (``select.rescale_baseline``),
            or None for the fit as it is.
        membrane: the scan of the baseline's overall membrane stiffness over fresh drops
            (``membrane.membrane_baseline``), run when the baseline is not within the noise floor
            (its fitted drape, then its fresh drops: ``select.expected_within_noise``); a better
            factor rescales the fabric every later fit starts from. None (the default): the
            tag's or the network's membrane as it is. The scan removes a false effect that a
            membrane held far too soft provokes, and can itself stand in for a real effect (a
            heavier hem scanned to a four times softer membrane): see ``membrane``. Not run when
            the folders hold tensile readings: every fit then holds the membrane they imply
            (``refine.membrane_of_captures``).
        config: solver of the baseline fit and of every drop and refit of the search
            (``select.MODEL_CONFIG``: exact Newton, as the virtual lab drops).
        buckling: cap the base membrane's compression at the element scale
            (``energy.Membrane``) in every fit and drop, so that soft fabrics fold on the coarse
            fit mesh as on a fine one (``refine.MIN_BENDING_LENGTH_M``).
        identifiability: the settings of the Fisher-information analysis of every candidate at
            the baseline fit (``identifiability.identifiability_at_fit``: can the captures tell
            it from a change of k1, and which measurement would), or None to skip it.
        bench: the settings of the test of each candidate on the bench readings the folders hold
            (``bench.bench_evidence``: cantilever strips, pure bending; none held, no test).

    Returns:
        {"baseline": {"params", "std" (the fabric the model estimates, in the ``drapejax estimate``
        schema: k/ρ keys when "density_normalized"; ``select.fabric_estimate``), "error": {...},
        "heldout_error": [...], "loss", "error_ratio", "heldout_misfit",
        "misfit_within_noise", "expected": ``select.expected_error`` (held-out misfit and
        error ratio over fresh drops, the model's error without one drape's fold placement)},
        "effects_tested": [...],
        "selected": [names], "selected_values": {name: physical values}, "final": {same as baseline;
        its "params" are the better estimate when an effect was selected, not a sure one: an
        effect that trades against k1 can leave them off, and the std covers noise, not model
        bias}, "density_normalized",
        "within_noise_floor": the final model's residual is within the noise floor by the test
        that also stops the search (``select.Trial.within_noise``: mean held-out error ratio ≤ 1
        and held-out misfit consistent with noise), "baseline_within_noise_floor": the same for
        the baseline,
        "noise_floor": {...}, "mesh": {"spacing_m", "rim_spacing_m", "verts", "buckling"} (the fit mesh and
        whether its membrane was capped),
        "residual": baseline residual digest, "signatures", "reason", "screen": per screened step
        the best fresh drop of each candidate and of no added effect (``select.Selection.screen``)
        or None,
        "baseline_scan": ``select.rescale_baseline``'s record (None without ``rescale``),
        "membrane_scan": ``membrane.membrane_baseline``'s record (None when not run),
        "tensile": the membrane the folders' tensile readings set (``refine.membrane_of_captures``'s
        record; None without any),
        "identifiability": {candidate name: ``identifiability.analyse_identifiability``'s record
        (std of θ with k1 known and free, k1 confounding, identifiable, the measurement that would
        separate it from k1, the verdict in words)} at the baseline fit, or None when skipped,
        "bench": ``bench.bench_evidence``'s record on the folders' bench readings (None without any);
        an effect it finds that the captures' search did not select is added to "selected" and
        "selected_values", "selected_by" says which evidence chose each ("captures" or "bench
        readings"), and "final" is then the captures' model with that effect held at the readings' θ
        and k1 refitted to the first capture (``bench_refit``), scored on the held-out captures; unless
        that model's error ratio on fresh drops rises against the captures' final model's at the same
        drops (``select.ratio_rises``, the test the search applies to its candidates): the readings'
        effect is then refused, with the reason in "bench"'s "refused",
        "report": path or None, "seconds", "stage_seconds": {stage: wall seconds} (the setup, the network
        start included, then each stage run, in order)}.
    """
    t0 = time.perf_counter()
    ms = _load(folders)
    if candidates is None:
        from ..effects import candidate_effects

        candidates = candidate_effects()
    floor = NoiseFloor.from_captures(ms)
    if init is None:  # the network reads the drape at the membrane the tensile readings set
        init, tensile = _network_start(ms[0], NOMINAL_DENSITY, buckling)
    else:
        init, tensile = refine.membrane_of_captures(ms, init)
    membrane_std = refine.measured_membrane_std(tensile)
    if membrane_std is not None:
        membrane = None  # measured, not scanned
    mesh = refine.fit_mesh(ms[0], spacing_m, rim_spacing_m)
    ctx = refine.FitContext(init=init, mesh=mesh, spacing_m=spacing_m, config=config, buckling=buckling,
                            max_steps=max_steps, noise_floor=floor)
    readings = _bench_readings(ms)
    n_stages = 3 + (rescale is not None) + (membrane is not None) + (identifiability is not None) + bool(readings)
    setup_s = time.perf_counter() - t0
    with bar(total=n_stages, desc="diagnose", unit="stage") as stage_bar:
        stages = _Stages(stage_bar, "baseline fit")
        base_fit = refine.fit(ms[0], seed=seed, **ctx.fit_keywords())
        base_scan = None
        if rescale is not None:
            stages.next("k1 scale scan")
            base_fit, base_scan = rescale_baseline(ms, base_fit, ctx=ctx, rescale=rescale)
        membrane_scan = before = None
        if membrane is not None:
            stages.next("membrane scale scan")
            base = evaluate_baseline(ms, base_fit, mesh, floor)
            before = expected_error(ms, [], base_fit.theta, ctx=ctx) if base.within_noise else None
            if before is None or not expected_within_noise(before, base.n_rows):
                base_fit, ctx, membrane_scan = membrane_baseline(ms, base_fit, ctx=ctx, scan=membrane)
                before = None if membrane_scan["factor"] != 1.0 else before
        ident = None
        if identifiability is not None:
            stages.next("identifiability")
            ident = identifiability_at_fit(ms, base_fit, candidates, ctx=ctx, settings=identifiability,
                                           membrane_std=membrane_std)
        stages.next("effect search")
        sel = _search(ms, base_fit, candidates, ctx=ctx, max_effects=max_effects, max_refits=max_refits,
                      min_gain=min_gain, screen=screen, expected_seeds=EXPECTED_SEEDS, baseline_expected=before)
        final, final_effects = sel.final, list(sel.selected)
        final_expected = (sel.expected or {}).get("final")
        selected_by = {e.name: "captures" for e in sel.selected}
        bench_out = None
        if readings:
            stages.next("bench readings")
            fisher = None if ident is None else {k: v["fisher"] for k, v in ident.items()}
            bench_out = bench_evidence(readings, base_fit.params, candidates, fisher=fisher, settings=bench)
            name = bench_out["selected"]
            if name is not None and name not in selected_by:
                rec = bench_out["effects"][name]
                effect = next(e for e in candidates if e.name == name)
                theta = np.asarray(effect.theta0(), float) + np.asarray(rec["theta_prior_stds"]) * effect.prior_std()
                stages.bar.set_postfix_str(f"refit with {name} at the readings' value")
                effs, trial, expected = bench_refit(ms, sel, effect, theta, ctx=ctx)
                refused = bench_refused(name, final_expected, expected)
                if refused:
                    bench_out["refused"] = refused
                else:
                    final_effects, final, final_expected = effs, trial, expected
                    selected_by[name] = "bench readings"
        final_values = final.summary(final_effects)["values"]
        stages.next("fabric estimates")
        estimate_of = lambda t, effs: fabric_estimate(ms[0], t.fit, effs, ctx=ctx)
        fabric = {"baseline": estimate_of(sel.baseline, [])}
        fabric["final"] = fabric["baseline"] if final is sel.baseline else estimate_of(final, final_effects)
        stages.next("done")
    out = {
        "baseline": {"params": fabric["baseline"]["params"], "std": fabric["baseline"]["std"],
                     "error": sel.baseline.report.errors, "heldout_error": sel.baseline.heldout,
                     "loss": sel.baseline.fit.loss, "error_ratio": sel.baseline.error_ratio,
                     "heldout_misfit": sel.baseline.heldout_loss,
                     "misfit_within_noise": sel.baseline.misfit_within_noise,
                     "expected": (sel.expected or {}).get("baseline")},
        "effects_tested": sel.tested,
        "selected": list(selected_by),
        "selected_values": final_values,
        "selected_by": selected_by,
        "final": {"params": fabric["final"]["params"], "std": fabric["final"]["std"],
                  "error": final.report.errors, "heldout_error": final.heldout, "loss": final.fit.loss,
                  "error_ratio": final.error_ratio, "heldout_misfit": final.heldout_loss,
                  "misfit_within_noise": final.misfit_within_noise, "expected": final_expected},
        "density_normalized": fabric["final"]["density_normalized"],
        "within_noise_floor": final.within_noise,
        "baseline_within_noise_floor": sel.baseline.within_noise,
        "noise_floor": floor.to_dict(),
        "mesh": {"spacing_m": spacing_m, "rim_spacing_m": rim_spacing_m, "verts": mesh.n_verts, "buckling": buckling},
        "residual": sel.baseline.report.summary(),
        "signatures": sel.signatures,
        "reason": sel.reason,
        "screen": sel.screen,
        "baseline_scan": base_scan,
        "membrane_scan": membrane_scan,
        "tensile": tensile,
        "identifiability": ident,
        "bench": bench_out,
        "folders": [str(f) for f in folders],
        "report": None,
    }
    out["seconds"] = time.perf_counter() - t0
    out["stage_seconds"] = {"setup": setup_s, **stages.seconds}
    if report is not None:
        out["report"] = str(Path(report))
        write_report(report, out, sel.baseline.report, final.report,
                     title=f"drapejax diagnosis of {Path(folders[0]).name}")
    return out


def recovery(result: dict, hidden: dict) -> dict:
    """Was the hidden set of effects found? ``result``: a ``diagnose`` dict; ``hidden``: {name: θ}.

    Found means exactly the hidden effects are selected, and each fitted parameter vector points
    the hidden one's way (within 45°: cosine above √½): a hem fitted lighter, or an offset fitted
    at right angles to the true one, is not the hidden effect found. (A positive dot product
    is not enough: a demo run fitted (5·10⁻¹⁴, −0.015) m for a hidden (0.02, 0) m, at right
    angles, and the rounding-size positive dot product counted it as agreeing.) Returns
    {"found", "direction_agrees": {name: bool}, "strength_ratio": {name: the fitted θ's
    component along the hidden θ, over the hidden θ's length, None for a hidden θ at null}} over
    the selected effects that were hidden (every effect's null is θ = 0). Found does not check
    strength; the ratio reports it (e.g. a hidden 20 mm offset found at 60 mm gives 3.0).
    """
    agrees, strength = {}, {}
    for n in (n for n in result["selected"] if n in hidden):
        a = np.ravel(result["selected_values"][n]["theta"]).astype(float)
        b = np.ravel(hidden[n]).astype(float)
        dot, norm = float(np.dot(a, b)), float(np.linalg.norm(a) * np.linalg.norm(b))
        agrees[n] = norm > 0 and dot > math.sqrt(0.5) * norm
        strength[n] = dot / float(np.dot(b, b)) if np.any(b) else None
    return {"found": sorted(result["selected"]) == sorted(hidden) and all(agrees.values()), "direction_agrees": agrees,
            "strength_ratio": strength}


def demo(out_dir: str | os.PathLike, *, seed: int = 0, full: bool = False) -> dict:
    """Virtual-lab captures with a hidden effect → estimate → diagnose → report, in ``out_dir``.

    One effect is hidden, so the search stops after one (``max_effects=1``). By default the
    search weighs the hidden effect against its closest look-alike (``virtual_lab.DEMO_CANDIDATES``)
    with no baseline rescale, about 3 minutes on two CPU cores; ``full`` searches every candidate
    effect after the rescale scan, 12–20 minutes.

    The captures are drops of one specimen with a different seed each (fold placement varies),
    so the effect search is judged on held-out captures. Returns the ``diagnose`` dict plus
    "measurements" (folders), "truth" (the hidden effects), "found", "direction_agrees" and
    "strength_ratio" (``recovery``: the hidden effects selected, pointing the hidden way, at what
    fraction of the hidden strength).
    """
    from ..effects import REGISTRY
    from ..virtual_lab import DEMO_CANDIDATES, default_demo_lab

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    folders = default_demo_lab(out_dir / "measurements")
    truth = load_truth(folders[0]) or {}
    mesh = truth.get("mesh", {})
    quick = {} if full else {"candidates": [REGISTRY[n] for n in DEMO_CANDIDATES], "rescale": None}
    res = diagnose(folders, report=out_dir / "report.html",
                   spacing_m=float(mesh.get("spacing_m", refine.FIT_SPACING_M)),
                   rim_spacing_m=mesh.get("rim_spacing_m"), seed=seed, max_effects=1, **quick)
    hidden = {n: v["theta"] for n, v in (truth.get("effects") or {}).items()}
    res.update(measurements=[str(f) for f in folders], truth={"effects": truth.get("effects", {})},
               **recovery(res, hidden))
    return res


__all__ = ["diagnose", "demo", "recovery", "initial_params", "analyse", "analyse_views", "measured_views",
           "simulated_views", "NoiseFloor", "ResidualReport", "Views", "DiagnoseError", "Screen", "Rescale", "search",
           "rank", "signature_scores", "Selection", "write_report", "render_html", "Identifiability", "MembraneScan",
           "identifiability_at_fit"]
