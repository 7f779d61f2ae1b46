"""Backend selection: which implementation of a primitive runs, and where.

Names accepted everywhere a ``backend=`` argument is taken:

``"cpu"``        the NumPy/OpenCV implementation (``warpvx.kernels_cpu``).
``"warp-cpu"``   the Warp kernels on Warp's CPU device (what tests use without a GPU).
``"cuda"``       the Warp kernels on the current CUDA device; ``"cuda:N"`` on device N.
``None``         the process-wide default (:func:`set_backend`), else CUDA when a GPU is
                 present, else ``"cpu"``. A ``wp.array`` input with ``backend=None`` runs on
                 its own device.

Warp is initialised lazily, on the first Warp backend request, never at import time.
"""

from __future__ import annotations

import os
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
    """Import and initialise Warp once (quietly); return the ``warp`` module."""
    global _warp_ready
    import warp as wp

    if not _warp_ready:
        with _lock:
            if not _warp_ready:
                if os.environ.get("WARPVX_VERBOSE") is None:
                    # Warp >= 1.19 greets at LOG_INFO; keep library users' output clean.
                    wp.config.quiet = True
                    if hasattr(wp, "LOG_WARNING"):
                        wp.config.log_level = wp.LOG_WARNING
                wp.init()
                _warp_ready = True
    return wp


def cuda_available() -> bool:
    """True when Warp sees at least one CUDA device."""
    try:
        wp = init_warp()
    except ImportError:  # warp-lang is a dependency, but a CPU-only user may lack it
        return False
    return wp.get_cuda_device_count() > 0


def available_backends() -> list[str]:
    """Backends that can run on this machine, e.g. ``["cpu", "warp-cpu", "cuda:0"]``."""
    names = ["cpu"]
    try:
        wp = init_warp()
    except ImportError:
        return names
    names.append("warp-cpu")
    names += [f"cuda:{i}" for i in range(wp.get_cuda_device_count())]
    return names


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
