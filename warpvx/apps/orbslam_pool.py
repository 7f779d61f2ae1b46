"""The process pool of the batched ORB-SLAM2 front end (:mod:`warpvx.apps.orbslam_batch`):
:class:`PosePool`, spawned processes with one OpenCV thread each that run the state-free
tracking work (essential matrices, stereo depths), jobs by priority, a batch's arrays sent
once in shared memory (:class:`SharedBlock`, :class:`Segments`), and a handler thread that
does not spin while results wait (:func:`_quiet_pool_class`). Split from
:mod:`~warpvx.apps.orbslam_batch`, which re-exports the public names.
"""

from __future__ import annotations

import collections
import contextlib
import functools
import heapq
import itertools
import os
import sys
import threading
import time

import numpy as np

from ..errors import WarpvxValueError


def _init_worker(bound: bool = False, nice: int = 0):
    import cv2

    # One OpenCV thread per process: the pool already spreads the work over the cores.
    cv2.setNumThreads(1)
    if nice:
        # Below the chain's priority: a core freeing up goes to the thread the others wait on.
        os.nice(nice)
    if bound:
        _die_with_parent()


def _die_with_parent():
    """Linux: SIGTERM to this process when the thread that started it exits (a pool's workers
    wait on a queue whose write end they hold too: a parent killed outright would leave them
    waiting for ever). Elsewhere nothing."""
    import ctypes
    import signal

    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, int(signal.SIGTERM))  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


@contextlib.contextmanager
def _caller_script_hidden():
    """While processes start, the caller's ``__main__`` looks like an interactive session:
    a spawned process then does not re-run the caller's script (it only needs warpvx's
    functions), so a script need not guard its entry point with ``if __name__ ==
    "__main__"`` to use a pool."""
    main = sys.modules.get("__main__")
    saved = {k: main.__dict__[k] for k in ("__file__", "__spec__") if main is not None and k in main.__dict__}
    try:
        for k in saved:
            if k == "__spec__":
                main.__spec__ = None
            else:
                del main.__dict__[k]
        yield
    finally:
        for k, v in saved.items():
            setattr(main, k, v)


def _quiet_pool_class():
    """multiprocessing's ``Pool`` whose worker-handler thread sleeps until a process exits or
    the pool closes. The stock one also wakes whenever a result waits in the pipe, and loops
    (poll every process, select) until the result thread has read it: with that thread
    waiting for the GIL, it spins, taking the GIL again and again from the tracking chain (on
    the H100 host: 17% of its samples in ``waitpid``; here ~35 ms of CPU per 16-frame batch).
    It wakes on results only to replace processes retired by ``maxtasksperchild``, which
    :class:`PosePool` does not set. (Python's ``ThreadPool`` waits on the same one notifier.)"""
    from multiprocessing.pool import Pool

    if not (hasattr(Pool, "_get_sentinels") and hasattr(Pool, "_wait_for_updates")):
        return Pool  # a Python whose Pool has other internals: the stock one, correct if busier

    class QuietPool(Pool):
        def _get_sentinels(self):
            return [self._change_notifier._reader]

    return QuietPool


class PoolTask:
    """One job on a :class:`PosePool`: :meth:`get` waits for its value; :meth:`cancel` drops
    it if no process has started it yet."""

    def __init__(self, fn, args, lock, block=None):
        self._job, self._result, self.cancelled, self._lock = (fn, args), None, False, lock
        self._settled = threading.Event()  # started, or cancelled
        self._block = block  # the SharedBlock its arguments refer to, held until it is done or dropped
        if block is not None:
            block.hold()

    def get(self):
        self._settled.wait()
        if self._result is None:
            raise WarpvxValueError("task: cancelled before it started")
        return self._result.get()

    def ready(self) -> bool:
        """Whether its value is there (:meth:`get` would not wait)."""
        return self._result is not None and self._result.ready()

    def cancel(self):
        with self._lock:
            self._drop()

    def _drop(self):
        """Cancel if not started (the caller holds the pool's lock)."""
        if self._result is None and not self.cancelled:
            self.cancelled = True
            self._settled.set()
            self._unshare()

    def _unshare(self):
        block, self._block = self._block, None
        if block is not None:
            block.release()


#: Arrays of fewer bytes travel in a job's pickle (K, ...), larger ones in a :class:`SharedBlock`.
SHARE_MIN_BYTES = 1024


class SharedRef:
    """What a job's pickle carries in place of an array of a :class:`SharedBlock`: the block's
    name, the array's byte offset, shape and dtype (:func:`_resolve` reads it in the worker)."""

    __slots__ = ("name", "offset", "shape", "dtype")

    def __init__(self, name, offset, shape, dtype):
        self.name, self.offset, self.shape, self.dtype = name, offset, shape, dtype

    def __getstate__(self):
        return self.name, self.offset, self.shape, self.dtype

    def __setstate__(self, state):
        self.name, self.offset, self.shape, self.dtype = state


def _arrays_in(value):
    """The NumPy arrays of at least :data:`SHARE_MIN_BYTES` in ``value``, through nested tuples."""
    if isinstance(value, np.ndarray):
        return [value] if value.nbytes >= SHARE_MIN_BYTES else []
    if isinstance(value, tuple):
        return [a for v in value for a in _arrays_in(v)]
    return []


class SharedBlock:
    """The large arrays of a batch's jobs, each once (jobs share a frame's points: frame f's
    job reads them as the current frame's, frame f + 1's as the previous one's, the guesses
    again), in one shared-memory segment: a job's pickle then carries a :class:`SharedRef` per
    array (bytes) instead of the array (~120 kB for a frame job, ~190 kB for a guess). The
    pool's task hand-off thread pickles the jobs holding the GIL, the one the tracking chain
    needs. Values are copied, bit for bit (the arrays C-contiguous in the segment).

    Each :class:`PoolTask` holds the block until it is done or dropped unstarted; the creator
    holds it until its jobs are submitted (:meth:`release`); the last release hands the
    segment back to ``segments`` (:class:`Segments`: a later batch reuses it, already mapped
    in the processes)."""

    def __init__(self, jobs, segments: Segments):
        unique = {id(a): a for job in jobs for a in _arrays_in(job)}
        offsets, size = {}, 0
        for key, a in unique.items():
            offsets[key] = size
            size += -(-a.nbytes // 64) * 64  # (64-byte aligned)
        self._segments = segments
        self._shm = segments.take(size, self)
        self._refs = {}
        for key, a in unique.items():
            # A memoryview copy holds the GIL (NumPy's would let it go and wait to take it back).
            at = offsets[key]
            self._shm.buf[at:at + a.nbytes] = memoryview(np.ascontiguousarray(a)).cast("B")
            self._refs[key] = SharedRef(self._shm.name, at, a.shape, a.dtype.str)
        self._holds, self._lock = 1, threading.Lock()

    def refer(self, value):
        """``value`` with its shared arrays replaced by their :class:`SharedRef` (nested tuples)."""
        if isinstance(value, np.ndarray):
            return self._refs.get(id(value), value)
        if isinstance(value, tuple):
            return tuple(self.refer(v) for v in value)
        return value

    def hold(self):
        with self._lock:
            self._holds += 1

    def release(self):
        with self._lock:
            self._holds -= 1
            last = self._holds == 0
        if last:
            self.free()

    def free(self):
        """Hand the segment back (once)."""
        with self._lock:
            shm, self._shm = self._shm, None
        if shm is not None:
            self._segments.give_back(shm, self)


class Segments:
    """The shared-memory segments of a :class:`PosePool`'s blocks: a free one large enough is
    reused (no new segment, no page faults, no new mapping in the processes), else one a
    quarter larger than asked is made; at most :data:`FREE_SEGMENTS` kept free. :meth:`close`
    unlinks them all, those of blocks still held included (their tasks were terminated)."""

    def __init__(self):
        self._free, self._held, self._closed, self._lock = [], {}, False, threading.Lock()

    def take(self, size: int, block):
        from multiprocessing import shared_memory

        with self._lock:
            if self._closed:
                raise WarpvxValueError("pool: shut down")
            fits = [shm for shm in self._free if shm.size >= size]
            shm = min(fits, key=lambda m: m.size) if fits else None
            if shm is not None:
                self._free.remove(shm)
        if shm is None:
            shm = shared_memory.SharedMemory(create=True, size=max(size + size // 4, 4096))
        with self._lock:
            self._held[id(block)] = (block, shm)
        return shm

    def give_back(self, shm, block):
        with self._lock:
            if self._held.pop(id(block), None) is None:
                return  # (a task dropped after close(), which unlinked it)
            self._free.append(shm)
            if len(self._free) <= FREE_SEGMENTS:
                return
            shm = min(self._free, key=lambda m: m.size)
            self._free.remove(shm)
        _unlink(shm)

    def close(self):
        with self._lock:
            self._closed = True
            gone = self._free + [shm for _, shm in self._held.values()]
            self._free, self._held = [], {}
        for shm in gone:
            _unlink(shm)


#: Free segments a :class:`Segments` keeps (a few batches in flight, each one block).
FREE_SEGMENTS = 6


def _unlink(shm):
    shm.close()
    shm.unlink()


#: In a pool process: the segments last attached (name -> read-only mmap), kept open: the pool
#: reuses its segments (:class:`Segments`); an array still viewing a dropped one keeps its mapping.
_ATTACHED = collections.OrderedDict()


def _attached(name: str):
    """The segment ``name`` mapped read-only. Not through ``SharedMemory``: before Python 3.13 it
    registers every attachment with the resource tracker, which then reports the block
    leaked, or fails to forget it, once the parent unlinks it."""
    m = _ATTACHED.get(name)
    if m is None:
        import _posixshmem
        import mmap

        fd = _posixshmem.shm_open("/" + name, os.O_RDONLY, mode=0o600)
        try:
            m = mmap.mmap(fd, 0, access=mmap.ACCESS_READ)
        finally:
            os.close(fd)
        _ATTACHED[name] = m
        while len(_ATTACHED) > FREE_SEGMENTS + 2:
            _ATTACHED.popitem(last=False)
    return m


def _resolve(value, copy: bool = False):
    """:meth:`SharedBlock.refer` undone in another process: read-only arrays over the block,
    or ``copy``: copies (what outlives the block's reuse)."""
    if isinstance(value, SharedRef):
        dtype = np.dtype(value.dtype)
        count = int(np.prod(value.shape, dtype=np.int64))
        a = np.frombuffer(_attached(value.name), dtype, count, value.offset).reshape(value.shape)
        return a.copy() if copy else a
    if isinstance(value, tuple):
        return tuple(_resolve(v, copy) for v in value)
    return value


def _shared_call(fn, *args):
    """``fn(*args)`` in a pool process, its :class:`SharedRef` arguments read from their block."""
    return fn(*_resolve(args))


class PosePool:
    """Processes for :func:`~warpvx.apps.orbslam_batch.pose_batch`, all started on
    construction (about a second each; spawned, not forked: the parent holds a CUDA context
    and executor threads), each with one OpenCV thread since the pool already spreads the
    work over the cores. ``workers``: the number of processes. Close it with
    :meth:`shutdown` (or use it as a context manager).

    Jobs wait in the parent, by priority, and go to the processes only as these free up (no
    more in flight than processes): a job with a sooner ``need`` (the run's frame at which
    the tracking chain will wait for it: a frame's essential core, a batch's frame jobs at its
    first frame) then starts before every queued one needed later (the next batch's work)
    instead of behind it, an ``urgent`` one before all, and a job cancelled before it starts
    costs nothing. ``waited_s`` sums the seconds
    :meth:`wait` spent blocked, by its ``what``; ``started`` counts the jobs started and
    ``cancelled`` those dropped unstarted, by function name. ``ahead`` False (to measure
    what it gives): every job in submit order, and ``pose_batch`` guesses no core.
    ``share`` False (to measure what it gives): a batch's jobs carry their arrays in their
    pickles instead of a :class:`SharedBlock`. ``quiet`` False (likewise): multiprocessing's
    stock ``Pool``, whose handler thread spins while results wait (see :func:`_quiet_pool_class`).
    ``bound`` (Linux): the processes end when the thread that opened the pool does (for a
    process's own thread that lives as long as the pool: the chain process's main thread).
    ``nice`` (POSIX, 0 to 19): the processes' niceness increment (:func:`make_pool`'s).
    ``direct`` False (to measure what it gives): jobs go through multiprocessing's task
    hand-off thread (see :meth:`_apply`). ``look_ahead``: frames ahead of the tracking chain
    whose essential cores it keeps started (int >= 1; None, the default: from the processes,
    see :func:`~warpvx.apps.orbslam_speculate.look_ahead`). ``graphs``: the verified graphs of
    the runs it served, for the next run with the same settings
    (:func:`~warpvx.apps.orbslam_batch.track_frames_batched`'s; dropped on :meth:`shutdown`)."""

    def __init__(self, workers: int, ahead: bool = True, share: bool = True, quiet: bool = True,
                 bound: bool = False, nice: int = 0, direct: bool = True, look_ahead: int | None = None):
        from multiprocessing import get_context
        from multiprocessing.pool import Pool

        look_ahead = check_look_ahead(look_ahead)

        with _caller_script_hidden():
            self._pool = (_quiet_pool_class() if quiet else Pool)(workers, initializer=_init_worker,
                                                                  initargs=(bound, nice), context=get_context("spawn"))
        # the shared blocks are POSIX shared memory (read through _posixshmem in the workers)
        self.workers, self.ahead, self.share = workers, ahead, share and os.name == "posix"
        self.direct, self.look_ahead, self.graphs = direct, look_ahead, {}
        # (re-entrant: a job whose pickling fails is settled, its callback run, while dispatching)
        self._lock = threading.RLock()
        self._queue, self._order, self._running = [], itertools.count(), 0
        self._segments = Segments()
        self.waited_s, self.started, self.cancelled = (collections.Counter() for _ in range(3))

    def submit(self, fn, *args, urgent: bool = False, need: int | None = None,
               block: SharedBlock | None = None) -> PoolTask:
        """``fn(*args)`` on a process, as soon as one is free and no job more urgent waits:
        ``urgent`` ones first, then by ``need`` (the run's frame at which the chain waits for
        the value; sooner first), then those with none; each in submit order (every job so
        without ``ahead``). ``block``: the :class:`SharedBlock` whose arrays ``args`` refer to
        (:meth:`SharedBlock.refer`), held until the job is done."""
        task = PoolTask(fn, args, self._lock, block)
        rank = (2, 0) if not self.ahead else (0, 0) if urgent else (2, 0) if need is None else (1, need)
        with self._lock:
            heapq.heappush(self._queue, (rank, next(self._order), task))
            self._dispatch()
        return task

    def shared(self, jobs) -> SharedBlock:
        """A :class:`SharedBlock` of ``jobs``' arrays (argument tuples), held by the caller
        until it calls its ``release`` (after submitting them)."""
        return SharedBlock(jobs, self._segments)

    def _dispatch(self):
        """Start queued jobs while processes are free (the caller holds the lock)."""
        while self._running < self.workers and self._queue:
            task = heapq.heappop(self._queue)[2]
            fn, args = task._job
            if task.cancelled:
                self.cancelled[fn.__name__] += 1
                continue
            self.started[fn.__name__] += 1
            self._running += 1
            job = (_shared_call, (fn, *args)) if task._block is not None else task._job
            task._result = self._apply(*job, functools.partial(self._done, task))
            task._settled.set()

    def _apply(self, fn, args, done):
        """``apply_async(fn, args)`` with ``done`` as both callbacks. ``direct`` (and a Python
        whose ``Pool`` has these internals): the job pickled and written to the processes'
        queue here, by the thread that dispatches it (the caller holds the lock, as
        multiprocessing's task thread would be the only writer), instead of handed to that
        thread: in the chain process each hand-off woke a thread that took the GIL from the
        chain (~30 per batch)."""
        from multiprocessing.pool import ApplyResult

        pool = self._pool
        if not (self.direct and hasattr(pool, "_quick_put") and hasattr(pool, "_check_running")):
            return pool.apply_async(fn, args, callback=done, error_callback=done)
        pool._check_running()
        result = ApplyResult(pool, done, done)
        try:
            pool._quick_put((result._job, 0, fn, args, {}))
        except Exception as exc:  # noqa: BLE001 - as the task thread does: the job's error
            result._set(0, (False, exc))
        return result

    def _done(self, task, _):
        task._unshare()
        with self._lock:
            self._running -= 1
            self._dispatch()

    def map(self, fn, jobs) -> list:
        """``[fn(*job) for job in jobs]`` on the processes, one job per task."""
        return [t.get() for t in [self.submit(fn, *job) for job in jobs]]

    def wait(self, task, what: str):
        """``task.get()``, its blocked time added to ``waited_s[what]``."""
        t = time.perf_counter()
        try:
            return task.get()
        finally:
            self.waited_s[what] += time.perf_counter() - t

    def shutdown(self, cancel_futures: bool = False):
        self.graphs.clear()
        with self._lock:
            for *_, task in self._queue:
                task._drop()
            self._queue.clear()
        if cancel_futures:
            self._pool.terminate()
        else:
            self._pool.close()
        self._pool.join()
        self._segments.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.shutdown(cancel_futures=exc[0] is not None)


#: Cores :func:`make_pool` leaves to the calling process: its busy threads (the GPU thread,
#: ``pose_batch``, ``chain``, the pool's own hand-off threads) take turns on the GIL, and each
#: hand-off waits for a core when the pose processes take them all.
SPARE_CORES = 3


def check_look_ahead(value):
    """A pool's ``look_ahead`` (None, or frames: an int >= 1), checked by name."""
    from ..check import check_int

    return None if value is None else check_int(value, "look_ahead", min_value=1)


def default_workers() -> int:
    """:func:`make_pool`'s default: all cores but :data:`SPARE_CORES`, at least 2."""
    return max(2, os.cpu_count() - SPARE_CORES)


def make_pool(workers: int | None = None, chain_process: bool = False, nice: int = 0,
              look_ahead: int | None = None):
    """A :class:`PosePool` for :func:`~warpvx.apps.orbslam_batch.pose_batch` (``workers``
    processes, default :func:`default_workers`; 0: None, the work runs in the calling thread);
    ``chain_process``: a :class:`~warpvx.apps.orbslam_chain.ChainProcess` with such a pool
    (0: none, the work in that process), on POSIX (elsewhere the pool as without it).
    ``nice``: the pose processes' niceness increment (``os.nice``, 0 to 19; 0, the default:
    the caller's priority; ignored off POSIX), so that the chain and the GPU host thread get
    a free core before them. ``look_ahead``: :class:`PosePool`'s."""
    from ..check import check_bool, check_int

    workers = default_workers() if workers is None else check_int(workers, "workers", min_value=0)
    nice = check_int(nice, "nice", min_value=0, max_value=19) if os.name == "posix" else 0
    look_ahead = check_look_ahead(look_ahead)
    if check_bool(chain_process, "chain_process") and os.name == "posix":
        from .orbslam_chain import ChainProcess

        return ChainProcess(workers, nice=nice, look_ahead=look_ahead)
    return PosePool(workers, nice=nice, look_ahead=look_ahead) if workers else None


__all__ = ["PosePool", "PoolTask", "SharedBlock", "Segments", "make_pool", "default_workers", "SPARE_CORES"]
