"""Resumable, sharded generation of synthetic drape datasets (prior sample → drape → observations).

Sample i's parameters and drop seed depend only on (seed, i), so any process can produce any
sample and a restarted run reproduces exactly what an uninterrupted one would. Shard k holds
samples [k·shard_size, (k+1)·shard_size) and is written atomically (temporary file, then
``os.replace``) as ``shard_{k:06d}.npz``; a restart skips shards that exist. Shards are dealt
round-robin to processes (k % process_count == process_index), so several hosts (with
``jax.distributed``) or independent processes fill one directory without coordination.

Each shard holds ``index`` (b,), ``params`` (b, 13) in ``PARAM_KEYS`` order (SI),
``drop_seed`` (b,), ``status`` (b,) (0 = at rest; nonzero = the simulator's failure code)
and one array per observation, (b, ...). Failed members keep their parameters and status,
their observations are NaN (float) or 0 (integer), and they are logged to ``failures.jsonl``.

With ``drops_per_member`` D > 1, samples D·j … D·j + D − 1 are prior member j dropped with D
different seeds (``member`` = index // D): repeated drapes of one fabric, whose spread is the fold
pattern's and whose mean is what several specimens of a fabric give.

Run from the command line: ``drapejax dataset --out DIR --n N ...`` (or ``python -m drapejax.inverse.dataset``),
which runs in float64 as the simulator needs.
"""

from __future__ import annotations

import argparse
import hashlib
import importlib
import json
import os
import sys
from pathlib import Path
from typing import Callable, Mapping, NamedTuple, Sequence

import numpy as np

from ..material import PARAM_KEYS, FabricParams, to_matrix, unstack
from ..mesh import ClothMesh, cusick_mesh
from .prior import FabricPrior, default_prior

FORMAT = "drapejax-dataset/1"
RESERVED = ("index", "params", "drop_seed", "status")

OBSERVATION_SETTINGS = {
    "silhouette": {"n": 256, "extent_m": 0.16},
    "height": {"n": 256, "extent_m": 0.16},
    "depth4": {"n_views": 4, "size": 128},
    "boundary": {"n_samples": 256},
}
"""Renderer settings of the named observations (spec: 256 px over ±0.16 m top views)."""

Observer = Callable[[np.ndarray, np.ndarray], np.ndarray]
"""An observation: (verts (n, 3) m, faces (m, 3)) → array of a fixed shape."""


class DatasetError(RuntimeError):
    """An inconsistent dataset directory; the message names the file and what is wrong."""


def named_observer(name: str) -> Observer:
    """The renderer of ``drapejax.observe`` behind an observation name (``OBSERVATION_SETTINGS``)."""
    from .. import observe

    table = {
        "silhouette": lambda v, f: observe.silhouette(v, f, **OBSERVATION_SETTINGS["silhouette"]),
        "height": lambda v, f: observe.height_map(v, f, **OBSERVATION_SETTINGS["height"]),
        "depth4": lambda v, f: observe.depth_views(v, f, **OBSERVATION_SETTINGS["depth4"]),
        "boundary": lambda v, f: observe.boundary_curve(v, f, **OBSERVATION_SETTINGS["boundary"]),
    }
    if name not in table:
        raise DatasetError(f"unknown observation {name!r}; known: {sorted(table)} "
                           f"(or give 'name=module:function')")
    return table[name]


def import_callable(spec: str) -> Callable:
    """Resolve ``"package.module:function"`` to the callable it names."""
    module, sep, attr = spec.partition(":")
    if not sep or not module or not attr:
        raise DatasetError(f"{spec!r}: expected 'module:function'")
    try:
        return getattr(importlib.import_module(module), attr)
    except (ImportError, AttributeError) as e:
        raise DatasetError(f"{spec!r}: cannot import ({e})") from None


def resolve_observations(observations: Sequence[str] | Mapping[str, Observer]) -> dict[str, Observer]:
    """Observation name → function, from names, ``"name=module:function"`` strings or a mapping."""
    if isinstance(observations, Mapping):
        obs = dict(observations)
    else:
        obs = {}
        for item in observations:
            name, sep, target = item.partition("=")
            obs[name] = import_callable(target) if sep else named_observer(name)
    clash = sorted(set(obs) & set(RESERVED))
    if clash:
        raise DatasetError(f"observation name(s) {clash} collide with shard arrays {list(RESERVED)}")
    return obs


def default_simulate(mesh: ClothMesh, params: FabricParams, seeds: np.ndarray, config=None, terms=None):
    """``drapejax.solve.drape_batch`` with ``config`` (default ``SolverConfig()``) and ``terms``
    (default: the base model), imported lazily."""
    import jax.numpy as jnp

    from ..solve import SolverConfig, drape_batch

    return drape_batch(mesh, params, jnp.asarray(seeds), terms=terms,
                       config=SolverConfig() if config is None else config)


def quick_simulate(mesh: ClothMesh, params: FabricParams, seeds: np.ndarray):
    """``default_simulate`` with ``quick_config()`` (0.3 s drop, then the static solve): ~5x cheaper."""
    from ..solve import quick_config

    return default_simulate(mesh, params, seeds, quick_config())


def quick_buckling_simulate(mesh: ClothMesh, params: FabricParams, seeds: np.ndarray):
    """``quick_simulate`` with the membrane's compression capped at the element scale
    (``energy.Membrane(buckling=True)``), so that soft fabrics fold on a coarse graded mesh."""
    from ..energy import default_energies
    from ..solve import quick_config

    return default_simulate(mesh, params, seeds, quick_config(), default_energies(mesh.info.test, buckling=True))


class ConvergedDrapes(NamedTuple):
    """``converged_simulate``'s result: the rest states on the dataset mesh and each member's status."""

    x: np.ndarray
    status: np.ndarray


def converged_simulate(mesh: ClothMesh, params: FabricParams, seeds: np.ndarray) -> ConvergedDrapes:
    """Each member draped to its converged rest state as ``drapejax simulate`` drapes it, carried
    to the dataset mesh.

    The drape runs on nested meshes whose finest level has the dataset mesh's interior spacing and
    its disc edge graded to a fifth of that (``mesh.cusick_hierarchy``), with the drop on the
    coarsest level the fabric's folds allow (``solve.coarsest_spacing_m``) and a static solve on
    each finer level (``solve.drape_multilevel``). The finest rest state is carried to the dataset
    mesh by barycentric interpolation in the flat rest state (``transfer.transfer``), so give the
    dataset the same interior spacing (``--spacing``) and no coarser. Members run side by side on
    the CPU's cores (``solve.threads``); members with the same hierarchy share one compiled
    program. A member that does not come to rest keeps its own status (``invalid_parameters`` for
    parameters outside the model's range, as ``solve.drape``).
    """
    import jax

    from ..mesh import cusick_hierarchy
    from ..solve import coarsest_spacing_m, drape_multilevel
    from ..solve.threads import run_side_by_side
    from ..transfer import rest_barycentrics, transfer

    if mesh.info.test != "cusick":
        raise DatasetError(f"converged_simulate drapes Cusick specimens; the dataset mesh is {mesh.info.test!r}")
    spacing = float(mesh.info.spacing_m)
    members = unstack(params)

    hierarchies = [cusick_hierarchy(spacing, coarsest_spacing_m=coarsest_spacing_m(p)) for p in members]
    programs: dict[int, tuple[Callable, tuple]] = {}
    for meshes, prolongs in hierarchies:  # compiled one by one before the drapes share the cores
        key = id(meshes[-1])
        if key not in programs:
            run = jax.jit(lambda p, s, m=meshes, pr=prolongs: drape_multilevel(m, pr, p, s))
            programs[key] = run.lower(members[0], np.int32(0)).compile(), rest_barycentrics(meshes[-1], mesh)

    def one(j: int) -> tuple[np.ndarray, int]:
        meshes, _ = hierarchies[j]
        run, barycentrics = programs[id(meshes[-1])]
        r = run(members[j], np.int32(seeds[j]))
        return transfer(r.finest.x, meshes[-1], mesh, barycentrics), int(r.finest.status)

    done = run_side_by_side(one, len(members), desc="converged drapes")
    return ConvergedDrapes(x=np.stack([x for x, _ in done]), status=np.array([s for _, s in done], np.int32))


def drop_seeds(seed: int, indices) -> np.ndarray:
    """Per-sample drop seeds (int32-safe), a function of (seed, index) only."""
    return np.array([np.random.SeedSequence([int(seed), int(i), 1]).generate_state(1)[0] & 0x7FFFFFFF
                     for i in np.asarray(indices).reshape(-1)], np.int64)


def params_matrix(params: FabricParams) -> np.ndarray:
    """(b, 13) float64 array of a batched ``FabricParams`` in ``PARAM_KEYS`` order (``material.to_matrix``)."""
    return to_matrix(params)


def _atomic_write(path: Path, write: Callable) -> None:
    tmp = path.with_name(f"{path.name}.tmp.{os.getpid()}")
    with open(tmp, "wb") as f:
        write(f)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def _check_config(out: Path, config: dict) -> None:
    """Write ``dataset.json`` or check that an existing one describes the same dataset."""
    path = out / "dataset.json"
    if path.exists():
        old = json.loads(path.read_text())
        diff = sorted(k for k in set(old) | set(config) if old.get(k) != config.get(k))
        if diff:
            raise DatasetError(f"{path}: existing dataset differs in {diff} "
                               f"({ {k: old.get(k) for k in diff} } vs { {k: config.get(k) for k in diff} }); "
                               f"use a new output directory")
    else:
        _atomic_write(path, lambda f: f.write(json.dumps(config, indent=1).encode()))


def _fill_like(template: np.ndarray) -> np.ndarray:
    fill = np.nan if np.issubdtype(template.dtype, np.floating) else 0
    return np.full_like(template, fill)


def generate(out_dir, *, n_samples: int, shard_size: int, prior: FabricPrior | None = None,
             mesh_spacing_m: float = 0.01, mesh_rim_spacing_m: float | None = None,
             observations: Sequence[str] | Mapping[str, Observer] = ("silhouette", "height", "depth4", "boundary"),
             seed: int = 0, process_index: int | None = None, process_count: int | None = None,
             progress: bool = True, simulate: Callable | str | None = None, drops_per_member: int = 1) -> dict:
    """Generate (or resume) this process's shards of a Cusick drape dataset.

    Args:
        out_dir: dataset directory (created; shared by all processes).
        n_samples: total number of samples over all processes.
        shard_size: samples per shard (one simulator batch).
        prior: parameter prior (default: ``default_prior()``).
        mesh_spacing_m: target edge length of the Cusick specimen mesh, m.
        mesh_rim_spacing_m: grade the mesh's rings from this spacing on the disc edge
            (``cusick_mesh``); default uniform.
        observations: names (``OBSERVATION_SETTINGS``), ``"name=module:function"`` strings, or
            a mapping name → function(verts (n,3), faces (m,3)) → array.
        seed: dataset seed; sample i depends on (seed, i) only.
        process_index, process_count: this process's share; default ``jax.process_index()``
            and ``jax.process_count()``.
        progress: show a tqdm bar (only on a terminal).
        simulate: (mesh, params (batched), drop seeds (b,)) → result with ``x`` (b, n, 3) and
            ``status`` (b,); default ``drapejax.solve.drape_batch``. A ``"module:function"``
            string is imported and recorded in ``dataset.json`` (key ``simulate``), so the dataset
            says how its drapes were made and a resume with another one is refused.
        drops_per_member: drops of each prior member, each with its own seed (sample i is member
            i // drops_per_member); recorded in ``dataset.json`` when above 1.

    Returns:
        ``{"written": [k...], "skipped": [k...], "failures": int}`` for this process.
    """
    from tqdm.auto import tqdm

    if (process_index is None) != (process_count is None):
        raise DatasetError("give both process_index and process_count, or neither")
    if process_index is None:
        import jax

        process_index, process_count = jax.process_index(), jax.process_count()
    if not 0 <= process_index < process_count:
        raise DatasetError(f"process_index {process_index} not in [0, {process_count})")
    if n_samples < 1 or shard_size < 1 or drops_per_member < 1:
        raise DatasetError(f"n_samples ({n_samples}), shard_size ({shard_size}) and drops_per_member "
                           f"({drops_per_member}) must be positive")
    prior = default_prior() if prior is None else prior
    simulate_spec = simulate if isinstance(simulate, str) else None
    if simulate_spec is not None:
        simulate = import_callable(simulate_spec)
    elif simulate is None:
        simulate = default_simulate
    obs = resolve_observations(observations)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    _check_config(out, {
        "format": FORMAT, "n_samples": int(n_samples), "shard_size": int(shard_size), "seed": int(seed),
        "mesh_spacing_m": float(mesh_spacing_m), "observations": sorted(obs), "param_keys": list(PARAM_KEYS),
        "prior_sha256": hashlib.sha256(prior.to_json().encode()).hexdigest(),
        **({} if mesh_rim_spacing_m is None else {"mesh_rim_spacing_m": float(mesh_rim_spacing_m)}),
        **({} if simulate_spec is None else {"simulate": simulate_spec}),
        **({} if drops_per_member == 1 else {"drops_per_member": int(drops_per_member)}),
    })
    n_shards = -(-n_samples // shard_size)
    mine = [k for k in range(n_shards) if k % process_count == process_index]
    for k in mine:
        for stale in out.glob(f"shard_{k:06d}.npz.tmp.*"):
            stale.unlink()
    done = [k for k in mine if (out / f"shard_{k:06d}.npz").exists()]
    todo = [k for k in mine if k not in done]
    mesh = cusick_mesh(mesh_spacing_m, rim_spacing_m=mesh_rim_spacing_m)
    faces = np.asarray(mesh.faces)
    rest = np.asarray(mesh.rest)
    templates = {name: np.asarray(fn(rest, faces)) for name, fn in obs.items()} if todo else {}
    n_fail = 0
    bar = tqdm(total=len(mine), initial=len(done), desc=f"shards (process {process_index})",
               disable=not (progress and sys.stderr.isatty()), position=process_index)
    for k in todo:
        idx = np.arange(k * shard_size, min((k + 1) * shard_size, n_samples))
        params = prior.sample_indices(idx // drops_per_member, seed)
        seeds = drop_seeds(seed, idx)
        res = simulate(mesh, params, seeds)
        x, status = np.asarray(res.x), np.asarray(res.status).astype(np.int32).reshape(-1)
        if x.shape != (len(idx), mesh.n_verts, 3) or status.shape != (len(idx),):
            raise DatasetError(f"simulate returned x {x.shape} and status {status.shape}; expected "
                               f"({len(idx)}, {mesh.n_verts}, 3) and ({len(idx)},)")
        arrays = {"index": idx, "params": params_matrix(params), "drop_seed": seeds, "status": status}
        for name, fn in obs.items():
            arrays[name] = np.stack([np.asarray(fn(x[j], faces)) if status[j] == 0 else _fill_like(templates[name])
                                     for j in range(len(idx))])
        _atomic_write(out / f"shard_{k:06d}.npz", lambda f: np.savez(f, **arrays))
        failed = np.flatnonzero(status != 0)
        if failed.size:
            n_fail += failed.size
            lines = "".join(json.dumps({"index": int(idx[j]), "shard": k, "status": int(status[j]),
                                        "drop_seed": int(seeds[j]), "process": process_index,
                                        "params": dict(zip(PARAM_KEYS, arrays["params"][j].tolist()))}) + "\n"
                            for j in failed)
            with open(out / "failures.jsonl", "a") as f:
                f.write(lines)
        bar.update(1)
    bar.close()
    return {"written": todo, "skipped": done, "failures": n_fail}


def load(out_dir) -> dict[str, np.ndarray]:
    """All shards concatenated and sorted by index; raises if samples are missing or repeated."""
    out = Path(out_dir)
    cfg_path = out / "dataset.json"
    if not cfg_path.exists():
        raise DatasetError(f"{cfg_path}: not found (not a drapejax dataset directory)")
    n = json.loads(cfg_path.read_text())["n_samples"]
    files = sorted(out.glob("shard_*.npz"))
    if not files:
        raise DatasetError(f"{out}: no shard_*.npz files")
    parts = []
    for f in files:
        with np.load(f) as z:
            parts.append({k: z[k] for k in z.files})
    keys = set(parts[0])
    for f, p in zip(files, parts):
        if set(p) != keys:
            raise DatasetError(f"{f}: arrays {sorted(p)} differ from {sorted(keys)} in {files[0].name}")
    data = {k: np.concatenate([p[k] for p in parts]) for k in sorted(keys)}
    order = np.argsort(data["index"], kind="stable")
    data = {k: v[order] for k, v in data.items()}
    idx = data["index"]
    dup = np.unique(idx[1:][idx[1:] == idx[:-1]])
    missing = np.setdiff1d(np.arange(n), idx)
    extra = idx[(idx < 0) | (idx >= n)]
    if dup.size or missing.size or extra.size:
        raise DatasetError(f"{out}: dataset of {n} samples is incomplete or inconsistent: "
                           f"{missing.size} missing (first {missing[:10].tolist()}), "
                           f"{dup.size} duplicated (first {dup[:10].tolist()}), "
                           f"{extra.size} out of range")
    return data


def main(argv: Sequence[str] | None = None, prog: str = "python -m drapejax.inverse.dataset") -> None:
    """Command-line entry point (``drapejax dataset``, or ``python -m drapejax.inverse.dataset``)."""
    ap = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n")[0])
    ap.add_argument("--out", required=True, help="dataset directory")
    ap.add_argument("--n", type=int, required=True, help="total number of samples")
    ap.add_argument("--shard-size", type=int, default=64)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--spacing", type=float, default=0.01, help="mesh edge length, m")
    ap.add_argument("--rim-spacing", type=float, default=None,
                    help="grade the mesh from this edge length on the disc edge up to --spacing, m (default: uniform)")
    ap.add_argument("--observations", default="silhouette,height,depth4,boundary",
                    help="comma-separated names or name=module:function")
    ap.add_argument("--prior", default=None, help="prior JSON (default: the shipped 618-fabric prior)")
    ap.add_argument("--simulate", default=None, help="module:function replacing drapejax.solve.drape_batch "
                    "(e.g. drapejax.inverse.dataset:quick_simulate)")
    ap.add_argument("--process-index", type=int, default=None)
    ap.add_argument("--process-count", type=int, default=None)
    ap.add_argument("--coordinator", default=None,
                    help="host:port of process 0; with --process-count > 1 calls jax.distributed.initialize")
    ap.add_argument("--drops-per-member", type=int, default=1, metavar="D",
                    help="drop each prior member D times with different seeds (sample i is member i // D)")
    ap.add_argument("--no-progress", action="store_true")
    a = ap.parse_args(argv)
    import jax

    jax.config.update("jax_enable_x64", True)
    if (a.process_index is None) != (a.process_count is None):
        ap.error("give both --process-index and --process-count, or neither")
    if a.coordinator and a.process_count and a.process_count > 1:
        jax.distributed.initialize(a.coordinator, num_processes=a.process_count, process_id=a.process_index)
        a.process_index, a.process_count = jax.process_index(), jax.process_count()
    if a.prior is None:
        prior = default_prior()
    elif not Path(a.prior).is_file():
        ap.error(f"--prior {a.prior}: file not found")
    else:
        prior = FabricPrior.from_json(Path(a.prior).read_text(), source=a.prior)
    obs = [s for s in a.observations.split(",") if s]
    summary = generate(a.out, n_samples=a.n, shard_size=a.shard_size, prior=prior, mesh_spacing_m=a.spacing,
                       mesh_rim_spacing_m=a.rim_spacing,
                       observations=obs, seed=a.seed, process_index=a.process_index,
                       process_count=a.process_count, progress=not a.no_progress,
                       simulate=a.simulate, drops_per_member=a.drops_per_member)
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
