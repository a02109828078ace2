"""Independent drops side by side: a thread pool sized to the CPUs, for the host-side loops over drops.

A drop is one jitted solve. While it runs, JAX releases the GIL, and so does the host sparse
factorisation inside it (an FFI target, ``_host_ffi``). Much of a small mesh's drop is those
factorisations and small XLA kernels, about one core's worth. So independent drops, run from
several Python threads, share the cores. A diagnosis's fresh drops and the virtual lab's
captures are such drops (``diagnose.trials.pooled_drops``, ``virtual_lab.make_measurements``).

On two cores, eight drops of "mid" on the 20 mm fit mesh took 38 s with two threads, 41 s with
three, and 66 s one at a time (``docs/results/2026-12-07-parallel-drops.md``). Each drop depends
on its own inputs alone, so results do not depend on the thread count.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from typing import Any

from ..progress import bar

THREADS_ENV = "DRAPEJAX_DROP_THREADS"
"""Environment variable: how many drops run side by side (1: one at a time)."""


def available_cpus() -> int:
    """The CPUs this process may run on (its affinity where the platform has one), at least 1."""
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1))


def drop_threads() -> int:
    """Threads of ``run_side_by_side``: ``DRAPEJAX_DROP_THREADS`` when set to a positive integer, else
    ``available_cpus()``."""
    flag = os.environ.get(THREADS_ENV, "").strip()
    if flag:
        if not flag.isdigit() or int(flag) < 1:
            raise ValueError(f"{THREADS_ENV} must be a positive integer, got {flag!r}")
        return int(flag)
    return available_cpus()


def run_side_by_side(fn: Callable[[int], Any], n: int, *, threads: int | None = None, desc: str = "drops",
                     unit: str = "drop") -> list:
    """[fn(0), ..., fn(n - 1)], ``threads`` calls at a time (default ``drop_threads()``); a progress
    bar (``desc``) counts them as they finish. One thread calls them in order in this thread; an
    exception of any call is raised here."""
    k = min(drop_threads() if threads is None else int(threads), n)
    with bar(total=n, desc=desc, unit=unit) as b:
        if k <= 1:
            out = []
            for i in range(n):
                out.append(fn(i))
                b.update()
            return out
        with ThreadPoolExecutor(max_workers=k) as pool:
            futures = [pool.submit(fn, i) for i in range(n)]
            for _ in as_completed(futures):
                b.update()
            return [f.result() for f in futures]


def map_side_by_side(fn: Callable[[Any], Any], items: Sequence, **kwargs) -> list:
    """``run_side_by_side`` of ``fn`` over ``items``, in their order."""
    items = list(items)
    return run_side_by_side(lambda i: fn(items[i]), len(items), **kwargs)


__all__ = ["THREADS_ENV", "available_cpus", "drop_threads", "run_side_by_side", "map_side_by_side"]
