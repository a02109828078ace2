"""Batched drapes: ``vmap`` over parameters and seeds, sharded over all local devices."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from ..material import FabricParams
from ..mesh import ClothMesh
from .drop import DrapeResult, SolverConfig, drape


def drape_batch(mesh: ClothMesh, params: FabricParams, seeds, *, terms=None,
                config: SolverConfig = SolverConfig()) -> DrapeResult:
    """Drape a batch (leading axis of every params field and of ``seeds``); never raises per member.

    Each member gets its own status (an impossible or diverging member does not affect the
    others). With several local devices the batch is sharded across them; the batch size
    is padded to a multiple of the device count.
    """
    seeds = jnp.asarray(seeds)
    b = seeds.shape[0]
    devices = jax.local_devices()
    run = jax.vmap(lambda p, s: drape(mesh, p, s, terms=terms, config=config))
    if len(devices) == 1:
        return jax.jit(run)(params, seeds)
    nd = len(devices)
    pad = (-b) % nd
    padf = lambda a: jnp.concatenate([a, jnp.repeat(a[-1:], pad, 0)]) if pad else a
    params, seeds = jax.tree.map(padf, params), padf(seeds)
    sharding = NamedSharding(Mesh(np.asarray(devices), ("batch",)), PartitionSpec("batch"))
    params, seeds = jax.device_put((params, seeds), sharding)
    out = jax.jit(run)(params, seeds)
    return jax.tree.map(lambda a: a[:b], out)
