"""Candidate physical effects the base model lacks: each adds energy terms, never edits the solver."""

from __future__ import annotations

import abc
import math
from collections.abc import Mapping
from typing import TYPE_CHECKING, ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ..energy import AbstractEnergy, Bending
from ..energy.bending import bending_density, curvature_tensor, jet_curvature, jet_hessian
from ..mesh import ClothMesh
from ..solve._sparse import psd_project

if TYPE_CHECKING:
    from ..diagnose.signatures import Evidence


class Effect(eqx.Module):
    """A named candidate effect with a parameter vector θ (θ = ``theta0()`` means absent).

    An effect carries everything the diagnosis (``drapejax.diagnose``) needs to weigh it, so that
    the diagnosis knows no effect by name and a new effect is its module plus one entry in
    ``drapejax.effects.REGISTRY``: its energy (``terms``), prior (``prior_std``, ``lower_bound``),
    the residual it would leave (``signature``), what rules it out before any drop
    (``inadmissible``), whether the scans point to its strength (``seeded_by_centroid``), and how
    the report names it (``label``) and places it on the specimen (``where``). The hooks have
    neutral defaults (no signature, never ruled out, no label or place), so an effect without
    them still runs, scored 0 in the ranking.
    """

    name: str = eqx.field(static=True)

    label: ClassVar[str | None] = None
    """What the effect is, in words, beside its name in the report (None: the name alone)."""

    seeded_by_centroid: ClassVar[bool] = False
    """θ is the specimen centre's world-frame offset (dx, dy), m. Where the scans' mean centroid
    sits off the disc axis beyond fold noise, the screen then also probes θ along it
    (``diagnose.signatures.centroid_probes``, at ``Screen.centroid_factors`` times its length),
    since its axis probes may lie far from the offset the data point to."""

    @abc.abstractmethod
    def n_params(self) -> int:
        """Length of θ."""

    def theta0(self) -> np.ndarray:
        """The neutral θ at which the effect vanishes."""
        return np.zeros(self.n_params())

    def prior_std(self) -> np.ndarray:
        """Prior standard deviation of θ for fitting (in θ's own units)."""
        return np.ones(self.n_params())

    def lower_bound(self) -> np.ndarray:
        """Smallest physically possible θ, per component (-inf: unbounded); fits stay above it."""
        return np.full(self.n_params(), -np.inf)

    def probes(self, steps: tuple[float, ...], vector_steps: tuple[float, ...]) -> list[np.ndarray]:
        """Distinct θ moved from ``theta0()`` along one axis at a time by ``steps`` prior stds
        (``vector_steps`` when θ has several components), clipped to ``lower_bound()``: the
        starting points of a fresh-drop screen."""
        t0, sd, lo = self.theta0(), self.prior_std(), self.lower_bound()
        out: list[np.ndarray] = []
        for i in range(len(t0)):
            for k in (steps if len(t0) == 1 else vector_steps):
                th = np.array(t0, float)
                th[i] = max(t0[i] + k * sd[i], lo[i])
                if th[i] != t0[i] and not any(np.array_equal(th, o) for o in out):
                    out.append(th)
        return out

    @abc.abstractmethod
    def terms(self, mesh: ClothMesh, theta) -> tuple[AbstractEnergy, ...]:
        """Extra energy terms for parameters θ (differentiable in θ)."""

    def strip_terms(self, mesh: ClothMesh, theta) -> tuple[AbstractEnergy, ...]:
        """The effect's energy on a cantilever strip cut from the same fabric (``mesh`` a strip
        mesh), for the strip test's row of the identifiability analysis
        (``diagnose.strip``). Default (): the effect belongs to the drape test's specimen or setup
        (placement, clamp, hem band, ...), which a strip does not share. An effect of the fabric
        itself, felt by any piece cut from it, returns its ``terms``."""
        return ()

    def unloading_strip_terms(self, mesh: ClothMesh, theta) -> tuple[AbstractEnergy, ...]:
        """The effect's energy on a strip on the unloading branch of a pure bending test (the
        curvature coming back down from the test's largest), whose gradient is the moment there.
        Default ``strip_terms``: an elastic effect gives back along the same curve the energy it
        stored. A dissipative one (a frictional couple) returns the pseudo-potential of the
        reversed motion, so that loading and unloading differ by its hysteresis."""
        return self.strip_terms(mesh, theta)

    @abc.abstractmethod
    def describe(self, theta) -> dict:
        """Physical values of θ with units."""

    def signature(self, evidence: Evidence) -> float | None:
        """How well the residual of a fit without the effect (``evidence``, its features read off
        the residual maps, rim spectrum and bands) matches the one the effect would leave, 0..1,
        larger = better. It costs no drop, and only orders the candidates the selection tries
        (``diagnose.select.rank``); the drops decide. None: the effect has no signature to look
        for, and ranks as 0."""
        return None

    def inadmissible(self, evidence: Evidence) -> str | None:
        """Why the captures in ``evidence`` rule the effect out before any drop, in words (None:
        they do not). A ruled-out effect is not tried: reserve this for a hard, model-free
        signature that the effect must show and a fitted θ could otherwise mimic without it."""
        return None

    def where(self, values: Mapping) -> str | None:
        """Where on the specimen the effect acts, in words, for the report; ``values`` are its
        ``describe`` values as a result file records them (possibly partial). None: no place."""
        return None


def is_number(v) -> bool:
    """A finite real number (not a bool): a value a report may print."""
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool) and math.isfinite(v)


def band_width_text(values: Mapping) -> str | None:
    """The ``band_m`` of an effect's ``describe`` values in whole millimetres ("10 mm"), or None."""
    band = values.get("band_m")
    return f"{float(band) * 1e3:.0f} mm" if is_number(band) else None


class CurvatureTerm(AbstractEnergy):
    """Base for effects acting on the per-vertex curvature tensor (same stencils as ``Bending``)."""

    def elements(self, mesh):
        idx = jnp.concatenate([mesh.curv_verts[:, None], mesh.nbr], 1)
        return idx, (mesh.fit, mesh.curv_area, self.vertex_data(mesh))

    @abc.abstractmethod
    def vertex_data(self, mesh):
        """Per-curvature-vertex data (leading axis = len(mesh.curv_verts))."""

    @abc.abstractmethod
    def density(self, K, d, params):
        """Extra energy per area (J/m²) at curvature K (2,2)."""

    def element_energy(self, xe, data, params):
        fit, area, d = data
        return area * self.density(curvature_tensor(xe, fit), d, params)

    def element_hessian(self, xe, data, params):
        fit, area, d = data
        return jet_hessian(lambda c: area * self.density(jet_curvature(c), d, params), xe, fit)


def scaled_bending_hessian(scale, xe, fit, area, params):
    """``scale`` times the PSD-projected Hessian ``Bending`` gives the same element.

    A term that removes the fraction f of the bending energy hands Newton this with scale −f, so
    the sum stays (1 − f) times a PSD matrix: projected on its own, the negative term would be
    dropped and Newton would see the unsoftened fabric (a heavy drape with the clamp hinge at
    θ = 2 then ended with the static solve unconverged)."""
    return scale * psd_project(Bending().element_hessian(xe, (fit, area), params))


def rest_curvature_density(K, K0, params):
    """$w(K - K_0) - w(K)$: the energy change from a spontaneous (rest) curvature $K_0$."""
    return bending_density(K - K0, params) - bending_density(K, params)


def radial_coords(mesh: ClothMesh, idx=None):
    """Rest radius (m) and unit radial direction in material (u, v) axes of each vertex."""
    uv = mesh.uv if idx is None else mesh.uv[idx]
    r = jnp.sqrt(jnp.sum(uv * uv, -1))
    e = uv / jnp.maximum(r, 1e-12)[:, None]
    return r, e
