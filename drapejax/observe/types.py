"""Observation types: each kind of drape observation is one class, known to the rest through ``REGISTRY``.

An observation type (``AbstractObservation``) says whether a measurement has it (``present``),
how a mesh looks in it (``render``, the hard renderer, and ``soft``, its differentiable
counterpart), what the fit compares (``target``: the measured features; ``features`` and
``soft_features``: the same features of a rest state, hard and soft), its noise-whitened
residual rows (``misfit_rows``, each over the noise floor it uses, and their Jacobian
``misfit_jacobian``) and what the inverse network reads from it (``network_input``).
``refine.Misfit`` builds its rows by walking ``REGISTRY`` in order, so an observation type
registered with ``register`` contributes rows to every fit whose measurement has it, with no
edit elsewhere.

The library's own types (``Silhouette``, ``HeightMap`` and ``WarpHarmonic``, the rim's second
harmonic in the warp frame, a separate type because it exists only when the warp angle was
recorded) share one feature vector: ``refine.measured_targets`` renders the capture once for
all of them and ``refine.observables._F`` lays out their features, so they are
``CoreObservation``\\ s whose ``misfit_rows`` read that shared vector (``refine.Targets`` holds
their measured side). Any other type carries its own features: ``target`` fills
``Targets.extra[name]`` and ``features``/``soft_features`` are appended after the shared
vector. The noise floors and the feature layout live in ``drapejax.refine``, which builds on
this package, so the core types import them when called.
"""

from __future__ import annotations

import abc
from typing import Any, ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..mesh import ClothMesh
from .render import EXTENT_M, height_map, rim_profile, silhouette
from .soft import soft_height_map, soft_rim_profile, soft_silhouette


def _sharpness(n: int, extent_m: float) -> float:
    """Default soft-renderer sharpness (1/m): a blur of about one pixel of an n-pixel window."""
    return n / (2.0 * extent_m)


class AbstractObservation(eqx.Module):
    """One kind of drape observation: what a type must provide to be rendered, fitted and read.

    ``name`` (a class attribute) is its key in ``REGISTRY`` and in ``refine.Targets.extra``.
    ``measured`` and ``n_rows`` have defaults for a type that carries its own features (one
    residual row per measured feature); ``misfit_jacobian`` defaults to the chain rule through
    ``misfit_rows``.
    """

    name: ClassVar[str]

    @abc.abstractmethod
    def present(self, m) -> bool:
        """Whether measurement ``m`` (``io.Measurement``) holds this observation."""

    @abc.abstractmethod
    def render(self, verts, faces, *, n: int = 256, extent_m: float = EXTENT_M) -> np.ndarray:
        """Hard (NumPy) rendering of a mesh as this observation."""

    @abc.abstractmethod
    def soft(self, x, mesh: ClothMesh, *, n: int = 256, extent_m: float = EXTENT_M) -> jax.Array:
        """Differentiable (JAX) rendering of positions x (n, 3) of ``mesh``."""

    @abc.abstractmethod
    def network_input(self, m) -> np.ndarray | None:
        """What the inverse network reads from measurement ``m``; None when it reads nothing of it."""

    @abc.abstractmethod
    def target(self, m) -> np.ndarray | None:
        """Measured features of ``m`` compared by the fit (stored in ``Targets.extra[name]``)."""

    @abc.abstractmethod
    def features(self, x, mesh: ClothMesh) -> np.ndarray:
        """The same features of a rest state x (hard renderer): the values the fit scores."""

    @abc.abstractmethod
    def soft_features(self, x, mesh: ClothMesh, spacing_m: float) -> jax.Array:
        """Soft surrogate of ``features`` (JAX), whose Jacobian the fit steps with."""

    @abc.abstractmethod
    def misfit_rows(self, measured, simulated):
        """Noise-whitened residual rows (simulated − measured) / noise floor, in row order."""

    def measured(self, targets, *, profile: bool = False) -> Any:
        """This type's measured side in ``targets`` (``refine.Targets``); None when absent.
        ``profile``: the misfit scores the height profile (``refine.Misfit(profile=True)``)."""
        return targets.extra.get(self.name)

    def n_rows(self, measured) -> int:
        """Number of residual rows ``misfit_rows`` gives for ``measured``."""
        return int(np.size(measured))

    def misfit_jacobian(self, measured, simulated_soft, jf: np.ndarray) -> np.ndarray:
        """Jacobian of ``misfit_rows`` given the soft features and their Jacobian ``jf`` (features × θ)."""
        d = jax.jacfwd(lambda f: jnp.asarray(self.misfit_rows(measured, f)))(jnp.asarray(simulated_soft))
        return np.asarray(d).reshape(-1, np.size(simulated_soft)) @ np.asarray(jf)


class CoreObservation(AbstractObservation):
    """A library type whose features are part of the fit's shared feature vector
    (``refine.observables._F``): ``Targets`` carries its measured side and ``misfit_rows`` reads
    the shared vector, so it has no features of its own."""

    def target(self, m) -> None:
        return None

    def features(self, x, mesh: ClothMesh) -> np.ndarray:
        return np.zeros(0)

    def soft_features(self, x, mesh: ClothMesh, spacing_m: float) -> jax.Array:
        return jnp.zeros(0)

    @abc.abstractmethod
    def linear_rows(self, measured) -> list[tuple[int, float, float]]:
        """(index in the shared vector, measured value, noise floor) of each linear row."""

    def n_rows(self, measured) -> int:
        return len(self.linear_rows(measured))

    def misfit_rows(self, measured, simulated):
        return np.array([(simulated[i] - t) / s for i, t, s in self.linear_rows(measured)])

    def misfit_jacobian(self, measured, simulated_soft, jf: np.ndarray) -> np.ndarray:
        rows = [jf[i:i + 1] / s for i, _, s in self.linear_rows(measured)]
        return np.concatenate(rows) if rows else np.zeros((0, np.shape(jf)[1]))


class Silhouette(CoreObservation):
    """Top-view silhouette: the drape coefficient, the fold depth (rms of rim harmonics 3..12,
    phase-invariant) and the world-frame first harmonic of the rim."""

    name: ClassVar[str] = "silhouette"

    def present(self, m) -> bool:
        return any(v is not None for v in (m.silhouette, m.height, m.scan_vertices, m.photo))

    def render(self, verts, faces, *, n=256, extent_m=EXTENT_M):
        return silhouette(np.asarray(verts, float), np.asarray(faces), n=n, extent_m=extent_m)

    def soft(self, x, mesh, *, n=256, extent_m=EXTENT_M):
        return soft_silhouette(x, mesh.faces, sharpness=_sharpness(n, extent_m), n=n, extent_m=extent_m)

    def network_input(self, m):
        from ..inverse.estimate import silhouette_feature
        return None if m.silhouette is None else silhouette_feature(m.silhouette)

    def measured(self, targets, *, profile=False):
        return targets

    def linear_rows(self, t):
        from ..refine.misfit import SIGMA_C1_M, SIGMA_DC
        from ..refine.observables import _F
        return [(_F["dc"], t.dc, SIGMA_DC)] + [(_F["c1"] + i, t.c1_m[i], SIGMA_C1_M) for i in range(2)]

    def n_rows(self, measured) -> int:
        return 1 + super().n_rows(measured)

    def misfit_rows(self, t, simulated):
        """Fold depth first, then the drape coefficient and the first harmonic (Re, Im)."""
        from ..refine.misfit import SIGMA_HARMONIC_M
        from ..refine.observables import N_HARMONICS, _F, fold_rms
        amp = simulated[_F["amp"]:_F["amp"] + N_HARMONICS]
        fold = (fold_rms(amp) - fold_rms(t.harmonics)) / SIGMA_HARMONIC_M
        return np.concatenate([[fold], super().misfit_rows(t, simulated)])

    def misfit_jacobian(self, t, simulated_soft, jf):
        """The fold row linearised at the soft amplitudes, then the linear rows."""
        from ..refine.misfit import SIGMA_HARMONIC_M
        from ..refine.observables import N_HARMONICS, _F, fold_rms
        a = np.asarray(simulated_soft)[_F["amp"]:_F["amp"] + N_HARMONICS]
        g = a[2:] / max(fold_rms(a) * (N_HARMONICS - 2), 1e-12)
        fold = (g @ jf[_F["amp"] + 2:_F["amp"] + N_HARMONICS])[None] / SIGMA_HARMONIC_M
        return np.concatenate([fold, super().misfit_jacobian(t, simulated_soft, jf)])


class HeightMap(CoreObservation):
    """Top-view height map (or a scan standing in for it): the mean hem height and the mean
    height on the fitted rings, or the skirt's height profile and its world-frame first harmonic
    when the misfit scores them."""

    name: ClassVar[str] = "height_map"

    def present(self, m) -> bool:
        return m.height is not None or m.scan_vertices is not None

    def render(self, verts, faces, *, n=256, extent_m=EXTENT_M):
        return height_map(np.asarray(verts, float), np.asarray(faces), n=n, extent_m=extent_m)

    def soft(self, x, mesh, *, n=256, extent_m=EXTENT_M):
        return soft_height_map(x, mesh.faces, sharpness=_sharpness(n, extent_m), n=n, extent_m=extent_m)

    def network_input(self, m):
        from ..inverse.estimate import height_feature
        return None if m.height is None else height_feature(m.height)

    def measured(self, targets, *, profile=False):
        if targets.hem_m is None:
            return None
        return targets, bool(profile and targets.profile_m is not None)

    def linear_rows(self, measured):
        from ..refine.misfit import SIGMA_HEIGHT_C1_M, SIGMA_HEM_M, SIGMA_PROFILE_M
        from ..refine.observables import RING_RADII_M, _F
        t, profile = measured
        rows = [(_F["hem"], t.hem_m, SIGMA_HEM_M)]
        if profile:
            i0 = _F["rings"] + len(RING_RADII_M)
            rows += [(i0 + i, t.profile_m[i], s) for i, s in enumerate(SIGMA_PROFILE_M)]
            i0 += len(SIGMA_PROFILE_M)
            return rows + ([] if t.height_c1_m is None else
                           [(i0 + i, t.height_c1_m[i], SIGMA_HEIGHT_C1_M) for i in range(2)])
        return rows + [(_F["rings"] + i, t.rings_m[i], SIGMA_HEM_M) for i in range(len(RING_RADII_M))]


class WarpHarmonic(CoreObservation):
    """The rim's second harmonic in the warp frame (warp anisotropy, bias shear): the silhouette's
    phase-dependent rows, an observation only when the warp angle was recorded."""

    name: ClassVar[str] = "warp_harmonic"

    def present(self, m) -> bool:
        return m.warp_angle_deg is not None and Silhouette().present(m)

    def render(self, verts, faces, *, n=256, extent_m=EXTENT_M):
        from ..refine.observables import N_ANGLES
        return rim_profile(Silhouette().render(verts, faces, n=n, extent_m=extent_m), extent_m, n_angles=N_ANGLES)

    def soft(self, x, mesh, *, n=256, extent_m=EXTENT_M):
        from ..refine.observables import N_ANGLES
        return soft_rim_profile(x, sharpness=_sharpness(n, extent_m), n_angles=N_ANGLES)

    def network_input(self, m):
        return None

    def measured(self, targets, *, profile=False):
        return None if targets.aniso_m is None else targets

    def linear_rows(self, t):
        from ..refine.misfit import SIGMA_H2_M
        from ..refine.observables import _F
        return [(_F["aniso"], t.aniso_m, SIGMA_H2_M), (_F["shear"], t.shear_m, SIGMA_H2_M)]


REGISTRY: dict[str, AbstractObservation] = {}
"""Every observation type by name, in the order the misfit's rows come in."""


def register(observation: AbstractObservation) -> AbstractObservation:
    """Add ``observation`` to ``REGISTRY`` under its ``name`` (replacing one of the same name)."""
    if not isinstance(observation, AbstractObservation):
        raise TypeError(f"register: expected an AbstractObservation, got {type(observation).__name__}")
    REGISTRY[observation.name] = observation
    return observation


for _obs in (Silhouette(), HeightMap(), WarpHarmonic()):
    register(_obs)
del _obs
