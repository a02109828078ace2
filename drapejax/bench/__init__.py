"""Speed and memory benchmark of a Cusick drape (mid-weight fabric), with the Newton peer.

Reports, for a ``cusick_mesh`` at the given spacing: the median wall time of a full drape to
rest after compilation, the compile time, the time of an implicit gradient of a scalar of the
rest shape w.r.t. all 13 parameters, the throughput of a ``drape_batch`` (16 members by
default) under each strategy asked for (``--strategies``, default "vmap" and "map"; the
device's default is always timed) and of a Python loop over the same members with
the compiled single drape (the peer the batch must beat), the peak resident memory, and
Newton's SolverStyle3D time to rest on the same mesh (``newton_peer``; null when newton is
not installed), and the peer again on the nested drape's finest mesh. The same figures for the
nested-mesh drape ``drapejax simulate`` runs (``mesh.cusick_hierarchy``: the drop on a coarse
rim-graded level, a static solve on each finer one, ``solve.drape_multilevel``) carry the prefix
``multilevel_``, with its levels (spacings, vertices, Newton iterations) and the gradient on its
finest level; ``simulate_process_s`` is the
wall time of two whole ``drapejax simulate`` processes in a row at the same spacing (start-up,
compilation and writing the folder included), with a compilation cache that starts empty: the
first compiles, the second loads what the first compiled.

``run_bench`` is what ``drapejax bench`` and ``python benchmarks/bench_drape.py`` run; the peer
lives in ``drapejax.bench.newton_peer``. On a CPU, ``--strategies=`` times "map" alone: at 5 mm a
batch of one ran at 0.41 drapes per minute under "vmap" against 1.13 under "map" , so 16 members
under "vmap" would add about 40 minutes.
"""

from __future__ import annotations

import contextlib
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from ..material import PARAM_KEYS, FabricParams, example_params
from ..mesh import cusick_hierarchy, cusick_mesh
from ..solve import SolverConfig, coarsest_spacing_m, drape, drape_batch, drape_multilevel, equilibrium
from ..solve.batch import auto_strategy
from .newton_peer import newton_time_to_rest


def timed(fn, *args):
    """(wall seconds, result) of one call, waiting for the result."""
    start = time.perf_counter()
    out = jax.block_until_ready(fn(*args))
    return time.perf_counter() - start, out


def rest_scalar(x):
    """Rotation-invariant scalar of a rest shape (m): mean height plus mean radius."""
    return jnp.mean(x[:, 2]) + jnp.mean(jnp.sqrt(jnp.sum(x[:, :2] ** 2, 1)))


def density_batch(params: FabricParams, batch: int) -> FabricParams:
    """``batch`` copies of ``params`` with densities 0.8-1.2x (the benchmark's batch members)."""
    scale = jnp.linspace(0.8, 1.2, batch)
    pb = FabricParams(**{k: jnp.broadcast_to(getattr(params, k), (batch,)) for k in PARAM_KEYS})
    return FabricParams(**{**{k: getattr(pb, k) for k in PARAM_KEYS}, "density": pb.density * scale})


def parse_strategies(text: str) -> tuple[str, ...]:
    """``--strategies`` ("vmap,map", or "" for the device's default alone) as a tuple."""
    return tuple(s for s in text.split(",") if s)


def time_compiled(run, params: FabricParams, repeats: int):
    """Compile ``run(params, seed)`` and time it at seeds 0 … ``repeats`` − 1: (compile seconds,
    wall seconds per run, results)."""
    start = time.perf_counter()
    compiled = run.lower(params, 0).compile()
    compile_s = time.perf_counter() - start
    runs, results = [], []
    for seed in range(repeats):
        t, res = timed(compiled, params, seed)
        runs.append(t)
        results.append(res)
    return compiled, compile_s, runs, results


def gradient_seconds(mesh, params: FabricParams, x_rest, repeats: int) -> list[float]:
    """Wall seconds of ``repeats`` implicit gradients of ``rest_scalar`` at the rest state
    ``x_rest`` on ``mesh`` (after one compiling call)."""
    grad = jax.jit(jax.grad(lambda p: rest_scalar(equilibrium(mesh, p, x_rest))))
    timed(grad, params)
    return [timed(grad, params)[0] for _ in range(repeats)]


def multilevel_bench(spacing_m: float, params: FabricParams, repeats: int,
                     config: SolverConfig | None = None) -> dict:
    """Median seconds of the nested-mesh drape whose finest level has ``spacing_m`` (after compiling),
    its levels, and the implicit gradient's seconds on the finest level."""
    meshes, prolongs = cusick_hierarchy(spacing_m, coarsest_spacing_m=coarsest_spacing_m(params))
    run = jax.jit(lambda p, s: drape_multilevel(meshes, prolongs, p, s, config=config))
    _, compile_s, runs, results = time_compiled(run, params, repeats)
    grad_runs = gradient_seconds(meshes[-1], params, results[0].finest.x, repeats)
    return {
        "multilevel_rest_s": statistics.median(runs),
        "multilevel_rest_s_runs": runs,
        "multilevel_compile_s": compile_s,
        "multilevel_grad_s": statistics.median(grad_runs),
        "multilevel_status": [int(r.finest.status) for r in results],
        "multilevel_levels": [{"spacing_mm": 1e3 * m.info.spacing_m, "verts": int(m.n_verts)} for m in meshes],
        "multilevel_newton_iters": [np.asarray(r.level_newton_iters).tolist() for r in results],
    }


def simulate_process_seconds(spacing_m: float, runs: int = 2) -> list[float]:
    """Wall seconds of ``runs`` whole ``drapejax simulate`` processes in a row (the mid fabric),
    sharing a compilation cache that starts empty: the first compiles, the later ones load."""
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, DRAPEJAX_CACHE_DIR=str(Path(tmp) / "jax-cache"))
        for i in range(runs):
            start = time.perf_counter()
            r = subprocess.run([sys.executable, "-m", "drapejax.cli", "simulate",
                                "--spacing-mm", f"{1e3 * spacing_m:g}", "--out", str(Path(tmp) / f"m{i}"), "--json"],
                               capture_output=True, text=True, env=env)
            out.append(time.perf_counter() - start if r.returncode in (0, 1) else None)
    return out


def run_bench(spacing_m: float = 0.005, repeats: int = 3, *, fabric: str = "mid", batch: int = 16,
              newton: bool = True, strategies: tuple[str, ...] = ("vmap", "map"), process: bool = True) -> dict:
    """Benchmark one Cusick drape configuration (medians over ``repeats`` runs after compiling).

    Args:
        spacing_m: mesh edge length, m.
        repeats: timed runs per measurement.
        fabric: example fabric name.
        batch: members of the batched run (densities 0.8-1.2x the fabric's, distinct seeds).
        newton: also time Newton's SolverStyle3D on the same mesh.
        process: also time two whole ``drapejax simulate`` processes at ``spacing_m``.
        strategies: ``drape_batch`` strategies to time; the device's default ("auto") is always
            timed, so ``batch_per_min`` and ``batch16_per_min`` are never missing.

    Returns:
        dict with verts, rest_s, compile_s, grad_s, batch_per_min (the default "auto" strategy),
        batch16_per_min (the same, under the issue's name; null unless ``batch`` is 16),
        batch_per_min_by_strategy, batch_strategy (the default's name), loop_per_min,
        batch_speedup_vs_loop, peak_mb, newton_rest_s, newton_converged, speedup_vs_newton (the
        peer on the direct drape's uniform mesh), the ``multilevel_`` fields (``multilevel_bench``,
        and multilevel_newton_rest_s, multilevel_newton_converged, multilevel_speedup_vs_newton:
        the peer on the multilevel drape's finest mesh, against the whole nested drape),
        simulate_process_s, and context (spacing_mm: the direct drape's uniform mesh and the
        multilevel drape's finest level; status, steps, backend).
    """
    jax.config.update("jax_enable_x64", True)
    mesh = cusick_mesh(spacing_m)
    params = example_params(fabric)
    config = SolverConfig()
    run = jax.jit(lambda p, s: drape(mesh, p, s, config=config))
    compiled, compile_s, rest_runs, results = time_compiled(run, params, repeats)
    grad_runs = gradient_seconds(mesh, params, results[0].x, repeats)

    pb = density_batch(params, batch)
    seeds = jnp.arange(batch)
    t_loop, _ = timed(lambda: [compiled(jax.tree.map(lambda a: a[i], pb), seeds[i]) for i in range(batch)])
    per_min, batch_res = {}, {}
    auto = auto_strategy()
    for strategy in dict.fromkeys((auto, *strategies)):
        run_batch = jax.jit(lambda p, s: drape_batch(mesh, p, s, config=config, strategy=strategy))
        t, batch_res[strategy] = timed(run_batch.lower(pb, seeds).compile(), pb, seeds)
        per_min[strategy] = 60.0 * batch / t

    out = {
        "verts": int(mesh.n_verts),
        "rest_s": statistics.median(rest_runs),
        "compile_s": compile_s,
        "grad_s": statistics.median(grad_runs),
        "batch_per_min": per_min[auto],
        "batch16_per_min": per_min[auto] if batch == 16 else None,
        "batch_per_min_by_strategy": per_min,
        "loop_per_min": 60.0 * batch / t_loop,
        "batch_speedup_vs_loop": per_min[auto] * t_loop / (60.0 * batch),
        "newton_rest_s": None,
        "speedup_vs_newton": None,
        "spacing_mm": spacing_m * 1e3,
        "rest_s_runs": rest_runs,
        "status": [int(r.status) for r in results],
        "steps": [int(r.steps) for r in results],
        "batch_size": batch,
        "batch_strategy": auto,
        "batch_status": np.asarray(batch_res[auto].status).tolist(),
        "backend": jax.default_backend(),
    }
    out.update(multilevel_bench(spacing_m, params, repeats))
    out.update(multilevel_newton_rest_s=None, multilevel_speedup_vs_newton=None)
    out["simulate_process_s"] = simulate_process_seconds(spacing_m) if process else None
    out["peak_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # after every drape above
    if newton:
        finest = cusick_hierarchy(spacing_m, coarsest_spacing_m=coarsest_spacing_m(params))[0][-1]
        for prefix, peer_mesh, ours in (("", mesh, "rest_s"), ("multilevel_", finest, "multilevel_rest_s")):
            with contextlib.redirect_stdout(sys.stderr):
                peer = newton_time_to_rest(np.asarray(peer_mesh.rest)[:, :2], np.asarray(peer_mesh.faces),
                                           np.asarray(peer_mesh.clamped), params.to_dict(), repeats=repeats)
            out[f"{prefix}newton_rest_s"] = peer["rest_s"]
            out[f"{prefix}newton_converged"] = peer.get("converged")
            if peer["rest_s"] is not None:
                out[f"{prefix}speedup_vs_newton"] = peer["rest_s"] / out[ours]
            else:
                out[f"{prefix}newton_reason"] = peer.get("reason")
    return out
