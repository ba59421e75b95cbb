"""Spread a Warp CPU launch over all cores.

One `wp.launch` on the CPU runs on one core, but launches from several Python threads run at the same time
(Warp releases the GIL). Kernels launched through here take the index of their first item as their last
input, so each thread launches over its own contiguous range of the same arrays: no copies, and the
result does not depend on how many threads there are.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import warp as wp


def default_threads() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def launch_ranges(kernel, n: int, inputs: list, threads: int | None = None, device: str = "cpu") -> None:
    """Launch `kernel` over n items as `kernel(*inputs, first)` on ranges of the items, one per thread."""
    if n == 0:
        return
    if threads is not None and threads < 1:
        raise ValueError(f"threads must be at least 1, got {threads}")
    if not wp.get_device(device).is_cpu:
        wp.launch(kernel, dim=n, inputs=[*inputs, 0], device=device)
        return
    threads = min(threads or default_threads(), n)
    # Compile (or fetch from the cache) once, before the threads race to do it each.
    wp.load_module(kernel.module, device=device)
    bounds = [n * k // threads for k in range(threads + 1)]

    def run(k: int) -> None:
        wp.launch(kernel, dim=bounds[k + 1] - bounds[k], inputs=[*inputs, bounds[k]], device=device)

    if threads == 1:
        run(0)
        return
    with ThreadPoolExecutor(threads) as pool:
        list(pool.map(run, range(threads)))
