"""Residual analysis after a fit: what the remaining sim-vs-measurement difference looks like.

The simulated drape is first turned (and possibly mirrored) about the disc axis to best match
the measured silhouette (fold phase is random from drop to drop). Then: a signed silhouette
residual map (+1 measured-only, −1 simulated-only), a height residual map (measured − simulated,
m), the rim-profile residual r_meas(φ) − r_sim(φ) and its angular spectrum, symmetry statistics
and radial bands. These are what point to missing effects: anisotropic material is symmetric
under a 180° turn, so residual energy in ODD harmonics (harmonic 1: a displaced specimen) means
something the model cannot make; a residual antisymmetric under the warp mirror breaks a
symmetry every base-model drape keeps; the radial bands say where along the skirt the difference
sits. Which pattern each candidate effect leaves is the effect's own (``Effect.signature`` in
``drapejax.effects``, read through ``signatures.Evidence``).

Scalar errors {"iou", "dc_abs", "spectral_mm", "scan_mm"} are compared with a noise floor:
a residual within it means "nothing missing".
"""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Sequence

import cv2
import numpy as np
from jaxtyping import Float, Int, UInt8

from .. import observe
from ..io import Measurement
from ..photo import photo_silhouette

EXTENT_M = 0.16
N_PIXELS = 256
N_ANGLES = 360
N_HARMONICS = 16
BANDS = (("near_disc", 0.0, 1.0 / 3.0), ("mid", 1.0 / 3.0, 2.0 / 3.0), ("hem", 2.0 / 3.0, np.inf))
"""Radial bands as fractions of the way from the disc edge to the measured rim along each ray
(the hem band runs on outwards, covering simulated fabric beyond the measured rim)."""


class DiagnoseError(ValueError):
    """A measurement or argument the diagnosis cannot use; the message names it."""


@dataclasses.dataclass(frozen=True)
class NoiseFloor:
    """Capture-to-capture spread of the error metrics; errors inside it are indistinguishable from
    re-dropping the same specimen.

    Defaults: medians over re-drops of one specimen in the real scans (aligned IoU, |ΔDC|,
    rim spectral distance in mm, rotation-aligned scan distance in mm).
    """

    iou: float = 0.927
    dc_abs: float = 0.035
    spectral_mm: float = 6.2
    scan_mm: float = 2.5

    @classmethod
    def from_captures(cls, measurements: Sequence[Measurement]) -> "NoiseFloor":
        """Looser of the default floor and the median pairwise spread of several captures.

        With fewer than two captures this is the default. The default stays a lower bound
        because a handful of captures (or virtual captures of one simulation) underestimates
        the drop-to-drop spread.
        """
        if len(measurements) < 2:
            return cls()
        views = [measured_views(m) for m in measurements]
        pairs = []
        for (a, b) in itertools.combinations(range(len(views)), 2):
            pairs.append(compare_views(views[a], views[b], measurements[a], measurements[b]))
        d = cls()
        med = {k: float(np.median([p[k] for p in pairs if p[k] is not None]))
               if any(p[k] is not None for p in pairs) else None for k in ("iou", "dc_abs", "spectral_mm", "scan_mm")}
        return cls(iou=min(d.iou, med["iou"]), dc_abs=max(d.dc_abs, med["dc_abs"]),
                   spectral_mm=max(d.spectral_mm, med["spectral_mm"]),
                   scan_mm=d.scan_mm if med["scan_mm"] is None else max(d.scan_mm, med["scan_mm"]))

    def within(self, errors: dict) -> bool:
        """True when every available error is inside the floor."""
        ok = [errors["iou"] >= self.iou, errors["dc_abs"] <= self.dc_abs, errors["spectral_mm"] <= self.spectral_mm]
        if errors.get("scan_mm") is not None:
            ok.append(errors["scan_mm"] <= self.scan_mm)
        return bool(all(ok))

    def ratio(self, errors: dict, keys: Sequence[str] = ("iou", "dc_abs", "spectral_mm", "scan_mm")) -> float:
        """Largest of the errors ``keys`` in units of its floor (IoU through 1 − IoU): ≤ 1 is within
        the floor. Missing (None) errors are skipped."""
        floor = self.to_dict()
        r = [(1.0 - errors[k]) / (1.0 - floor[k]) if k == "iou" else errors[k] / floor[k]
             for k in keys if errors.get(k) is not None]
        return float(max(r))

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


@dataclasses.dataclass(frozen=True)
class Views:
    """Top views on one grid: silhouette (uint8 0/255), height (m, NaN off fabric) or None,
    scan mesh or None, window half side (m)."""

    silhouette: UInt8[np.ndarray, "n n"]
    height: Float[np.ndarray, "n n"] | None
    extent_m: float
    verts: Float[np.ndarray, "k 3"] | None = None
    faces: Int[np.ndarray, "j 3"] | None = None


@dataclasses.dataclass(frozen=True)
class ResidualReport:
    """Residuals of a simulated drape against a measurement (see module docstring).

    Attributes:
        errors: {"iou", "dc_abs", "spectral_mm", "scan_mm" (None without a scan)}.
        errors_within_floor: every error of this capture inside ``noise_floor`` (stricter than the
            diagnosis verdict ``select.Trial.within_noise``, which averages over held-out captures).
        noise_floor: the floor used.
        angle_deg, mirrored: rotation (after optional mirror y → −y) applied to the simulation.
        measured, simulated: aligned top views (silhouette, height).
        silhouette_residual: (n, n) int8, +1 measured-only, −1 simulated-only.
        height_residual: (n, n) measured − simulated height, m; NaN where either is off fabric.
        rim_measured, rim_simulated: (360,) rim profiles r(φ), m.
        rim_residual: (360,) r_meas − r_sim, m.
        rim_residual_spectrum: (17,) harmonic amplitudes k = 0..16 of the rim residual, m.
        symmetry: {"odd_fraction": share of residual energy (k ≥ 1) in odd harmonics,
            "mirror_antisymmetric_fraction": share antisymmetric under the warp mirror,
            "low_fraction": share in harmonics 1–2, "dominant_harmonic": k ≥ 1 of largest amplitude}.
        bands: {"near_disc"|"mid"|"hem": {"height_mm": mean signed height residual,
            "height_abs_mm": mean |height residual|, "silhouette": mean |silhouette residual|}}.
        rim_mean_mm: mean rim residual (harmonic 0 with sign), mm.
    """

    errors: dict
    errors_within_floor: bool
    noise_floor: NoiseFloor
    angle_deg: float
    mirrored: bool
    measured: Views
    simulated: Views
    silhouette_residual: np.ndarray
    height_residual: np.ndarray | None
    rim_measured: np.ndarray
    rim_simulated: np.ndarray
    rim_residual: np.ndarray
    rim_residual_spectrum: np.ndarray
    symmetry: dict
    bands: dict
    rim_mean_mm: float

    def summary(self) -> dict:
        """Plain-number digest (JSON-ready)."""
        return {"errors": self.errors, "errors_within_floor": self.errors_within_floor,
                "noise_floor": self.noise_floor.to_dict(), "angle_deg": self.angle_deg, "mirrored": self.mirrored,
                "rim_mean_mm": self.rim_mean_mm,
                "rim_residual_spectrum_mm": [float(v * 1e3) for v in self.rim_residual_spectrum],
                "symmetry": self.symmetry, "bands": self.bands}


def measured_views(m: Measurement) -> Views:
    """Top views of a measurement on the spec grid: the scan rendered spec-exactly when present,
    else the stored silhouette and height map, else a scanned point cloud's alpha-shape mesh
    (``observe.point_cloud_mesh``) rendered, else the rectified photo."""
    if m.has_scan_mesh:
        return _mesh_views(m.scan_vertices, m.scan_faces, N_PIXELS, EXTENT_M)
    if m.silhouette is not None:
        h = m.height if m.height is not None and m.height.shape == m.silhouette.shape else None
        return Views(np.asarray(m.silhouette), None if h is None else np.asarray(h, float), m.silhouette_extent_m)
    if m.height is not None:
        h = np.asarray(m.height, float)
        return Views(np.where(np.isfinite(h), 255, 0).astype(np.uint8), h, m.height_extent_m)
    if m.scan_vertices is not None:
        return _mesh_views(*observe.point_cloud_mesh(m.scan_vertices), N_PIXELS, EXTENT_M)
    if m.photo is not None:
        return Views(photo_silhouette(m, n=N_PIXELS, extent_m=EXTENT_M), None, EXTENT_M)
    raise DiagnoseError(f"{getattr(m, 'path', 'measurement')}: needs a silhouette, a height map, a photo or a scan")


def _mesh_views(verts, faces, n: int, extent_m: float) -> Views:
    """Silhouette and height map of a triangle mesh on the n x n grid of half side ``extent_m``."""
    v, f = np.asarray(verts, float), np.asarray(faces)
    return Views(observe.silhouette(v, f, n=n, extent_m=extent_m), observe.height_map(v, f, n=n, extent_m=extent_m),
                 extent_m, v, f)


def simulated_views(verts: Float[np.ndarray, "n 3"], faces: Int[np.ndarray, "m 3"], like: Views) -> Views:
    """Silhouette and height map of a simulated mesh on the grid of ``like``."""
    return _mesh_views(verts, faces, like.silhouette.shape[0], like.extent_m)


def rotate_float(img: Float[np.ndarray, "n n"], angle_deg: float, *, mirror: bool = False) -> np.ndarray:
    """``observe.rotate_image`` for float maps: NaN stays NaN, outside the image becomes NaN."""
    a = np.asarray(img, np.float32)
    if mirror:
        a = a[::-1]
    n = a.shape[0]
    c = (n - 1) / 2.0
    rot = cv2.getRotationMatrix2D((c, c), float(angle_deg), 1.0)
    return cv2.warpAffine(np.ascontiguousarray(a), rot, (n, n), flags=cv2.INTER_NEAREST,
                          borderMode=cv2.BORDER_CONSTANT, borderValue=float("nan")).astype(float)


def _errors(a: Views, b: Views, iou: float, m: Measurement, scan: bool = True) -> dict:
    kw = dict(specimen_radius_m=m.specimen_radius_m, disk_radius_m=m.disk_radius_m, test=m.test)
    dc = abs(observe.drape_coefficient(a.silhouette, a.extent_m, **kw)
             - observe.drape_coefficient(b.silhouette, b.extent_m, **kw))
    spec = observe.spectral_distance(observe.rim_profile(a.silhouette, a.extent_m, n_angles=N_ANGLES),
                                     observe.rim_profile(b.silhouette, b.extent_m, n_angles=N_ANGLES))
    scan_mm = None
    if scan and a.verts is not None and b.verts is not None:
        scan_mm = observe.scan_distance_mm(b.verts, b.faces, a.verts, a.faces, mirror=True, n_points=2000)
    return {"iou": float(iou), "dc_abs": float(dc), "spectral_mm": float(spec), "scan_mm": scan_mm}


def compare_views(a: Views, b: Views, ma: Measurement, mb: Measurement) -> dict:
    """Error metrics between two captures (b aligned onto a)."""
    del mb
    iou, _, _ = observe.aligned_iou(a.silhouette, b.silhouette, mirror=True, step_deg=2.0)
    return _errors(a, b, iou, ma)


def _harmonic_fractions(resid: np.ndarray, warp_deg: float) -> dict:
    spec = observe.rim_spectrum(resid, N_HARMONICS)
    e = spec[1:] ** 2
    total = float(e.sum())
    k = np.arange(1, N_HARMONICS + 1)
    r0 = resid - resid.mean()
    n = len(r0)
    shift = int(round(2.0 * warp_deg * n / 360.0))
    mirrored = np.roll(r0[::-1], shift + 1)
    anti = 0.5 * (r0 - mirrored)
    sym = 0.5 * (r0 + mirrored)
    e_anti, e_sym = float(np.sum(anti**2)), float(np.sum(sym**2))
    return {"odd_fraction": float(e[k % 2 == 1].sum() / total) if total > 0 else 0.0,
            "low_fraction": float(e[:2].sum() / total) if total > 0 else 0.0,
            "mirror_antisymmetric_fraction": e_anti / (e_anti + e_sym) if e_anti + e_sym > 0 else 0.0,
            "dominant_harmonic": int(np.argmax(spec[1:]) + 1)}


def _bands(sil_res: np.ndarray, h_res: np.ndarray | None, rim_meas: np.ndarray, extent_m: float,
           disk_radius_m: float) -> dict:
    n = sil_res.shape[0]
    c = observe.pixel_centres(n, extent_m)
    x, y = np.meshgrid(c, c[::-1])
    rho = np.hypot(x, y)
    phi = np.mod(np.arctan2(y, x), 2 * np.pi)
    rim = np.interp(phi, 2 * np.pi * np.arange(len(rim_meas) + 1) / len(rim_meas), np.append(rim_meas, rim_meas[0]))
    s = (rho - disk_radius_m) / np.maximum(rim - disk_radius_m, 1e-6)
    out = {}
    for name, lo, hi in BANDS:
        sel = (s >= lo) & (s < hi)
        band = {"silhouette": float(np.abs(sil_res[sel]).mean()) if sel.any() else 0.0}
        if h_res is not None:
            hv = h_res[sel & np.isfinite(h_res)]
            band["height_mm"] = float(hv.mean() * 1e3) if hv.size else 0.0
            band["height_abs_mm"] = float(np.abs(hv).mean() * 1e3) if hv.size else 0.0
        out[name] = band
    return out


def analyse_views(measurement: Measurement, meas: Views, sim: Views, *, noise_floor: NoiseFloor = NoiseFloor(),
                  warp_angle_deg: float | None = None, scan: bool = True) -> ResidualReport:
    """Residual analysis of simulated views against measured views on the same grid.

    Args:
        measurement: provides specimen/disc radii and the test type.
        meas: measured top views.
        sim: simulated top views (same grid), unaligned.
        noise_floor: errors inside it mean nothing is missing.
        warp_angle_deg: warp direction of the simulation before alignment, degrees (default the
            measurement's, 0 when unknown); the mirror statistic is taken about its aligned image.
        scan: compute the scan distance (an alignment of the two surfaces, the costliest error);
            False leaves ``errors["scan_mm"]`` None, for callers that score other errors only.
    """
    if meas.silhouette.shape != sim.silhouette.shape or abs(meas.extent_m - sim.extent_m) > 1e-12:
        raise DiagnoseError(f"measured and simulated views must share a grid, got {meas.silhouette.shape} over "
                            f"±{meas.extent_m} m and {sim.silhouette.shape} over ±{sim.extent_m} m")
    iou, ang, mir = observe.aligned_iou(meas.silhouette, sim.silhouette, mirror=True)
    sil_al = observe.rotate_image(sim.silhouette, ang, mirror=mir)
    h_al = None if sim.height is None else rotate_float(sim.height, ang, mirror=mir)
    v_al = None if sim.verts is None else observe.rotate_about_axis(sim.verts, ang, mirror=mir)
    sim_al = Views(sil_al, h_al, sim.extent_m, v_al, sim.faces)
    errors = _errors(meas, sim_al, iou, measurement, scan=scan)
    sil_res = (meas.silhouette > 127).astype(np.int8) - (sil_al > 127).astype(np.int8)
    h_res = None if meas.height is None or h_al is None else np.asarray(meas.height, float) - h_al
    rim_m = observe.rim_profile(meas.silhouette, meas.extent_m, n_angles=N_ANGLES)
    rim_s = observe.rim_profile(sil_al, sim.extent_m, n_angles=N_ANGLES)
    resid = rim_m - rim_s
    warp = measurement.warp_angle_deg if warp_angle_deg is None else warp_angle_deg
    warp_al = ((-(warp or 0.0)) if mir else (warp or 0.0)) + ang
    return ResidualReport(
        errors=errors, errors_within_floor=noise_floor.within(errors), noise_floor=noise_floor, angle_deg=float(ang),
        mirrored=bool(mir), measured=meas, simulated=sim_al, silhouette_residual=sil_res, height_residual=h_res,
        rim_measured=rim_m, rim_simulated=rim_s, rim_residual=resid,
        rim_residual_spectrum=observe.rim_spectrum(resid, N_HARMONICS),
        symmetry=_harmonic_fractions(resid, warp_al),
        bands=_bands(sil_res, h_res, rim_m, meas.extent_m, measurement.disk_radius_m),
        rim_mean_mm=float(resid.mean() * 1e3))


def analyse(measurement: Measurement, sim_verts: Float[np.ndarray, "n 3"], sim_faces: Int[np.ndarray, "m 3"], *,
            noise_floor: NoiseFloor = NoiseFloor(), warp_angle_deg: float | None = None,
            scan: bool = True) -> ResidualReport:
    """Residual analysis of a simulated rest mesh (m) against a measurement; see ``analyse_views``."""
    meas = measured_views(measurement)
    return analyse_views(measurement, meas, simulated_views(sim_verts, sim_faces, meas), noise_floor=noise_floor,
                         warp_angle_deg=warp_angle_deg, scan=scan)


__all__ = ["NoiseFloor", "Views", "ResidualReport", "DiagnoseError", "measured_views", "simulated_views",
           "analyse", "analyse_views", "compare_views", "rotate_float", "BANDS"]
