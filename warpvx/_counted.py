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
    rows : wp.array or numpy.ndarray
        [capacity, ...] (e.g. float32 [capacity, 2] points).
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
        return int(self.rows.shape[0])

    @property
    def device(self):
        return self.rows.device

    def __warpvx_flatten__(self):
        return (self.rows, self.count), None

    @classmethod
    def __warpvx_unflatten__(cls, aux, arrays):
        rows, count = arrays
        if isinstance(rows, np.ndarray) and isinstance(count, np.ndarray):
            return _trim(rows, count)
        return cls(rows, count)

    def to(self, where):
        """``"host"``: the NumPy value ``rows[:count]``; a Warp device: a Counted there."""
        if where == "host":
            return _trim(_host(self.rows), _host(self.count))
        if str(self.rows.device) == str(where):
            return self
        return Counted(self.rows.to(where), self.count.to(where))

    def __repr__(self):
        return f"Counted(capacity={self.capacity}, rows={type(self.rows).__name__})"


def _host(a) -> np.ndarray:
    return a if isinstance(a, np.ndarray) else a.numpy()


def _trim(rows: np.ndarray, count: np.ndarray) -> np.ndarray:
    return rows[: max(0, min(int(count.reshape(-1)[0]), rows.shape[0]))]


def is_counted(value) -> bool:
    return type(value) is Counted


def check_counted(value, name: str, shape: tuple, dtypes) -> Counted:
    """Validate a device :class:`Counted`: ``rows`` of ``shape`` (None: any size) and
    ``dtypes``, an int32 [1] ``count`` on the same device; raises warpvx errors naming
    ``name``."""
    from .arrays import is_warp_array
    from .check import check_array
    from .errors import WarpvxTypeError, WarpvxValueError

    if not is_counted(value):
        raise WarpvxTypeError(f"{name}: expected a Counted (rows and a device count), got "
                              f"{type(value).__name__}")
    if not (is_warp_array(value.rows) and is_warp_array(value.count)):
        raise WarpvxTypeError(f"{name}: expected Warp arrays for rows and count")
    check_array(value.rows, f"{name}.rows", shape=shape, dtypes=dtypes)
    check_array(value.count, f"{name}.count", shape=(1,), dtypes=(np.int32,))
    if value.count.device != value.rows.device:
        raise WarpvxValueError(f"{name}: count on {value.count.device}, rows on "
                               f"{value.rows.device}")
    return value


__all__ = ["Counted", "check_counted", "is_counted"]
