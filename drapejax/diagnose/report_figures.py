"""The diagnosis report's figures, drawn with OpenCV/NumPy and inlined as base64 PNGs.

Each map is a PANEL × PANEL image of the window [−extent, extent]² with a physical scale bar in
its lower-left corner; each colour-mapped map has a colour bar with numeric ends below it
(viridis for height, blue–white–red for residuals), so a colour reads as a length without the
caption. The rim profile and the residual spectrum are plots with numbered axes and a legend.
Labels are drawn into the images rather than left to captions, and the PNGs are inlined, so the
page stays one self-contained HTML file. ``_maps`` lays out one fit's figures as HTML rows for the
page in ``report``.
"""

from __future__ import annotations

import base64
import html
import math
from collections.abc import Sequence

import cv2
import numpy as np

from .residuals import ResidualReport

PANEL = 256
"""Side of an image panel, px."""

_FONT = cv2.FONT_HERSHEY_SIMPLEX


def _png(img_rgb: np.ndarray) -> str:
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(img_rgb[..., ::-1]))
    if not ok:
        raise RuntimeError("PNG encoding failed")
    return "data:image/png;base64," + base64.b64encode(buf.tobytes()).decode("ascii")


def _resize(img: np.ndarray) -> np.ndarray:
    return cv2.resize(img, (PANEL, PANEL), interpolation=cv2.INTER_NEAREST)


def _text(img: np.ndarray, s: str, org: tuple[int, int], *, scale: float = 0.45, colour=(0, 0, 0),
          anchor: str = "left") -> None:
    """ASCII text at ``org`` (baseline), anchored left, centre or right."""
    (w, _), _ = cv2.getTextSize(s, _FONT, scale, 1)
    x = org[0] - (w if anchor == "right" else w // 2 if anchor == "centre" else 0)
    cv2.putText(img, s, (int(x), int(org[1])), _FONT, scale, colour, 1, cv2.LINE_AA)


def _scale_bar(img: np.ndarray, extent_m: float) -> np.ndarray:
    """A physical scale bar (black on a white box) in the lower-left corner of a PANEL image
    showing the window [−extent_m, extent_m]²; the bar is the round length (1, 2, 5 · 10ⁿ cm)
    nearest a fifth of the window."""
    m_per_px = 2.0 * extent_m / img.shape[1]
    target = 0.2 * 2.0 * extent_m
    lengths = [m * 10.0 ** e for e in range(-4, 2) for m in (1.0, 2.0, 5.0)]
    length = min(lengths, key=lambda L: abs(math.log(L / target)))
    px = max(int(round(length / m_per_px)), 1)
    label = f"{length * 100:g} cm" if length >= 0.01 else f"{length * 1000:g} mm"
    out = img.copy()
    x0, y0 = 8, img.shape[0] - 10
    cv2.rectangle(out, (x0 - 4, y0 - 22), (x0 + max(px, 40) + 4, y0 + 5), (255, 255, 255), -1)
    cv2.rectangle(out, (x0, y0 - 3), (x0 + px, y0 + 1), (0, 0, 0), -1)
    _text(out, label, (x0, y0 - 8), scale=0.42)
    return out


def _strip(height: int = 46) -> np.ndarray:
    return np.full((height, PANEL, 3), 255, np.uint8)


def _colour_bar(colours: np.ndarray, labels: Sequence[str], title: str) -> np.ndarray:
    """A horizontal colour bar under a PANEL image: ``colours`` (k, 3) uint8 RGB from the low end to
    the high end, ``labels`` at evenly spaced positions along it (the first and last at its ends)."""
    img = _strip()
    x0, x1, y0, y1 = 14, PANEL - 14, 4, 16
    idx = np.linspace(0, len(colours) - 1, x1 - x0).astype(int)
    img[y0:y1, x0:x1] = colours[idx][None, :, :]
    cv2.rectangle(img, (x0, y0), (x1 - 1, y1 - 1), (0, 0, 0), 1)
    for i, s in enumerate(labels):
        x = x0 + (x1 - 1 - x0) * i / max(len(labels) - 1, 1)
        cv2.line(img, (int(x), y1), (int(x), y1 + 3), (0, 0, 0), 1)
        _text(img, s, (int(x), y1 + 14), anchor="left" if i == 0 else "right" if i == len(labels) - 1 else "centre")
    _text(img, title, (PANEL // 2, y1 + 28), scale=0.4, anchor="centre")
    return img


def _mm_labels(values_m: Sequence[float], *, signed: bool = False) -> list[str]:
    """Colour-bar labels in mm, with the decimals the span needs, "mm" on the first and last, and
    no "-0"."""
    span = (max(values_m) - min(values_m)) * 1e3
    d = 0 if span >= 20 else 1 if span >= 2 else 2
    out = []
    for v in values_m:
        s = f"{v * 1e3:{'+' if signed else ''}.{d}f}"
        s = "0" if float(s) == 0 else s
        out.append(s)
    out[0], out[-1] = out[0] + " mm", out[-1] + " mm"
    return out


def _viridis(t: np.ndarray) -> np.ndarray:
    """RGB uint8 of viridis at t ∈ [0, 1]."""
    return cv2.applyColorMap((np.clip(t, 0, 1) * 255).astype(np.uint8), cv2.COLORMAP_VIRIDIS)[..., ::-1].copy()


def _diverging_rgb(t: np.ndarray) -> np.ndarray:
    """Blue (t = −1) – white (0) – red (+1), RGB uint8."""
    t = np.clip(t, -1, 1)
    rgb = np.empty(np.shape(t) + (3,), float)
    pos, neg = np.clip(t, 0, 1), np.clip(-t, 0, 1)
    rgb[..., 0] = 1 - neg
    rgb[..., 1] = 1 - pos - neg
    rgb[..., 2] = 1 - pos
    return (np.clip(rgb, 0, 1) * 255).astype(np.uint8)


def _silhouette_rgb(sil: np.ndarray, extent_m: float) -> np.ndarray:
    m = sil > 127
    out = np.full(m.shape + (3,), 255, np.uint8)
    out[m] = (60, 60, 60)
    return _scale_bar(_resize(out), extent_m)


def _height_rgb(values: np.ndarray, lo: float, hi: float, extent_m: float) -> np.ndarray:
    """Viridis height map over [lo, hi] m (NaN, off fabric, white) with its scale bar and a colour
    bar in mm."""
    t = (np.nan_to_num(values, nan=lo) - lo) / max(hi - lo, 1e-12)
    rgb = _viridis(t)
    rgb[~np.isfinite(values)] = 255
    bar = _colour_bar(_viridis(np.linspace(0, 1, 256)[None])[0],
                      _mm_labels([lo, (lo + hi) / 2, hi]), "height (disc top = 0), mm")
    return np.concatenate([_scale_bar(_resize(rgb), extent_m), bar])


def _residual_rgb(values: np.ndarray, scale: float, extent_m: float) -> np.ndarray:
    """Measured − simulated height over [−scale, scale] m, blue–white–red (NaN light grey), with
    its scale bar and a colour bar in mm."""
    rgb = _diverging_rgb(np.nan_to_num(values) / max(scale, 1e-12))
    rgb[~np.isfinite(values)] = 225
    bar = _colour_bar(_diverging_rgb(np.linspace(-1, 1, 256)), _mm_labels([-scale, 0.0, scale], signed=True),
                      "measured - simulated height, mm")
    return np.concatenate([_scale_bar(_resize(rgb), extent_m), bar])


def _silhouette_residual_rgb(res: np.ndarray, meas: np.ndarray, extent_m: float) -> np.ndarray:
    out = np.full(res.shape + (3,), 255, np.uint8)
    out[(meas > 127) & (res == 0)] = (200, 200, 200)
    out[res > 0] = (220, 40, 40)
    out[res < 0] = (40, 80, 220)
    legend = _strip(46)
    for i, (label, col) in enumerate((("fabric measured only", (220, 40, 40)), ("fabric simulated only", (40, 80, 220)),
                                      ("both", (200, 200, 200)))):
        x, y = (14, 6 + 20 * i) if i < 2 else (PANEL // 2 + 30, 6)
        cv2.rectangle(legend, (x, y), (x + 12, y + 12), col, -1)
        _text(legend, label, (x + 18, y + 11), scale=0.42)
    return np.concatenate([_scale_bar(_resize(out), extent_m), legend])


def _axes(img: np.ndarray, x0: int, x1: int, y0: int, y1: int, xticks, yticks, xlabel: str, ylabel: str) -> None:
    """Frame, ticks with numbers, and axis titles of a plot area [x0, x1] × [y1, y0] (y0 bottom)."""
    cv2.rectangle(img, (x0, y1), (x1, y0), (0, 0, 0), 1)
    for x, s in xticks:
        cv2.line(img, (int(x), y0), (int(x), y0 + 4), (0, 0, 0), 1)
        _text(img, s, (int(x), y0 + 17), scale=0.45, anchor="centre")
    for y, s in yticks:
        cv2.line(img, (x0 - 4, int(y)), (x0, int(y)), (0, 0, 0), 1)
        _text(img, s, (x0 - 6, int(y) + 5), scale=0.45, anchor="right")
    _text(img, xlabel, ((x0 + x1) // 2, img.shape[0] - 4), scale=0.42, anchor="centre")
    _text(img, ylabel, (4, y1 - 8), scale=0.42)


def _nice_ticks(lo: float, hi: float, n: int = 5) -> np.ndarray:
    """Round tick values (steps of 1, 2 or 5 · 10ⁿ) inside [lo, hi], about ``n`` of them."""
    raw = (hi - lo) / max(n - 1, 1)
    mag = 10.0 ** math.floor(math.log10(raw)) if raw > 0 else 1.0
    step = min((m * mag for m in (1.0, 2.0, 5.0, 10.0)), key=lambda s: abs(math.log(s / raw))) if raw > 0 else 1.0
    return np.arange(math.ceil(lo / step - 1e-9), math.floor(hi / step + 1e-9) + 1) * step


def _legend(img: np.ndarray, series, x: int, y: int) -> None:
    for j, (name, _, col) in enumerate(series):
        cv2.line(img, (x, y + 16 * j - 4), (x + 18, y + 16 * j - 4), col, 3)
        _text(img, name, (x + 24, y + 16 * j), scale=0.42)


def _lines(series: list[tuple[str, np.ndarray, tuple[int, int, int]]], *, width: int = 520,
           height: int = 260) -> np.ndarray:
    """Rim profiles r(φ) in mm over φ = 0..360°, with numbered axes and a legend."""
    img = np.full((height, width, 3), 255, np.uint8)
    lo = min(float(np.min(s)) for _, s, _ in series)
    hi = max(float(np.max(s)) for _, s, _ in series)
    pad = max(0.05 * (hi - lo), 1.0)
    lo, hi = lo - pad, hi + pad
    x0, x1, y0, y1 = 52, width - 150, height - 40, 30
    for name, vals, col in series:
        x = x0 + np.arange(len(vals) + 1) * (x1 - x0) / len(vals)
        v = np.append(vals, vals[0])
        y = y0 - (v - lo) / (hi - lo) * (y0 - y1)
        cv2.polylines(img, [np.stack([x, y], 1).astype(np.int32)], False, col, 2, cv2.LINE_AA)
    xt = [(x0 + d / 360 * (x1 - x0), f"{d}") for d in (0, 90, 180, 270, 360)]
    yt = [(y0 - (v - lo) / (hi - lo) * (y0 - y1), f"{v:g}") for v in _nice_ticks(lo, hi)]
    _axes(img, x0, x1, y0, y1, xt, yt, "angle phi, degrees", "rim radius, mm")
    _legend(img, series, x1 + 12, y1 + 12)
    return img


def _bars(series: list[tuple[str, np.ndarray, tuple[int, int, int]]], *, width: int = 520,
          height: int = 260) -> np.ndarray:
    """Grouped bars of rim-residual harmonic amplitudes in mm, k = 0..K, one colour per series."""
    img = np.full((height, width, 3), 255, np.uint8)
    k = len(series[0][1])
    top = max(max(float(np.max(s)) for _, s, _ in series), 1e-9) * 1.05
    x0, x1, y0, y1 = 52, width - 150, height - 40, 30
    slot = (x1 - x0) / k
    bw = max(int(slot / (len(series) + 1)), 1)
    for i in range(k):
        for j, (_, vals, col) in enumerate(series):
            x = int(x0 + i * slot + (j + 0.5) * bw)
            h = int((y0 - y1) * vals[i] / top)
            cv2.rectangle(img, (x, y0 - h), (x + bw - 1, y0), col, -1)
    xt = [(x0 + (i + 0.5) * slot, str(i)) for i in range(0, k, 2)]
    yt = [(y0 - (y0 - y1) * v / top, f"{v:g}") for v in _nice_ticks(0.0, top)]
    _axes(img, x0, x1, y0, y1, xt, yt, "harmonic k of the rim residual", "amplitude, mm")
    _legend(img, series, x1 + 12, y1 + 12)
    return img


def _figure(src: str, caption: str) -> str:
    return (f'<figure><img src="{src}" alt="{html.escape(caption)}"/>'
            f"<figcaption>{html.escape(caption)}</figcaption></figure>")


def _maps(rep: ResidualReport, label: str) -> str:
    ext_m, ext_s = rep.measured.extent_m, rep.simulated.extent_m
    row1 = [_figure(_png(_silhouette_rgb(rep.measured.silhouette, ext_m)), "measured silhouette (top view)"),
            _figure(_png(_silhouette_rgb(rep.simulated.silhouette, ext_s)),
                    f"simulated silhouette, {label} model (turned onto the measured one)"),
            _figure(_png(_silhouette_residual_rgb(rep.silhouette_residual, rep.measured.silhouette, ext_m)),
                    "silhouette residual")]
    row2 = []
    if rep.measured.height is not None and rep.simulated.height is not None:
        both = np.concatenate([np.ravel(rep.measured.height), np.ravel(rep.simulated.height)])
        both = both[np.isfinite(both)]
        lo, hi = (float(both.min()), float(both.max())) if both.size else (0.0, 1.0)
        hi = hi if hi > lo else lo + 1e-3
        row2 += [_figure(_png(_height_rgb(rep.measured.height, lo, hi, ext_m)), "measured height"),
                 _figure(_png(_height_rgb(rep.simulated.height, lo, hi, ext_s)),
                         f"simulated height, {label} model (same colour scale)")]
        if rep.height_residual is not None:
            hr = rep.height_residual
            scale = float(np.nanpercentile(np.abs(hr), 98)) if np.isfinite(hr).any() else 1e-3
            row2.append(_figure(_png(_residual_rgb(hr, max(scale, 1e-4), ext_m)),
                                "height residual (red: measured higher; colours saturate at the 98th percentile)"))
    return "".join('<div class="row">' + "".join(r) + "</div>" for r in (row1, row2) if r)
