"""Batched drapes: ``vmap`` over parameters and seeds, sharded over all local devices.

A vmapped drape runs its members in lockstep: every Newton and CG loop iterates until the
slowest member is done, and on a CPU the wider arrays buy no parallelism, so there a batch is
slower than a Python loop (2.5x at 10 mm, ``benchmarks/bench_drape.py``). On a single CPU device
the batch is therefore run as a sequential ``lax.map`` inside one compiled program (each member
stops when it is done); accelerators and multi-device runs use ``vmap``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from ..material import FabricParams
from ..mesh import ClothMesh
from .drop import DrapeResult, SolverConfig, drape

_RUNNERS: dict = {}
STRATEGIES = ("auto", "vmap", "map")


def auto_strategy() -> str:
    """The batch strategy "auto" stands for here: "map" on a single CPU device, else "vmap"."""
    devices = jax.local_devices()
    return "map" if len(devices) == 1 and devices[0].platform == "cpu" else "vmap"


def _runner(mesh: ClothMesh, terms, config: SolverConfig, strategy: str):
    """One jitted batched drape per (mesh, terms, config, strategy), so repeated batches (dataset
    shards) reuse the compiled program instead of tracing and compiling it again."""
    key = (id(mesh), id(terms), config, strategy)
    hit = _RUNNERS.get(key)
    if hit is None or hit[0] is not mesh or hit[1] is not terms:
        if len(_RUNNERS) >= 8:
            _RUNNERS.pop(next(iter(_RUNNERS)))
        one = lambda p, s: drape(mesh, p, s, terms=terms, config=config)
        run = jax.jit(jax.vmap(one) if strategy == "vmap" else lambda p, s: jax.lax.map(lambda a: one(*a), (p, s)))
        hit = _RUNNERS[key] = (mesh, terms, run)
    return hit[2]


def drape_batch(mesh: ClothMesh, params: FabricParams, seeds, *, terms=None,
                config: SolverConfig = SolverConfig(), strategy: str = "auto") -> DrapeResult:
    """Drape a batch (leading axis of every params field and of ``seeds``); never raises per member.

    Each member gets its own status (an impossible or diverging member does not affect the
    others). With several local devices the batch is sharded across them; the batch size
    is padded to a multiple of the device count.

    Args:
        strategy: "vmap" (members in lockstep), "map" (members one after another in one
            compiled program) or "auto": "map" on a single CPU device, else "vmap" (see the
            module docstring).
    """
    if strategy not in STRATEGIES:
        raise ValueError(f"drape_batch: strategy must be one of {STRATEGIES}, got {strategy!r}")
    seeds = jnp.asarray(seeds)
    b = seeds.shape[0]
    devices = jax.local_devices()
    if strategy == "auto":
        strategy = auto_strategy()
    if len(devices) > 1 and strategy == "map":
        raise ValueError("drape_batch: strategy 'map' runs on one device; use 'vmap' to shard over "
                         f"{len(devices)} devices")
    run = _runner(mesh, terms, config, strategy)
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
