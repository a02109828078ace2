"""Short human-readable summaries of the ``drapejax`` commands' results.

One function per command (``simulate``, ``inspect``, ``measure``, ``estimate``, ``export``, ``diagnose``,
``demo``, ``validate``, ``bench``, ``dataset``) turns the dict the command prints with ``--json``
into a few lines of text with units, conclusion first; ``generic`` summarises any other dict.
Every function tolerates missing keys (it prints fewer lines) and imports nothing heavy.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from .text_format import WIDTH, get, is_num, mm, num, pct, seconds, short, wrap, yes_no

DIRECTIONS = ("warp", "weft", "bias")


# (key prefix, label, SI -> shown factor, unit, per-density unit)
_GROUPS = (
    ("bend_k1", "bending rigidity k1", 1e6, "µN·m", "µN·m per g/m²"),
    ("bend_k2", "quadratic bending k2", 1e6, "µN·m²", "µN·m² per g/m²"),
    ("stretch_alpha", "tensile stiffness α", 1.0, "N/m", "mN/m per g/m²"),
    ("stretch_beta", "stiffening exponent β", 1.0, "", ""),
)


def _value_pm(v, sd, factor: float) -> str:
    text = num(float(v) * factor)
    if is_num(sd) and math.isfinite(float(sd)) and float(sd) > 0:
        text += f" ± {num(float(sd) * factor, 2)}"
    return text


def fabric_lines(params, std=None, indent: str = "  ", width: int = 24) -> list[str]:
    """Lines for a parameter dict in the ``drapejax estimate`` schema (SI keys, or k/ρ keys
    ``*_per_density`` without a density): density in g/m², k1 in µN·m with its std, k2, α, β."""
    if not isinstance(params, Mapping):
        return []
    std = std if isinstance(std, Mapping) else {}
    lines = []
    if is_num(params.get("density")):
        lines.append(f"{indent}{'areal density':<{width}}{num(float(params['density']) * 1e3)} g/m²")
    for prefix, label, factor, unit, unit_rho in _GROUPS:
        parts = []
        shown_unit = unit
        for d in DIRECTIONS:
            for key, f, u in ((f"{prefix}_{d}", factor, unit),
                              # per density: k/rho in SI (m^3/s^2 ...) x 1e-3 kg/m^2 per g/m^2
                              (f"{prefix}_{d}_per_density", factor * 1e-3 if prefix != "stretch_alpha" else 1.0,
                               unit_rho)):
                if is_num(params.get(key)):
                    parts.append(f"{d} {_value_pm(params[key], std.get(key), f)}")
                    shown_unit = u
                    break
        if parts:
            name = label if shown_unit == unit else label + "/ρ"
            lines.append(f"{indent}{name:<{width}}{'   '.join(parts)}{(' ' + shown_unit) if shown_unit else ''}")
    return lines


# --------------------------------------------------------------------------- commands


def simulate(res: Mapping) -> str:
    """``drapejax simulate``: status, steps, vertices, drape coefficient if present, folder, seconds."""
    status = get(res, "status")
    head = "drapejax simulate: " + ("at rest" if status == "at_rest" else f"NOT at rest ({status})" if status
                                   else "done")
    if is_num(get(res, "steps")):
        head += f" after {int(res['steps'])} steps"
    lines = [head]
    if is_num(get(res, "dc")):
        lines.append(f"  drape coefficient  {num(res['dc'])}")
    if is_num(get(res, "folds")):
        lines.append(f"  folds              {int(res['folds'])}")
    if is_num(get(res, "verts")):
        mesh = f"  mesh               {int(res['verts'])} vertices"
        if is_num(get(res, "spacing_mm")):
            mesh += f", {num(res['spacing_mm'])} mm spacing"
        its = get(res, "newton_iters")
        if is_num(get(res, "levels")) and int(res["levels"]) > 1 and isinstance(its, (list, tuple)):
            mesh += (f" (finest of {int(res['levels'])} nested levels; Newton iterations per level, coarsest "
                     f"first: {', '.join(str(int(i)) for i in its)})")
        lines.append(mesh)
    if get(res, "out"):
        lines.append(f"  measurement folder {res['out']}")
    if is_num(get(res, "seconds")):
        lines.append(f"  time               {seconds(res['seconds'])}")
    return "\n".join(lines)


def inspect(res: Mapping) -> str:
    """``drapejax inspect``: the drape descriptors with units."""
    dc, folds = get(res, "dc"), get(res, "folds")
    head = "drapejax inspect:"
    if is_num(dc):
        head += f" drape coefficient {num(dc)}"
    if is_num(folds):
        head += f"{',' if is_num(dc) else ''} {int(folds)} folds"
    lines = [head if head != "drapejax inspect:" else "drapejax inspect: no descriptors"]
    if is_num(dc):
        lines.append(f"  {'drape coefficient':<24}{num(dc)}  (the overhang's projected share; 1 = no drape)")
    if is_num(folds):
        extra = (f" (dominant harmonic {int(res['dominant_harmonic'])})" if is_num(get(res, "dominant_harmonic"))
                 else "")
        lines.append(f"  {'folds':<24}{int(folds)}{extra}")
    if is_num(get(res, "fold_amplitude_mm")):
        sd = get(res, "fold_amplitude_std_mm")
        lines.append(f"  {'fold amplitude':<24}{num(res['fold_amplitude_mm'])}"
                     f"{(' ± ' + num(sd, 2)) if is_num(sd) else ''} mm")
    radii = [f"{w} {num(res[k])}" for w, k in (("mean", "r_mean_mm"), ("min", "r_min_mm"), ("max", "r_max_mm"))
             if is_num(get(res, k))]
    if radii:
        lines.append(f"  {'outline radius':<24}{', '.join(radii)} mm")
    hem = [f"{w} {num(res[k])}" for w, k in (("mean", "hem_height_mean_mm"), ("min", "hem_height_min_mm"),
                                             ("max", "hem_height_max_mm")) if is_num(get(res, k))]
    if hem:
        lines.append(f"  {'hem height':<24}{', '.join(hem)} mm (relative to the support top)")
    below = [(k[len("area_below_"):-2], res[k]) for k in (res or {}) if str(k).startswith("area_below_")
             and str(k).endswith("mm") and is_num(res[k])]
    if below:
        lines.append(f"  {'fabric area below':<24}" + ", ".join(f"{d} mm: {pct(v)}" for d, v in below))
    known = {"dc", "folds", "dominant_harmonic", "fold_amplitude_mm", "fold_amplitude_std_mm", "r_mean_mm",
             "r_min_mm", "r_max_mm", "hem_height_mean_mm", "hem_height_min_mm", "hem_height_max_mm"}
    for k, v in (res or {}).items():
        if k not in known and not str(k).startswith("area_below_"):
            lines.append(f"  {str(k):<24}{_scalar(v)}")
    return "\n".join(lines)


def measure(res: Mapping) -> str:
    """``drapejax measure``: the folder written and what it holds, then its descriptors as ``inspect``."""
    obs = ", ".join(str(o).replace("_", " ") for o in get(res, "observations", default=None) or ())
    rho, warp, desc = get(res, "areal_density_kg_m2"), get(res, "warp_angle_deg"), get(res, "descriptors")
    lines = [f"drapejax measure: wrote {get(res, 'out', default='the folder')}" + (f" ({obs})" if obs else ""),
             f"  {'areal density':<24}" + (f"{num(rho * 1e3)} g/m²" if is_num(rho) else "not weighed (k/rho only)"),
             f"  {'warp angle':<24}" + (f"{num(warp)}°" if is_num(warp) else "not recorded")]
    return "\n".join(lines + (inspect(desc).splitlines()[1:] if isinstance(desc, Mapping) else []))


def estimate(res: Mapping) -> str:
    """``drapejax estimate``: the fabric's parameters with units (k1 in µN·m per direction with
    its std where present, density in g/m²), how they were obtained, the fit, status and warnings;
    with ``export`` (``--to``) the export table after them."""
    status = get(res, "status")
    how = []
    if get(res, "method"):
        how.append(f"network {res['method']}" + (f" from {res['checkpoint']}" if get(res, "checkpoint") else ""))
    if get(res, "init"):
        how.append(f"started from {res['init']}")
    if status == "not_refined" or (status is None and get(res, "method")):
        how.append("not refined")
    elif status:
        how.append(f"refined through the simulator: {status}")
    n = get(res, "specimens")
    head = "drapejax estimate: fabric parameters" + (f" from {int(n)} specimens" if is_num(n) and n > 1 else "")
    lines = [head + (f" ({', '.join(how)})" if how else "")]
    if get(res, "density_normalized"):
        lines.append("  no areal density in the measurement: values per unit density (k/ρ)")
    lines += fabric_lines(get(res, "params"), get(res, "std"))
    if len(lines) == 1 + bool(get(res, "density_normalized")):
        lines.append("  (no parameters)")
    sd = get(res, "target_sd_between_specimens")
    if isinstance(sd, Mapping):
        spread = [f"{d} {pct(sd[k])}" for d in DIRECTIONS for k in sd
                  if str(k).startswith(f"log_k1_{d}") and is_num(sd[k])]
        if spread:
            lines.append(f"  {'k1 spread (specimens)':<24}{'   '.join(spread)} (std of log k1)")
    if is_num(get(res, "bending_length_mm")):
        lines.append(f"  {'bending length':<24}{num(res['bending_length_mm'])} mm")
    membrane = get(res, "membrane")
    if isinstance(membrane, Mapping) and isinstance(membrane.get("factor"), Mapping):
        factors = "   ".join(f"{d} ×{num(v)}" for d, v in membrane["factor"].items() if is_num(v))
        lines.append(f"  {'membrane':<24}α from {membrane.get('readings')} tensile reading(s): {factors} the "
                     "tag's or prior's")
    ident = get(res, "identified")
    if isinstance(ident, Mapping) and isinstance(ident.get("data_share"), Mapping):
        shares = [f"{str(k).split('_')[2]} {pct(v)}" for k, v in ident["data_share"].items() if is_num(v)]
        extra = f"; best-determined log-k1 combination ± {num(ident['std_log'], 2)}" if is_num(
            ident.get("std_log")) else ""
        if shares:
            lines.append(f"  {'k1 precision from data':<24}{'   '.join(shares)}{extra}")
    fit = get(res, "fit")
    if isinstance(fit, Mapping):
        parts = []
        if is_num(fit.get("dc_measured")) or is_num(fit.get("dc_simulated")):
            parts.append(f"drape coefficient {num(fit.get('dc_measured'))} measured, "
                         f"{num(fit.get('dc_simulated'))} simulated")
        if is_num(fit.get("iou")):
            parts.append(f"IoU {num(fit['iou'])}")
        if is_num(fit.get("scan_mm")):
            parts.append(f"scan {num(fit['scan_mm'])} mm")
        if parts:
            lines.append(f"  {'fit':<24}{'; '.join(parts)}")
    if is_num(get(res, "spacing_m")):
        mesh = f"{mm(res['spacing_m'])} spacing"
        if is_num(get(res, "rim_spacing_m")):
            mesh += f", graded to {mm(res['rim_spacing_m'])} on the disc edge"
        mesh += ", membrane compression capped (--buckling)" if get(res, "buckling") else ""
        conv = get(res, "converged")
        mesh += (f", nested meshes after the fit mesh (its values' loss here {num(conv.get('loss_coarse_model'))}, "
                 f"refitted {num(conv.get('loss'))})") if isinstance(conv, Mapping) else ""
        lines.append(f"  {'fit mesh':<24}{mesh}")
    bias = get(res, "mesh_bias")
    if isinstance(bias, Mapping) and is_num(bias.get("factor")):
        fitted = isinstance(get(res, "params_fit_mesh"), Mapping)  # a refined result warns of extrapolation itself
        whose = "the fit mesh's" if fitted else "the network's"
        lines += wrap(f"{'mesh bias':<24}k1 and k2 above are {whose} ÷ {num(bias['factor'], 3)}, its stiffness bias "
                      f"against converged drapes at this bending length (± {num(bias.get('std_log'), 2)} in log"
                      + (f"; each direction's std includes ± {num(bias['std_log_direction'], 2)}, how one drape "
                         "splits it" if fitted and is_num(bias.get("std_log_direction"))
                         and bias["std_log_direction"] != bias.get("std_log") else "") + "): "
                      "values for a converged simulator" + ("; the fit mesh's own in params_fit_mesh (--json)"
                                                            if fitted else "; --no-mesh-bias for the network's own")
                      + ("; this bending length lies outside the calibrated ones, so the nearest end's factor"
                         if bias.get("inside_calibration") is False and not fitted else ""),
                      max_lines=5)
    src = [s for s in (f"orientation {res['orientation']}" if get(res, "orientation") else None,
                       f"stretching from {str(res['stretch_source']).replace('_', ' ')}"
                       if get(res, "stretch_source") else None) if s]
    if src:
        lines.append(f"  {'inputs':<24}{'; '.join(src)}")
    outside = get(res, "outside_training_range")
    if outside:
        lines.append(f"  outside the network's training range (clipped): {short(', '.join(map(str, outside)), 70)}")
    if is_num(get(res, "seconds")):
        lines.append(f"  {'time':<24}{seconds(res['seconds'])}")
    warnings = get(res, "warnings") or []
    for w in warnings[:3]:
        lines += wrap(f"warning: {w}", max_lines=2)
    if len(warnings) > 3:
        lines.append(f"  ... and {len(warnings) - 3} more warnings (--json)")
    if isinstance(get(res, "export"), Mapping):
        try:
            lines.append(export(res["export"]))
        except (KeyError, TypeError, ValueError):
            lines.append("  export: see --json")
    return "\n".join(lines)


def export(res: Mapping) -> str:
    """``drapejax export``: ``drapejax.export.format_export``'s table."""
    from .export import format_export

    try:
        return format_export(res)
    except (KeyError, TypeError, ValueError):
        return generic(res, "drapejax export")


def _effect_values(values) -> list[str]:
    out = []
    if isinstance(values, Mapping):
        for name, v in values.items():
            if isinstance(v, Mapping):
                parts = [f"{k} {num(x)}" for k, x in v.items() if k != "theta" and is_num(x)]
                out.append("  " + short(f"{name}: {', '.join(parts) or 'fitted'}", WIDTH - 2))
    return out


def _expected_line(res: Mapping) -> str | None:
    b, f = get(res, "baseline", "expected"), get(res, "final", "expected")
    if not isinstance(b, Mapping) and not isinstance(f, Mapping):
        return None
    b, f = b if isinstance(b, Mapping) else {}, f if isinstance(f, Mapping) else {}
    drops = f.get("drops", b.get("drops"))
    return (f"  expected held-out misfit {num(b.get('misfit'))} -> {num(f.get('misfit'))}, "
            f"error ratio {num(b.get('error_ratio'))} -> {num(f.get('error_ratio'))}\n"
            f"    (baseline -> final model{f', mean over {int(drops)} fresh drops' if is_num(drops) else ''};"
            " error ratio <= 1: within the noise floor)")


_ERRORS = (("iou", "outline IoU", ""), ("dc_abs", "|ΔDC|", ""), ("spectral_mm", "rim spectrum", " mm"),
           ("scan_mm", "scan distance", " mm"))


def _errors_line(label: str, errors) -> str | None:
    if not isinstance(errors, Mapping):
        return None
    parts = [f"{name} {num(errors[key])}{unit}" for key, name, unit in _ERRORS if is_num(errors.get(key))]
    return f"  {label:<24}{', '.join(parts)}" if parts else None


def diagnose(res: Mapping, *, command: str = "diagnose") -> str:
    """``drapejax diagnose``: the selected effect (or that none was found) first, then the
    expected held-out misfit and error ratio baseline -> final, whether the final model is within
    the noise floor, the fitted effect values, the final fabric parameters, mesh, report, time."""
    selected = get(res, "selected")
    if selected is None:
        head = f"drapejax {command}: no effect search result"
    elif selected:
        head = f"drapejax {command}: selected effect: {', '.join(map(str, selected))}"
    else:
        head = f"drapejax {command}: no missing effect found (the baseline model is kept)"
    lines = [head]
    if get(res, "reason"):
        lines += wrap(f"why: {res['reason']}", max_lines=2)
    if get(res, "bench", "refused"):
        lines += wrap(f"the bench readings asked for {res['bench']['refused']}: not kept", max_lines=2)
    exp = _expected_line(res)
    if exp:
        lines.append(exp)
    wnf = get(res, "within_noise_floor")
    if wnf is not None:
        base = get(res, "baseline_within_noise_floor")
        lines.append(f"  final model within the noise floor: {yes_no(wnf)}"
                     + (f" (baseline: {yes_no(base)})" if base is not None else ""))
    lines += _effect_values(get(res, "selected_values"))
    for label, key in (("baseline fit errors", "baseline"), ("final fit errors", "final")):
        if key == "final" and not selected:
            continue
        line = _errors_line(label, get(res, key, "error"))
        if line:
            lines.append(line)
    line = _errors_line("noise floor", get(res, "noise_floor"))
    if line:
        lines.append(line.replace("IoU ", "IoU >= ", 1))
    final = get(res, "final")
    fab = fabric_lines(get(final, "params"), get(final, "std"), indent="    ", width=22)
    if fab:
        lines.append("  fabric of the final model" + (", per unit density (k/ρ)" if get(res, "density_normalized")
                                                     else "") + ":")
        lines += [line for line in fab if "k2" not in line and "β" not in line]
    tested = get(res, "effects_tested")
    if isinstance(tested, list) and tested:
        names = list(dict.fromkeys(str(t.get("name")) for t in tested if isinstance(t, Mapping) and t.get("name")))
        lines.append(f"  {'effects tested':<24}" + short(f"{len(tested)} refits: {', '.join(names)}", WIDTH - 26))
    mesh = get(res, "mesh")
    if isinstance(mesh, Mapping) and is_num(mesh.get("spacing_m")):
        text = f"{mm(mesh['spacing_m'])} spacing"
        if is_num(mesh.get("rim_spacing_m")):
            text += f", {mm(mesh['rim_spacing_m'])} on the disc edge"
        if is_num(mesh.get("verts")):
            text += f", {int(mesh['verts'])} vertices"
        if mesh.get("buckling"):
            text += ", compression capped"
        lines.append(f"  {'fit mesh':<24}{text}")
    folders = get(res, "folders")
    if isinstance(folders, list) and folders:
        lines.append(f"  {'captures':<24}{len(folders)} (the first fitted, the others held out)")
    if get(res, "report"):
        lines.append(f"  {'report':<24}{res['report']}")
    if is_num(get(res, "seconds")):
        lines.append(f"  {'time':<24}{seconds(res['seconds'])}")
    return "\n".join(lines)


def demo(res: Mapping) -> str:
    """``drapejax demo``: the selected effect and whether it is the hidden one (``found``) first,
    then the hidden effect's true values, and ``diagnose``'s summary."""
    hidden = get(res, "truth", "effects")
    hidden_names = list(hidden) if isinstance(hidden, Mapping) else []
    found = get(res, "found")
    selected = get(res, "selected")
    sel = ", ".join(map(str, selected)) if selected else None
    if found is True:
        head = f"drapejax demo: found the hidden effect: selected {sel}"
    elif found is False:
        head = (f"drapejax demo: did not find the hidden effect {', '.join(hidden_names) or '(unknown)'}: "
                + (f"selected {sel}" if sel else "no missing effect found"))
    else:
        head = f"drapejax demo: selected effect: {sel}" if sel else "drapejax demo: no missing effect found"
    lines = [head]
    if isinstance(hidden, Mapping):
        for name, v in hidden.items():
            parts = [f"{k} {num(x)}" for k, x in v.items() if k != "theta" and is_num(x)] if isinstance(
                v, Mapping) else []
            lines.append("  " + short(f"hidden (truth): {name}{(': ' + ', '.join(parts)) if parts else ''}",
                                       WIDTH - 2))
    sr = get(res, "strength_ratio")
    if isinstance(sr, Mapping):
        parts = [f"{k} {num(v)}" for k, v in sr.items() if is_num(v)]
        if parts:
            lines.append(f"  fitted strength / hidden strength: {', '.join(parts)}")
    body = diagnose(res, command="demo").splitlines()[1:]
    lines += body
    ms = get(res, "measurements")
    if isinstance(ms, list) and ms:
        lines.append(f"  {'virtual captures':<24}{len(ms)} in {_common_parent(ms)}")
    return "\n".join(lines)


def _common_parent(paths) -> str:
    import os

    try:
        return os.path.commonpath([os.path.dirname(str(p)) for p in paths]) or "."
    except ValueError:
        return str(paths[0])


def validate(res: Mapping) -> str:
    """``drapejax validate cantilever``: passed or not, the worst relative error against the
    tolerance, how many cases converged, the worst case, the worst error per mesh spacing."""
    passed = get(res, "passed")
    worst, tol = get(res, "max_rel_err"), get(res, "tolerance")
    head = "drapejax validate cantilever: " + ("PASSED" if passed else "FAILED" if passed is False else "done")
    if is_num(worst):
        head += f": worst error {pct(worst)}" + (f" (tolerance {pct(tol)})" if is_num(tol) else "")
    lines = [head]
    cases = [c for c in (get(res, "cases") or []) if isinstance(c, Mapping)]
    if cases:
        conv = sum(bool(c.get("converged")) for c in cases)
        lines.append(f"  {len(cases)} cases, {conv} converged")
        with_err = [c for c in cases if is_num(c.get("rel_err"))]
        if with_err:
            w = max(with_err, key=lambda c: float(c["rel_err"]))
            lines.append(f"  worst case: Γ {num(w.get('gamma'))}, cut {num(w.get('angle_deg'))}°, "
                         f"mesh {mm(w.get('spacing_m'))}: H/W {num(w.get('hw_sim'))} vs reference "
                         f"{num(w.get('hw_ref'))} ({pct(w['rel_err'])})")
            by_spacing = {}
            for c in with_err:
                by_spacing.setdefault(c.get("spacing_m"), []).append(float(c["rel_err"]))
            for s, errs in list(by_spacing.items())[:8]:
                lines.append(f"  mesh {mm(s)}: worst {pct(max(errs))} over {len(errs)} cases")
        bad = [c for c in cases if not c.get("converged")]
        for c in bad[:3]:
            lines.append(f"  not converged: Γ {num(c.get('gamma'))}, cut {num(c.get('angle_deg'))}°, "
                         f"mesh {mm(c.get('spacing_m'))}")
    return "\n".join(lines)


def bench(res: Mapping) -> str:
    """``drapejax bench``: times to rest, compile and gradient, batch throughput, memory, the Newton peer."""
    head = "drapejax bench: Cusick drape"
    if is_num(get(res, "spacing_mm")):
        head += f", {num(res['spacing_mm'])} mm mesh"
    if is_num(get(res, "verts")):
        head += f", {int(res['verts'])} vertices"
    lines = [head + (f" ({res['backend']})" if get(res, "backend") else "")]
    if is_num(get(res, "rest_s")):
        runs = get(res, "rest_s_runs")
        n = f" (median of {len(runs)})" if isinstance(runs, list) else ""
        lines.append(f"  {'time to rest':<24}{seconds(res['rest_s'])}{n}")
    for key, label in (("compile_s", "compile"), ("grad_s", "gradient")):
        if is_num(get(res, key)):
            lines.append(f"  {label:<24}{seconds(res[key])}")
    if is_num(get(res, "batch_per_min")):
        size = get(res, "batch_size")
        text = f"{num(res['batch_per_min'])} drapes/min"
        if get(res, "batch_strategy"):
            text += f" ({res['batch_strategy']}{f', batch of {size}' if is_num(size) else ''})"
        if is_num(get(res, "loop_per_min")):
            text += f"; one at a time {num(res['loop_per_min'])}/min"
        if is_num(get(res, "batch_speedup_vs_loop")):
            text += f"; {num(res['batch_speedup_vs_loop'])}x"
        lines.append(f"  {'batched throughput':<24}{text}")
    by = get(res, "batch_per_min_by_strategy")
    if isinstance(by, Mapping) and len(by) > 1:
        lines.append(f"  {'by strategy':<24}" + ", ".join(f"{k} {num(v)}/min" for k, v in by.items()))
    if is_num(get(res, "peak_mb")):
        lines.append(f"  {'peak memory':<24}{num(res['peak_mb'])} MB")
    if is_num(get(res, "newton_rest_s")):
        sp = get(res, "speedup_vs_newton")
        lines.append(f"  {'Newton (Style3D) rest':<24}{seconds(res['newton_rest_s'])}"
                     + (f"; drapejax {num(sp)}x faster" if is_num(sp) else ""))
    elif "newton_rest_s" in (res or {}):
        why = get(res, "newton_reason")
        lines.append(f"  {'Newton (Style3D) rest':<24}not timed" + (f": {short(why, 60)}" if why else ""))
    if is_num(get(res, "multilevel_rest_s")):
        levels = get(res, "multilevel_levels")
        where = (" on " + " > ".join(f"{num(lv['spacing_mm'])} mm ({int(lv['verts'])} v)" for lv in levels)
                 if isinstance(levels, list) and levels else "")
        lines.append(f"  {'nested-mesh drape':<24}{seconds(res['multilevel_rest_s'])}{where}")
        if is_num(get(res, "multilevel_grad_s")):
            lines.append(f"  {'its gradient':<24}{seconds(res['multilevel_grad_s'])}")
        if is_num(sp := get(res, "multilevel_speedup_vs_newton")):
            peer = seconds(res["multilevel_newton_rest_s"])
            lines.append(f"  {'Style3D, finest mesh':<24}{peer}; drapejax {num(sp)}x faster")
    proc = get(res, "simulate_process_s")
    if isinstance(proc, list) and proc and all(is_num(t) for t in proc):
        lines.append(f"  {'`drapejax simulate`':<24}" + ", then ".join(seconds(t) for t in proc) + " (whole process)")
    for key, label in (("status", "drape statuses"), ("batch_status", "batch statuses"),
                       ("multilevel_status", "nested-mesh statuses")):
        st = get(res, key)
        if isinstance(st, list) and st:
            ok = sum(1 for s in st if s == 0)
            lines.append(f"  {label:<24}{ok} of {len(st)} at rest")
    return "\n".join(lines)


def dataset(res: Mapping) -> str:
    """``drapejax dataset``: shards written and skipped (already there), failed drapes."""
    w, s = get(res, "written"), get(res, "skipped")
    parts = []
    if isinstance(w, list):
        parts.append(f"{len(w)} shard{'' if len(w) == 1 else 's'} written")
    if isinstance(s, list):
        parts.append(f"{len(s)} already there")
    if is_num(get(res, "failures")):
        parts.append(f"{int(res['failures'])} failed sample{'' if int(res['failures']) == 1 else 's'}")
    return "drapejax dataset: " + (", ".join(parts) if parts else "done")


def _scalar(v) -> str:
    if v is None or isinstance(v, (bool, str)) or is_num(v):
        return short(num(v) if is_num(v) else yes_no(v) if isinstance(v, bool) else str(v) if v is not None
                      else "n/a", 76)
    if isinstance(v, Mapping):
        if len(v) <= 4 and all(x is None or is_num(x) or isinstance(x, (bool, str)) for x in v.values()):
            return short(", ".join(f"{k} {_scalar(x)}" for k, x in v.items()), 76)
        return f"{len(v)} entries (--json)"
    if isinstance(v, (list, tuple)):
        if len(v) <= 6 and all(x is None or is_num(x) or isinstance(x, (bool, str)) for x in v):
            return short(", ".join(_scalar(x) for x in v), 76) or "none"
        return f"{len(v)} items (--json)"
    return short(str(v), 76)


def generic(res, title: str = "drapejax") -> str:
    """Any result: one line per key, nested values shortened to a line (at most 25 lines)."""
    if not isinstance(res, Mapping):
        return f"{title}: {_scalar(res)}"
    lines = [f"{title}:" + ("" if res else " (empty result)")]
    items = list(res.items())
    for k, v in items[:24]:
        lines.append(f"  {str(k):<24}{_scalar(v)}")
    if len(items) > 24:
        lines.append(f"  ... {len(items) - 24} more keys (--json)")
    return "\n".join(lines)


SUMMARIES = {"simulate": simulate, "inspect": inspect, "measure": measure, "estimate": estimate, "export": export,
             "diagnose": diagnose, "demo": demo, "validate": validate, "bench": bench, "dataset": dataset}


def summarize(command: str, res) -> str:
    """The summary of ``command``'s result (``generic`` for other commands, or a result that the
    command's own summary cannot read)."""
    fn = SUMMARIES.get(command)
    if fn is None or not isinstance(res, Mapping):
        return generic(res, f"drapejax {command}")
    try:
        return fn(res)
    except Exception:  # a result of an unexpected shape: fewer words, never a crash
        return generic(res, f"drapejax {command}")


__all__ = ["num", "pct", "fabric_lines", "simulate", "inspect", "measure", "estimate", "export", "diagnose", "demo",
           "validate", "bench", "dataset", "generic", "summarize", "SUMMARIES"]
