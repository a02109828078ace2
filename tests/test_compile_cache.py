"""Programs that hold the direct solver's host functions are kept by JAX's persistent cache.

A second process that traces the same program must load it from the cache instead of compiling
it, and get the same numbers: the host functions are found again by name.
"""

import json
import subprocess
import sys
import textwrap

import numpy as np

_SCRIPT = textwrap.dedent("""
    import json, sys
    import jax, jax.numpy as jnp, numpy as np
    jax.config.update("jax_enable_x64", True)
    jax.config.update("jax_compilation_cache_dir", sys.argv[1])
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    events = []
    jax.monitoring.register_event_listener(lambda name, **kw: events.append(name))
    from drapejax.solve._sparse import psd_project, sparse_solve, sparse_solve_shifted

    n = 12  # a path graph's Laplacian plus a diagonal: 3x3 blocks on a 4-vertex chain
    i = np.arange(n)
    rows = np.concatenate([i, i[:-1], i[1:]])
    cols = np.concatenate([i, i[1:], i[:-1]])

    @jax.jit
    def program(d, rhs, blocks):
        vals = jnp.concatenate([d, -jnp.ones(n - 1), -jnp.ones(n - 1)])
        y = sparse_solve(rows, cols, vals, rhs)
        z, mu = sparse_solve_shifted(rows, cols, vals - jnp.concatenate([jnp.full(n, 2.5), jnp.zeros(2 * n - 2)]), rhs)
        batched = jax.vmap(lambda r: sparse_solve(rows, cols, vals, r))(jnp.stack([rhs, 2 * rhs]))
        return y, z, mu, batched, psd_project(blocks)

    # NumPy inputs: no eager JAX operation compiles (and is cached) besides the program
    d = np.full(n, 3.0)
    rhs = np.sin(np.arange(n, dtype=np.float64))
    blocks = np.stack([np.diag([1.0, -2.0, 3.0])] * 5)
    y, z, mu, batched, proj = program(d, rhs, blocks)
    print(json.dumps({"y": np.asarray(y).tolist(), "z": np.asarray(z).tolist(), "mu": float(mu),
                      "batched": np.asarray(batched).tolist(), "proj": np.asarray(proj).tolist(),
                      "hits": events.count("/jax/compilation_cache/cache_hits")}))
""")


def _run(cache_dir) -> dict:
    out = subprocess.run([sys.executable, "-c", _SCRIPT, str(cache_dir)], capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_a_program_with_host_solves_is_cached_and_gives_the_same_numbers_from_the_cache(tmp_path):
    first, second = _run(tmp_path), _run(tmp_path)
    assert first["hits"] == 0
    assert second["hits"] == 1, "the second process compiled the program again"

    n = 12
    a = 3.0 * np.eye(n) - np.eye(n, k=1) - np.eye(n, k=-1)
    rhs = np.sin(np.arange(n))
    for run in (first, second):
        np.testing.assert_allclose(run["y"], np.linalg.solve(a, rhs), rtol=1e-12)
        np.testing.assert_allclose(run["batched"], [np.linalg.solve(a, rhs), np.linalg.solve(a, 2 * rhs)], rtol=1e-12)
        # 0.5 I - offdiagonals is indefinite: the ladder shifts it until it is positive definite
        assert run["mu"] > 0 and np.isfinite(run["mu"])
        np.testing.assert_allclose(run["proj"][0], np.diag([1.0, 0.0, 3.0]), atol=1e-12)
    assert second["z"] == first["z"]
