"""Host buffers for downloads, handed to readers as NumPy arrays and recycled only once garbage.

A download into page-locked (pinned) host memory is a DMA the device runs asynchronously, at
full bus speed, on a stream of its own; into pageable memory the driver copies through its
own staging, synchronously and several times slower. :class:`HostPool` lends pinned buffers
as NumPy arrays whose base owns the buffer: the buffer goes back to the pool when that array
and every view of it are garbage (a caller may keep a frame's outputs as long as it likes),
never before.

:func:`pinned_array` is the other direction: a NumPy array in pinned memory for a caller to
write frames into (decode, grab, ``np.copyto``); a captured segment uploads it with one
asynchronous DMA instead of staging it through a pinned buffer of its own first.
"""

from __future__ import annotations

import math
import threading

import numpy as np

from ..check import check_int
from ..errors import WarpvxTypeError
from .native_copy import warp


class _Pinned:
    """Owns one pinned host ``wp.array`` (``buf``) while a NumPy array on it (its ``base``),
    or a view of it, lives, exposing its first ``shape``/``dtype`` bytes through the array
    interface; marks that array as pinned (:func:`is_pinned`)."""

    __slots__ = ("__array_interface__", "buf")

    def __init__(self, buf, shape: tuple, dtype: np.dtype):
        self.buf = buf
        self.__array_interface__ = {"data": (buf.ptr, False), "shape": shape,
                                    "typestr": dtype.str, "version": 3}


class _Lease(_Pinned):
    """A :class:`_Pinned` on one pool buffer that gives the buffer back when garbage
    (``__del__``: a tenth of ``weakref.finalize``'s cost)."""

    __slots__ = ("pool", "nbytes")

    def __init__(self, pool, buf, nbytes: int, shape: tuple, dtype: np.dtype):
        super().__init__(buf, shape, dtype)
        self.pool, self.nbytes = pool, nbytes

    def __del__(self):
        self.pool._give_back(self.buf, self.nbytes)


#: Requests up to this many bytes get a buffer of their exact size; larger ones one of a size
#: class (:func:`size_class`).
EXACT_MAX_BYTES = 4096


def size_class(nbytes: int) -> int:
    """The buffer size a request of ``nbytes`` gets: exact up to :data:`EXACT_MAX_BYTES`, else
    rounded up to one of 8 sizes per power of two (at most 12.5% more). Counted rows (a
    detector's keypoints) change size every frame: buffers of exact sizes would each be
    allocated once (a page-locked allocation costs far more than the copy) and pile up to
    the pool's cap, past which every download takes the slow path."""
    if nbytes <= EXACT_MAX_BYTES:
        return nbytes
    step = 1 << (nbytes.bit_length() - 4)
    return -(-nbytes // step) * step


class HostPool:
    """Host buffers of one executor for downloads: pinned where CUDA is (plain host memory on
    Warp's CPU device), at most ``cap`` bytes allocated at a time, free or lent.

    :meth:`take` lends a buffer as a NumPy array; when the array and all its views are
    garbage the buffer returns to the pool (reused for a download of the same size). The
    borrower lets its arrays go only once no copy into them may still run (a reader has
    waited for the copy; :meth:`~.slots.Slot.release_staged` waits for a download nobody
    read).

    Parameters
    ----------
    cap : int
        Bytes of buffers allocated at most (free and lent); beyond it :meth:`take` returns
        None and the caller downloads the usual way.
    pinned : bool
        Page-locked memory (needs CUDA).
    """

    def __init__(self, cap: int, pinned: bool):
        self.cap = int(cap)
        self.pinned = bool(pinned)
        self.allocated = 0  # bytes, free and lent
        self._free: dict[int, list] = {}  # nbytes -> free buffers (host wp.arrays of uint8)
        # Reentrant: a lease's __del__ (_give_back) may run inside a locked region, on a
        # garbage collection triggered by an allocation there.
        self._lock = threading.RLock()
        self._closed = False

    def take(self, shape: tuple, dtype) -> np.ndarray | None:
        """A NumPy array of ``shape`` and ``dtype`` (contents undefined) in a pool buffer, or
        None (the pool is full of lent buffers, or closed)."""
        if not isinstance(dtype, np.dtype):
            dtype = np.dtype(dtype)
        nbytes = math.prod(shape) * dtype.itemsize
        if nbytes > EXACT_MAX_BYTES:
            nbytes = size_class(nbytes)
        with self._lock:
            if self._closed:
                return None
            free = self._free.get(nbytes)
            buf = free.pop() if free else None
            if buf is None:
                if self.allocated + nbytes > self.cap:
                    return None
                self.allocated += nbytes
        if buf is None:
            buf = warp().empty(max(nbytes, 1), dtype=warp().uint8, device="cpu", pinned=self.pinned)
        return np.asarray(_Lease(self, buf, nbytes, tuple(shape), dtype))

    def _give_back(self, buf, nbytes: int):
        """A lent buffer is garbage: back to the pool, or freed once the pool is closed."""
        with self._lock:
            if not self._closed:
                self._free.setdefault(nbytes, []).append(buf)
                return
            self.allocated -= nbytes

    def lent(self) -> int:
        """Bytes lent now (allocated and not free)."""
        with self._lock:
            return self.allocated - sum(n * len(b) for n, b in self._free.items())

    def close(self):
        """Free the buffers not lent; lent ones are freed when their arrays are garbage."""
        with self._lock:
            self._closed = True
            for n, bufs in self._free.items():
                self.allocated -= n * len(bufs)
            self._free.clear()


def pinned_array(shape, dtype=np.uint8) -> np.ndarray:
    """A C-contiguous NumPy array of ``shape`` and ``dtype`` (zeros) in page-locked host
    memory, for input frames: write a frame into it (``np.copyto``, ``cv2.cvtColor(...,
    dst=)``, ``cv2.VideoCapture.read(image)``) and hand it to ``Graph.process``/``stream``
    as usual. A captured segment copies it to the device with one asynchronous DMA (a
    pageable array is first copied into a pinned staging buffer on the host, ~0.3 ms per
    2.76 MB frame). Being asynchronous, the DMA reads the array after the call returns: do
    not write the array again before its frame's results are in (keep ``depth + 1`` of them
    for a pipelined stream, round robin). Plain host memory where CUDA is not available.
    Freed when the array and its views are garbage.

    Raises
    ------
    WarpvxValueError
        ``shape`` is not a tuple of non-negative ints.
    WarpvxTypeError
        ``dtype`` is no NumPy dtype, or one of Python objects.
    """
    shape = tuple(check_int(n, "shape", min_value=0) for n in
                  (shape if isinstance(shape, (tuple, list)) else (shape,)))
    try:
        dtype = np.dtype(dtype)
    except TypeError as exc:
        raise WarpvxTypeError(f"dtype: {dtype!r} is not a NumPy dtype ({exc})") from None
    if dtype.hasobject:
        raise WarpvxTypeError(f"dtype: {dtype} holds Python objects; pinned frames hold numbers")
    wp = warp()
    buf = wp.zeros(max(math.prod(shape) * dtype.itemsize, 1), dtype=wp.uint8, device="cpu",
                   pinned=wp.is_cuda_available())
    return np.asarray(_Pinned(buf, shape, dtype))


def pinned_copy(a) -> np.ndarray:
    """A copy of NumPy array ``a`` in pinned memory (:func:`pinned_array`)."""
    a = np.asarray(a)
    out = pinned_array(a.shape, a.dtype)
    np.copyto(out, a)
    return out


def is_pinned(a) -> bool:
    """``a`` is a C-contiguous NumPy array in page-locked memory of :func:`pinned_array` (or a
    view of one)."""
    if not isinstance(a, np.ndarray) or not a.flags.c_contiguous:
        return False
    base = a.base
    while isinstance(base, np.ndarray):  # a view's base: the array it views
        base = base.base
    return type(base) is _Pinned and base.buf.pinned


__all__ = ["HostPool", "is_pinned", "pinned_array", "pinned_copy", "size_class"]
