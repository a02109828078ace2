"""Gradient refinement of fabric parameters through the simulator (issue 5).

Fitted vector θ (log space): ``log k1`` along warp, weft and bias (k2 scaled with k1, i.e.
the k2/k1 ratio of the initial estimate is kept), followed by the parameters of caller-given
effects. When the areal density is unknown the drape depends on k/ρ only, so ρ is held at its
initial (nominal) value and k/ρ is reported.

Residuals are PHASE-INVARIANT because fold placement is random from drop to drop: the drape
coefficient, the amplitudes of the rim-profile harmonics 1..12 (|FFT| discards the fold phase,
so a rotated or mirrored fold pattern costs nothing and neither the in-plane rotation nor an
unknown warp angle has to be optimised), and, when a height map or scan exists, the mean hem
height. Amplitudes cannot tell warp from weft (a 90° turn swaps them), so when the warp angle is
known one phase-dependent term is added: the second-harmonic component along the warp
(``warp_anisotropy``), a material property rather than a fold placement; when it is unknown, warp
is by convention the stiffer direction of the initial estimate. Terms that the base model keeps
at zero by symmetry are fitted too, so that effects added to the model (``drapejax.effects``)
have something to explain: the world-frame first harmonic (off-centre), the bias shear
(unequal bias rigidities, when the warp angle is known) and, with heights, the mean height on
two rings (the hanging profile's shape). Each is whitened by its re-drop noise floor (DC 0.035, 2 mm per harmonic ≈ 6.2 mm
spectral distance over 12 harmonics, 5 mm hem height). A Gaussian prior in log space around the
initial estimate keeps weakly identified directions in place. Stretching is not fitted (weakly
identifiable from a drape): it stays at the tag/prior estimate of the initial guess.

Values are the HARD observables of the rest mesh (spec-exact renderer, as used for the
measurement); gradients are those of soft surrogates (soft rim profile, vertex hem heights):
``f = soft + stop_gradient(hard - soft)``, so the fit targets exactly what is evaluated while
gradients exist. The rest state is found by a warm-started ``static_solve`` on the host side and
differentiated by ``equilibrium`` (implicit function theorem), never by unrolling.

The optimiser is a Levenberg–Marquardt loop on the whitened residuals written in Python around
jitted (residual, Jacobian) evaluations, because every evaluation warm-starts the forward solve
from the previous accepted rest state (a host-side cache optimistix' pure loop cannot hold);
the damped normal equations are solved with ``lineax``. Uncertainty is the Laplace
(Gauss–Newton) covariance ``(JᵀJ + P)⁻¹`` of θ at the end point.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
from jaxtyping import Array, Float

from .. import observe
from ..energy import AbstractEnergy, default_energies
from ..io import Measurement, load_measurement
from ..material import PARAM_KEYS, FabricParams, bending_length, validity
from ..mesh import ClothMesh, cusick_mesh, square_mesh
from ..photo import photo_silhouette
from ..solve import SolverConfig, drape, equilibrium, quick_config, static_solve
from ..solve._reuse import Same, by_value, reuse

DIRECTIONS = ("warp", "weft", "bias")
N_HARMONICS = 12
SIGMA_DC = 0.035
"""Re-drop noise floor of the drape coefficient."""
SIGMA_HARMONIC_M = 0.002
"""Per-harmonic rim amplitude noise, m (6.2 mm re-drop spectral distance over ~12 harmonics)."""
SIGMA_C1_M = 0.0055
"""Drop-to-drop spread of each world-frame first-harmonic component of the rim, m: fold
placement alone shifts the skirt (rms |c1| 7.8 mm over 6 drop seeds of the "mid" fabric at
20 mm), so only a shift well beyond this points to an off-centre specimen."""
SIGMA_H2_M = 0.004
"""Drop-to-drop spread of the warp-aligned and bias second-harmonic rim components, m
(3.5 and 4.3 mm over the same 6 drops)."""
SIGMA_HEM_M = 0.005
"""Mean hem height noise, m (also used for the ring heights)."""
RING_RADII_M = (0.10, 0.12)
"""World radii (m) of the rings whose mean fabric height (top view) is fitted: with the hem
height they give the hanging profile's shape, which tells a heavier hem from softer fabric."""
PROFILE_RADII_M = (0.095, 0.100, 0.105, 0.110, 0.115, 0.120)
"""World radii (m) of the hanging skirt's height profile that effect selection scores
(``Misfit(profile=True)``): from the disc edge out to where every fold trough is still fabric in
top view (farther out a ring sees fabric only under fold crests, and its mean height swings by
10–20 mm from drop to drop)."""
SIGMA_PROFILE_M = (0.0025, 0.0033, 0.0036, 0.0037, 0.0046, 0.0057)
"""Noise of the ``PROFILE_RADII_M`` ring heights, m: drop-to-drop ⊕ capture-to-capture std over
three drops and three captures of "mid" in eight labs: seven hidden effects and clean (25 mm mesh,
``experiments/k1_ladder.py``), below the 5 mm the fit's two rings use."""
RING_HALF_WIDTH_M = 0.005
EXTENT_M = 0.16
N_ANGLES = 360
K_PRIOR_STD = (math.log(3.0), 0.25)
"""Default log-space prior stds of the overall k1 scale and of the k1 direction ratios (``fit``)."""
FIT_SPACING_M = 0.02
FIT_RIM_SPACING_M = 0.003
"""Default fit mesh of ``estimate`` and ``diagnose``: 20 mm, its rings graded from 3 mm at the
disc edge (487 vertices). The uniform 20 mm mesh droops too far at the disc edge and its fits
came out 2.0-2.5x stiffer than at 5 mm on three real fabrics; this one 1.3x, in about the same
time as uniform 10 mm (``experiments/README.md``)."""
CONTINUATION_CONFIG = quick_config(exact_step_hessian=False, exact_static_hessian=False, linear_solver="direct")
"""Solver of ``fit`` by default: projected Newton only. Its warm-started static solves lag
behind θ (after 200 iterations most are not yet at equilibrium), and the lag keeps the
continuation on one fold pattern. With exact steps the 25 mm "mid" fit of all k1 ×2
(``tests/test_refine.py``) stalls at ½χ² 9.4: on the line to the truth the loss stays at
9.2-9.6 until the drape changes fold pattern 90 % of the way, and the truth then scores 7.5.
A direct host solve on every backend: a fit drapes one member at a time, where the matrix-free
CG path ("auto" on a GPU) only adds inexact steps (it stops short of equilibrium on a thin strip, see
``validate``)."""
EXACT_CONFIG = quick_config(linear_solver="direct")
"""Exact Newton wherever the Hessian is positive definite: every rest state at equilibrium, and
4-7x faster than ``CONTINUATION_CONFIG`` (a warm-started static solve in 9-24 iterations
against 200 unconverged ones); ``estimate``'s default (``experiments/README.md``)."""
SOLVERS = {"continuation": CONTINUATION_CONFIG, "exact": EXACT_CONFIG}

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

Effect = Callable[[ClothMesh, Float[Array, " e"]], tuple[AbstractEnergy, ...]]


class RefineError(ValueError):
    """A measurement or argument the refinement cannot use; the message names it."""


@dataclass(frozen=True)
class Targets:
    """Measured observables: DC, harmonic amplitudes 1..12 (m), mean hem z (m or None), the
    silhouette, the warp-frame 2nd-harmonic components (``warp_anisotropy``, ``bias_shear``; None
    when the warp angle is unknown), the world-frame first harmonic (Re, Im) c1 (m) and the
    ring heights at ``RING_RADII_M`` and ``PROFILE_RADII_M`` (m or None)."""

    dc: float
    harmonics: np.ndarray
    hem_m: float | None
    silhouette: np.ndarray
    aniso_m: float | None
    c1_m: np.ndarray
    shear_m: float | None
    rings_m: np.ndarray | None
    profile_m: np.ndarray | None = None


@dataclass
class FitResult:
    """Outcome of ``fit``: best parameters, θ, its covariance, rest state, losses and status."""

    params: FabricParams
    theta: np.ndarray
    cov: np.ndarray
    x: np.ndarray
    loss_start: float
    loss: float
    steps: int
    status: str
    history: list
    n_residuals: int = 0


LAPLACE_STATUSES = ("converged", "max_steps", "no_improvement_returned_start")
"""``FitResult.status`` values whose ``cov`` is the Laplace one at the fit's end point (``run_lm``;
"nan_returned_start" carries the prior's covariance instead)."""


def _sil_from(m: Measurement) -> tuple[np.ndarray, float]:
    """Top-view silhouette: spec-exact render of the scan mesh when there is one, else the stored
    silhouette, the height map's footprint, the scanned point cloud's view, the rectified photo."""
    if m.has_scan_mesh:
        v = np.asarray(m.scan_vertices, float)
        return observe.silhouette(v, np.asarray(m.scan_faces), n=256, extent_m=EXTENT_M), EXTENT_M
    if m.silhouette is not None:
        return np.asarray(m.silhouette), m.silhouette_extent_m
    if m.height is not None:
        return np.where(np.isfinite(m.height), 255, 0).astype(np.uint8), m.height_extent_m
    if m.scan_vertices is not None:
        return observe.point_cloud_views(m.scan_vertices, n=256, extent_m=EXTENT_M)[0], EXTENT_M
    if m.photo is not None:
        return photo_silhouette(m, extent_m=EXTENT_M), EXTENT_M
    raise RefineError(f"{getattr(m, 'path', 'measurement')}: needs a silhouette, a height map, a photo or a scan")


def _hard_features(sil, extent_m, height, height_extent_m, specimen_radius_m, disk_radius_m, test="cusick"):
    dc = observe.drape_coefficient(sil, extent_m, specimen_radius_m=specimen_radius_m, disk_radius_m=disk_radius_m,
                                   test=test)
    spec = observe.rim_spectrum(observe.rim_profile(sil, extent_m, n_angles=N_ANGLES), N_HARMONICS)[1:]
    hem = None
    if height is not None:
        hem = float(np.nanmean(observe.descriptors.hem_heights_from_height_map(height, height_extent_m)))
    return dc, spec, hem


def measured_targets(m: Measurement) -> Targets:
    """Phase-invariant targets of a measurement (scan rendered with the spec-exact renderer if present;
    a point-cloud scan stands in for a missing height map)."""
    if m.test not in ("cusick", "square"):
        raise RefineError(f"{getattr(m, 'path', 'measurement')}: refinement supports tests 'cusick' and 'square', "
                          f"got {m.test!r}")
    sil, ext = _sil_from(m)
    height, hext = m.height, m.height_extent_m
    if m.has_scan_mesh:
        height = observe.height_map(np.asarray(m.scan_vertices, float), np.asarray(m.scan_faces), n=256,
                                    extent_m=EXTENT_M)
        hext = EXTENT_M
    elif height is None and m.scan_vertices is not None:
        height, hext = observe.point_cloud_views(m.scan_vertices, n=256, extent_m=EXTENT_M)[1], EXTENT_M
    dc, spec, hem = _hard_features(sil, ext, height, hext, m.specimen_radius_m, m.disk_radius_m, m.test)
    profile = observe.rim_profile(sil, ext, n_angles=N_ANGLES)
    aniso = shear = None
    if m.warp_angle_deg is not None:
        aniso, shear = warp_anisotropy(profile, m.warp_angle_deg), bias_shear(profile, m.warp_angle_deg)
    rings = None if height is None else ring_heights(height, hext)
    heights = None if height is None else ring_heights(height, hext, PROFILE_RADII_M)
    return Targets(dc=float(dc), harmonics=spec, hem_m=hem, silhouette=sil, aniso_m=aniso, c1_m=first_harmonic(profile),
                   shear_m=shear, rings_m=rings, profile_m=heights)


def warp_anisotropy(profile: Float[np.ndarray, " a"], warp_angle_deg: float) -> float:
    """2·Re(c₂ e^{-2iψ}) of the rim profile r(φ) (m): > 0 when the drape reaches farther along the warp.

    The only phase-dependent residual: warp and weft are swapped by a 90° rotation, which the
    harmonic amplitudes cannot see, so when the warp angle ψ is known this ±-sign of the
    second harmonic along the warp tells the stiffer direction.
    """
    r = np.asarray(profile, float)
    phi = 2 * np.pi * np.arange(len(r)) / len(r)
    return float(2.0 * np.mean(r * np.cos(2.0 * (phi - np.deg2rad(warp_angle_deg)))))


def bias_shear(profile: Float[np.ndarray, " a"], warp_angle_deg: float) -> float:
    """2·Im(c₂ e^{-2iψ}) of r(φ) (m): > 0 when the drape reaches farther along the +45° bias than
    the −45° one. Zero by symmetry for any material the base model has (equal bias directions)."""
    r = np.asarray(profile, float)
    phi = 2 * np.pi * np.arange(len(r)) / len(r)
    return float(2.0 * np.mean(r * np.sin(2.0 * (phi - np.deg2rad(warp_angle_deg)))))


def first_harmonic(profile: Float[np.ndarray, " a"]) -> np.ndarray:
    """(Re, Im) of 2·c₁ of r(φ) in the world frame (m): how far, and towards where, the drape is
    off-centre. Zero by symmetry for a centred specimen of any homogeneous material."""
    r = np.asarray(profile, float)
    phi = 2 * np.pi * np.arange(len(r)) / len(r)
    return np.array([2.0 * np.mean(r * np.cos(phi)), 2.0 * np.mean(r * np.sin(phi))])


def ring_heights(height: Float[np.ndarray, "n n"], extent_m: float,
                 radii_m: Sequence[float] = RING_RADII_M) -> np.ndarray:
    """Mean top-view fabric height (m) in thin rings at ``radii_m`` (NaN-free fabric pixels)."""
    z = np.asarray(height, float)
    c = observe.pixel_centres(z.shape[0], extent_m)
    xx, yy = np.meshgrid(c, c[::-1])
    rho = np.hypot(xx, yy)
    out = []
    for r0 in radii_m:
        sel = (np.abs(rho - r0) <= RING_HALF_WIDTH_M) & np.isfinite(z)
        out.append(float(z[sel].mean()) if sel.any() else 0.0)
    return np.array(out)


def _params_at(init: FabricParams, theta_k: Float[Array, " 3"]) -> FabricParams:
    s = jnp.exp(theta_k)
    kw = {f: getattr(init, f) for f in PARAM_KEYS}
    for i, d in enumerate(DIRECTIONS):
        kw[f"bend_k1_{d}"] = getattr(init, f"bend_k1_{d}") * s[i]
        kw[f"bend_k2_{d}"] = getattr(init, f"bend_k2_{d}") * s[i]
    return FabricParams(**kw)


def _soft_features(x, mesh: ClothMesh, spacing_m: float):
    """Soft feature vector of rest positions x (n,3), laid out as ``Problem.hard`` (see ``_F``)."""
    r = observe.soft_rim_profile(x, sharpness=2.0 / spacing_m * 10.0, n_angles=N_ANGLES, vertex_radius_m=spacing_m)
    info = mesh.info
    area = 0.5 * jnp.mean(r**2) * 2 * jnp.pi
    disc = math.pi * info.disk_radius_m**2
    square = info.test == "square"
    dc = (area - disc) / (observe.descriptors.specimen_area_m2(info.test, info.specimen_radius_m) - disc)
    c = jnp.fft.rfft(r)[1:N_HARMONICS + 1] / N_ANGLES
    amp = 2.0 * jnp.sqrt(jnp.real(c) ** 2 + jnp.imag(c) ** 2 + 1e-12)
    rad = jnp.max(jnp.abs(mesh.rest[:, :2]), axis=1) if square else jnp.linalg.norm(mesh.rest[:, :2], axis=1)
    hem = rad > info.specimen_radius_m - 0.5 * spacing_m
    z = jnp.sum(jnp.where(hem, x[:, 2], 0.0)) / jnp.sum(hem)
    phi = 2 * jnp.pi * jnp.arange(N_ANGLES) / N_ANGLES
    psi = jnp.deg2rad(info.warp_angle_deg)
    aniso = 2.0 * jnp.mean(r * jnp.cos(2.0 * (phi - psi)))
    shear = 2.0 * jnp.mean(r * jnp.sin(2.0 * (phi - psi)))
    c1 = 2.0 * jnp.stack([jnp.mean(r * jnp.cos(phi)), jnp.mean(r * jnp.sin(phi))])
    rho = jnp.linalg.norm(x[:, :2], axis=1)
    rings = []
    for r0 in RING_RADII_M:
        w = mesh.vertex_area * jnp.exp(-0.5 * ((rho - r0) / RING_HALF_WIDTH_M) ** 2)
        rings.append(jnp.sum(w * x[:, 2]) / jnp.maximum(jnp.sum(w), 1e-12))
    return jnp.concatenate([dc[None], amp, z[None], aniso[None], shear[None], c1, jnp.stack(rings)])


_F = {"dc": 0, "amp": 1, "hem": 1 + N_HARMONICS, "aniso": 2 + N_HARMONICS, "shear": 3 + N_HARMONICS,
      "c1": 4 + N_HARMONICS, "rings": 6 + N_HARMONICS}
"""Layout of the feature vector (soft and hard): DC, harmonic amplitudes 1..12, mean hem z,
warp anisotropy, bias shear, first harmonic (Re, Im), ring heights."""


def _fold_rms(amp: np.ndarray) -> float:
    """RMS amplitude (m) of rim harmonics 3..12: fold depth, independent of fold phase and count."""
    return float(np.sqrt(np.mean(np.asarray(amp)[2:] ** 2)))


class Misfit:
    """Noise-whitened data residuals of a rest state against one measurement's targets.

    Every row is (simulated feature − measured) / its drop-to-drop noise (``SIGMA_*``), so
    ½‖r‖² is a misfit in noise units that any capture of the specimen can score (held-out
    evidence in effect selection).

    With ``profile``, the two fitted rings give way to the skirt's height profile
    (``PROFILE_RADII_M``, each ring over its own noise ``SIGMA_PROFILE_M``): the rows effect
    selection scores fresh drops by. Effects that reshape the skirt (a heavier hem, edge curl,
    an off-centre specimen) move the profile by more than its noise where k1 alone cannot
    follow. The fit keeps the coarser rings: with a tight height profile to chase, a k1-only fit
    gives up the drape coefficient (``experiments/README.md``, ``effect_detectability.py``).
    Profile rows have no Jacobian (``Problem`` raises when asked for one).
    """

    def __init__(self, mesh: ClothMesh, targets: Targets, profile: bool = False):
        self.mesh, self.targets = mesh, targets
        self.use_hem = targets.hem_m is not None
        self.profile = profile and self.use_hem and targets.profile_m is not None

    def hard(self, x: np.ndarray) -> np.ndarray:
        info = self.mesh.info
        faces = np.asarray(self.mesh.faces)
        sil = observe.silhouette(x, faces, n=256, extent_m=EXTENT_M)
        hm = observe.height_map(x, faces, n=256, extent_m=EXTENT_M) if self.use_hem else None
        dc, spec, hem = _hard_features(sil, EXTENT_M, hm, EXTENT_M, info.specimen_radius_m, info.disk_radius_m,
                                       info.test)
        prof = observe.rim_profile(sil, EXTENT_M, n_angles=N_ANGLES)
        rings = ring_heights(hm, EXTENT_M) if self.use_hem else np.zeros(len(RING_RADII_M))
        heights = ring_heights(hm, EXTENT_M, PROFILE_RADII_M) if self.profile else np.zeros(0)
        return np.concatenate([[dc], spec, [hem if hem is not None else 0.0, warp_anisotropy(prof, info.warp_angle_deg),
                                            bias_shear(prof, info.warp_angle_deg)], first_harmonic(prof), rings,
                               heights])

    def _rows(self):
        """(feature index, target, sigma) of every residual but the fold depth, in order."""
        t = self.targets
        rows = [(_F["dc"], t.dc, SIGMA_DC)]
        rows += [(_F["c1"] + i, t.c1_m[i], SIGMA_C1_M) for i in range(2)]
        if self.use_hem:
            rows.append((_F["hem"], t.hem_m, SIGMA_HEM_M))
            if self.profile:
                i0 = _F["rings"] + len(RING_RADII_M)
                rows += [(i0 + i, t.profile_m[i], s) for i, s in enumerate(SIGMA_PROFILE_M)]
            else:
                rows += [(_F["rings"] + i, t.rings_m[i], SIGMA_HEM_M) for i in range(len(RING_RADII_M))]
        if t.aniso_m is not None:
            rows += [(_F["aniso"], t.aniso_m, SIGMA_H2_M), (_F["shear"], t.shear_m, SIGMA_H2_M)]
        return rows

    def _whiten(self, f: np.ndarray) -> np.ndarray:
        amp = f[_F["amp"]:_F["amp"] + N_HARMONICS]
        fold = (_fold_rms(amp) - _fold_rms(self.targets.harmonics)) / SIGMA_HARMONIC_M
        return np.array([fold] + [(f[i] - t) / s for i, t, s in self._rows()])

    def _whiten_jac(self, jf: np.ndarray) -> np.ndarray:
        a = self._last_amp
        g = a[2:] / max(_fold_rms(a) * (N_HARMONICS - 2), 1e-12)
        i0 = _F["amp"] + 2
        fold = (g @ jf[i0:_F["amp"] + N_HARMONICS])[None] / SIGMA_HARMONIC_M
        return np.concatenate([fold] + [jf[i:i + 1] / s for i, _, s in self._rows()])

    @property
    def n_rows(self) -> int:
        """Number of data residuals (fold depth plus ``_rows``)."""
        return 1 + len(self._rows())

    def loss(self, x: np.ndarray) -> float:
        """½‖r‖² of the data rows (no prior) at rest state x."""
        r = self._whiten(self.hard(x))
        return 0.5 * float(r @ r)


class Problem(Misfit):
    """Whitened residuals r(θ) of one measurement, with a warm-started host-side rest-state cache.

    Args:
        mesh: simulation mesh (its warp angle is the measured one, or 0 when unknown).
        targets: measured observables.
        init: initial parameters (density = nominal when unknown).
        effects: callables ``effect(mesh, theta_e) -> tuple[AbstractEnergy, ...]``.
        theta0: prior mean of θ: 3 log-k1 scales then the effect vector (every effect receives
            the whole effect vector θ[3:]).
        prior_std: (overall k1 scale, direction ratios, effects...) prior stds, see
            ``prior_sqrt_information``.
        spacing_m: mesh spacing, m.
        lower: smallest allowed θ (default: unbounded), e.g. the physical limits of effects.
        profile: score the height profile (``Misfit``); for evaluating drops only, not for fitting.
        config: solver of the drops and warm-started static solves (``CONTINUATION_CONFIG`` or
            ``EXACT_CONFIG``).
        buckling: the base model's membrane caps compression at the element scale
            (``energy.Membrane``).
    """

    def __init__(self, mesh: ClothMesh, targets: Targets, init: FabricParams, effects: Sequence[Effect],
                 theta0: np.ndarray, prior_std: np.ndarray, spacing_m: float, lower: np.ndarray | None = None,
                 profile: bool = False, config: SolverConfig = CONTINUATION_CONFIG, buckling: bool = False):
        super().__init__(mesh, targets, profile)
        self.init, self.effects = init, tuple(effects)
        self.theta0, self.spacing_m = np.asarray(theta0, float), spacing_m
        self.lower = np.full(len(self.theta0), -np.inf) if lower is None else np.asarray(lower, float)
        self.prior_sqrt_info = prior_sqrt_information(np.asarray(prior_std, float), len(self.theta0))
        self.max_step = np.concatenate([np.ones(3), 2.0 / np.diag(self.prior_sqrt_info)[3:]])
        self.base = default_energies(mesh.info.test, buckling=buckling)
        self.config = config
        key = ("problem", Same(mesh), by_value(init), self.effects, config, float(spacing_m), buckling)
        self._split, self._drape, self._static, self._soft, self._soft_jac = reuse(
            key, lambda: _problem_functions(mesh, init, self.base, self.effects, config, spacing_m))
        self.x = None

    def rest(self, theta: np.ndarray, seed: int) -> np.ndarray:
        """Rest state at θ: warm-started static solve from the cached state, else a quick drape.

        NaN where θ gives impossible parameters (``material.validity``, e.g. a bias rigidity no
        positive-definite plate has): the drape would otherwise return the rest state of the
        safe stand-in material it drops such a member with, and the static solve a state of a
        non-convex one, either scored as if it were θ's. The warm-started solve's status is not
        checked: with ``CONTINUATION_CONFIG`` most stop short of the equilibrium by design (the
        lag keeps the fit on one fold pattern), and with ``EXACT_CONFIG`` all 99 of four
        virtual-lab diagnoses converged (``experiments/README.md``)."""
        th = jnp.asarray(theta)
        if not bool(validity(_params_at(self.init, th[:3]))):
            return np.full(np.shape(self.mesh.rest), np.nan)
        if self.x is None:
            return np.asarray(self._drape(th, seed).x)
        return np.asarray(self._static(th, jnp.asarray(self.x)).x)

    def drop(self, theta: np.ndarray, seed: int) -> np.ndarray:
        """Rest state of a fresh drop at θ (the cached state is dropped, not warm-started from)."""
        self.x = None
        return self.rest(theta, seed)

    def params(self, theta: np.ndarray) -> FabricParams:
        """The fabric at θ: ``init`` with its k1 and k2 per direction scaled by exp(θ[:3])."""
        return jax.tree.map(lambda a: jnp.asarray(a), _params_at(self.init, jnp.asarray(np.asarray(theta)[:3])))

    def prior_residual(self, theta):
        return self.prior_sqrt_info @ (np.asarray(theta) - self.theta0)

    def evaluate(self, theta: np.ndarray, x: np.ndarray, jacobian: bool):
        """(whitened residuals incl. prior, Jacobian or None) at θ with rest state x."""
        r = np.concatenate([self._whiten(self.hard(x)), self.prior_residual(theta)])
        if not jacobian:
            return r, None
        if self.profile:
            raise RefineError("Problem.evaluate: the height-profile rows have no Jacobian; fit with profile=False")
        jf = np.asarray(self._soft_jac(jnp.asarray(theta), jnp.asarray(x)))
        self._last_amp = np.asarray(self._soft(jnp.asarray(theta), jnp.asarray(x)))[_F["amp"]:_F["amp"] + N_HARMONICS]
        j = np.concatenate([self._whiten_jac(jf), self.prior_sqrt_info])
        return r, j


def _problem_functions(mesh: ClothMesh, init: FabricParams, base: tuple, effects: tuple, config: SolverConfig,
                       spacing_m: float):
    """``Problem``'s jitted drop, warm-started static solve and soft features (with their Jacobian)
    at θ; shared by every problem of the same mesh, fabric, effects and solver (``reuse``)."""
    n_k = 3

    def split(theta):
        return _params_at(init, theta[:n_k]), base + tuple(t for e in effects for t in e(mesh, theta[n_k:]))

    def soft(theta, x_rest):
        p, terms = split(theta)
        x = equilibrium(mesh, p, x_rest, terms=terms)
        return _soft_features(x, mesh, spacing_m)

    return (split,
            jax.jit(lambda theta, seed: drape(mesh, split(theta)[0], seed, terms=split(theta)[1], config=config)),
            jax.jit(lambda theta, x0: static_solve(mesh, split(theta)[0], x0, terms=split(theta)[1], config=config)),
            jax.jit(soft), jax.jit(jax.jacfwd(soft)))


def prior_sqrt_information(prior_std: np.ndarray, n: int) -> np.ndarray:
    """Square root L of the prior precision of θ, in (overall scale, ratio) coordinates.

    The drape pins the overall bending stiffness (geometric mean of the three k1) far better
    than the split between directions (warp and weft trade off nearly freely on coarse
    meshes), so the prior is loose on the scale and tight on the ratios warp/weft and
    bias/√(warp·weft), which then stay near the network's. ``prior_std`` = (scale std, ratio
    std, effect stds...), all in log space.
    """
    s = np.broadcast_to(prior_std, (n - 1,)) if np.ndim(prior_std) == 0 else np.asarray(prior_std)
    if s.shape != (n - 1,):
        raise RefineError(f"prior_std: expected {n - 1} values (scale, ratio, {n - 3} effect), got {s.shape[0]}")
    a = np.zeros((n, n))
    a[0, :3] = np.array([1.0, 1.0, 1.0]) / 3.0 / s[0]
    a[1, :3] = np.array([1.0, -1.0, 0.0]) / s[1]
    a[2, :3] = np.array([-0.5, -0.5, 1.0]) / s[1]
    for i in range(3, n):
        a[i, i] = 1.0 / s[i - 1]
    return a


def _lm_step(j: np.ndarray, r: np.ndarray, lam: float) -> np.ndarray:
    """Levenberg–Marquardt step: solve (JᵀJ + λ diag(JᵀJ)) δ = -Jᵀr with lineax."""
    a = j.T @ j
    a = a + lam * np.diag(np.diag(a))
    op = lx.MatrixLinearOperator(jnp.asarray(a), lx.positive_semidefinite_tag)
    return np.asarray(lx.linear_solve(op, jnp.asarray(-j.T @ r), lx.Cholesky()).value)


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


def fit(measurement: Measurement, *, init: FabricParams, spacing_m: float = 0.02, effects: Sequence[Effect] = (),
        theta_effects0: np.ndarray | None = None, prior_std: np.ndarray | None = None,
        max_steps: int = 8, seed: int = 0, mesh: ClothMesh | None = None, start: FitResult | None = None,
        lower_effects: np.ndarray | None = None, config: SolverConfig = CONTINUATION_CONFIG,
        buckling: bool = False) -> FitResult:
    """Refine the bending rigidities (and effect parameters) of ``init`` against ``measurement``.

    Args:
        measurement: a Cusick or square measurement (any of its observations).
        init: initial parameters; scalar fields (density = nominal value when unknown).
        spacing_m: simulation mesh spacing, m.
        effects: extra energy terms as functions of their parameter vector θ_e.
        theta_effects0: initial/prior-mean θ_e (required when ``effects`` is given).
        prior_std: log-space prior stds (overall k1 scale, k1 direction ratios, effects...);
            default (log 3, 0.25, 1 per effect).
        max_steps: Levenberg–Marquardt iterations.
        seed: drop seed of the first forward solve (unused with ``start``).
        mesh: optional pre-built mesh (default ``fit_mesh(measurement, spacing_m)``).
        start: an earlier fit of this measurement on ``mesh`` to continue from instead of dropping
            afresh: θ starts at ``start.theta`` (its k1 scales and effects, which must lead
            ``effects``), extended by ``theta_effects0`` for the added effects, and the rest state
            at ``start.x``; the prior mean stays (init, ``theta_effects0``). With the added effects
            at null and the same prior as ``start``, the refit is nested in it (same fold pattern,
            loss never above its), so a gain measures the effects, not a new fold pattern.
        lower_effects: smallest allowed θ_e (e.g. ``Effect.lower_bound()``; default unbounded).
        config: the solver (``Problem``).
        buckling: cap the membrane's compression at the element scale (``energy.Membrane``), so
            that a soft fabric can fold on a coarse fit mesh.

    Returns:
        ``FitResult``; ``status`` is "converged", "max_steps", "nan_returned_start" (the start
        was not finite) or "no_improvement_returned_start" (no step lowered the loss).
    """
    if effects and theta_effects0 is None:
        raise RefineError("fit: theta_effects0 is required when effects are given")
    th_e = np.zeros(0) if theta_effects0 is None else np.asarray(theta_effects0, float).ravel()
    theta0 = np.concatenate([np.zeros(3), th_e])
    pstd = np.concatenate([K_PRIOR_STD, np.ones(len(th_e))]) if prior_std is None else prior_std
    th_start = theta0 if start is None else np.asarray(start.theta, float)
    if len(th_start) > len(theta0):
        raise RefineError(f"fit: start has {len(th_start)} parameters, more than the {len(theta0)} of this fit")
    if mesh is None:
        mesh = fit_mesh(measurement, spacing_m)
    lower = None if lower_effects is None else np.concatenate([np.full(3, -np.inf), np.ravel(lower_effects)])
    prob = Problem(mesh, measured_targets(measurement), init, effects, theta0, pstd, spacing_m, lower, config=config,
                   buckling=buckling)
    if start is not None:
        prob.x = np.asarray(start.x)
    return run_lm(prob, np.concatenate([th_start, theta0[len(th_start):]]), max_steps=max_steps, seed=seed)


def run_lm(prob: Problem, theta0: np.ndarray, *, max_steps: int, seed: int = 0, lam0: float = 1e-2,
           tol: float = 1e-3) -> FitResult:
    """Levenberg–Marquardt from θ0 with rejection of NaN/worse steps; never ends worse than θ0.
    Steps are projected onto θ ≥ ``prob.lower``."""
    theta = np.asarray(theta0, float)
    x = prob.rest(theta, seed)
    r, j = prob.evaluate(theta, x, jacobian=True)
    loss0 = loss = 0.5 * float(r @ r)
    history = [loss]
    if not (np.isfinite(loss) and np.all(np.isfinite(j))):
        cov = np.linalg.inv(prob.prior_sqrt_info.T @ prob.prior_sqrt_info)
        return FitResult(prob.params(theta), theta, cov, x, loss0, loss0, 0, "nan_returned_start", history,
                         len(r) - len(theta))
    prob.x = x
    lam, status, steps, improved = lam0, "max_steps", 0, False
    for steps in range(1, max_steps + 1):
        delta = _lm_step(j, r, lam)
        cand = np.maximum(theta + np.clip(delta, -prob.max_step, prob.max_step), prob.lower)
        try:
            xc = prob.rest(cand, seed)
            lc = np.nan
            if np.all(np.isfinite(xc)):
                rc, _ = prob.evaluate(cand, xc, jacobian=False)
                lc = 0.5 * float(rc @ rc)
        except (FloatingPointError, ValueError):
            lc = np.nan
        if np.isfinite(lc) and lc < loss:
            gain = loss - lc
            theta, x, loss, improved = cand, xc, lc, True
            prob.x = x
            r, j = prob.evaluate(theta, x, jacobian=True)
            lam = max(lam / 3.0, 1e-6)
            history.append(loss)
            if gain < tol * max(loss, 1.0) or np.max(np.abs(delta) / prob.max_step) < 1e-3:
                status = "converged"
                break
        else:
            lam *= 10.0
            history.append(loss)
            if lam > 1e4:
                status = "converged" if improved else "no_improvement_returned_start"
                break
    cov = np.linalg.inv(j.T @ j)
    return FitResult(prob.params(theta), theta, cov, x, loss0, loss, steps, status, history, len(r) - len(theta))


def laplace_cov(prob: Problem, theta: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Gauss–Newton (Laplace) covariance ``(JᵀJ)⁻¹`` of θ at θ with rest state ``x``, prior rows
    included: the covariance ``run_lm`` reports at its end point, for a model reached otherwise
    (a fresh drop kept by a scan)."""
    _, j = prob.evaluate(np.asarray(theta, float), np.asarray(x), jacobian=True)
    return np.linalg.inv(j.T @ j)


def reported_params(p: FabricParams, density_known: bool, sd_log: np.ndarray | None = None) -> tuple[dict, dict]:
    """(params, std) of ``p`` in the ``drapejax estimate`` schema: SI keys, or k/ρ keys
    (``*_per_density``, no density) when the density is unknown; ``std`` is k1 × the log-space
    std ``sd_log`` per direction (warp, weft, bias), null for parameters not refined."""
    pd = p.to_dict()
    scale = 1.0 if density_known else 1.0 / float(pd["density"])
    params, std = {}, {}
    for k, v in pd.items():
        if not density_known and k == "density":
            continue
        name = k if (density_known or k.startswith("stretch_beta")) else k + "_per_density"
        val = float(v) * (1.0 if k.startswith("stretch_beta") else scale)
        params[name] = val
        std[name] = None
        if sd_log is not None and k.startswith("bend_k1_"):
            std[name] = val * float(sd_log[DIRECTIONS.index(k.split("_")[-1])])
    return params, std


# --------------------------------------------------------------------------- estimate


def _initial_guess(m: Measurement, buckling: bool = False) -> tuple[dict, str]:
    """Network estimate (SI or density-normalised dict) and its source name; ``buckling``: by the
    packaged models that go with the capped membrane (``InverseModel.for_measurement``)."""
    from ..inverse.estimate import InverseModel

    return InverseModel.for_measurement(m, buckling=buckling).estimate_no_refine(m)["params"], "network"


def _to_fabric(params: dict, density: float | None, nominal_density: float) -> FabricParams:
    if density is not None:
        return FabricParams.from_dict(params, source="initial estimate")
    vals = {"density": nominal_density}
    for k, v in params.items():
        if k.endswith("_per_density"):
            vals[k[: -len("_per_density")]] = v * nominal_density
        else:
            vals[k] = v
    return FabricParams.from_dict(vals, source="initial estimate")


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


def best_combination(info: Float[np.ndarray, "k k"]) -> tuple[np.ndarray, float | None]:
    """Best-determined linear combination of the parameters under the information matrix ``info``.

    Returns the leading eigenvector, scaled so that its weights sum to 1 in absolute value with
    the largest positive, and the std of that combination (None when ``info`` carries nothing).
    """
    w, v = np.linalg.eigh(0.5 * (info + info.T))
    best = v[:, -1] / np.sum(np.abs(v[:, -1]))
    best = best if best[np.argmax(np.abs(best))] > 0 else -best
    return best, (float(np.linalg.norm(best) / np.sqrt(w[-1])) if w[-1] > 0 else None)


def identified(cov: Float[np.ndarray, "3 3"], prior_std: Sequence[float] = K_PRIOR_STD) -> dict:
    """What the data, rather than the prior, determine of log k1 (warp, weft, bias) in a fit.

    A fit's precision ``cov⁻¹`` is the data's information plus the prior's
    (``prior_sqrt_information``), so their difference is what the drape told. One capture
    typically pins one combination of the three k1 to a few per cent and leaves another free
    (``experiments/k1_information.py``), so per direction this reports the share of the
    posterior precision that the data supply: near 0 the value restates the prior (the
    network's direction ratios), near 1 the drape set it.

    Returns:
        ``{"weights": (3,), "std_log": float | None, "data_share": (3,)}``: the best-determined
        combination of log k1 (``best_combination`` of the data information) with its data-only
        std, and the data's share per direction.
    """
    cov = np.asarray(cov, float)
    if cov.shape != (3, 3):
        raise RefineError(f"identified: expected the 3x3 covariance of log k1, got shape {cov.shape}")
    lp = prior_sqrt_information(np.asarray(prior_std, float), 3)
    prec = np.linalg.inv(cov)
    data = prec - lp.T @ lp
    best, std = best_combination(data)
    share = np.clip(np.diag(data) / np.diag(prec), 0.0, 1.0)
    return {"weights": best, "std_log": std, "data_share": share}


def estimate(folder_or_measurement: str | Path | Measurement, *, refine: bool = True,
             spacing_m: float = FIT_SPACING_M, rim_spacing_m: float | None = FIT_RIM_SPACING_M, seed: int = 0,
             max_steps: int = 8, nominal_density: float = 0.2, config: SolverConfig = EXACT_CONFIG,
             buckling: bool = False) -> dict:
    """Network estimate refined through the simulator, in the ``drapejax estimate --json`` schema.

    ``config`` is the fit's solver (``EXACT_CONFIG``: exact Newton, every rest state at equilibrium).
    ``buckling`` fits with the membrane's compression capped at the element scale
    (``energy.Membrane``), which lets a soft fabric fold on the coarse fit mesh, and starts a scan
    from the 3DH models trained on such drapes (``InverseModel.for_measurement``).

    Returns:
        ``{"params", "std", "identified", "density_normalized", "fit": {"dc_measured",
        "dc_simulated", "iou", "scan_mm"}, "status", "init", "spacing_m", "rim_spacing_m", "buckling",
        "bending_length_mm", "warnings", "seconds"}``; ``warnings`` lists reasons to distrust the
        estimate (``mesh_warnings`` of the softer of the initial and the fitted parameters: a
        locked fit can come out too stiff; k1 directions the drape hardly informed).
        ``identified`` (null without refinement) is ``identified`` of the fit keyed by the k1
        names: ``combination_log`` (weights of the best-determined log-k1 combination),
        ``std_log`` (its data-only std) and ``data_share`` per direction.
        ``params``/``std`` hold k/ρ keys (``*_per_density``) when the density is unknown;
        ``std`` covers the fitted k1 (Laplace) and is null for parameters that are not refined
        (stretching, k2 ratio: prior values). ``spacing_m``/``rim_spacing_m`` describe the fit
        mesh (``fit_mesh``: a square mesh is uniform): the drape is not mesh-converged, and on three real fabrics the
        default mesh's k1 came out 1.3× the uniform 5 mm fits' (``experiments/README.md``).
    """
    t0 = time.perf_counter()
    m = folder_or_measurement if isinstance(folder_or_measurement, Measurement) else load_measurement(
        folder_or_measurement)
    rho = m.areal_density_kg_m2
    guess, source = _initial_guess(m, buckling)
    init = _to_fabric(guess, rho, nominal_density)
    mesh = fit_mesh(m, spacing_m, rim_spacing_m)
    if refine:
        res = fit(m, init=init, spacing_m=spacing_m, max_steps=max_steps, seed=seed, mesh=mesh, config=config,
                  buckling=buckling)
        p, x, status = res.params, res.x, res.status
        sd_log = np.sqrt(np.diag(res.cov))[:3]
        ident = identified(res.cov)
    else:
        p = init
        terms = default_energies(mesh.info.test, buckling=buckling)
        x = np.asarray(jax.jit(lambda q: drape(mesh, q, seed, terms=terms, config=config))(init).x)
        status, sd_log, ident = "not_refined", None, None
    params, std = reported_params(p, rho is not None, sd_log)
    fit_block = compare(x, np.asarray(mesh.faces), m)
    warnings = mesh_warnings(min(p, init, key=bending_length_m), spacing_m, buckling)
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
            "status": status, "init": source, "spacing_m": spacing_m,
            "rim_spacing_m": rim_spacing_m, "buckling": buckling, "bending_length_mm": bending_length_m(p) * 1e3,
            "warnings": warnings, "seconds": time.perf_counter() - t0}


__all__ = ["fit", "fit_mesh", "estimate", "identified", "laplace_cov", "reported_params", "best_combination", "SOLVERS",
           "CONTINUATION_CONFIG", "EXACT_CONFIG", "bending_length_m", "mesh_warnings", "run_lm", "measured_targets",
           "Misfit", "Problem", "FitResult", "LAPLACE_STATUSES", "Targets", "RefineError"]
