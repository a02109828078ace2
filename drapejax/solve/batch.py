"""Batched drapes over parameters and seeds, sharded over all local devices.

Members are independent, so with several local devices each device runs its own slice of the
batch (``shard_map``): no collective sits inside the solver's loops, and one device's members
need not take as many iterations as another's. Only accelerator batches on the
device-resident CG solver are sharded. CPU "devices" share the same cores anyway, and a CPU
program calls host functions (the direct solver's sparse solves, and the CG fallback's
element-Hessian projection, which avoids jaxlib's CPU ``eigh``), which deadlocked inside a
program sharded over two CPU devices.

On each device the slice runs either in lockstep (``vmap``: every Newton and CG loop iterates
until the slowest member is done) or one member after another inside one compiled program
(``lax.map``: each member stops when it is at rest). On a CPU the wider arrays of ``vmap`` buy
no parallelism, and it ran at half the speed of a Python loop (10 mm, 6 members,
``benchmarks/bench_drape.py``), so CPUs use ``lax.map`` and accelerators ``vmap``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, PartitionSpec

from ..material import FabricParams
from ..mesh import ClothMesh
from .drop import DrapeResult, SolverConfig, drape, linear_solver
from ._reuse import Same, reuse

try:
    from jax import shard_map

    _NO_CHECK = {"check_vma": False}
except ImportError:  # older jax
    from jax.experimental.shard_map import shard_map

    _NO_CHECK = {"check_rep": False}

STRATEGIES = ("auto", "vmap", "map")


def auto_strategy() -> str:
    """The per-device strategy "auto" stands for here: "map" on CPU devices, else "vmap"."""
    return "map" if jax.local_devices()[0].platform == "cpu" else "vmap"


def _shardable(config: SolverConfig) -> bool:
    """Whether a batch is split over the local devices: CG on accelerators (module docstring)."""
    return linear_solver(config) == "cg" and jax.local_devices()[0].platform != "cpu"


def _runner(mesh: ClothMesh, terms, config: SolverConfig, strategy: str, n_devices: int):
    """One jitted batched drape per (mesh, terms, config, strategy, device count), so repeated
    batches (dataset shards) reuse the compiled program instead of tracing and compiling it again."""

    def build():
        one = lambda p, s: drape(mesh, p, s, terms=terms, config=config)
        local = jax.vmap(one) if strategy == "vmap" else lambda p, s: jax.lax.map(lambda a: one(*a), (p, s))
        if n_devices > 1:
            spec = PartitionSpec("batch")
            local = shard_map(local, mesh=Mesh(np.asarray(jax.local_devices()), ("batch",)),
                              in_specs=(spec, spec), out_specs=spec, **_NO_CHECK)  # per-member loops vary by device
        return jax.jit(local)

    return reuse(("drape_batch", Same(mesh), Same(terms), config, strategy, n_devices), build)


def drape_batch(mesh: ClothMesh, params: FabricParams, seeds, *, terms=None,
                config: SolverConfig = SolverConfig(), strategy: str = "auto") -> DrapeResult:
    """Drape a batch (leading axis of every params field and of ``seeds``); never raises per member.

    Each member gets its own status (an impossible or diverging member does not affect the
    others). With several local accelerators and the device-resident CG solver the batch is
    split across them, padded to a multiple of the device count (the padding is dropped from the
    result); see the module docstring.

    Args:
        strategy: how each device runs its members: "vmap" (in lockstep), "map" (one after
            another in one compiled program) or "auto" ("map" on CPUs, "vmap" on
            accelerators; see the module docstring).
    """
    if strategy not in STRATEGIES:
        raise ValueError(f"drape_batch: strategy must be one of {STRATEGIES}, got {strategy!r}")
    strategy = auto_strategy() if strategy == "auto" else strategy
    seeds = jnp.asarray(seeds)
    b = seeds.shape[0]
    nd = jax.local_device_count() if _shardable(config) else 1
    run = _runner(mesh, terms, config, strategy, nd)
    pad = (-b) % nd
    if not pad:
        return run(params, seeds)
    padf = lambda a: jnp.concatenate([a, jnp.repeat(a[-1:], pad, 0)])
    out = run(jax.tree.map(padf, params), padf(seeds))
    return jax.tree.map(lambda a: a[:b], out)
