"""Counted rows: a data-dependent result in a fixed-capacity buffer with its count on the device.

Corners, tracked points: how many there are is known only once the kernels have run. A
captured GPU segment (:mod:`warpvx.runtime.capture`) must neither read that count back to the
host nor allocate a result of its size, so inside a graph such a primitive writes a
:class:`Counted` instead: ``rows`` of a fixed capacity and ``count``, an int32 [1] on the same
device; the value is ``rows[:count[0]]``. Rows past the count hold nothing meaningful.

A Counted behaves as its value wherever it reaches the host: moved there (a CPU node's input,
a graph output), by :func:`warpvx.arrays.like_input` (``.to("host")``) or by the runtime's
transfers (the flatten protocol), it becomes the plain NumPy array ``rows[:count]``, exactly
what the public function returns.

A graph node's Counted outputs live in one allocation, a :class:`Block` (the count and every
row array, views of it): moving them costs one copy, not one per array plus a read of the
count first (each a host sync on CUDA). Neutral module: NumPy only, Warp only when a block is
laid out.
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
    block : Block, optional
        The one allocation ``rows`` and ``count`` are views of (a graph node's outputs).
    """

    __slots__ = ("rows", "count", "block")

    def __init__(self, rows, count, block=None):
        self.rows = rows
        self.count = count
        self.block = block

    @property
    def capacity(self) -> int:
        return int(row_arrays(self.rows)[0].shape[0])

    @property
    def device(self):
        return self.count.device

    def __warpvx_flatten__(self):
        # The rows' arrays themselves (not a flattenable rows value): rebuilt only once cut
        # to the count, so what lies past it is never validated as data.
        arrays, aux = _flat(self.rows)
        return tuple(arrays) + (self.count,), aux

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


class Block:
    """Where a Counted lives in a byte allocation shared with its node's other Counted
    outputs: their count (int32, at offset 0), then every rows array at a 16-byte aligned
    offset. :meth:`layout` makes them; the Counteds' arrays are views of :attr:`array`.

    Attributes
    ----------
    array : wp.array
        uint8 [nbytes], the allocation, on the values' device.
    part : tuple
        This Counted's rows arrays as (byte offset, bytes, shape, NumPy dtype), in
        :func:`row_arrays` order.
    aux : object
        Its flatten aux (:meth:`Counted.__warpvx_flatten__`), to rebuild its value.
    """

    __slots__ = ("array", "part", "aux")

    ALIGN = 16

    def __init__(self, array, part, aux):
        self.array = array
        self.part = part
        self.aux = aux

    @staticmethod
    def layout(samples, capacity: int, device) -> list:
        """Counteds of ``capacity`` rows shaped as ``samples`` (rows values: an array or a
        flattenable, whose arrays give each row's shape and dtype) sharing one count, all
        views of one zeroed allocation (zeroed rows stay finite for the kernels that read
        past the count)."""
        from .backend import init_warp

        wp = init_warp()
        layouts, at = [], Block.ALIGN
        for s in samples:
            arrays, aux = _flat(s)
            part = []
            for a in arrays:
                shape = (capacity,) + tuple(a.shape[1:])
                nbytes = int(np.prod(shape)) * a.dtype.itemsize
                part.append((at, nbytes, shape, np.dtype(a.dtype)))
                at += -(-nbytes // Block.ALIGN) * Block.ALIGN
            layouts.append((tuple(part), aux))
        array = wp.zeros(at, dtype=wp.uint8, device=device)
        return [Block(array, part, aux).view() for part, aux in layouts]

    def view(self, array=None) -> "Counted":
        """This Counted as Warp views of ``array`` (default :attr:`array`; another
        allocation of the same size: a copy of it)."""
        from .backend import init_warp

        wp = init_warp()
        base = self.array if array is None else array

        def view(offset, _nbytes, shape, dtype):
            v = wp.array(ptr=base.ptr + offset, shape=shape, dtype=wp.dtype_from_numpy(dtype),
                         device=base.device)
            v._ref = base  # the views keep the allocation alive
            return v

        arrays = tuple(view(*p) for p in self.part)
        rows = arrays[0] if self.aux is None else \
            self.aux[0].__warpvx_unflatten__(self.aux[1], arrays)
        block = self if array is None else Block(array, self.part, self.aux)
        return Counted(rows, view(0, 4, (1,), np.dtype(np.int32)), block)

    def host_value(self, raw: np.ndarray):
        """The host value (``rows[:count]``, NumPy) of this Counted from ``raw``, a host
        copy of :attr:`array`."""
        leaves = tuple(raw[o:o + n].view(dt).reshape(sh) for o, n, sh, dt in self.part)
        return Counted.__warpvx_unflatten__(self.aux, leaves + (raw[:4].view(np.int32),))


def _flat(rows):
    """(arrays, aux) of a rows value, aux as :meth:`Counted.__warpvx_flatten__` gives it:
    None for a plain array, else (its type, its own aux)."""
    flatten = getattr(rows, "__warpvx_flatten__", None)
    if flatten is None:
        return (rows,), None
    arrays, aux = flatten()
    return arrays, (type(rows), aux)


#: A :class:`Block` of this many bytes or fewer is downloaded in one copy; a larger one (a
#: capacity far above the usual count: FAST's keypoints) reads its count, then its rows.
ONE_COPY_MAX_BYTES = 1 << 16


def download(value: Counted, fetch):
    """The host value of device Counted ``value`` (``fetch(a)``: a host copy of Warp array
    ``a``, after the producer): one copy of its small :class:`Block` (up to
    :data:`ONE_COPY_MAX_BYTES`); else its count, then the rows it counts (device views, for
    the caller to copy)."""
    if value.block is not None and value.block.array.shape[0] <= ONE_COPY_MAX_BYTES:
        return value.block.host_value(fetch(value.block.array))
    return trimmed(value, int(fetch(value.count)[0]))


def _host(a) -> np.ndarray:
    return a if isinstance(a, np.ndarray) else a.numpy()


def row_arrays(rows) -> tuple:
    """The arrays of ``rows``: itself, or its flattened arrays."""
    return _flat(rows)[0]


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


__all__ = ["Block", "Counted", "check_counted", "check_counted_keypoints", "download", "is_counted", "map_counted",
           "refuse_uncounted", "row_arrays", "trimmed"]
