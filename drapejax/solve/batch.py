"""Batched drapes: ``vmap`` over parameters and seeds, sharded over all local devices."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from ..material import FabricParams
from ..mesh import ClothMesh
from .drop import DrapeResult, SolverConfig, drape

_RUNNERS: dict = {}


def _runner(mesh: ClothMesh, terms, config: SolverConfig):
    """One jitted, vmapped drape per (mesh, terms, config), so repeated batches (dataset shards)
    reuse the compiled program instead of tracing and compiling it again."""
    key = (id(mesh), id(terms), config)
    hit = _RUNNERS.get(key)
    if hit is None or hit[0] is not mesh or hit[1] is not terms:
        if len(_RUNNERS) >= 8:
            _RUNNERS.pop(next(iter(_RUNNERS)))
        run = jax.jit(jax.vmap(lambda p, s: drape(mesh, p, s, terms=terms, config=config)))
        hit = _RUNNERS[key] = (mesh, terms, run)
    return hit[2]


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
    run = _runner(mesh, terms, config)
    if len(devices) == 1:
        return run(params, seeds)
    nd = len(devices)
    pad = (-b) % nd
    padf = lambda a: jnp.concatenate([a, jnp.repeat(a[-1:], pad, 0)]) if pad else a
    params, seeds = jax.tree.map(padf, params), padf(seeds)
    sharding = NamedSharding(Mesh(np.asarray(devices), ("batch",)), PartitionSpec("batch"))
    params, seeds = jax.device_put((params, seeds), sharding)
    out = run(params, seeds)
    return jax.tree.map(lambda a: a[:b], out)
