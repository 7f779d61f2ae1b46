"""The warpvx error hierarchy.

Every error warpvx raises on bad input derives from :class:`WarpvxError` and from the builtin
that fits (``ValueError`` or ``TypeError``), so ``except ValueError`` keeps working for callers
who do not know warpvx. Messages name the argument and say what was expected against what came.
"""

from __future__ import annotations


class WarpvxError(Exception):
    """Base of every warpvx error."""


class WarpvxValueError(WarpvxError, ValueError):
    """An argument has the right type but a bad value (shape, range, code, ...)."""


class WarpvxTypeError(WarpvxError, TypeError):
    """An argument has the wrong type or dtype."""


class ShapeError(WarpvxValueError):
    """An array has the wrong number of dimensions, channels or size."""


class DTypeError(WarpvxTypeError):
    """An array has the wrong element type."""


class BackendError(WarpvxValueError):
    """An unknown backend, or one that is not available on this machine."""


class UnsupportedError(WarpvxValueError):
    """A code, flag or mode that warpvx does not implement (yet)."""


class GraphError(WarpvxValueError):
    """A graph fails verification: type or shape mismatch, missing input, cycle."""


class ScheduleError(WarpvxValueError):
    """A task graph cannot be scheduled: cycle, bad costs, a task no processor can run."""


class NodeExecutionError(WarpvxError, RuntimeError):
    """A graph node raised while running; the original exception is ``__cause__``."""


class CaptureAllocationError(WarpvxError, RuntimeError):
    """A call would allocate state it keeps (a primitive's scratch) inside a CUDA graph
    capture, where the memory would belong to the graph: run the call once uncaptured, on the
    same stream and thread, before capturing it."""


def caused_by(exc: BaseException | None, kind: type) -> bool:
    """``exc`` or an exception in its chain (``__cause__``/``__context__``) is a ``kind``."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, kind):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


__all__ = [
    "WarpvxError",
    "WarpvxValueError",
    "WarpvxTypeError",
    "ShapeError",
    "DTypeError",
    "BackendError",
    "UnsupportedError",
    "GraphError",
    "ScheduleError",
    "NodeExecutionError",
    "CaptureAllocationError",
]
