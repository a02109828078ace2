"""Noise-whitened misfit of a rest state against one capture's targets (``Misfit``).

Every residual row is divided by its drop-to-drop noise floor (``SIGMA_*``, measured over
re-drops of one fabric), so that ½‖r‖² counts noise units: the fit minimises it, and effect
selection compares it across captures and models. The rows come from the observation types of
``observe.types.REGISTRY`` that the targets hold, in registry order: each type's
``misfit_rows`` (and ``misfit_jacobian``) over the shared feature vector (``observables._F``)
for the library's types, over its own features (appended after it) for any other.
"""

from __future__ import annotations

import numpy as np

from .. import observe
from ..mesh import ClothMesh
from ..observe.types import REGISTRY, CoreObservation
from .observables import (EXTENT_M, N_ANGLES, PROFILE_RADII_M, RING_RADII_M, Targets, bias_shear, first_harmonic,
                          hard_features, height_first_harmonic, ring_heights, warp_anisotropy)

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
SIGMA_PROFILE_M = (0.0025, 0.0033, 0.0036, 0.0037, 0.0046, 0.0057)
"""Noise of the ``PROFILE_RADII_M`` ring heights, m: drop-to-drop ⊕ capture-to-capture std over
three drops and three captures of "mid" in eight labs: seven hidden effects and clean (25 mm mesh,
``experiments/k1_ladder.py``), below the 5 mm the fit's two rings use."""
SIGMA_HEIGHT_C1_M = 0.0025
"""Drop-to-drop spread of each world-frame first-harmonic component of the skirt's height
(``observables.height_first_harmonic``), m: rms about zero over drops of centred specimens on
the default fit mesh, 1.3 mm for "mid" (6 seeds), 0.6 mm for "heavy" and 2.6 mm for "light" (3
each); the largest is taken. A specimen 13 mm off-centre gives −7.6 to −8.5 mm on Style3D."""


class Misfit:
    """Noise-whitened data residuals of a rest state against one measurement's targets.

    Every row is (simulated feature − measured) / its drop-to-drop noise (``SIGMA_*``), so
    ½‖r‖² is a misfit in noise units that any capture of the specimen can score (held-out
    evidence in effect selection).

    With ``profile``, the two fitted rings give way to the skirt's height profile
    (``PROFILE_RADII_M``, each ring over its own noise ``SIGMA_PROFILE_M``) and the world-frame
    first harmonic of the height on those rings (over ``SIGMA_HEIGHT_C1_M``): the rows effect
    selection scores fresh drops by. Effects that reshape the skirt (a heavier hem, edge curl,
    an off-centre specimen) move the profile by more than its noise where k1 alone cannot
    follow. The fit keeps the coarser rings: with a tight height profile to chase, a k1-only fit
    gives up the drape coefficient (``docs/results/2026-11-24-effect-detectability.md``, ``effect_detectability.py``).
    Profile rows have no Jacobian (``Problem`` raises when asked for one).
    """

    def __init__(self, mesh: ClothMesh, targets: Targets, profile: bool = False):
        self.mesh, self.targets = mesh, targets
        self.use_hem = targets.hem_m is not None
        self.profile = profile and self.use_hem and targets.profile_m is not None
        self.observations = [(obs, meas) for obs in REGISTRY.values()
                             if (meas := obs.measured(targets, profile=profile)) is not None]
        # (observation type, its measured side) of every type the targets hold, in row order

    @property
    def own_observations(self) -> tuple:
        """The types among ``observations`` with features of their own (after the shared vector)."""
        return tuple(obs for obs, _ in self.observations if not isinstance(obs, CoreObservation))

    def hard(self, x: np.ndarray) -> np.ndarray:
        info = self.mesh.info
        faces = np.asarray(self.mesh.faces)
        sil = observe.silhouette(x, faces, n=256, extent_m=EXTENT_M)
        hm = observe.height_map(x, faces, n=256, extent_m=EXTENT_M) if self.use_hem else None
        dc, spec, hem = hard_features(sil, EXTENT_M, hm, EXTENT_M, info.specimen_radius_m, info.disk_radius_m,
                                      info.test)
        prof = observe.rim_profile(sil, EXTENT_M, n_angles=N_ANGLES)
        rings = ring_heights(hm, EXTENT_M) if self.use_hem else np.zeros(len(RING_RADII_M))
        heights = ring_heights(hm, EXTENT_M, PROFILE_RADII_M) if self.profile else np.zeros(0)
        if self.profile and self.targets.height_c1_m is not None:
            heights = np.r_[heights, height_first_harmonic(hm, EXTENT_M)]
        own = [np.asarray(obs.features(x, self.mesh), float).ravel() for obs in self.own_observations]
        return np.concatenate([[dc], spec, [hem if hem is not None else 0.0, warp_anisotropy(prof, info.warp_angle_deg),
                                            bias_shear(prof, info.warp_angle_deg)], first_harmonic(prof), rings,
                               heights, *own])

    def _slices(self, n: int):
        """(type, measured, slice of an n-long feature vector it reads) of every observation: the
        whole vector for the library's types, its own features in the vector's tail for any other."""
        start = n - sum(int(np.size(meas)) for obs, meas in self.observations if not isinstance(obs, CoreObservation))
        out = []
        for obs, meas in self.observations:
            if isinstance(obs, CoreObservation):
                out.append((obs, meas, slice(None)))
            else:
                k = int(np.size(meas))
                out.append((obs, meas, slice(start, start + k)))
                start += k
        return out

    def _rows(self):
        """(feature index, target, sigma) of every linear residual of the library's types, in order
        (the fold depth and other types' rows aside)."""
        return [row for obs, meas in self.observations if isinstance(obs, CoreObservation)
                for row in obs.linear_rows(meas)]

    def whiten(self, f: np.ndarray) -> np.ndarray:
        """The whitened data residuals of a feature vector ``f`` (``hard``'s layout): every observation's
        ``misfit_rows``, in row order. Public because the experiments whiten features of drops and
        captures they render themselves."""
        return np.concatenate([np.asarray(obs.misfit_rows(meas, f[sl]), float).ravel()
                               for obs, meas, sl in self._slices(len(f))])

    def _whiten_jac(self, jf: np.ndarray) -> np.ndarray:
        soft = self._last_soft
        return np.concatenate([obs.misfit_jacobian(meas, soft[sl], jf[sl])
                               for obs, meas, sl in self._slices(len(soft))])

    @property
    def n_rows(self) -> int:
        """Number of data residuals (every observation type's ``n_rows``)."""
        return sum(obs.n_rows(meas) for obs, meas in self.observations)

    def loss(self, x: np.ndarray) -> float:
        """½‖r‖² of the data rows (no prior) at rest state x."""
        r = self.whiten(self.hard(x))
        return 0.5 * float(r @ r)
