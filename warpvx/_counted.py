"""Counted rows: a data-dependent result in a fixed-capacity buffer with its count on the device.

Corners, tracked points: how many there are is known only once the kernels have run. A
captured GPU segment (:mod:`warpvx.runtime.capture`) must neither read that count back to the
host nor allocate a result of its size, so inside a graph such a primitive writes a
:class:`Counted` instead: ``rows`` of a fixed capacity and ``count``, an int32 [1] on the same
device; the value is ``rows[:count[0]]``. Rows past the count hold nothing meaningful.

A Counted behaves as its value wherever it reaches the host: moved there (a CPU node's input,
a graph output), by :func:`warpvx.arrays.like_input` (``.to("host")``) or by the runtime's
transfers (the flatten protocol), it becomes the plain NumPy array ``rows[:count]``, exactly
what the public function returns. Neutral module: NumPy only, no Warp import.
"""

from __future__ import annotations

import numpy as np


class Counted:
    """``rows[:count[0]]`` of a fixed-capacity buffer.

    Parameters
    ----------
    rows : wp.array, numpy.ndarray or Keypoints
        [capacity, ...] (e.g. float32 [capacity, 2] points), or a flattenable value (the
        runtime's flatten protocol, e.g. :class:`~warpvx.Keypoints`) whose arrays all have
        ``capacity`` rows.
    count : wp.array or numpy.ndarray
        int32 [1] on the same device as ``rows``: the number of valid rows, at most the
        capacity (writers clamp it; a reader clamps again).
    """

    __slots__ = ("rows", "count")

    def __init__(self, rows, count):
        self.rows = rows
        self.count = count

    @property
    def capacity(self) -> int:
        return int(row_arrays(self.rows)[0].shape[0])

    @property
    def device(self):
        return self.count.device

    def __warpvx_flatten__(self):
        # The rows' arrays themselves (not a flattenable rows value): rebuilt only once cut
        # to the count, so what lies past it is never validated as data.
        flatten = getattr(self.rows, "__warpvx_flatten__", None)
        if flatten is None:
            return (self.rows, self.count), None
        arrays, aux = flatten()
        return tuple(arrays) + (self.count,), (type(self.rows), aux)

    @classmethod
    def __warpvx_unflatten__(cls, aux, arrays):
        *leaves, count = arrays
        host = isinstance(count, np.ndarray) and all(isinstance(a, np.ndarray) for a in leaves)
        if host:  # the value: the counted rows only
            n = _count(count, leaves[0])
            leaves = [a[:n] for a in leaves]
        rows = leaves[0] if aux is None else aux[0].__warpvx_unflatten__(aux[1], tuple(leaves))
        return rows if host else cls(rows, count)

    def to(self, where):
        """``"host"``: the NumPy value ``rows[:count]``; a Warp device: a Counted there."""
        if where == "host":
            arrays, aux = self.__warpvx_flatten__()
            return Counted.__warpvx_unflatten__(aux, tuple(_host(a) for a in arrays))
        if str(self.count.device) == str(where):
            return self
        return Counted(_map(lambda a: a.to(where), self.rows), self.count.to(where))

    def __repr__(self):
        return f"Counted(capacity={self.capacity}, rows={type(self.rows).__name__})"


def _host(a) -> np.ndarray:
    return a if isinstance(a, np.ndarray) else a.numpy()


def row_arrays(rows) -> tuple:
    """The arrays of ``rows``: itself, or its flattened arrays."""
    flatten = getattr(rows, "__warpvx_flatten__", None)
    return (rows,) if flatten is None else flatten()[0]


def _map(fn, rows):
    """``fn`` applied to ``rows``, or to each of its flattened arrays."""
    flatten = getattr(rows, "__warpvx_flatten__", None)
    if flatten is None:
        return fn(rows)
    arrays, aux = flatten()
    return type(rows).__warpvx_unflatten__(aux, tuple(fn(a) for a in arrays))


def _count(count: np.ndarray, first) -> int:
    """A host count clamped to the rows of array ``first``."""
    return max(0, min(int(count.reshape(-1)[0]), int(first.shape[0])))


def map_counted(fn, value):
    """``value`` with ``fn`` applied to each :class:`Counted` in it (inside tuples, lists and
    dicts); anything else is kept."""
    if type(value) is Counted:
        return fn(value)
    if isinstance(value, (tuple, list)):
        return type(value)(map_counted(fn, v) for v in value)
    if isinstance(value, dict):
        return {k: map_counted(fn, v) for k, v in value.items()}
    return value


def trimmed(value: Counted, n: int):
    """The value of device ``value`` as views of its first ``n`` rows (``n`` read from its
    count by the caller, who has synchronised with its producer)."""
    return _map(lambda a: a[:n], value.rows)


def is_counted(value) -> bool:
    return type(value) is Counted


def refuse_uncounted(out, primitive: str) -> None:
    """A data-dependent primitive's kernels take ``out=`` only as a Counted: anything else is
    refused (UnsupportedError) rather than ignored."""
    if out is not None and not is_counted(out):
        from .errors import UnsupportedError

        raise UnsupportedError(f"out: {primitive} returns a data-dependent number of rows; it "
                               f"takes only a Counted out= (fixed rows and a device count)")


def check_counted(value, name: str, shape: tuple, dtypes) -> Counted:
    """Validate a device :class:`Counted`: ``rows`` of ``shape`` (None: any size) and
    ``dtypes``, an int32 [1] ``count`` on the same device; raises warpvx errors naming
    ``name``."""
    from .check import check_array

    _check_count(value, name, (value.rows,) if is_counted(value) else ())
    check_array(value.rows, f"{name}.rows", shape=shape, dtypes=dtypes)
    return value


def check_counted_keypoints(value, name: str, capacity: int) -> Counted:
    """Validate a device :class:`Counted` of :class:`~warpvx.Keypoints` with ``capacity``
    rows (float32 x, y, response, size, angle; int32 octave)."""
    from .check import check_array
    from .errors import WarpvxTypeError
    from .keypoints import FIELDS, Keypoints

    if is_counted(value) and not isinstance(value.rows, Keypoints):
        raise WarpvxTypeError(f"{name}.rows: expected Keypoints, got {type(value.rows).__name__}")
    _check_count(value, name, row_arrays(value.rows) if is_counted(value) else ())
    for field in FIELDS:
        check_array(getattr(value.rows, field), f"{name}.rows.{field}", shape=(capacity,),
                    dtypes=(np.int32,) if field == "octave" else (np.float32,))
    return value


def _check_count(value, name: str, arrays) -> None:
    """A Counted whose count is an int32 [1] Warp array on the device of ``arrays``."""
    from .arrays import is_warp_array
    from .check import check_array
    from .errors import WarpvxTypeError, WarpvxValueError

    if not is_counted(value):
        raise WarpvxTypeError(f"{name}: expected a Counted (rows and a device count), got "
                              f"{type(value).__name__}")
    if not (is_warp_array(value.count) and all(is_warp_array(a) for a in arrays)):
        raise WarpvxTypeError(f"{name}: expected Warp arrays for rows and count")
    check_array(value.count, f"{name}.count", shape=(1,), dtypes=(np.int32,))
    if any(a.device != value.count.device for a in arrays):
        raise WarpvxValueError(f"{name}: rows and count on different devices")


__all__ = ["Counted", "check_counted", "check_counted_keypoints", "is_counted", "map_counted",
           "refuse_uncounted", "row_arrays", "trimmed"]
