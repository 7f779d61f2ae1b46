"""Host <-> device copies of whole values (arrays, tuples, lists, dicts, flattenable types).

A value the runtime moves is a tree: NumPy or Warp arrays as leaves, inside tuples, lists,
dicts and any type implementing the flatten protocol (:func:`tree_map`). :class:`Transfers`
copies every leaf of a tree between host memory and the GPU role's device, through
:mod:`.native_copy`.
"""

from __future__ import annotations

import functools
import itertools
import math
from collections import deque

import numpy as np

from .._counted import ONE_COPY_MAX_BYTES, Block, Counted, download, map_counted
from .native_copy import (address, bytes_to_host_async, is_warp_array, numpy_dtype,
                          record_event, synchronize_event, synchronize_stream, to_device,
                          to_host, to_host_async, wait_event, warp)
from .pinned import HostPool


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


def host_value(value, fetch, counted):
    """The host value of device value ``value`` (a tree, see :func:`tree_map`) made from
    ``fetch(a)``, a host copy (NumPy) of each device array ``a`` in it, and ``counted(c)``,
    the host value of each :class:`~warpvx._counted.Counted` with a block (a graph node's);
    any other Counted is cut to its count on the host (its flatten protocol)."""
    if is_warp_array(value):
        return fetch(value)
    if _block_counted(value):  # a node's Counted output, the usual tree: no walk
        return counted(value)
    value = map_counted(lambda c: c if c.block is None or not is_warp_array(c.count)
                        else counted(c), value)
    return tree_map(lambda a: fetch(a) if is_warp_array(a) else a, value)


def _block_counted(value) -> bool:
    """``value`` is a device :class:`~warpvx._counted.Counted` with a block (a graph node's),
    which :func:`host_value` hands to its ``counted`` whole (what its tree walk would do)."""
    return type(value) is Counted and value.block is not None and is_warp_array(value.count)


def _large(c) -> bool:
    """Counted ``c``'s block is too large to copy whole (FAST's keypoints: rows for every
    pixel pair): its count is copied first, then the rows it counts."""
    return c.block.array.shape[0] > ONE_COPY_MAX_BYTES


class _RowHints:
    """How many rows to stage ahead of a large Counted's count (:meth:`Transfers.stage_download`):
    the last count read of a block of that layout, with a margin. A stream's detector finds
    about as many keypoints frame after frame, so a staged prefix of that many rows usually
    holds the whole value and the reader waits for no second copy; a count past it copies
    the rows it counts as before. Shared by every thread (the stager and the reader differ);
    a hint only, never a correctness matter."""

    #: Rows staged beyond the last count: 1/4 more, plus this many.
    MARGIN = 64
    #: Layouts remembered (a stream has a few; past this, forgotten all at once).
    MAX_LAYOUTS = 256

    def __init__(self):
        self._last: dict = {}

    def rows(self, block) -> int:
        """Rows to stage ahead for ``block`` (0: no count read yet), at most its capacity."""
        last = self._last.get(block.part)
        if last is None:
            return 0
        return min(block.part[0][2][0], last + (last >> 2) + self.MARGIN)

    def saw(self, block, n: int):
        if len(self._last) >= self.MAX_LAYOUTS and block.part not in self._last:
            self._last.clear()
        self._last[block.part] = n


ROW_HINTS = _RowHints()


def _prefix_layout(part: tuple, k: int) -> tuple:
    """Where the first ``k`` rows of each rows array of a :class:`~warpvx._counted.Block` part
    go in one host buffer (:meth:`Transfers._take_prefix`): ``(((block offset, buffer offset,
    bytes, shape, dtype) per rows array), buffer bytes)``, each array
    :data:`~warpvx._counted.Block.ALIGN`-aligned in the buffer."""
    layout, at = [], 0
    for offset, _, shape, dtype in part:
        rows = (k,) + tuple(shape[1:])
        n = math.prod(rows) * dtype.itemsize
        layout.append((offset, at, n, rows, dtype))
        at += -(-n // Block.ALIGN) * Block.ALIGN
    return tuple(layout), at


class _UploadStage:
    """A pinned host buffer of one shape and dtype an upload goes through, and the event of
    its last copy (None: never used)."""

    __slots__ = ("buffer", "view", "event")

    def __init__(self, buffer):
        self.buffer = buffer
        self.view = buffer.numpy()  # aliases the pinned memory
        self.event = None


class _Unstageable(Exception):
    """A leaf :meth:`Transfers.stage_download` cannot copy asynchronously, or no pool room."""


class _Sharers:
    """How many downloads share one event (:meth:`Transfers.stage_downloads`); the last to
    close recycles it. Counted with ``itertools.count`` (atomic: readers close on their own
    threads)."""

    __slots__ = ("n", "closed")

    def __init__(self, n: int):
        self.n = n
        self.closed = itertools.count(1)

    def last(self) -> bool:
        return next(self.closed) == self.n


class _Staged:
    """A download under way (:meth:`Transfers.stage_download`): the device value, the host
    arrays its device arrays are being copied into (id of the device array -> (it, its host
    copy); of a large Counted block its count and a prefix of its rows so far), the event
    after the copies (None on Warp's CPU device: done, or once closed; shared by a batch's
    downloads: ``sharers``) and their bytes."""

    __slots__ = ("value", "copies", "prefix", "event", "nbytes", "_events", "_sharers")

    def __init__(self, value, copies: dict, prefix: dict, event, nbytes: int, events: deque,
                 sharers: _Sharers):
        self.value, self.copies, self.event, self.nbytes = value, copies, event, nbytes
        # id of a large Counted's count -> the host buffers of its rows' first rows
        # (:class:`_RowHints`), one per rows array, being copied with it.
        self.prefix = prefix
        self._events = events  # where its event goes back to
        self._sharers = sharers

    def close(self):
        """Read or dropped, its copy waited for: its event may be recorded again once every
        download sharing it is closed too."""
        if self.event is not None:
            if self._sharers.last():
                self._events.append(self.event)
            self.event = None

    def host(self, io: "Transfers"):
        """The host value, its arrays views of the pool's buffers (call after the copy; the
        rows of a large Counted block are copied now, on ``io``'s stream: the reader's)."""
        copies, value = self.copies, self.value
        if is_warp_array(value):  # the usual values: no tree to walk
            return copies[id(value)][1]
        if _block_counted(value):
            return self._counted(io, value)
        return host_value(value, lambda a: copies[id(a)][1], functools.partial(self._counted, io))

    def _counted(self, io: "Transfers", c):
        """The host value of Counted ``c`` (with a block) from its copies (:meth:`host`)."""
        copies = self.copies
        if _large(c):
            return io.counted_rows(c, copies[id(c.count)][1], self.prefix.get(id(c.count)))
        return c.block.host_value(copies[id(c.block.array)][1])


class Transfers:
    """Host <-> device copies for one thread.

    On CUDA each thread that downloads owns a ``wp.Stream``: a download makes that stream wait
    for the producer's event, copies, and synchronises only that stream, so it never touches
    the device's current stream (which belongs to the GPU thread) and never waits for
    unrelated kernels. A download can also be started as soon as its producer is enqueued
    (:meth:`stage_download`): queued on that copy stream into pinned buffers of a
    :class:`~.pinned.HostPool`, which the reader gets as NumPy arrays without a host copy.
    Uploads run on the device's current stream (the GPU thread's), so
    the device buffer is filled in that stream's order. An upload of
    :attr:`PINNED_MIN_BYTES` or more goes through a pinned staging buffer (one per shape and
    dtype, a few in rotation, reused once their copy has completed): the host copies into it
    and the device copy is asynchronous. From pageable memory, a large copy would wait for
    every kernel queued before it on the stream, stalling the GPU thread. A smaller upload
    copies from pageable memory: the driver stages it at once (measured faster than pinned
    staging for small copies: benchmarks/results/graph/overhead.md).

    Uploads take the device buffer from ``into`` when given (the executor's per-edge pools:
    allocating a ``wp.array`` costs ~10 us of Python, more than a small copy); downloads make
    fresh NumPy arrays, or views of the pool's buffers (staged).

    Parameters
    ----------
    device : str or None
        Warp device of the GPU role (``"cuda:N"``, ``"cpu"``), or None (no GPU role: only
        host values, which pass through).
    pool : HostPool, optional
        Host buffers for :meth:`stage_download` (None: downloads are never staged).
    """

    #: Uploads from this size (bytes) on use pinned staging buffers.
    PINNED_MIN_BYTES = 1 << 16
    #: Staging buffers per shape and dtype before an upload waits for the oldest one.
    STAGING_DEPTH = 4
    #: Staged downloads below this size (bytes) may go on the producer's stream
    #: (:meth:`stage_download`'s ``after``): the copy delays the producer's next kernels by
    #: about a microsecond, a cross-stream wait would delay the reader by more.
    SAME_STREAM_MAX_BYTES = 1 << 12
    #: A staged batch's buffers up to this size (bytes) share one pool lease
    #: (:meth:`stage_downloads`); larger ones get their own, so a caller keeping one small
    #: output of a frame does not keep a large one's buffer from the pool.
    BATCH_LEASE_MAX_BYTES = 1 << 16

    def __init__(self, device: str | None, pool: HostPool | None = None):
        self.device = device
        self.cuda = bool(device) and device.startswith("cuda")
        self.pool = pool
        self._stream = None
        self._dev = None
        self._staging: dict = {}
        # Staged downloads' events (CUDA) free to record: one goes back once its download is
        # read or dropped (_Staged.close), from any thread (deque: atomic append and pop).
        self._events: deque = deque()
        self._wp_dtypes: dict = {}  # NumPy dtype -> Warp dtype, looked up once
        # stage_downloads' batches: unit -> bytes its last batch carved (its next lease's
        # size); the batch under way's lease and bytes carved, and bytes wanted.
        self._arena_hints: dict = {}
        self._arena = None
        self._wanted = 0
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
        if _block_counted(value) and not _large(value):  # one copy of its block, no walk
            return download(value, lambda a: self._download_array(a, event))
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

    def stage_download(self, value, event=None, *, after=None):
        """Start downloading device value ``value`` (any tree of contiguous scalar-dtype
        arrays) into buffers of :attr:`pool`, after ``event`` (the producer's), on this
        thread's copy stream: the compute stream goes on meanwhile, and the reader waits for
        the copy's event only (:meth:`unstage`). Returns the download, or None (no pool, no
        device array, a leaf of another kind, or the pool full: download as usual).

        ``after``: the stream the producer was queued on, with nothing queued behind it yet
        (CUDA). A download of fewer than :attr:`SAME_STREAM_MAX_BYTES` goes there, in stream
        order, with no event wait between streams (a native call, and the device's latency
        of a cross-stream wait, on a GPU -> CPU hand-off).

        Every other staged copy goes on this thread's copy stream (see
        :class:`~.pinned.HostPool`)."""
        return self.stage_downloads((value,), event, after=after)[0]

    def stage_downloads(self, values, event=None, *, after=None, unit=None) -> list:
        """:meth:`stage_download` of several values made by one producer (a GPU unit's
        outputs, all ready after ``event``), as one: one stream choice and wait, one event
        after all the copies (shared by the downloads, recycled once every one is read or
        dropped) and, for ``unit`` (any hashable naming the producer), the host buffers of
        up to :attr:`BATCH_LEASE_MAX_BYTES` carved from one pool buffer of the size the
        unit's last batch needed (a lease costs several times a view; the rest from the
        pool as usual). Returns a download or None per value, in order."""
        if self.pool is None:
            return [None] * len(values)
        if unit is not None:  # carve the batch's buffers from one lease
            hint = self._arena_hints.get(unit)
            raw = self.pool.take((hint,), np.uint8) if hint else None
            self._arena = [raw, 0]  # the lease (None: every buffer from the pool), bytes carved
            self._wanted = 0
        parts = []
        try:
            for value in values:
                copies: dict = {}
                prefix: dict = {}
                try:
                    if is_warp_array(value):  # the usual values: no tree to walk
                        self._take(copies, value)
                    elif _block_counted(value):
                        self._take_counted(copies, prefix, value)
                    else:
                        # The walk that builds the value once copied (_Staged.host) lists
                        # what to copy.
                        host_value(value, functools.partial(self._take, copies),
                                   functools.partial(self._take_counted, copies, prefix))
                except _Unstageable:
                    parts.append(None)  # the buffers taken are garbage: back to the pool
                    continue
                if not copies:
                    parts.append(None)
                    continue
                nbytes = sum(host.nbytes for _, host in copies.values())
                nbytes += sum(n for _, _, spans in prefix.values() for _, _, n in spans)
                parts.append((value, copies, prefix, nbytes))
        finally:
            if unit is not None:
                self._arena = None
                # Room for the next batch to grow a little (a detector's rows vary).
                self._arena_hints[unit] = self._wanted + (self._wanted >> 3)
        nbytes = sum(part[3] for part in parts if part is not None)
        if not nbytes:
            return [None] * len(values)
        stream = self.stream
        if after is not None and stream is not None and nbytes < self.SAME_STREAM_MAX_BYTES:
            stream = after
        elif stream is not None and event is not None:
            wait_event(stream, event)
        for part in parts:
            if part is None:
                continue
            for a, host in part[1].values():
                to_host_async(host, a, stream)
            for src, _, spans in part[2].values():
                for offset, dst, n in spans:
                    bytes_to_host_async(dst, src.device, src.ptr + offset, n, stream)
        done = None
        if stream is not None:
            done = self._events.pop() if self._events else warp().Event(self.device)
            record_event(stream, done)
        sharers = _Sharers(sum(part is not None for part in parts))
        return [None if part is None else
                _Staged(part[0], part[1], {k: v[1] for k, v in part[2].items()}, done, part[3],
                        self._events, sharers)
                for part in parts]

    def _host_buffer(self, shape: tuple, dtype: np.dtype):
        """A host buffer of ``shape`` and ``dtype`` for a staged copy: carved from the batch's
        lease while it has room (:meth:`stage_downloads`), else the pool's (None: no room)."""
        arena = self._arena
        if arena is None:
            return self.pool.take(shape, dtype)
        if not isinstance(dtype, np.dtype):
            dtype = np.dtype(dtype)
        nbytes = math.prod(shape) * dtype.itemsize
        if nbytes > self.BATCH_LEASE_MAX_BYTES:
            return self.pool.take(shape, dtype)
        step = -(-nbytes // Block.ALIGN) * Block.ALIGN  # (aligned as a Block's arrays are)
        self._wanted += step
        raw, at = arena
        if raw is None or at + nbytes > raw.shape[0]:
            return self.pool.take(shape, dtype)
        arena[1] = at + step
        return raw[at:at + nbytes].view(dtype).reshape(shape)

    def _take_counted(self, copies: dict, prefix: dict, c):
        """The host buffer (:meth:`_take`) a staged download copies Counted ``c`` (with a
        block) into: its whole block, or for a large one its count, with the rows it likely
        counts (:class:`_RowHints`: :meth:`_take_prefix`; the rest of its counted rows are
        copied when read)."""
        if not _large(c):
            return self._take(copies, c.block.array)
        self._take_prefix(prefix, c)
        return self._take(copies, c.count)

    def _take_prefix(self, prefix: dict, c):
        """One pool buffer for the first :class:`_RowHints` rows of large Counted ``c``'s rows
        arrays: ``prefix[id(c.count)] = (block array, [host view per rows array], [(byte
        offset in the block, host address, bytes) per rows array])``; nothing when there is
        no hint yet or no pool room (its rows are copied when read)."""
        block = c.block
        k = ROW_HINTS.rows(block)
        if k <= 0 or id(c.count) in prefix:
            return
        # One buffer, not one per rows array: a lease costs several times a view.
        layout, nbytes = _prefix_layout(block.part, k)
        raw = self._host_buffer((nbytes,), np.dtype(np.uint8))
        if raw is None:
            return  # no pool room: its rows are copied when read
        base = address(raw)
        leaves, spans = [], []
        for offset, at, n, rows, dtype in layout:
            leaves.append(raw[at:at + n].view(dtype).reshape(rows))
            spans.append((offset, base + at, n))
        prefix[id(c.count)] = (block.array, leaves, spans)

    def _take(self, copies: dict, a):
        """The pool's host buffer device array ``a`` of a staged download is copied into (one
        per array: ``copies``, id -> (it, its buffer)); :class:`_Unstageable` when none."""
        got = copies.get(id(a))
        if got is None:
            dtype = numpy_dtype(a.dtype)
            if dtype is None or not a.is_contiguous:
                raise _Unstageable
            host = self._host_buffer(a.shape, dtype)
            if host is None:
                raise _Unstageable
            got = copies[id(a)] = (a, host)
        return got[1]

    def unstage(self, staged, *, ready: bool = False):
        """The host value of download ``staged`` (:meth:`stage_download`), waiting for its copy
        unless ``ready`` (the caller did). Its arrays are views of the pool's buffers, which
        go back to the pool once they (and every view of them) are garbage: no copy."""
        if not ready and staged.event is not None:
            synchronize_event(staged.event)
        staged.close()
        self.moved += staged.nbytes
        value = staged.host(self)
        staged.copies = None  # the value holds the pool's buffers now, not the download
        return value

    def counted_rows(self, c, count: np.ndarray, prefix: list | None = None):
        """The host value of Counted ``c`` (with a block) from its ``count`` already on the
        host: views of ``prefix`` (host copies of the first rows of each of its rows arrays,
        already copied) when they hold the counted rows, else its counted rows copied into
        buffers of the pool (fresh arrays past its cap), on this thread's copy stream,
        waited for."""
        block = c.block
        n = max(0, min(int(count[0]), block.part[0][2][0]))
        ROW_HINTS.saw(block, n)
        if prefix is not None and n <= prefix[0].shape[0]:
            return Counted.__warpvx_unflatten__(block.aux, tuple(prefix) + (count,))
        return self._counted_rows_copy(block, n, count)

    def _counted_rows_copy(self, block, n: int, count: np.ndarray):
        """:meth:`counted_rows`'s copy of ``n`` rows of ``block``, waited for."""
        src = block.array
        stream = self.stream
        leaves = []
        for offset, _, shape, dtype in block.part:
            rows = (n,) + shape[1:]
            host = self.pool.take(rows, dtype) if self.pool is not None else None
            if host is None:
                host = np.empty(rows, dtype)
            bytes_to_host_async(address(host), src.device, src.ptr + offset, host.nbytes,
                                stream)
            leaves.append(host)
            self.moved += host.nbytes
        if stream is not None:
            synchronize_stream(stream)
        return Counted.__warpvx_unflatten__(block.aux, tuple(leaves) + (count,))

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
                stage = _UploadStage(wp.empty(a.shape, dtype=dst.dtype, device="cpu", pinned=True))
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


__all__ = ["Transfers", "host_value", "tree_map"]
