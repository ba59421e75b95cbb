"""Where a render runs: a Warp device named by the user, checked once with a clear error.

    check_device("cuda")        # "cuda:0" on a machine with a GPU; a ValueError naming what is there otherwise

The same kernels run on every device: "cpu" (the default; its launches are tiled over a thread pool,
parallel.py) or "cuda" / "cuda:N" (one launch covers the image). Asking Warp itself for a CUDA device it does not
have prints a CUDA driver error and raises a RuntimeError (or "Invalid device identifier"), so the name is checked
here first and the error says which option was wrong and which devices exist.

    init_warp()                 # what the command does first: Warp started without its "no CUDA driver" line
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile

import warp as wp

DEFAULT_DEVICE = "cpu"
# What Warp's native library prints on stderr when it starts on a machine without a GPU (cuda_util.cpp).
NO_DRIVER_LINE = "Could not find or load the NVIDIA CUDA driver"


def init_warp(verbose: bool = False) -> None:
    """Start Warp, as the command does before its work. Warp's native library prints "Could not find or load the
    NVIDIA CUDA driver. GPU execution will not be available." on every machine without a GPU: what the CPU
    default expects, so that one line is dropped (a --device cuda there gets `check_device`'s error instead);
    every other line Warp prints passes. `verbose`: drop nothing. Warp's banner follows its log level."""
    if verbose:
        wp.init()
        return
    with native_stderr_without(NO_DRIVER_LINE):
        wp.init()


@contextlib.contextmanager
def native_stderr_without(text: str | None):
    """Hold what is written to file descriptor 2 (C code's stderr, which sys.stderr cannot intercept) and pass on
    the lines that do not contain `text` (with None, none: native chatter hidden whole)."""
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError, AttributeError):  # no descriptor 2 (a GUI host): nothing to filter
        yield
        return
    with tempfile.TemporaryFile() as held:
        os.dup2(held.fileno(), 2)
        try:
            yield
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            held.seek(0)
            lines = held.read().decode(errors="replace").splitlines(True)
            kept = [] if text is None else [line for line in lines if text not in line]
            if kept:
                sys.stderr.write("".join(kept))
                sys.stderr.flush()


def available_devices() -> list[str]:
    """The devices this machine has, as Warp names them: "cpu", then "cuda:0", "cuda:1", ..."""
    return [device.alias for device in wp.get_devices()]


def why_no_cuda() -> str:
    """Why this machine has no CUDA device, in a few words."""
    if wp.get_cuda_driver_version() is None:
        return "Warp finds no CUDA driver on this machine"
    return "the CUDA driver reports no GPU"


def check_device(device, name: str = "device") -> str:
    """The canonical name ("cpu", "cuda:0", ...) of `device`: None (the default, "cpu"), a name such as "cuda" or
    "cuda:1", a `warp.Device` or a `torch.device`. A device this machine lacks, or a name that is not one, raises
    ValueError naming the option (`name`, e.g. "--device") and the devices available."""
    if device is None:
        return DEFAULT_DEVICE
    if isinstance(device, wp.Device) or type(device).__name__ == "device":  # a Warp or a torch device
        device = str(device)
    if not isinstance(device, str):
        raise ValueError(f"{name} must be a device name such as 'cpu' or 'cuda', got {device!r}")
    available = ", ".join(available_devices())
    if device.startswith("cuda") and not wp.is_cuda_available():
        raise ValueError(f"{name} = {device!r}, but {why_no_cuda()}; available: {available}")
    try:
        return wp.get_device(device).alias
    except (ValueError, RuntimeError):
        raise ValueError(
            f"{name} = {device!r} is not a device of this machine; available: {available} ('cuda' is the current GPU)"
        ) from None


def is_cpu(device: str) -> bool:
    return wp.get_device(device).is_cpu
