"""Where a CPU drape's time goes: the direct solver's host work against the compiled rest.

Times full drapes (default ``SolverConfig``, "mid" fabric, Cusick) after a compile drop, in two
phases: the dynamic drop (its final static solve cut off) and the static solve that ends every
drape, from the drop's end state (its hourglass control couples 2-rings, so its iterations cost
several drop iterations). The two run exactly what one ``drape`` call runs. In the same runs it
times the host side of every Newton iteration: the shifted sparse solves
(``_sparse._host_solve_shifted``: summing the triplets into the matrix, CHOLMOD factorisations
that succeed and those that fail on an indefinite matrix, the solves) and the projected fallback
(``_host_solve``). What is not host time is XLA: gradients, element Hessians, line searches.
The count of each diagonal shift says how often the exact Hessian was positive definite (shift 0).

Run ``python benchmarks/drop_profile.py --spacing-mm 5 --seeds 0,1,2`` (``--quick``: drapes of
``quick_config``, as datasets and fits drop them; ``--spacing-mm 20 --rim-mm 3 --buckling``: on
their graded mesh with the compression cap); prints one JSON object (medians over seeds, and each
run).
"""

from __future__ import annotations

import argparse
import collections
import json
import statistics
import time

import jax

import drapejax.solve._sparse as sparse
from drapejax.bench import timed
from drapejax.energy import default_energies
from drapejax.material import example_params
from drapejax.mesh import cusick_mesh
from drapejax.solve import NewtonConfig, SolverConfig, drape, quick_config, static_solve


class _HostClock:
    """Counts and times the direct solver's host calls (wraps them in place, before tracing)."""

    def __init__(self):
        self.count, self.seconds = collections.Counter(), collections.Counter()
        self._wrap(sparse._Pattern, "cholesky_solve",
                   lambda out: "cholesky_ok" if out is not None else "cholesky_failed")
        self._wrap(sparse, "_host_solve_shifted", lambda out: f"shift_{float(out[1]):.0e}", total="shifted_solve")
        self._wrap(sparse, "_host_solve", lambda out: None, total="projected_solve")

    def _wrap(self, owner, name, label, total=None):
        inner = getattr(owner, name)

        def clocked(*args, **kw):
            start = time.perf_counter()
            out = inner(*args, **kw)
            dt = time.perf_counter() - start
            for key in filter(None, (label(out), total)):
                self.count[key] += 1
                self.seconds[key] += dt
            return out
        setattr(owner, name, clocked)

    def reset(self):
        self.count.clear()
        self.seconds.clear()


def _phase(clock: _HostClock, fn, *args) -> tuple[object, dict]:
    """Result, and seconds with their host breakdown, of one call."""
    clock.reset()
    seconds, res = timed(fn, *args)
    host_s = clock.seconds["shifted_solve"] + clock.seconds["projected_solve"]
    return res, {"s": seconds, "newton_iters": int(res.newton_iters),
                 "ms_per_iter": 1e3 * seconds / max(int(res.newton_iters), 1), "host_s": host_s,
                 "xla_s": seconds - host_s, "cholesky_ok_s": clock.seconds["cholesky_ok"],
                 "cholesky_failed_s": clock.seconds["cholesky_failed"], "counts": dict(clock.count)}


def profile(spacing_m: float, seeds: list[int], fabric: str = "mid", quick: bool = False,
            rim_spacing_m: float | None = None, buckling: bool = False) -> dict:
    """Per-seed rest time (dynamic + static phase), steps, Newton iterations and host-side breakdown (seconds)."""
    jax.config.update("jax_enable_x64", True)
    clock = _HostClock()
    mesh = cusick_mesh(spacing_m, rim_spacing_m=rim_spacing_m)
    terms = default_energies(mesh.info.test, buckling=buckling)
    params = example_params(fabric)
    make = quick_config if quick else SolverConfig
    config = make()
    dynamic_only = make(static=NewtonConfig(max_iters=0))
    dynamic = jax.jit(lambda p, s: drape(mesh, p, s, terms=terms, config=dynamic_only))
    static = jax.jit(lambda p, x: static_solve(mesh, p, x, terms=terms, config=config))
    jax.block_until_ready(static(params, dynamic(params, seeds[0]).x))
    runs = []
    for seed in seeds:
        drop, drop_parts = _phase(clock, dynamic, params, seed)
        res, static_parts = _phase(clock, static, params, drop.x)
        rest_s = drop_parts["s"] + static_parts["s"]
        iters = int(drop.newton_iters) + int(res.newton_iters)
        host_s = drop_parts["host_s"] + static_parts["host_s"]
        runs.append({"seed": seed, "rest_s": rest_s, "status": int(res.status), "steps": int(drop.steps),
                     "newton_iters": iters, "ms_per_iter": 1e3 * rest_s / max(iters, 1), "host_s": host_s,
                     "xla_s": rest_s - host_s, "dynamic": drop_parts, "static": static_parts})
    med = lambda key, phase=None: statistics.median((r[phase] if phase else r)[key] for r in runs)
    return {"verts": int(mesh.rest.shape[0]), "spacing_mm": 1e3 * spacing_m,
            "rim_mm": None if rim_spacing_m is None else 1e3 * rim_spacing_m, "buckling": buckling,
            "quick_config": quick, "rest_s": med("rest_s"),
            "host_s": med("host_s"), "xla_s": med("xla_s"), "newton_iters": med("newton_iters"),
            "ms_per_iter": med("ms_per_iter"), "dynamic_s": med("s", "dynamic"), "static_s": med("s", "static"),
            "static_ms_per_iter": med("ms_per_iter", "static"), "runs": runs}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spacing-mm", type=float, default=5.0)
    ap.add_argument("--seeds", default="0,1,2", help="comma-separated drop seeds (one timed drape each)")
    ap.add_argument("--fabric", default="mid")
    ap.add_argument("--quick", action="store_true", help="quick_config drapes (0.3 s of drop, then the static solve)")
    ap.add_argument("--rim-mm", type=float, default=None,
                    help="grade the mesh from this spacing at the disc edge (the fit and dataset mesh: 20 from 3)")
    ap.add_argument("--buckling", action="store_true", help="cap the membrane's compression (as fits and datasets do)")
    args = ap.parse_args()
    print(json.dumps(profile(1e-3 * args.spacing_mm, [int(s) for s in args.seeds.split(",")], args.fabric, args.quick,
                             None if args.rim_mm is None else 1e-3 * args.rim_mm, args.buckling)))


if __name__ == "__main__":
    main()
