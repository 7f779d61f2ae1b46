"""Backend selection: which implementation of a primitive runs, and where.

Names accepted everywhere a ``backend=`` argument is taken:

``"cpu"``        the NumPy/OpenCV implementation (``warpvx.kernels_cpu``).
``"warp-cpu"``   the Warp kernels on Warp's CPU device (what tests use without a GPU).
``"cuda"``       the Warp kernels on the current CUDA device; ``"cuda:N"`` on device N.
``None``         the process-wide default (:func:`set_backend`), else CUDA when a GPU is
                 present, else ``"cpu"``. A ``wp.array`` input with ``backend=None`` runs on
                 its own device.

Warp is imported and initialised lazily, on the first Warp backend request, never at import
time; resolving ``None`` on a machine without the CUDA driver picks ``"cpu"`` without importing
Warp at all (:func:`cuda_driver_present`).
"""

from __future__ import annotations

import contextlib
import ctypes
import importlib.util
import os
import sys
import tempfile
import threading
from dataclasses import dataclass

from .errors import BackendError

_default_backend: str | None = None
_lock = threading.Lock()
_warp_ready = False


@dataclass(frozen=True)
class Backend:
    """A resolved backend.

    Attributes
    ----------
    name : str
        Canonical name: ``"cpu"``, ``"warp-cpu"`` or ``"cuda:N"``.
    kind : str
        ``"cpu"`` for the NumPy/OpenCV implementations, ``"warp"`` for Warp kernels.
    device : str or None
        The Warp device alias (``"cpu"`` or ``"cuda:N"``) for Warp backends, else None.
    """

    name: str
    kind: str
    device: str | None = None

    @property
    def is_cuda(self) -> bool:
        return self.device is not None and self.device.startswith("cuda")


def init_warp():
    """Import and initialise Warp once (quietly); return the ``warp`` module.

    Warp's greeting is silenced, and so is the native "Could not find or load the NVIDIA CUDA
    driver" line when :func:`cuda_driver_present` already knows there is no driver (a CPU-only
    machine, where no GPU is expected). ``WARPVX_VERBOSE=1`` keeps Warp's own output.
    """
    global _warp_ready
    import warp as wp

    if not _warp_ready:
        with _lock:
            if not _warp_ready:
                quiet = os.environ.get("WARPVX_VERBOSE") is None
                if quiet:
                    # Warp >= 1.19 greets at LOG_INFO; keep library users' output clean.
                    wp.config.quiet = True
                    if hasattr(wp, "LOG_WARNING"):
                        wp.config.log_level = wp.LOG_WARNING
                filtered = quiet and not cuda_driver_present()  # no GPU expected
                with _stderr_without(_NO_DRIVER_LINE) if filtered else contextlib.nullcontext():
                    wp.init()
                _warp_ready = True
    return wp


# What Warp's native library prints (to fd 2, not through Python) when libcuda cannot be loaded.
_NO_DRIVER_LINE = b"Could not find or load the NVIDIA CUDA driver"
_driver_present: bool | None = None


def cuda_driver_present() -> bool:
    """True when the NVIDIA CUDA driver library loads, probed as Warp does (``libcuda.so`` or
    ``libcuda.so.1`` on Linux, ``nvcuda.dll`` on Windows) without importing Warp.

    A few milliseconds once, then cached. False means no CUDA device can exist; True only that
    one may (Warp counts the devices).
    """
    global _driver_present
    if _driver_present is None:
        names = {"win32": ("nvcuda.dll",), "linux": ("libcuda.so", "libcuda.so.1")}
        _driver_present = any(_loads(n) for n in names.get(sys.platform, ()))
    return _driver_present


def _loads(library: str) -> bool:
    try:
        ctypes.CDLL(library)
    except OSError:
        return False
    return True


@contextlib.contextmanager
def _stderr_without(line: bytes):
    """Send file descriptor 2 to a temporary file for the block, then replay what was written
    there except the lines containing ``line`` (native code writes to fd 2, bypassing
    ``sys.stderr``; a file, unlike a pipe, never blocks a writer)."""
    try:
        saved = os.dup(2)
    except OSError:  # no stderr at all (e.g. pythonw): nothing to filter
        yield
        return
    sys.stderr.flush()
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            yield
        finally:
            sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            kept = [ln for ln in tmp.read().splitlines(keepends=True) if line not in ln]
            if kept:
                os.write(2, b"".join(kept))


def cuda_available() -> bool:
    """True when Warp sees at least one CUDA device (Warp is not imported without a driver)."""
    if not cuda_driver_present():
        return False
    try:
        wp = init_warp()
    except ImportError:  # warp-lang is a dependency, but a CPU-only user may lack it
        return False
    return wp.get_cuda_device_count() > 0


def available_backends() -> list[str]:
    """Backends that can run on this machine, e.g. ``["cpu", "warp-cpu", "cuda:0"]``."""
    if importlib.util.find_spec("warp") is None:
        return ["cpu"]
    if not cuda_available():
        return ["cpu", "warp-cpu"]
    return ["cpu", "warp-cpu"] + [f"cuda:{i}" for i in range(init_warp().get_cuda_device_count())]


def set_backend(backend: str | None) -> None:
    """Set the process-wide default backend (``None`` restores automatic choice)."""
    global _default_backend
    if backend is not None:
        resolve_backend(backend)  # validate now, not at the first call
    _default_backend = backend


def get_backend() -> Backend:
    """The backend that ``backend=None`` resolves to now."""
    return resolve_backend(None)


_resolved: dict = {}


def resolve_backend(backend=None, *, like=None) -> Backend:
    """Turn a backend name (or None) into a :class:`Backend`.

    ``like`` is an input array: with ``backend=None`` and no process default, a ``wp.array``
    input selects the Warp backend on its own device, so device data stays where it is.
    Resolutions are cached: this runs on every primitive call.
    """
    if isinstance(backend, Backend):
        return backend
    if backend is None:
        if _default_backend is not None:
            backend = _default_backend
        elif like is not None and _is_warp_array(like):
            device = like.device
            backend = "warp-cpu" if device.is_cpu else device.alias
        else:
            backend = "auto"
    hit = _resolved.get(backend) if isinstance(backend, str) else None
    if hit is not None:
        return hit
    if backend == "auto":
        resolved = _resolve("cuda" if cuda_available() else "cpu")
    else:
        resolved = _resolve(backend)
    _resolved[backend] = resolved
    return resolved


def _resolve(backend) -> Backend:
    if not isinstance(backend, str):
        raise BackendError(
            f"backend: expected one of 'cpu', 'warp-cpu', 'cuda', 'cuda:N' or None, got {backend!r}"
        )
    name = backend.strip().lower()
    if name == "cpu":
        return Backend("cpu", "cpu", None)
    if name == "warp-cpu":
        init_warp()
        return Backend("warp-cpu", "warp", "cpu")
    if name == "cuda" or name.startswith("cuda:"):
        wp = init_warp()
        count = wp.get_cuda_device_count()
        if count == 0:
            raise BackendError(f"backend: {backend!r} requested but no CUDA device is available")
        if name == "cuda":
            device = str(wp.get_cuda_device())
        else:
            try:
                ordinal = int(name.split(":", 1)[1])
            except ValueError:
                raise BackendError(f"backend: bad CUDA device in {backend!r}") from None
            if not 0 <= ordinal < count:
                raise BackendError(f"backend: {backend!r} but only {count} CUDA device(s) exist")
            device = f"cuda:{ordinal}"
        return Backend(device, "warp", device)
    raise BackendError(
        f"backend: expected one of 'cpu', 'warp-cpu', 'cuda', 'cuda:N' or None, got {backend!r}"
    )


# type -> whether its instances are Warp arrays; filled as types are met (this runs on every
# call, several times, so the module-name test is paid once per type).
_warp_array_types: dict = {}


def _is_warp_array(x) -> bool:
    t = type(x)
    known = _warp_array_types.get(t)
    if known is not None:
        return known
    is_array = t.__module__.startswith("warp") and hasattr(x, "device") and hasattr(x, "ptr")
    if is_array or not t.__module__.startswith("warp"):
        # Warp types other than arrays (vectors, structs) are not cached: the attribute test
        # is per instance there.
        _warp_array_types[t] = is_array
    return is_array
