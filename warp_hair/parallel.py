"""Spread a Warp CPU launch over all cores.

One `wp.launch` on the CPU runs on one core, but launches from several Python threads run at the same time
(Warp releases the GIL). Kernels launched through here take the index of their first item as their last
input, so each launch covers its own contiguous range of the same arrays: no copies, and the result does
not depend on how many threads there are. On a GPU one launch covers all the items: the device spreads it.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
from concurrent.futures import ThreadPoolExecutor, as_completed

import warp as wp

# A Ctrl-C that landed in a finalizer while a command ran (`interrupts_delivered`): the next `launch_ranges` raises it.
_PENDING = threading.Event()


def _interrupt(signum, frame):
    """Python's Ctrl-C (a KeyboardInterrupt where the main thread is), except inside a finalizer such as a Warp
    array's `__del__`: Python only prints an exception raised there, and the command would run on to its end.
    There it is kept pending instead, and the next `launch_ranges` raises it."""
    while frame is not None:
        if frame.f_code.co_name == "__del__":
            _PENDING.set()
            return
        frame = frame.f_back
    raise KeyboardInterrupt


def _python_handler() -> bool:
    """Whether SIGINT is Python's own handler (or ours in its place) and this is the main thread: a program that
    set its own, or a background process that ignores SIGINT, is left alone."""
    return threading.current_thread() is threading.main_thread() and signal.getsignal(signal.SIGINT) in (
        signal.default_int_handler,
        _interrupt,
    )


@contextlib.contextmanager
def interrupts_delivered():
    """While a command runs (cli.main, `exit_on_interrupt`): Ctrl-C raises KeyboardInterrupt as Python's handler
    does, but one that lands in a finalizer is not lost (`_interrupt`)."""
    if not _python_handler():
        yield
        return
    _PENDING.clear()
    previous = signal.signal(signal.SIGINT, _interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        _PENDING.clear()


def default_threads() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def launch_ranges(
    kernel,
    n: int,
    inputs: list,
    threads: int | None = None,
    device: str = "cpu",
    chunk: int | None = None,
    progress=None,
) -> None:
    """Launch `kernel(*inputs, first)` over n items, in ranges run by a pool of threads.

    Without `chunk`, one range per thread (for uniform work). With `chunk`, ranges of that many items
    handed out as threads free up, which balances uneven work (pixels on fibers cost more than background).
    `progress(done, total)` is called after each range. On Ctrl-C (or an error in a range) no further range
    starts: the running ones finish, and the KeyboardInterrupt (or the error) propagates within one range's time.
    """
    if _PENDING.is_set():
        _PENDING.clear()
        raise KeyboardInterrupt
    if n == 0:
        return
    if threads is not None and threads < 1:
        raise ValueError(f"threads must be at least 1, got {threads}")
    if not wp.get_device(device).is_cpu:
        wp.launch(kernel, dim=n, inputs=[*inputs, 0], device=device)
        if progress is not None:
            progress(n, n)
        return
    threads = min(threads or default_threads(), n)
    step = chunk or -(-n // threads)
    ranges = [(first, min(step, n - first)) for first in range(0, n, step)]
    # Compile (or fetch from the cache) once, before the threads race to do it each.
    wp.load_module(kernel.module, device=device)

    stop = threading.Event()

    def run(first_count):
        if stop.is_set():
            return 0
        first, count = first_count
        wp.launch(kernel, dim=count, inputs=[*inputs, first], device=device)
        return count

    done = 0
    with _stop_on_sigint(stop) as interrupted, ThreadPoolExecutor(threads) as pool:
        try:
            for future in as_completed([pool.submit(run, r) for r in ranges]):
                done += future.result()
                if progress is not None and not stop.is_set():
                    progress(done, n)
        except BaseException:
            stop.set()  # the queued ranges return at once; the pool's exit waits for the running ones only
            raise
    if interrupted:
        raise KeyboardInterrupt


@contextlib.contextmanager
def _stop_on_sigint(stop: threading.Event):
    """While ranges run, Ctrl-C sets `stop` (and is recorded in the yielded list) instead of raising: a
    KeyboardInterrupt raised inside the pool's locks can leave them broken ("release unlocked lock"). The caller
    raises it once the running ranges are done. Only in the main thread, and only over Python's own handler."""
    received = []
    if not _python_handler():
        yield received
        return

    def handler(signum, frame):
        received.append(signum)
        stop.set()

    previous = signal.signal(signal.SIGINT, handler)
    try:
        yield received
    finally:
        signal.signal(signal.SIGINT, previous)
