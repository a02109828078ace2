"""The energy interface: every physical effect is one term, a sum over small elements.

A term lists its elements once (vertex stencils plus per-element data) and gives the energy
of one element; the total energy, forces (``-jax.grad``), Hessian-vector products and the
block-diagonal preconditioner all follow generically, so adding an effect never touches the
solver.
"""

from __future__ import annotations

import abc
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int, PyTree

from ..material import FabricParams
from ..mesh import ClothMesh


class AbstractEnergy(eqx.Module):
    """One physical energy term $E(x) = \\sum_e \\epsilon(x_{s(e)}, d_e, p)$, in joules."""

    @abc.abstractmethod
    def elements(self, mesh: ClothMesh) -> tuple[Int[Array, "e k"], PyTree]:
        """Vertex stencil (e, k) of each element and per-element data (leading axis e)."""

    @abc.abstractmethod
    def element_energy(self, xe: Float[Array, "k 3"], data: PyTree, params: FabricParams) -> Array:
        """Energy of one element (J) from its stencil's positions (m)."""

    def __call__(self, x: Float[Array, "n 3"], mesh: ClothMesh, params: FabricParams) -> Array:
        idx, data = self.elements(mesh)
        return _summed_energy(self, x[idx], data, params)

    in_drop: ClassVar[bool] = True
    """False for a term that shapes the equilibrium but not the way to it (a control of
    zero-energy mesh modes): the drop's time steps leave it out, the static solve that ends
    every drape, ``equilibrium`` and its implicit gradients include it."""

    in_preconditioner: ClassVar[bool] = True
    """False for a term that only takes a fraction off another term's energy: the block-Jacobi
    preconditioner then keeps that term's (stiffer, still SPD) blocks, where adding this one's
    negative blocks could make them indefinite."""

    def element_hessian(self, xe: Float[Array, "k 3"], data: PyTree, params: FabricParams) -> Float[Array, "3*k 3*k"]:
        """Exact Hessian of ``element_energy`` (3k, 3k); a term may give a cheaper closed form."""
        k = xe.shape[0]
        return jax.hessian(self.element_energy)(xe, data, params).reshape(3 * k, 3 * k)

    element_instability: ClassVar[bool] = False
    """True for a term whose element Hessians turn indefinite at the element scale, not along a
    mode of the drape (a compressed membrane element is unstable across its springs): where the
    exact Hessian is indefinite, ``solve.Direct(absolute=True)`` takes this term's element
    Hessians with their eigenvalues' magnitudes before it shifts the whole diagonal."""

    def coarse_level(self) -> AbstractEnergy:
        """This term as the coarsest level of a multilevel drape uses it
        (``solve.drape_multilevel``): the same physics unless a coarse mesh misrepresents it (a
        membrane that locks in compression). The finer levels' static solves use the term
        itself, so the finest level's equilibrium is that of the terms as given."""
        return self

    has_psd_hessian: ClassVar[bool] = False
    """True where ``psd_element_hessian`` gives a positive semi-definite approximation that
    Newton steps use instead of eigen-projecting the exact element Hessian."""

    def psd_element_hessian(self, xe: Float[Array, "k 3"], data: PyTree,
                            params: FabricParams) -> Float[Array, "3*k 3*k"]:
        """PSD approximation of one element's Hessian (only read when ``has_psd_hessian``)."""
        raise NotImplementedError

    def hessian_blocks(self, x: Float[Array, "n 3"], mesh: ClothMesh, params: FabricParams) -> Float[Array, "n 3 3"]:
        """Per-vertex 3x3 diagonal blocks of this term's Hessian (for preconditioning)."""
        idx, data = self.elements(mesh)
        k = idx.shape[1]

        def blocks(xe, d):
            h = self.element_hessian(xe, d, params).reshape(k, 3, k, 3)
            return h[jnp.arange(k), :, jnp.arange(k), :]  # (k,3,3)

        b = jax.vmap(blocks)(x[idx], data)
        return jnp.zeros((x.shape[0], 3, 3), x.dtype).at[idx.reshape(-1)].add(b.reshape(-1, 3, 3))


def safe_norm(v: Array, axis: int = -1, eps: float = 1e-30) -> Array:
    """Euclidean norm with a finite gradient at zero (double-where trick)."""
    sq = jnp.sum(v * v, axis=axis)
    ok = sq > eps
    return jnp.where(ok, jnp.sqrt(jnp.where(ok, sq, 1.0)), 0.0)


def normalize(v: Array, axis: int = -1) -> Array:
    n = safe_norm(v, axis)
    return v / jnp.expand_dims(jnp.where(n > 0, n, 1.0), axis)


@eqx.filter_jit
def _summed_energy(term: AbstractEnergy, xe, data, params: FabricParams) -> Array:
    """Sum of ``term``'s element energies over its stencils' positions ``xe`` (e, k, 3).

    One jitted function, so that the energy (and its derivatives) is traced once per term and
    shape however often a Newton solve, its line search and its Hessian assembly ask for it."""
    return jnp.sum(jax.vmap(term.element_energy, in_axes=(0, 0, None))(xe, data, params))
