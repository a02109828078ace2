"""Candidate physical effects the base model lacks: each adds energy terms, never edits the solver."""

from __future__ import annotations

import abc

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ..energy import AbstractEnergy, Bending
from ..energy.bending import bending_density, curvature_tensor, jet_curvature, jet_hessian
from ..mesh import ClothMesh
from ..solve._sparse import psd_project


class Effect(eqx.Module):
    """A named candidate effect with a parameter vector θ (θ = ``theta0()`` means absent)."""

    name: str = eqx.field(static=True)

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

    @abc.abstractmethod
    def describe(self, theta) -> dict:
        """Physical values of θ with units."""


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
