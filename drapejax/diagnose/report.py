"""Self-contained HTML diagnosis report: figures are inline base64 PNGs drawn with OpenCV/NumPy.

Shows measured vs simulated silhouettes and height maps, the signed residual maps, the rim
profiles and the rim-residual spectrum before and after effect selection, the error table
against the noise floor, the bending rigidities the baseline and the final model estimate, and
the effects tested and selected with their physical values.
"""

from __future__ import annotations

import base64
import html
import json
import os
from pathlib import Path

import cv2
import numpy as np

from ..files import write_text_atomic
from .residuals import ResidualReport

PANEL = 256
"""Side of an image panel, px."""


def _png(img_rgb: np.ndarray) -> str:
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(img_rgb[..., ::-1]))
    if not ok:
        raise RuntimeError("PNG encoding failed")
    return "data:image/png;base64," + base64.b64encode(buf.tobytes()).decode("ascii")


def _resize(img: np.ndarray) -> np.ndarray:
    return cv2.resize(img, (PANEL, PANEL), interpolation=cv2.INTER_NEAREST)


def _silhouette_rgb(sil: np.ndarray) -> np.ndarray:
    m = sil > 127
    out = np.full(m.shape + (3,), 255, np.uint8)
    out[m] = (60, 60, 60)
    return _resize(out)


def _colormap(values: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Viridis colouring of ``values`` over [lo, hi]; NaN white."""
    t = np.clip((np.nan_to_num(values, nan=lo) - lo) / max(hi - lo, 1e-12), 0, 1)
    rgb = cv2.applyColorMap((t * 255).astype(np.uint8), cv2.COLORMAP_VIRIDIS)[..., ::-1].copy()
    rgb[~np.isfinite(values)] = 255
    return _resize(rgb)


def _diverging(values: np.ndarray, scale: float) -> np.ndarray:
    """Blue (negative) – white – red (positive) over [−scale, scale]; NaN light grey."""
    t = np.clip(np.nan_to_num(values) / max(scale, 1e-12), -1, 1)
    rgb = np.empty(values.shape + (3,), float)
    pos, neg = np.clip(t, 0, 1), np.clip(-t, 0, 1)
    rgb[..., 0] = 1 - neg
    rgb[..., 1] = 1 - pos - neg
    rgb[..., 2] = 1 - pos
    out = (np.clip(rgb, 0, 1) * 255).astype(np.uint8)
    out[~np.isfinite(values)] = 225
    return _resize(out)


def _silhouette_residual_rgb(res: np.ndarray, meas: np.ndarray) -> np.ndarray:
    out = np.full(res.shape + (3,), 255, np.uint8)
    out[(meas > 127) & (res == 0)] = (200, 200, 200)
    out[res > 0] = (220, 40, 40)
    out[res < 0] = (40, 80, 220)
    return _resize(out)


def _bars(series: list[tuple[str, np.ndarray, tuple[int, int, int]]], *, width: int = 420,
          height: int = 200) -> np.ndarray:
    """Grouped bar chart of harmonic amplitudes (mm) k = 0..K; one colour per series."""
    img = np.full((height, width, 3), 255, np.uint8)
    k = len(series[0][1])
    top = max(max(float(np.max(s)) for _, s, _ in series), 1e-9)
    x0, y0, y1 = 30, height - 25, 20
    slot = (width - x0 - 10) / k
    bw = max(int(slot / (len(series) + 1)), 1)
    for i in range(k):
        for j, (_, vals, col) in enumerate(series):
            x = int(x0 + i * slot + j * bw)
            h = int((y0 - y1) * vals[i] / top)
            cv2.rectangle(img, (x, y0 - h), (x + bw - 1, y0), col, -1)
        if i % 2 == 0:
            cv2.putText(img, str(i), (int(x0 + i * slot), height - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.35, (0, 0, 0), 1)
    cv2.line(img, (x0, y0), (width - 5, y0), (0, 0, 0), 1)
    cv2.putText(img, f"{top:.1f} mm", (2, y1 - 5), cv2.FONT_HERSHEY_SIMPLEX, 0.35, (0, 0, 0), 1)
    for j, (name, _, col) in enumerate(series):
        cv2.putText(img, name, (width - 150, 15 + 14 * j), cv2.FONT_HERSHEY_SIMPLEX, 0.4, col, 1)
    return img


def _lines(series: list[tuple[str, np.ndarray, tuple[int, int, int]]], *, width: int = 420,
           height: int = 200) -> np.ndarray:
    """Line plot of rim profiles r(φ) (mm) over φ = 0..360°."""
    img = np.full((height, width, 3), 255, np.uint8)
    lo = min(float(np.min(s)) for _, s, _ in series)
    hi = max(float(np.max(s)) for _, s, _ in series)
    hi = hi if hi > lo else lo + 1.0
    x0, y0, y1 = 40, height - 20, 15
    for name_i, (name, vals, col) in enumerate(series):
        x = x0 + np.arange(len(vals)) * (width - x0 - 10) / len(vals)
        y = y0 - (vals - lo) / (hi - lo) * (y0 - y1)
        cv2.polylines(img, [np.stack([x, y], 1).astype(np.int32)], False, col, 1, cv2.LINE_AA)
        cv2.putText(img, name, (width - 150, 15 + 14 * name_i), cv2.FONT_HERSHEY_SIMPLEX, 0.4, col, 1)
    cv2.putText(img, f"{hi:.0f}", (2, y1 + 5), cv2.FONT_HERSHEY_SIMPLEX, 0.35, (0, 0, 0), 1)
    cv2.putText(img, f"{lo:.0f} mm", (2, y0), cv2.FONT_HERSHEY_SIMPLEX, 0.35, (0, 0, 0), 1)
    cv2.putText(img, "phi 0..360 deg", (x0, height - 4), cv2.FONT_HERSHEY_SIMPLEX, 0.35, (0, 0, 0), 1)
    return img


def _figure(src: str, caption: str) -> str:
    return (f'<figure><img src="{src}" alt="{html.escape(caption)}"/>'
            f"<figcaption>{html.escape(caption)}</figcaption></figure>")


def _maps(rep: ResidualReport, label: str) -> str:
    figs = [_figure(_png(_silhouette_rgb(rep.measured.silhouette)), "measured silhouette"),
            _figure(_png(_silhouette_rgb(rep.simulated.silhouette)), f"simulated silhouette ({label}, aligned)"),
            _figure(_png(_silhouette_residual_rgb(rep.silhouette_residual, rep.measured.silhouette)),
                    "silhouette residual: red measured-only, blue simulated-only")]
    if rep.measured.height is not None and rep.simulated.height is not None:
        both = np.concatenate([np.ravel(rep.measured.height), np.ravel(rep.simulated.height)])
        both = both[np.isfinite(both)]
        lo, hi = (float(both.min()), float(both.max())) if both.size else (0.0, 1.0)
        figs += [_figure(_png(_colormap(rep.measured.height, lo, hi)),
                         f"measured height ({lo * 1e3:.0f}..{hi * 1e3:.0f} mm)"),
                 _figure(_png(_colormap(rep.simulated.height, lo, hi)), f"simulated height ({label})")]
        if rep.height_residual is not None:
            hr = rep.height_residual
            scale = float(np.nanpercentile(np.abs(hr), 98)) if np.isfinite(hr).any() else 1.0
            figs.append(_figure(_png(_diverging(hr, scale)),
                                f"height residual measured − simulated, ±{scale * 1e3:.0f} mm "
                                "(red: measured higher)"))
    return '<div class="row">' + "".join(figs) + "</div>"


def _table(rows: list[list], header: list[str]) -> str:
    def cell(v):
        if isinstance(v, float):
            return f"{v:.3f}"
        return html.escape("" if v is None else str(v))

    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{cell(v)}</td>" for v in r) + "</tr>" for r in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def _k1_label(key: str) -> str:
    return key + (" (µN·m per kg/m²)" if key.endswith("_per_density") else " (µN·m)")


def _k1_cell(model: dict, key: str) -> str:
    """k1 of one model in µN·m (per kg/m² when density-normalised), ± its std when known."""
    v, sd = model.get("params", {}).get(key), model.get("std", {}).get(key)
    if v is None:
        return ""
    return f"{v * 1e6:.2f}" + ("" if sd is None else f" ± {sd * 1e6:.2f}")


def render_html(result: dict, before: ResidualReport, after: ResidualReport | None, *, title: str) -> str:
    """The report page as a string (see module docstring)."""
    after = after or before
    keys = ("iou", "dc_abs", "spectral_mm", "scan_mm")
    floor = before.noise_floor.to_dict()
    err_rows = [[k, before.errors.get(k), after.errors.get(k), floor.get(k)] for k in keys]
    err_rows.append(["error ratio (held-out, floor units)", result.get("baseline", {}).get("error_ratio"),
                     result.get("final", {}).get("error_ratio"), 1.0])
    ex = [result.get(k, {}).get("expected") or {} for k in ("baseline", "final")]
    if ex[0]:
        n = ex[0].get("drops")
        err_rows.append([f"expected held-out misfit (½χ², mean of {n} fresh drops)", ex[0].get("misfit"),
                         ex[1].get("misfit"), ""])
        err_rows.append([f"expected error ratio (mean of {n} fresh drops)", ex[0].get("error_ratio"),
                         ex[1].get("error_ratio"), 1.0])
    err_rows.append(["within noise floor", result.get("baseline_within_noise_floor"),
                     result.get("within_noise_floor"), ""])
    fabric_rows = [[_k1_label(k), *(_k1_cell(result.get(m, {}), k) for m in ("baseline", "final"))]
                   for k in result.get("final", {}).get("params", {}) if k.startswith("bend_k1_")]
    tested = [[t["name"], ", ".join(t.get("with", [])), t.get("signature"), t.get("screen_loss"),
               t.get("screen_null_loss"), t.get("error_ratio"), t.get("gain_noise_units"), t.get("bic_gain"),
               t.get("accepted"), t.get("reason")]
              for t in result.get("effects_tested", [])]
    sel = result.get("selected", [])
    values = result.get("selected_values", {})
    sel_html = ("<p>No effect selected: " + html.escape(str(result.get("reason", ""))) + "</p>") if not sel else \
        "<ul>" + "".join(f"<li><b>{html.escape(n)}</b>: <code>{html.escape(json.dumps(values.get(n, {})))}</code></li>"
                         for n in sel) + "</ul>"
    spec = _bars([("before", before.rim_residual_spectrum * 1e3, (200, 60, 40)),
                  ("after", after.rim_residual_spectrum * 1e3, (40, 90, 200))])
    prof = _lines([("measured", before.rim_measured * 1e3, (0, 0, 0)),
                   ("sim before", before.rim_simulated * 1e3, (200, 60, 40)),
                   ("sim after", after.rim_simulated * 1e3, (40, 90, 200))])
    sym = before.symmetry
    verdict = ("Residual within the noise floor: nothing missing." if result.get("within_noise_floor")
               else "Residual outside the noise floor.")
    style = ("body{font-family:sans-serif;margin:20px;max-width:1200px}figure{display:inline-block;margin:4px}"
             "figcaption{font-size:12px;max-width:256px}table{border-collapse:collapse;margin:8px 0}"
             "td,th{border:1px solid #aaa;padding:3px 8px;font-size:13px}.row{display:flex;flex-wrap:wrap}")
    return f"""<!DOCTYPE html>
<html><head><meta charset="utf-8"/><title>{html.escape(title)}</title><style>{style}</style></head>
<body>
<h1>{html.escape(title)}</h1>
<p><b>{verdict}</b></p>
<h2>Errors before / after effect selection</h2>
{_table(err_rows, ["metric", "baseline", "final", "noise floor"])}
<h2>Selected effects</h2>
{sel_html}
<h2>Bending rigidity k1 before / after (Laplace std on the fitted capture)</h2>
{_table(fabric_rows, ["parameter", "baseline", "final"])}
<h2>Baseline fit: measured vs simulated</h2>
{_maps(before, "baseline")}
<h2>Final fit: measured vs simulated</h2>
{_maps(after, "final")}
<h2>Rim profile and residual spectrum</h2>
<div class="row">{_figure(_png(prof), "rim profile r(φ), mm")}
{_figure(_png(spec), "rim residual harmonic amplitudes k = 0..16, mm")}</div>
<p>Baseline residual symmetry: odd-harmonic share {sym['odd_fraction']:.2f} (180°-turn breaking),
warp-mirror antisymmetric share {sym['mirror_antisymmetric_fraction']:.2f}, harmonics 1–2 share
{sym['low_fraction']:.2f}, dominant harmonic {sym['dominant_harmonic']}; mean rim residual
{before.rim_mean_mm:.1f} mm. Radial bands (mean signed height residual, mm):
{html.escape(json.dumps({k: round(v.get('height_mm', float('nan')), 2) for k, v in before.bands.items()}))}.</p>
<h2>Effects tested</h2>
{_table(tested, ["effect", "with", "signature", "best drop ½χ²", "best null drop ½χ²", "error (floor units)",
                 "misfit drop (noise units)", "BIC gain", "accepted", "reason"])}
<h2>Result (JSON)</h2>
<pre>{html.escape(json.dumps(result, indent=1, default=str))}</pre>
</body></html>
"""


def write_report(path: str | os.PathLike, result: dict, before: ResidualReport, after: ResidualReport | None = None,
                 *, title: str = "drapejax diagnosis") -> Path:
    """Write the report page atomically (temporary file + rename) and return its path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_text_atomic(path, render_html(result, before, after, title=title), mode=0o644)  # meant to be shared


__all__ = ["write_report", "render_html"]
