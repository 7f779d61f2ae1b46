"""Host <-> device copies of whole values (arrays, tuples, lists, dicts, flattenable types).

A value the runtime moves is a tree: NumPy or Warp arrays as leaves, inside tuples, lists,
dicts and any type implementing the flatten protocol (:func:`tree_map`). :class:`Transfers`
copies every leaf of a tree between host memory and the GPU role's device, through
:mod:`.native_copy`.
"""

from __future__ import annotations

import numpy as np

from .._counted import download, map_counted
from .native_copy import (is_warp_array, numpy_dtype, record_event, synchronize_event, to_device,
                          to_host, to_host_async, wait_event, warp)


def tree_map(fn, obj):
    """Apply ``fn`` to every array leaf (NumPy or Warp) of ``obj``; other leaves are kept.

    Containers: tuples, lists, dicts, and any type with the flatten protocol: a method
    ``obj.__warpvx_flatten__() -> (arrays, aux)`` (``arrays`` a tuple of leaves, ``aux``
    anything else the type needs) and a classmethod ``cls.__warpvx_unflatten__(aux, arrays)``
    that rebuilds it (:class:`~warpvx.Keypoints` implements both).
    """
    if isinstance(obj, np.ndarray) or is_warp_array(obj):
        return fn(obj)
    if isinstance(obj, tuple):
        return tuple(tree_map(fn, o) for o in obj)
    if isinstance(obj, list):
        return [tree_map(fn, o) for o in obj]
    if isinstance(obj, dict):
        return {k: tree_map(fn, v) for k, v in obj.items()}
    flatten = getattr(obj, "__warpvx_flatten__", None)
    if flatten is not None:
        arrays, aux = flatten()
        return type(obj).__warpvx_unflatten__(aux, tuple(tree_map(fn, a) for a in arrays))
    return obj


class _Staging:
    """A pinned host buffer of one shape and dtype and the event of its last copy; for
    downloads also whether its reader is done with it (``free``)."""

    __slots__ = ("buffer", "view", "event", "free")

    def __init__(self, buffer, event):
        self.buffer = buffer
        self.view = buffer.numpy()  # aliases the pinned memory
        self.event = event
        self.free = True


class Transfers:
    """Host <-> device copies for one thread.

    On CUDA each thread that downloads owns a ``wp.Stream``: a download makes that stream wait
    for the producer's event, copies, and synchronises only that stream, so it never touches
    the device's current stream (which belongs to the GPU thread) and never waits for
    unrelated kernels. Uploads run on the device's current stream (the GPU thread's), so
    the device buffer is filled in that stream's order. An upload of
    :attr:`PINNED_MIN_BYTES` or more goes through a pinned staging buffer (one per shape and
    dtype, a few in rotation, reused once their copy has completed): the host copies into it
    and the device copy is asynchronous. From pageable memory, a large copy would wait for
    every kernel queued before it on the stream, stalling the GPU thread. A smaller upload
    copies from pageable memory: the driver stages it at once (measured faster than pinned
    staging for small copies: benchmarks/results/graph/overhead.md).

    Uploads take the device buffer from ``into`` when given (the executor's per-edge pools:
    allocating a ``wp.array`` costs ~10 us of Python, more than a small copy); downloads make
    fresh NumPy arrays.

    Parameters
    ----------
    device : str or None
        Warp device of the GPU role (``"cuda:N"``, ``"cpu"``), or None (no GPU role: only
        host values, which pass through).
    """

    #: Uploads from this size (bytes) on use pinned staging buffers.
    PINNED_MIN_BYTES = 1 << 16
    #: Staging buffers per shape and dtype before an upload waits for the oldest one.
    STAGING_DEPTH = 4

    def __init__(self, device: str | None):
        self.device = device
        self.cuda = bool(device) and device.startswith("cuda")
        self._stream = None
        self._dev = None
        self._staging: dict = {}
        self._unstaging: dict = {}  # (shape, dtype) -> pinned download buffers
        self._wp_dtypes: dict = {}  # NumPy dtype -> Warp dtype, looked up once
        self.moved = 0  # bytes copied so far, both ways

    @property
    def stream(self):
        """This thread's copy stream (CUDA; None otherwise)."""
        if self._stream is None and self.cuda:
            self._stream = warp().Stream(self.device)
        return self._stream

    def download(self, value, event=None):
        """``value`` with every device array copied to host NumPy (fresh arrays, never views
        of device-role memory: a pooled buffer may be overwritten by a later frame).

        ``event``: a CUDA event after the producer's kernels; the copy waits for it. A device
        :class:`~warpvx._counted.Counted` is copied in one piece where it has a block (a
        graph node's), else its count is read first and only the rows it counts are copied.
        """
        if is_warp_array(value):  # the usual value: no tree to walk
            return self._download_array(value, event)
        value = map_counted(lambda c: download(c, lambda a: self._download_array(a, event))
                            if is_warp_array(c.count) else c, value)
        return tree_map(lambda a: self._download_array(a, event) if is_warp_array(a) else a,
                        value)

    def _download_array(self, a, event):
        """Device array ``a`` -> a fresh NumPy array (see :meth:`download`)."""
        if a.device.is_cuda and not a.is_contiguous:
            # A strided view needs a gather kernel on the device's current stream (the GPU
            # thread's); wait for the producer, then let Warp copy synchronously.
            if event is not None:
                synchronize_event(event)
            out = a.numpy()
        else:
            s = self.stream if a.device.is_cuda else None
            if event is not None and s is not None:
                wait_event(s, event)
            # Warp's CPU device shares host memory: copied too, so the value outlives
            # the buffer.
            out = to_host(a, s)
        self.moved += out.nbytes
        return out

    def stage_download(self, a, event=None):
        """Start downloading ``a``, a contiguous CUDA ``wp.array`` of a scalar dtype, into a
        pinned host buffer on this thread's copy stream, after ``event`` (the producer's):
        the reader then waits for one event, the copy's, and copies out of the buffer
        (:meth:`unstage`), instead of waiting for the producer, then copying and waiting
        again. Returns the staging buffer, or None (another kind of value, or every buffer of
        that shape still in use: download as usual). The caller sets its ``free`` once no
        reader can take it any more."""
        if not (self.cuda and is_warp_array(a) and a.device.is_cuda and a.is_contiguous
                and numpy_dtype(a.dtype) is not None):
            return None
        wp = warp()
        ring = self._unstaging.setdefault((a.shape, a.dtype), [])
        stage = next((s for s in ring if s.free and s.event.is_complete), None)
        if stage is None:
            if len(ring) >= self.STAGING_DEPTH * 2:  # readers hold them all
                return None
            stage = _Staging(wp.empty(a.shape, dtype=a.dtype, device="cpu", pinned=True),
                             wp.Event(self.device))
            ring.append(stage)
        stream = self.stream
        if event is not None:
            wait_event(stream, event)
        to_host_async(stage.buffer, a, stream)
        record_event(stream, stage.event)
        stage.free = False
        return stage

    def unstage(self, stage, *, ready: bool = False):
        """A fresh host array with what :meth:`stage_download` copied into ``stage`` (waiting
        for that copy unless ``ready``: the caller did)."""
        if not ready:
            synchronize_event(stage.event)
        out = stage.view.copy()
        self.moved += out.nbytes
        return out

    def upload(self, value, into=None):
        """``value`` with every host array copied to the device (on its current stream).

        ``into(shape, dtype)``, when given, returns the contiguous device buffer an array leaf
        is copied into (or None: a fresh one); the caller owns its reuse.
        """
        if type(value) is np.ndarray:  # the usual value: no tree to walk
            return self._upload_array(value, into)
        return tree_map(lambda a: self._upload_leaf(a, into), value)

    def _upload_leaf(self, a, into):
        """One leaf of :meth:`upload`'s value: a device array of another device goes through
        the host; non-arrays pass."""
        if is_warp_array(a):
            if a.device == self._device():
                return a
            a = a.numpy()
        if not isinstance(a, np.ndarray):
            return a
        return self._upload_array(a, into)

    def _device(self):
        dev = self._dev
        if dev is None:
            dev = self._dev = warp().get_device(self.device)
        return dev

    def _upload_array(self, a: np.ndarray, into):
        """Host array ``a`` -> a device array (see :meth:`upload`)."""
        dev = self._device()
        wp = warp()
        dtype = self._wp_dtypes.get(a.dtype)
        if dtype is None:
            dtype = self._wp_dtypes[a.dtype] = wp.dtype_from_numpy(a.dtype)
        self.moved += a.nbytes
        if dev.is_cpu:
            # Warp's CPU device shares host memory: alias, do not copy (host values are
            # never written after their producer finished).
            return wp.array(np.ascontiguousarray(a), dtype=dtype, device=dev, copy=False)
        dst = into(a.shape, dtype) if into is not None else None
        if dst is None:
            dst = wp.empty(a.shape, dtype=dtype, device=dev)
        if a.nbytes < self.PINNED_MIN_BYTES:
            to_device(dst, np.ascontiguousarray(a), dev.stream)
        else:
            self._upload_staged(wp, dev, a, dst)
        return dst

    def _upload_staged(self, wp, dev, a, dst):
        """A large host array -> ``dst`` through a pinned staging buffer (asynchronous)."""
        stream = dev.stream
        key = (a.shape, a.dtype.str)
        ring = self._staging.setdefault(key, [])
        stage = None
        for s in ring:
            if s.event is None or s.event.is_complete:
                stage = s
                break
        if stage is None:
            if len(ring) < self.STAGING_DEPTH:
                stage = _Staging(wp.empty(a.shape, dtype=dst.dtype, device="cpu", pinned=True), None)
                ring.append(stage)
            else:  # all in flight: wait for the oldest (the first recorded)
                stage = ring.pop(0)
                wp.synchronize_event(stage.event)
                ring.append(stage)
        np.copyto(stage.view, a)
        to_device(dst, stage.buffer, stream)
        if stage.event is None:
            stage.event = wp.Event(dev)
        stream.record_event(stage.event)


__all__ = ["Transfers", "tree_map"]
