"""Self-contained HTML diagnosis report: one file, figures inline base64 PNGs drawn with OpenCV/NumPy.

The page opens with the conclusion, so a reader who stops there has the answer: the effect
selected (or that none was, and why), its physical values and where on the specimen it acts, the
truth beside it when the captures come from the virtual lab, the held-out error before and after
against the capture-to-capture noise floor, the fitted bending rigidities in µN·m and in the
field names and units of garment tools (``drapejax.export``), and one verdict. The verdict is
computed once (``verdict``) and every later statement about the noise floor is one of its two
parts, so the page cannot say "outside the floor" beside numbers that read as inside it without
saying which part failed.

The evidence follows: errors against the floor, the bending table, the fabric in every export
target's units, the effects tested (with whether the captures can tell each from a change of k1,
and the measurement that would: ``identifiability``), measured vs simulated silhouettes and
height maps with a physical scale bar and a colour bar with numeric ends for every colour-mapped
image, the rim profiles and residual spectrum, and the residual's symmetry. The full result is
not dumped on the page: ``write_report`` writes it as ``<report-stem>.json`` beside the HTML and
the page links it.

The figures are drawn in ``report_figures`` and numbers, units and effects are put into words in
``report_text``; this module computes the verdict, finds the truth, builds the tables and
assembles and writes the page.
"""

from __future__ import annotations

import dataclasses
import json
import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from ..files import write_text_atomic
from .report_figures import PANEL, _scale_bar  # noqa: F401  (re-exported: part of this module's interface)
from .report_figures import _bars, _figure, _lines, _maps, _png
from .report_text import (_METRICS, _e, _effect_values, _fmt, _is_num, _mean_errors, _strength, _unit, _where,
                          _yes_no, effect_label)
from .residuals import ResidualReport

_DIRS = ("warp", "weft", "bias")


# --------------------------------------------------------------------------- the verdict


@dataclasses.dataclass(frozen=True)
class Verdict:
    """The one statement the page makes about the noise floor.

    Attributes:
        within: the final model's held-out residual is within the noise floor (None: the result
            carries no test).
        baseline_within: the same for the baseline (None when unknown).
        error_ratio_ok, misfit_ok: its two parts for the final model, when the result carries them:
            the held-out error ratio is at most 1 (the errors are inside the capture-to-capture
            floor) and the held-out misfit is consistent with noise.
        text: the sentence shown.
    """

    within: bool | None
    baseline_within: bool | None
    error_ratio_ok: bool | None
    misfit_ok: bool | None
    text: str


def _parts(model: Mapping | None) -> tuple[bool | None, bool | None]:
    model = model if isinstance(model, Mapping) else {}
    r, m = model.get("error_ratio"), model.get("misfit_within_noise")
    return (float(r) <= 1.0 if _is_num(r) else None), (bool(m) if m is not None else None)


def verdict(result: Mapping) -> Verdict:
    """The noise-floor verdict of a ``diagnose`` result.

    ``result["within_noise_floor"]`` is the test that also stops the effect search (held-out
    error ratio ≤ 1 and held-out misfit consistent with noise); without it the two parts decide.
    The sentence names the part that fails, so errors inside the floor beside an "outside" verdict
    read as what they are: a misfit larger than noise explains.
    """
    ratio_ok, misfit_ok = _parts(result.get("final"))
    within = result.get("within_noise_floor")
    if within is None and ratio_ok is not None and misfit_ok is not None:
        within = ratio_ok and misfit_ok
    within = None if within is None else bool(within)
    base = result.get("baseline_within_noise_floor")
    if base is None:
        b_ratio, b_misfit = _parts(result.get("baseline"))
        base = None if b_ratio is None or b_misfit is None else b_ratio and b_misfit
    base = None if base is None else bool(base)
    selected = list(result.get("selected") or [])
    model = f"the model with {', '.join(selected)}" if selected else "the baseline model"
    ratio = (result.get("final") or {}).get("error_ratio") if isinstance(result.get("final"), Mapping) else None
    if within is None:
        text = "Verdict: none: the result carries no noise-floor test."
    elif within:
        text = (f"Verdict: within the noise floor: {model} leaves a held-out residual that re-dropping the same "
                "specimen would explain; nothing else is found missing.")
        if selected and base is False:
            text += " The baseline without the effect was outside it."
    else:
        why = []
        if ratio_ok is False:
            why.append(f"the held-out error ratio {_fmt(ratio)} is above 1 "
                       "(errors beyond the capture-to-capture floor)")
        if misfit_ok is False:
            lead = (f"the held-out errors are inside the capture-to-capture floor (error ratio {_fmt(ratio)} ≤ 1), "
                    "but " if ratio_ok else "")
            why.append(lead + "the held-out misfit is larger than measurement noise explains")
        text = (f"Verdict: outside the noise floor: {model} still misses something"
                + (": " + "; and ".join(why) if why else "") + ".")
        if base is True:
            text += " The baseline was within it."
    return Verdict(within, base, ratio_ok, misfit_ok, text)


# --------------------------------------------------------------------------- truth


def _truth(result: Mapping, truth: Mapping | None) -> tuple[dict | None, str | None]:
    """(truth, note): ``truth`` when given, else the result's "truth", else the ``truth.json`` of the
    first capture folder (the virtual lab writes it; real captures have none); note says why an
    existing truth.json could not be read."""
    if truth is not None:
        return dict(truth), None
    if isinstance(result.get("truth"), Mapping):
        return dict(result["truth"]), None
    folders = result.get("folders") or []
    if not folders:
        return None, None
    from ..io import TRUTH_FILE, MeasurementError, load_truth

    folder = Path(folders[0])
    if not (folder / TRUTH_FILE).is_file():
        return None, None
    try:
        return load_truth(folder), None
    except MeasurementError as err:
        return None, f"the capture's truth.json could not be read ({err})"


# --------------------------------------------------------------------------- tables


def _table(rows: list[list], header: list[str], *, cls: str = "") -> str:
    def cell(v):
        if _is_num(v):
            return _fmt(v)
        if isinstance(v, bool):
            return _yes_no(v)
        return _e(v)

    head = "".join(f"<th>{_e(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{cell(v)}</td>" for v in r) + "</tr>" for r in rows)
    attr = f' class="{cls}"' if cls else ""
    return f"<table{attr}><tr>{head}</tr>{body}</table>"


def _k1_keys(params: Mapping) -> tuple[list[str], str, bool]:
    """(bend_k1 keys warp/weft/bias present in ``params``, their unit, density-normalised)."""
    keys = [f"bend_k1_{d}" for d in _DIRS if f"bend_k1_{d}" in params]
    if keys:
        return keys, "µN·m", False
    return [f"bend_k1_{d}_per_density" for d in _DIRS if f"bend_k1_{d}_per_density" in params], \
        "µN·m per kg/m²", True


def _k1_truth(truth: Mapping | None, key: str) -> float | None:
    """The true k1 (µN·m, or µN·m per kg/m² for a ``*_per_density`` key) from a truth's params."""
    p = (truth or {}).get("params") if isinstance(truth, Mapping) else None
    if not isinstance(p, Mapping):
        return None
    base = key.removesuffix("_per_density")
    if not _is_num(p.get(base)):
        return None
    if base != key:
        return float(p[base]) / float(p["density"]) * 1e6 if _is_num(p.get("density")) and p["density"] > 0 else None
    return float(p[base]) * 1e6


def _pm(model: Mapping, key: str) -> str:
    v = (model.get("params") or {}).get(key)
    sd = (model.get("std") or {}).get(key)
    if not _is_num(v):
        return "—"
    return _fmt(v * 1e6) + (f" ± {_fmt(sd * 1e6, 2)}" if _is_num(sd) else "")


def _tool_exports(params: Mapping | None) -> tuple[list[dict], str | None]:
    """``export.export_params`` of ``params`` for every target, or ([], why not): the page shows the
    bending fields and what a tool has no field for, as export.py states it, never a filled-in value."""
    from ..export import TARGETS, export_params

    if not isinstance(params, Mapping) or not params:
        return [], "the result carries no fitted parameters"
    if not all(f"bend_k1_{d}" in params for d in _DIRS) and not any(k.endswith("_per_density") for k in params):
        return [], "the result lacks one of bend_k1_warp, bend_k1_weft, bend_k1_bias"
    try:
        return [export_params(dict(params), t) for t in TARGETS], None
    except ValueError as err:
        return [], str(err)


def _is_bending(s: str | None) -> bool:
    return s is not None and "bend_k1" in s


def _bending_fields(ex: dict) -> list[dict]:
    return [f for f in ex["fields"] if _is_bending(f["from"])]


def _tools_table(exports: list[dict]) -> str:
    rows = []
    for ex in exports:
        fields = "; ".join(f"{f['name']} {_fmt(f['value'])} {_unit(f['unit'])}" for f in _bending_fields(ex))
        missing = "; ".join(f"{s.get('field') or s['parameter']}: {s['reason']}" for s in ex["not_exported"]
                            if _is_bending(s.get("parameter")))
        notes = "; ".join(_unit(n) for n in ex["notes"] if "bend" in n.lower())
        rows.append([ex["tool"], fields or "none", missing or "—", notes or "—"])
    return _table(rows, ["tool", "bending fields (final model)", "no counterpart (export.py)", "notes"],
                  cls="tools")


# --------------------------------------------------------------------------- the page


def _conclusion(result: Mapping, v: Verdict, truth: Mapping | None, truth_note: str | None,
                exports: list[dict], export_note: str | None) -> str:
    selected = list(result.get("selected") or [])
    values = result.get("selected_values") or {}
    items = []
    if selected:
        names = ", ".join(f"<b>{_e(n)}</b>" + (f" ({_e(effect_label(n))})" if effect_label(n) else "")
                          for n in selected)
        head = f"Selected effect: {names}."
        for n in selected:
            who = f"<b>{_e(n)}</b> " if len(selected) > 1 else ""
            items.append(f"<li>{who}Strength: {_e(_strength(values.get(n)))}.</li>")
            if (result.get("selected_by") or {}).get(n) == "bench readings":
                items.append(f"<li>{who}Found by the bench readings on strips, not by the captures; the final "
                             "model holds it at the readings' strength with k1 refitted to the first capture, "
                             "and its drape figures below are that refit.</li>")
            where = _where(n, values.get(n))
            if where:
                items.append(f"<li>{who}Where: {_e(where)}.</li>")
    else:
        reason = result.get("reason")
        head = "No effect selected" + (f": {_e(reason)}" if reason else
                                       " (the result gives no reason)") + ". The baseline model is kept."
    if truth is not None:
        hidden = truth.get("effects") if isinstance(truth.get("effects"), Mapping) else {}
        if hidden:
            parts = [f"<b>{_e(n)}</b> with {_e(_strength(hv))}" for n, hv in hidden.items()]
            match = "the selection matches it" if sorted(hidden) == sorted(selected) else \
                "the selection does not match it"
            items.append(f"<li>Truth (virtual lab): hidden effect {'; '.join(parts)}; {match}.</li>")
        else:
            items.append("<li>Truth (virtual lab): no effect was hidden"
                         + ("; the selection matches it." if not selected else "; the selection does not match it.")
                         + "</li>")
    elif truth_note:
        items.append(f"<li>Truth: {_e(truth_note)}.</li>")
    b, f = result.get("baseline") or {}, result.get("final") or {}
    n_held = len(f.get("heldout_error") or b.get("heldout_error") or [])
    if _is_num(b.get("error_ratio")) or _is_num(f.get("error_ratio")):
        over = f", mean over {n_held} held-out capture{'s' if n_held != 1 else ''}" if n_held else ""
        line = (f"Held-out error: baseline {_fmt(b.get('error_ratio'))} → final {_fmt(f.get('error_ratio'))} "
                f"times the capture-to-capture noise floor (1 = the floor; each capture's largest error over its "
                f"floor{over})")
        eb, ef = b.get("expected") or {}, f.get("expected") or {}
        if _is_num(eb.get("error_ratio")) or _is_num(ef.get("error_ratio")):
            drops = eb.get("drops", ef.get("drops"))
            line += (f"; on {f'{int(drops)} ' if _is_num(drops) else ''}fresh drops "
                     f"{_fmt(eb.get('error_ratio'))} → {_fmt(ef.get('error_ratio'))}")
        items.append(f"<li>{_e(line)}.</li>")
    scan = result.get("membrane_scan") or {}
    if _is_num(scan.get("factor")) and scan["factor"] != 1.0:
        compare = scan.get("compare") or {}
        items.append(f"<li>Membrane stiffness: the tag's or the network's α times {_e(_fmt(scan['factor']))}, held by "
                     f"every model here: fresh drops of the baseline with it ({_e(scan.get('kept'))}) score "
                     f"{_e(_fmt(compare.get(scan.get('kept'))))} on the captures against "
                     f"{_e(_fmt(compare.get('baseline fit')))} (½χ²).</li>")
    tensile = result.get("tensile") or {}
    if isinstance(tensile.get("alpha"), Mapping):
        alpha = ", ".join(f"{d} {_fmt(a)}" for d, a in tensile["alpha"].items())
        items.append(f"<li>Membrane stiffness from {_e(tensile.get('readings'))} tensile reading(s), held by every "
                     f"model here: α {_e(alpha)} N/m.</li>")
    elif tensile.get("ignored"):
        items.append(f"<li>Tensile readings not used: {_e(tensile['ignored'])}.</li>")
    params = f.get("params") if isinstance(f.get("params"), Mapping) else {}
    keys, unit, _ = _k1_keys(params)
    if keys:
        fitted = ", ".join(f"{k.split('_')[2]} {_pm(f, k)}" for k in keys)
        line = f"Bending rigidity k1 of the final model: {fitted} {unit}"
        true = [_k1_truth(truth, k) for k in keys]
        if any(t is not None for t in true):
            line += f" (truth: {', '.join(_fmt(t) for t in true)} {unit})"
        items.append(f"<li>{_e(line)}.</li>")
    clo = next((ex for ex in exports if ex["target"] == "clo"), None)
    if clo is not None:
        fields = ", ".join(f"{fl['name']} {_fmt(fl['value'])}" for fl in _bending_fields(clo))
        unit_clo = _unit(_bending_fields(clo)[0]["unit"]) if _bending_fields(clo) else ""
        items.append(f"<li>In {_e(clo['tool'])}: {_e(fields)} {_e(unit_clo)} "
                     "(other tools in <a href=\"#tools\">the table below</a>).</li>")
    elif export_note:
        items.append(f"<li>In tool units: not available: {_e(export_note)}.</li>")
    return (f'<section class="conclusion" id="conclusion"><p class="headline">{head}</p>'
            f'<ul>{"".join(items)}</ul><p class="verdict">{_e(v.text)}</p></section>')


def _errors_table(result: Mapping, before: ResidualReport, after: ResidualReport, v: Verdict) -> str:
    floor = result.get("noise_floor") if isinstance(result.get("noise_floor"), Mapping) else \
        before.noise_floor.to_dict()
    b, f = result.get("baseline") or {}, result.get("final") or {}
    hb, hf = _mean_errors(b.get("heldout_error")), _mean_errors(f.get("heldout_error"))
    rows = []
    for k, label, unit, side in _METRICS:
        name = label + (f", {unit}" if unit else "")
        rows.append([name, before.errors.get(k), after.errors.get(k), hb[k], hf[k],
                     f"{side} {_fmt(floor.get(k))}" if _is_num(floor.get(k)) else "—"])
    rows.append(["error ratio (largest error over its floor)", "", "", b.get("error_ratio"), f.get("error_ratio"),
                 "≤ 1"])
    eb, ef = b.get("expected") or {}, f.get("expected") or {}
    if eb or ef:
        n = eb.get("drops", ef.get("drops"))
        tag = f"{int(n)} fresh drops" if _is_num(n) else "fresh drops"
        rows.append([f"expected error ratio, mean of {tag}", "", "", eb.get("error_ratio"), ef.get("error_ratio"),
                     "≤ 1"])
        rows.append([f"expected held-out misfit ½χ², mean of {tag}", "", "", eb.get("misfit"), ef.get("misfit"), ""])
    b_ratio, b_misfit = _parts(b)
    rows.append(["verdict part 1: held-out error ratio ≤ 1", "", "", _yes_no(b_ratio), _yes_no(v.error_ratio_ok), ""])
    rows.append(["verdict part 2: held-out misfit consistent with noise", "", "", _yes_no(b_misfit),
                 _yes_no(v.misfit_ok), ""])
    return _table(rows, ["metric", "fitted capture: baseline", "fitted capture: final", "held-out: baseline",
                         "held-out: final", "noise floor"])


def _k1_table(result: Mapping, truth: Mapping | None) -> str:
    b, f = result.get("baseline") or {}, result.get("final") or {}
    keys, unit, _ = _k1_keys((f.get("params") or b.get("params") or {}))
    if not keys:
        return "<p>The result carries no bending rigidities.</p>"
    has_truth = any(_k1_truth(truth, k) is not None for k in keys)
    rows = [[k.split("_")[2], _pm(b, k), _pm(f, k)] + ([_fmt(_k1_truth(truth, k))] if has_truth else [])
            for k in keys]
    return _table(rows, ["direction", f"baseline, {unit}", f"final, {unit}"] + ([f"truth, {unit}"] if has_truth
                                                                                    else []))


def _selected_table(result: Mapping) -> str:
    values = result.get("selected_values") or {}
    rows = [[n, label, val, unit or "—"] for n in (result.get("selected") or [])
            for label, val, unit in _effect_values(values.get(n))]
    if not rows:
        return ""
    return _table(rows, ["effect", "quantity", "value", "unit"])


def _identifiability(result: Mapping, name) -> list[str]:
    """[identifiable from the captures, the measurement that would separate it from k1] of the
    effect ``name`` (``identifiability.analyse_identifiability``); "—" where the result has none."""
    ident = result.get("identifiability")
    rec = ident.get(name) if isinstance(ident, Mapping) else None
    if not isinstance(rec, Mapping):
        return ["—", "—"]
    ok = rec.get("identifiable")
    std = f" (std {_fmt(rec['std_marginal'], 2)})" if _is_num(rec.get("std_marginal")) else ""
    if ok and rec.get("membrane_separated_by"):
        return [_yes_no(ok) + std + " with the membrane known", rec["membrane_separated_by"]]
    return [_yes_no(ok) + std, "—" if ok else (rec.get("separated_by") or "none of those tried")]


_IDENTIFIABILITY_HEADER = ["identifiable apart from k1 (std, prior stds)", "measurement that would separate it"]


def _tested_table(result: Mapping) -> str:
    tested = [t for t in (result.get("effects_tested") or []) if isinstance(t, Mapping)]
    if not tested:
        ident = result.get("identifiability")
        rows = [[n, *_identifiability(result, n)] for n in ident] if isinstance(ident, Mapping) else []
        return "<p>No effect was refitted.</p>" + (_table(rows, ["effect", *_IDENTIFIABILITY_HEADER]) if rows else "")
    rows = [[t.get("name"), ", ".join(t.get("with") or []) or "—", t.get("signature"), t.get("screen_loss"),
             t.get("screen_null_loss"), t.get("error_ratio"), t.get("gain_noise_units"), t.get("bic_gain"),
             _yes_no(t.get("accepted")), t.get("reason"), *_identifiability(result, t.get("name"))] for t in tested]
    return _table(rows, ["effect", "on top of", "signature score", "best drop ½χ²", "best null drop ½χ²",
                         "error ratio", "misfit drop (noise units)", "BIC gain", "accepted", "reason",
                         *_IDENTIFIABILITY_HEADER])


def _bench_tables(result: Mapping) -> str:
    """The bench readings the folders held and what each candidate effect made of them
    (``bench.bench_evidence``); empty without readings."""
    bench = result.get("bench")
    if not isinstance(bench, Mapping):
        return ""
    readings = [[r.get("test"), r.get("direction"),
                 ", ".join(f"{k} {_fmt(v)}" for k, v in r.items() if k not in ("test", "direction", "simulated",
                                                                                 "residual_log_k1")),
                 r.get("simulated"), r.get("residual_log_k1")] for r in bench.get("readings") or []]
    effects = [[n, _yes_no(e.get("felt")), _strength(e.get("theta")) if e.get("felt") else "—",
                e.get("chi2_drop"), e.get("chi2_needed"), e.get("error_baseline_refit"), e.get("error_after"),
                _yes_no(e.get("found")), e.get("why")] for n, e in (bench.get("effects") or {}).items()]
    return ("<h3>Bench readings on strips of the fabric</h3>"
            f"<p>Error of the baseline: {_fmt(bench.get('error_before'))} (RMS apparent log k1); found by the "
            f"readings: {_e(bench.get('selected') or 'nothing')}"
            + (f"; not kept: {_e(bench['refused'])}" if bench.get("refused") else "") + ".</p>"
            + _table(readings, ["test", "cut", "reading", "baseline's simulated reading", "residual (log k1)"])
            + _table(effects, ["effect", "a strip feels it", "fitted strength", "fall of the objective",
                               "fall needed", "error, k1 refitted (log k1)", "error with the effect (log k1)",
                               "found", "why"]))


def _symmetry_table(rep: ResidualReport) -> str:
    sym = rep.symmetry
    rows = [["odd-harmonic share (breaks the 180° turn symmetry anisotropy keeps)", sym.get("odd_fraction"), ""],
            ["warp-mirror antisymmetric share", sym.get("mirror_antisymmetric_fraction"), ""],
            ["harmonics 1–2 share", sym.get("low_fraction"), ""],
            ["dominant harmonic", sym.get("dominant_harmonic"), ""],
            ["mean rim residual (measured − simulated)", rep.rim_mean_mm, "mm"]]
    for name, band in rep.bands.items():
        if _is_num(band.get("height_mm")):
            rows.append([f"mean signed height residual, {name.replace('_', ' ')} band", band["height_mm"], "mm"])
    return _table(rows, ["baseline residual", "value", "unit"])


STYLE = ("body{font-family:system-ui,sans-serif;margin:20px auto;max-width:1180px;padding:0 16px;color:#111;"
         "line-height:1.4}h1{font-size:24px;margin-bottom:8px}h2{font-size:18px;margin-top:28px;"
         "border-bottom:1px solid #ccc;padding-bottom:3px}.conclusion{background:#f3f6fa;border:1px solid #b8c6d8;"
         "border-radius:6px;padding:10px 16px}.conclusion .headline{font-size:19px;margin:4px 0}"
         ".conclusion ul{margin:6px 0;padding-left:20px}.verdict{font-weight:bold;font-size:16px;margin:8px 0 4px}"
         "figure{display:inline-block;margin:6px;vertical-align:top}figure img{border:1px solid #ddd}"
         "figcaption{font-size:13px;max-width:260px}table{border-collapse:collapse;margin:8px 0}"
         "td,th{border:1px solid #aaa;padding:3px 8px;font-size:13px;vertical-align:top}th{background:#eee}"
         "table.tools td{max-width:360px}.row{display:flex;flex-wrap:wrap;align-items:flex-start}"
         ".note{font-size:13px;color:#444}")


def render_html(result: dict, before: ResidualReport, after: ResidualReport | None, *, title: str,
                truth: Mapping | None = None, json_name: str | None = None) -> str:
    """The report page as a string (see module docstring).

    Args:
        result: a ``diagnose`` result (missing keys are shown as unknown).
        before, after: residuals of the baseline and the final model (``after`` None: the baseline's).
        title: page title.
        truth: the virtual lab's truth ({"params", "effects"}), shown beside the estimates; None:
            the result's "truth", else the first capture folder's truth.json when it has one.
        json_name: file name of the result's JSON beside the page, linked from it (None: no link).
    """
    after = after or before
    v = verdict(result)
    truth, truth_note = _truth(result, truth)
    final = result.get("final") if isinstance(result.get("final"), Mapping) else {}
    exports, export_note = _tool_exports(final.get("params"))
    spec = _bars([("before", before.rim_residual_spectrum * 1e3, (200, 60, 40)),
                  ("after", after.rim_residual_spectrum * 1e3, (40, 90, 200))])
    prof = _lines([("measured", before.rim_measured * 1e3, (0, 0, 0)),
                   ("sim before", before.rim_simulated * 1e3, (200, 60, 40)),
                   ("sim after", after.rim_simulated * 1e3, (40, 90, 200))])
    tools = _tools_table(exports) if exports else f"<p>Not available: {_e(export_note)}.</p>"
    data = (f'<p>The whole result, every number on this page and more, is in <a href="{_e(json_name)}">'
            f"{_e(json_name)}</a> beside this page.</p>") if json_name else ""
    return f"""<!DOCTYPE html>
<html><head><meta charset="utf-8"/><title>{_e(title)}</title><style>{STYLE}</style></head>
<body>
<h1>{_e(title)}</h1>
{_conclusion(result, v, truth, truth_note, exports, export_note)}
<h2>Errors against the noise floor</h2>
<p class="note">Fitted capture: the capture the models were fitted to. Held-out: mean over the other captures.
The noise floor is the capture-to-capture spread of re-dropping one specimen; the verdict takes both of its
parts from the held-out columns.</p>
{_errors_table(result, before, after, v)}
<h2>Bending rigidity k1 (± Laplace std on the fitted capture)</h2>
{_k1_table(result, truth)}
<h2 id="tools">The final model's bending in your tool's units</h2>
<p class="note">Converted by drapejax.export; a field a tool has no documented counterpart for is listed, not
filled in.</p>
{tools}
<h2>Effects</h2>
{_selected_table(result)}
{_tested_table(result)}
{_bench_tables(result)}
<h2>Baseline fit: measured vs simulated</h2>
{_maps(before, "baseline")}
<h2>Final fit: measured vs simulated</h2>
{_maps(after, "final")}
<h2>Rim profile and residual spectrum</h2>
<div class="row">{_figure(_png(prof), "rim radius r(φ) around the specimen, measured and simulated")}
{_figure(_png(spec), "harmonic amplitudes of the rim residual before and after the effect search")}</div>
<h2>Residual symmetry (baseline)</h2>
{_symmetry_table(before)}
<h2>Data</h2>
{data or '<p class="note">No data file was written with this page.</p>'}
</body></html>
"""


def _json_default(obj):
    if isinstance(obj, np.generic):
        return obj.item()
    if hasattr(obj, "__array__"):
        return np.asarray(obj).tolist()
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    return str(obj)


def write_report(path: str | os.PathLike, result: dict, before: ResidualReport, after: ResidualReport | None = None,
                 *, title: str = "drapejax diagnosis", truth: Mapping | None = None) -> Path:
    """Write the report page and ``result`` as ``<stem>.json`` beside it, each atomically (temporary
    file + rename), the JSON first so the page's link never points at nothing; returns the page's path.

    Raises:
        ValueError: ``path`` ends in .json (the data file would replace the page).
    """
    path = Path(path)
    data_path = path.with_suffix(".json")
    if data_path == path:
        raise ValueError(f"{path}: the report is HTML; give a .html path (its data goes to <stem>.json beside it)")
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(data_path, json.dumps(result, indent=1, default=_json_default) + "\n", mode=0o644)
    page = render_html(result, before, after, title=title, truth=truth, json_name=data_path.name)
    return write_text_atomic(path, page, mode=0o644)  # meant to be shared


__all__ = ["write_report", "render_html", "verdict", "Verdict", "effect_label"]
