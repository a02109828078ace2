"""JAX's persistent compilation cache, switched on for drapejax's commands and tests.

A drape program (a Newton drop and static solves, with their sparse Hessian assembly) takes
20-30 s to compile on a 2-core CPU, longer than many drapes take to run. With the cache on, a
program compiled once is loaded from disk by every later process that traces the same program
(the key is the program's text, the JAX version and the backend). The direct solver's host
functions are named FFI targets (``drapejax.solve._host_ffi``), not Python callbacks, so the
drape programs qualify.

The cache is bounded (least recently used programs evicted), which also makes JAX hold a file
lock while writing an entry, so that processes sharing the folder (pytest workers, a sweep) never
read a half-written program.
"""

from __future__ import annotations

import os
from pathlib import Path

import jax

DEFAULT_DIR = Path.home() / ".cache" / "drapejax" / "jax"
"""Where the command line keeps compiled programs unless ``DRAPEJAX_CACHE_DIR`` says otherwise."""

MAX_BYTES = 4 * 2**30
"""Size bound of the cache folder; a 5 mm drape program is some tens of MB."""


def enable(path: str | os.PathLike | None = None, *, min_compile_s: float = 1.0,
           max_bytes: int = MAX_BYTES) -> Path | None:
    """Keep compiled programs in ``path`` (default: ``DRAPEJAX_CACHE_DIR``, else ``DEFAULT_DIR``;
    an empty ``DRAPEJAX_CACHE_DIR`` turns the cache off and returns None).

    Programs that compile in under ``min_compile_s`` are not written (loading costs about as much).
    Call before the first compilation: JAX reads these settings when it first uses the cache.
    """
    if path is None:
        env = os.environ.get("DRAPEJAX_CACHE_DIR")
        if env == "":
            return None
        path = env or DEFAULT_DIR
    path = Path(path).expanduser()
    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", float(min_compile_s))
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    jax.config.update("jax_compilation_cache_max_size", int(max_bytes))
    return path


__all__ = ["enable", "DEFAULT_DIR", "MAX_BYTES"]
