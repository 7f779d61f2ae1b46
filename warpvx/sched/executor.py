"""Run a :class:`~warpvx.sched.schedule.Schedule` for real: CPU worker threads beside one GPU queue.

The executor is the runtime half of SPEC §7. It knows nothing of graphs: it runs a
:class:`Program` (tasks with named inputs and outputs and one callable per processing
element) according to a schedule, frame after frame.

Threads
    One thread per processor of the schedule. A CPU worker (``"cpu<i>"``) runs its tasks' CPU
    callables in schedule order on host data (NumPy/OpenCV release the GIL, so workers
    overlap). The GPU host thread (``"gpu"``) runs the GPU callables in schedule order with the
    device's current stream set to the executor's ``wp.Stream``; on CUDA the calls only enqueue
    kernels, so the thread runs ahead of the device.
Cross-queue edges
    Every (frame, value) pair is a :class:`Slot` with a ``threading.Event`` set when its
    producer has finished (CPU) or enqueued (GPU). GPU -> CPU: the GPU thread records a CUDA
    event after the producer; the CPU consumer waits for the slot, then for the event
    (``wp.synchronize_event``), then downloads on its own copy stream. CPU -> GPU: the GPU
    thread waits for the CPU producer's slot and uploads on the GPU stream (stream-ordered, so
    the kernel after it sees the data; large arrays go through reusable pinned staging
    buffers, so the copy is asynchronous and the GPU thread does not wait for the kernels
    queued before it). Between two GPU tasks data stays on the device: one in-order stream
    needs no synchronisation at all.
Timing
    CPU tasks: host ``time.perf_counter`` before the task's downloads and after its call
    (waiting for a producer is not counted). GPU tasks on CUDA: timing events recorded on the
    stream before the task's uploads and after its kernels, mapped to the host clock through
    an anchor event recorded while the stream was idle (:meth:`Executor.reanchor`), so a GPU
    interval is when the device ran it, not when the host enqueued it. When the GPU thread
    did not have to wait between two tasks, the first one's end event is the second one's
    start (one event per task, not two). Events come from a pool and return to it once their
    frame has been waited for. The host-side time of each GPU call (enqueue plus any host
    syncs inside the primitive) is kept too (:attr:`FrameResult.host`), and so is the time
    each task spent on transfers (:attr:`FrameResult.transfers`). Without CUDA (the
    ``"warp-cpu"`` GPU role) calls are synchronous and host times are used; events are not
    used at all.
Buffers
    A task may come with ``gpu_out``, a factory of its output buffer: the executor then calls
    ``gpu(*values, out=buffer)`` with a buffer from the task's pool and returns the buffer to
    the pool once the frame has been waited for (unless a delay keeps the value or it was
    handed to the caller on the device), so steady-state frames allocate nothing for it.
    Uploads on CUDA work the same way: each host value a GPU task reads is copied into a
    device buffer from a pool of that edge (allocating a ``wp.array`` costs more host time
    than a small copy), returned under the same rules (:meth:`Executor._reuse_rule`).
CPU threads
    Calibration times each CPU implementation alone; OpenCV's own thread pool then competes
    with the workers when they run together, so predictions hold best with
    ``cv2.setNumThreads(1)`` (one core per worker, the thesis' model), as the graph benchmark
    does.
Pipelining
    :meth:`Executor.submit` hands a frame to every processor's queue and returns at once; each
    processor works through frames in order, so frame *i+1*'s early tasks run while frame *i*'s
    late ones finish. Inputs with a negative frame offset (delays) read the slot of an earlier
    frame from a :class:`Ring`, waiting for it like any other slot.
Errors
    A task that raises fails its frame: that frame and every later frame in flight are
    cancelled (their waits see the cancel flag within :data:`WAIT_SLICE` seconds and their
    remaining tasks are skipped), earlier frames complete, and :meth:`Executor.wait` raises
    :class:`~warpvx.errors.NodeExecutionError` with the task's exception as ``__cause__``. No
    wait is unbounded: each checks its frame's cancel flag and the executor's shutdown flag.
"""

from __future__ import annotations

import contextlib
import functools
import queue
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import networkx as nx

from ..errors import NodeExecutionError, ScheduleError, WarpvxValueError
from ..keypoints import FIELDS, Keypoints
from .schedule import Schedule, ScheduledTask

#: Seconds between cancellation checks of a blocked wait.
WAIT_SLICE = 0.02

#: Default of :class:`Executor`'s ``spin``: seconds a thread polls for a value (yielding the
#: GIL between polls) before it blocks on it. Blocking costs a thread wake-up per hand-off.
SPIN_SECONDS = 0.0

HOST = "host"
DEVICE = "device"

#: A GPU task's uploads of this many bytes or more get a timing event of their own (the
#: task's transfer time); a smaller copy is not worth an event.
TIMED_COPY_MIN_BYTES = 1 << 16


class _Cancelled(Exception):
    """Internal: the frame a wait belongs to was cancelled."""


# --------------------------------------------------------------------------- program


@dataclass(frozen=True)
class InputRef:
    """A task input: value ``key`` of this frame (``offset=0``) or of ``-offset`` frames ago."""

    key: str
    offset: int = 0


@dataclass
class ExecTask:
    """One task: inputs, outputs and its callables.

    ``cpu(*host_values)`` and ``gpu(*device_values)`` return one value per output (a tuple
    when there are several); ``None`` marks a missing implementation. ``gpu_out``, when
    given, makes a fresh output buffer for the GPU callable, which then takes it as
    ``gpu(*device_values, out=buffer)`` (buffers are pooled across frames).
    """

    name: str
    inputs: tuple
    outputs: tuple
    cpu: Callable | None = None
    gpu: Callable | None = None
    gpu_out: Callable | None = None


@dataclass
class Program:
    """What the executor runs each frame.

    Attributes
    ----------
    tasks : dict
        name -> :class:`ExecTask`.
    inputs : tuple of str
        Keys fed by :meth:`Executor.submit`.
    outputs : dict
        output name -> key, returned by :meth:`Executor.wait`.
    rings : dict
        key -> :class:`Ring` for every key read with a negative offset.
    """

    tasks: dict
    inputs: tuple
    outputs: dict
    rings: dict = field(default_factory=dict)


# --------------------------------------------------------------------------- values


class Flag:
    """A one-shot ``threading.Event`` (``set``, ``is_set``, ``wait(timeout)``) made of one
    lock: cheaper to create, set and wait on than an Event (a Condition per wait), and the
    executor makes one per value per frame and waits on them on every cross-thread edge."""

    __slots__ = ("_lock", "_set")

    def __init__(self):
        self._lock = threading.Lock()
        self._lock.acquire()
        self._set = False

    def set(self):
        if not self._set:
            self._set = True
            try:
                self._lock.release()
            except RuntimeError:  # released by a concurrent set()
                pass

    def is_set(self) -> bool:
        return self._set

    def wait(self, timeout: float | None = None) -> bool:
        if self._set:
            return True
        if self._lock.acquire(timeout=-1 if timeout is None else timeout):
            try:
                self._lock.release()  # let the other waiters through
            except RuntimeError:
                pass
            return True
        return self._set


class Slot:
    """One value of one frame, where its producer left it, with cached copies elsewhere.

    ``where`` is ``"host"`` (NumPy data) or ``"device"`` (``wp.array`` data on the GPU role's
    device). ``done`` is set once the value may be read (after the CUDA ``event``, if any).
    """

    __slots__ = ("value", "where", "event", "external", "done", "_host", "_device", "_lock")

    def __init__(self):
        self.value = None
        self.where = HOST
        self.event = None
        self.external = False  # a device value made outside the executor's stream
        self.done = Flag()
        self._host = None
        self._device = None
        self._lock = threading.Lock()

    @classmethod
    def ready(cls, value, where=HOST) -> "Slot":
        s = cls()
        s.set(value, where)
        return s

    def set(self, value, where, event=None):
        self.value, self.where, self.event = value, where, event
        self.done.set()

    def host(self, io: "Transfers", *, ready: bool = False):
        """The value as host data, downloaded once (thread-safe).

        ``ready``: the caller already waited for the producer's event on the host, so the
        copy need not wait for it again.
        """
        if self.where == HOST:
            return self.value
        with self._lock:
            if self._host is None:
                self._host = (io.download(self.value, None if ready else self.event),)
            return self._host[0]

    def device(self, io: "Transfers", into=None):
        """The value on the GPU role's device, uploaded once (call from the GPU thread).

        ``into(shape, dtype)``: a device buffer to upload an array leaf into, or None for a
        fresh one (see :meth:`Transfers.upload`).
        """
        if self.where == DEVICE:
            return self.value
        with self._lock:
            if self._device is None:
                self._device = (io.upload(self.value, into),)
            return self._device[0]

    def get(self, where, io):
        return self.host(io) if where == HOST else self.device(io)


class Ring:
    """Slots of one key for past frames (a delay's storage), indexed by absolute frame number.

    A frame's slot is reserved when the frame is submitted and filled when its producer runs.
    Frames before the first one, and frames whose slot was dropped (a cancelled frame), read
    the latest earlier slot that was filled, else the initial value. ``lock`` guards every
    access; the graph layer shares it with user threads (thesis §4.2).
    """

    def __init__(self, slots: int, initial, lock=None):
        self.slots = int(slots)
        self.lock = lock if lock is not None else threading.RLock()
        self._initial = Slot.ready(initial)
        self._by_frame: dict[int, Slot] = {}
        self.last_aged = -1

    def reserve(self, frame: int, slot: Slot):
        with self.lock:
            self._by_frame[frame] = slot

    def get(self, frame: int) -> Slot:
        with self.lock:
            slot = self._by_frame.get(frame)
            if slot is not None:
                return slot
            earlier = [f for f, s in self._by_frame.items() if f < frame and s.done.is_set()]
            return self._by_frame[max(earlier)] if earlier else self._initial

    def put(self, frame: int, value, where=HOST):
        """Replace frame ``frame``'s value (a user write through the communication wrapper)."""
        with self.lock:
            self._by_frame[frame] = Slot.ready(value, where)

    @property
    def initial(self):
        """The value frames before the first one read."""
        return self._initial.value

    def set_initial(self, value):
        with self.lock:
            self._initial = Slot.ready(value)

    def reset(self):
        """Forget every frame: reads return the initial value again."""
        with self.lock:
            self._by_frame.clear()
            self.last_aged = -1

    def age(self, frame: int):
        """Frame ``frame`` completed: it becomes the newest value; forget what no frame needs."""
        with self.lock:
            self.last_aged = max(self.last_aged, frame)
            keep_from = self.last_aged - self.slots
            for f in [f for f in self._by_frame if f < keep_from]:
                del self._by_frame[f]

    def discard_pending(self, frame: int):
        """Drop frame ``frame``'s slot if its producer never ran (the frame was cancelled)."""
        with self.lock:
            slot = self._by_frame.get(frame)
            if slot is not None and not slot.done.is_set():
                del self._by_frame[frame]


# --------------------------------------------------------------------------- transfers


_WP = None


def _wp():
    """The initialised ``warp`` module (cached: an import statement per copy costs ~1 us)."""
    global _WP
    if _WP is None:
        from ..backend import init_warp

        _WP = init_warp()
    return _WP


def _is_warp(x) -> bool:
    mod = type(x).__module__
    return mod.startswith("warp") and hasattr(x, "device") and hasattr(x, "ptr")


def tree_map(fn, obj):
    """Apply ``fn`` to every array leaf (NumPy or Warp) of tuples, lists, dicts and Keypoints."""
    import numpy as np

    if isinstance(obj, np.ndarray) or _is_warp(obj):
        return fn(obj)
    if isinstance(obj, tuple):
        return tuple(tree_map(fn, o) for o in obj)
    if isinstance(obj, list):
        return [tree_map(fn, o) for o in obj]
    if isinstance(obj, dict):
        return {k: tree_map(fn, v) for k, v in obj.items()}
    if isinstance(obj, Keypoints):
        return Keypoints(**{f: tree_map(fn, getattr(obj, f)) for f in FIELDS})
    return obj


def _native():
    """Warp's native copy and sync entry points, or None when this Warp lacks them.

    The executor's small copies use them directly: through ``wp.copy``, ``wp.empty(device=
    "cpu")`` and ``array.numpy()`` a 16-byte download costs tens of microseconds of Python,
    paid on every edge between a GPU task and a CPU task. Only contiguous arrays of scalar
    dtypes take this path, with the same calls ``wp.copy`` makes.
    """
    global _NATIVE
    if _NATIVE is False:
        try:
            from warp._src import context as ctx

            core = ctx.runtime.core
            _NATIVE = (core.wp_memcpy_h2d, core.wp_memcpy_d2h, core.wp_cuda_stream_synchronize,
                       core.wp_cuda_event_record, core.wp_cuda_event_synchronize)
        except (ImportError, AttributeError):
            _NATIVE = None
    return _NATIVE


def _record(stream, event):
    """``stream.record_event(event)`` (a timing event) without Warp's Python checks."""
    native = _native()
    if native is None:
        stream.record_event(event)
    else:
        native[3](event.cuda_event, stream.cuda_stream, True)


def _sync_event(event):
    """``wp.synchronize_event(event)`` without Warp's capture checks (never capturing here)."""
    native = _native()
    if native is None or not native[4](event.cuda_event):
        _wp().synchronize_event(event)  # the checked path, which also reports errors


_NATIVE = False
_NP_DTYPES: dict = {}


def _numpy_dtype(wp, dtype):
    """The NumPy dtype of a scalar Warp dtype, None for vectors, matrices and structs."""
    try:
        return _NP_DTYPES[dtype]
    except KeyError:
        pass
    try:
        np_dtype = wp.dtype_to_numpy(dtype)  # scalar types only; TypeError for the others
    except (TypeError, KeyError):
        np_dtype = None
    _NP_DTYPES[dtype] = np_dtype
    return np_dtype


class _Staging:
    """A pinned host buffer for uploads of one shape and dtype, and the event of its last copy."""

    __slots__ = ("buffer", "view", "event")

    def __init__(self, buffer, event):
        self.buffer = buffer
        self.view = buffer.numpy()  # aliases the pinned memory
        self.event = event


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
    copies from pageable memory: the driver stages it at once.

    Uploads take the device buffer from ``into`` when given (the executor's per-edge pools:
    allocating a ``wp.array`` costs ~10 us of Python, more than a small copy); downloads make
    fresh NumPy arrays. With :attr:`PINNED_DOWNLOADS`, a download up to
    :attr:`PINNED_DOWNLOAD_MAX` bytes lands in a reusable pinned buffer of this thread and is
    then copied out.
    """

    #: Uploads from this size on use pinned staging buffers.
    PINNED_MIN_BYTES = 1 << 16
    #: Staging buffers per shape and dtype before an upload waits for the oldest one.
    STAGING_DEPTH = 4
    #: Downloads through a reusable pinned buffer plus a host copy instead of straight into
    #: a fresh pageable array (measured: see benchmarks/results/graph/overhead.md).
    PINNED_DOWNLOADS = False
    PINNED_DOWNLOAD_MAX = 1 << 16

    def __init__(self, device: str | None):
        self.device = device
        self.cuda = bool(device) and device.startswith("cuda")
        self._stream = None
        self._dev = None
        self._staging: dict = {}
        self._landing: dict = {}  # (shape, dtype) -> pinned download buffer (NumPy view)
        self.moved = 0  # bytes copied so far, both ways

    @property
    def stream(self):
        if self._stream is None and self.cuda:
            self._stream = _wp().Stream(self.device)
        return self._stream

    def download(self, value, event=None):
        """``value`` with every device array copied to host NumPy (fresh arrays, never views
        of device-role memory: a pooled buffer may be overwritten by a later frame)."""
        wp = _wp() if self.cuda else None

        def leaf(a):
            if not _is_warp(a):
                return a
            if not a.device.is_cuda:
                # Warp's CPU device shares host memory: copy, so the value outlives the buffer.
                out = a.numpy().copy()
            elif not a.is_contiguous:
                # A strided view needs a gather kernel on the device's current stream (the GPU
                # thread's); wait for the producer, then let Warp copy synchronously.
                if event is not None:
                    wp.synchronize_event(event)
                out = a.numpy()
            else:
                s = self.stream
                if event is not None:
                    s.wait_event(event)
                out = self._download_native(wp, a, s)
                if out is None:
                    host = wp.empty(a.shape, dtype=a.dtype, device="cpu")
                    wp.copy(host, a, stream=s)
                    wp.synchronize_stream(s)
                    out = host.numpy()
            self.moved += out.nbytes
            return out

        return tree_map(leaf, value)

    def upload(self, value, into=None):
        """``value`` with every host array copied to the device (on its current stream).

        ``into(shape, dtype)``, when given, returns the contiguous device buffer an array leaf
        is copied into (or None: a fresh one); the caller owns its reuse.
        """
        import numpy as np

        wp = _wp()
        dev = self._dev
        if dev is None:
            dev = self._dev = wp.get_device(self.device)

        def leaf(a):
            if _is_warp(a):
                if a.device == dev:
                    return a
                a = a.numpy()
            if not isinstance(a, np.ndarray):
                return a
            dtype = wp.dtype_from_numpy(a.dtype)
            self.moved += a.nbytes
            if dev.is_cpu:
                # Warp's CPU device shares host memory: alias, do not copy (host values are
                # never written after their producer finished).
                return wp.array(np.ascontiguousarray(a), dtype=dtype, device=dev, copy=False)
            dst = into(a.shape, dtype) if into is not None else None
            if dst is None:
                dst = wp.empty(a.shape, dtype=dtype, device=dev)
            if a.nbytes < self.PINNED_MIN_BYTES:
                self._upload_small(wp, dev, np.ascontiguousarray(a), dst)
            else:
                self._upload_staged(wp, dev, a, dst)
            return dst

        return tree_map(leaf, value)

    def _download_native(self, wp, a, stream):
        """Contiguous scalar-dtype device array -> new NumPy array, copied on ``stream``
        (None: not this path)."""
        native = _native()
        np_dtype = _numpy_dtype(wp, a.dtype)
        if native is None or np_dtype is None:
            return None
        d2h, sync = native[1], native[2]
        import numpy as np

        pinned = self.PINNED_DOWNLOADS
        if pinned:
            key = (a.shape, np_dtype)
            land = self._landing.get(key)
            if land is None:
                n = int(np.prod(a.shape)) * np.dtype(np_dtype).itemsize
                if n > self.PINNED_DOWNLOAD_MAX:
                    pinned = False
                else:
                    land = self._landing[key] = wp.empty(a.shape, dtype=a.dtype, device="cpu",
                                                         pinned=True).numpy()
        out = land if pinned else np.empty(a.shape, dtype=np_dtype)
        if out.nbytes:
            if not d2h(a.device.context, out.ctypes.data, a.ptr, out.nbytes, stream.cuda_stream):
                raise RuntimeError(f"download of {out.nbytes} bytes failed")
            # The stream is this thread's alone: synchronising it waits for this copy only.
            if not sync(stream.cuda_stream):
                raise RuntimeError("download: stream synchronisation failed")
        return out.copy() if pinned else out

    @staticmethod
    def _upload_small(wp, dev, a, dst):
        """A small contiguous host array -> ``dst`` on the current stream (pageable: the
        driver stages it at once)."""
        native = _native()  # dtype is a scalar type: wp.dtype_from_numpy made it
        if native is None:
            wp.copy(dst, wp.array(a, dtype=dst.dtype, device="cpu", copy=False))
            return
        if a.nbytes and not native[0](dev.context, dst.ptr, a.ctypes.data, a.nbytes,
                                      dev.stream.cuda_stream):
            raise RuntimeError(f"upload of {a.nbytes} bytes failed")

    def _upload_staged(self, wp, dev, a, dst):
        import numpy as np

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
        native = _native()
        if native is None:
            wp.copy(dst, stage.buffer, stream=stream)
        elif a.nbytes and not native[0](dev.context, dst.ptr, stage.buffer.ptr, a.nbytes,
                                        stream.cuda_stream):
            raise RuntimeError(f"upload of {a.nbytes} bytes failed")
        if stage.event is None:
            stage.event = wp.Event(dev)
        stream.record_event(stage.event)


class EventPool:
    """Reusable CUDA timing events of one device (creating events per task costs more than
    recording them). :meth:`get` hands out a free one; :meth:`put` takes back events whose
    frame is over."""

    MAX_FREE = 4096

    def __init__(self, device: str):
        self.device = device
        self._free: list = []
        self._lock = threading.Lock()

    def get(self):
        with self._lock:
            if self._free:
                return self._free.pop()
        return _wp().Event(self.device, enable_timing=True)

    def put(self, events):
        with self._lock:
            room = self.MAX_FREE - len(self._free)
            if room > 0:
                self._free.extend(events[:room])

    def __len__(self):
        return len(self._free)


# --------------------------------------------------------------------------- frames


class Frame:
    """A frame in flight: its slots, cancel flag, completion and timeline."""

    def __init__(self, index: int, slots: dict, n_procs: int):
        self.index = index
        self.slots = slots
        self.cancel = threading.Event()
        self.finished = threading.Event()
        self.error = None  # (task, processor, exception)
        self.cancelled_by = None
        # task -> (processor, start, end, after_transfers or None): host seconds, or CUDA
        # events for GPU tasks on CUDA.
        self.trace = {}
        self.host_trace = {}  # GPU task -> (start, end) host seconds of its call
        self.copied = {}  # task -> bytes it moved between host and device
        self.t0 = time.perf_counter()
        self.gpu_last_event = None
        self.events = []  # pooled CUDA events this frame recorded
        self.leases = []  # (task, buffer) output buffers taken from the pools
        self.uploads = []  # (key, buffer) upload buffers taken from the pools
        self._remaining = n_procs
        self._lock = threading.Lock()
        if n_procs == 0:
            self.finished.set()

    def processor_done(self):
        with self._lock:
            self._remaining -= 1
            if self._remaining == 0:
                self.finished.set()

    def wait_slot(self, slot: Slot, closing: threading.Event, spin: float = 0.0):
        done = slot.done
        if done.is_set():
            return
        if spin > 0:
            deadline = time.perf_counter() + spin
            while time.perf_counter() < deadline:
                time.sleep(0)  # lets the producer have the GIL
                if done.is_set():
                    return
        while not done.wait(WAIT_SLICE):
            if self.cancel.is_set() or closing.is_set():
                raise _Cancelled()


@dataclass
class FrameResult:
    """What :meth:`Executor.wait` returns: outputs, the measured timeline and the makespan.

    ``timeline`` maps task -> :class:`ScheduledTask` with times in ms from the frame's
    submission (``t0``, host ``perf_counter`` seconds); ``makespan`` is the latest finish.
    ``transfers``: task -> ms of its interval spent on host <-> device copies (uploads of a
    GPU task, downloads of a CPU task); ``copied``: task -> bytes it copied; ``host``: GPU
    task -> (start, finish) ms of the GPU thread's call (enqueue plus host syncs inside it),
    on the same axis as ``timeline``.
    """

    index: int
    outputs: dict
    timeline: dict
    t0: float
    transfers: dict = field(default_factory=dict)
    copied: dict = field(default_factory=dict)
    host: dict = field(default_factory=dict)

    def compute_ms(self, task) -> float:
        """The task's measured time without its transfers (ms)."""
        t = self.timeline[task]
        return max(0.0, t.finish - t.start - self.transfers.get(task, 0.0))

    @property
    def makespan(self) -> float:
        return max((t.finish for t in self.timeline.values()), default=0.0)


# --------------------------------------------------------------------------- executor


def _is_gpu_processor(name: str) -> bool:
    return name.startswith("gpu")


class Executor:
    """Run ``program`` according to ``schedule`` on CPU worker threads and a GPU host thread.

    Parameters
    ----------
    schedule : Schedule
        Every task of ``program`` placed once; processors ``"cpu<i>"`` and ``"gpu"``.
    program : Program
        Tasks, inputs, outputs and rings (delays).
    gpu_device : str, optional
        Warp device of the GPU role: ``"cuda:N"`` or ``"cpu"`` (Warp's CPU device, the
        ``"warp-cpu"`` role). Required when a task is placed on ``"gpu"``.
    name : str
        For thread names and messages.
    spin : float, optional
        Seconds a thread polls for an input (yielding the GIL) before it blocks on it
        (default :data:`SPIN_SECONDS`): a short poll saves the thread wake-up of a
        hand-off, at the price of GIL traffic while it polls.

    Raises
    ------
    ScheduleError
        A task unscheduled or scheduled twice, a task on a processor it has no callable for,
        an unknown processor, or per-processor orders that contradict the data dependencies
        (running them would deadlock).
    """

    #: Device buffers kept per pooled upload edge (a few frames in flight, several leaves).
    UPLOAD_POOL = 16

    def __init__(self, schedule: Schedule, program: Program, *, gpu_device: str | None = None,
                 name: str = "graph", spin: float | None = None):
        self.spin = SPIN_SECONDS if spin is None else float(spin)
        self.schedule = schedule
        self.program = program
        self.name = name
        self.processors = list(schedule.processors)
        self.gpu_device = gpu_device
        self.cuda = bool(gpu_device) and str(gpu_device).startswith("cuda")
        unknown = [t for t in schedule.tasks if t not in program.tasks]
        if unknown:
            raise ScheduleError(f"schedule: places unknown task {unknown[0]!r}")
        self.queues = {p: [program.tasks[t] for t in self._order(p)] for p in self.processors}
        self._check()
        # The GPU thread first: it hands frames out in this order, and the threads woken
        # first take Python's GIL first; the GPU thread (Python-heavy, usually the critical
        # path) should not start its frame behind every CPU worker's Python prologue.
        self._active = sorted((p for p in self.processors if self.queues[p]),
                              key=lambda p: not _is_gpu_processor(p))
        self._inbox = {p: queue.SimpleQueue() for p in self._active}
        self._threads: dict[str, threading.Thread] = {}
        self._closing = threading.Event()
        self._inflight: list[Frame] = []
        self._lock = threading.Lock()
        self._local = threading.local()
        self._stream = None
        self._anchor = None  # (host seconds, timing event) on CUDA
        self._events = EventPool(gpu_device) if self.cuda else None
        self._out_pools: dict[str, list] = {t: [] for t, task in program.tasks.items()
                                            if task.gpu_out is not None}
        self._pool_rule = self._pool_rules()
        for name, rule in self._pool_rule.items():
            if rule == "never":  # the primitive allocates, as without a pool
                del self._out_pools[name]
        # Per-edge device buffers for uploads (CUDA: on Warp's CPU device uploads alias).
        self._upload_rule = self._upload_rules() if self.cuda else {}
        self._up_pools: dict[str, list] = {k: [] for k, rule in self._upload_rule.items()
                                           if rule != "never"}
        self._up_lock = threading.Lock()  # the GPU thread leases, wait() returns

    # ------------------------------------------------------------------ checks

    def _order(self, proc: str) -> list:
        """Tasks on ``proc`` by start time; ties (zero-cost tasks) in dependency order."""
        if not hasattr(self, "_topo"):
            producer = {k: t.name for t in self.program.tasks.values() for k in t.outputs}
            g = nx.DiGraph()
            g.add_nodes_from(self.program.tasks)
            g.add_edges_from((producer[r.key], t.name) for t in self.program.tasks.values()
                             for r in t.inputs if r.offset == 0 and r.key in producer)
            try:
                self._topo = {n: i for i, n in enumerate(nx.topological_sort(g))}
            except nx.NetworkXUnfeasible:
                raise ScheduleError("program: its data dependencies have a cycle") from None
        on = [st for st in self.schedule.tasks.values() if st.processor == proc]
        on.sort(key=lambda st: (st.start, st.finish, self._topo.get(st.task, 0)))
        return [st.task for st in on]

    def _check(self):
        placed = {}
        for p in self.processors:
            for task in self.queues[p]:
                if task.name in placed:
                    raise ScheduleError(f"schedule: task {task.name!r} is placed on both "
                                        f"{placed[task.name]!r} and {p!r}")
                placed[task.name] = p
                kind = "gpu" if _is_gpu_processor(p) else "cpu"
                if getattr(task, kind) is None:
                    raise ScheduleError(f"schedule: task {task.name!r} is placed on {p!r} but has "
                                        f"no {kind.upper()} implementation")
        missing = [t for t in self.program.tasks if t not in placed]
        if missing:
            raise ScheduleError(f"schedule: tasks {missing!r} are not scheduled")
        gpus = [p for p in self.processors if _is_gpu_processor(p)]
        if len(gpus) > 1:
            raise ScheduleError(f"schedule: one GPU processor is supported, got {gpus}")
        if any(_is_gpu_processor(p) and self.queues[p] for p in self.processors) and not self.gpu_device:
            raise ScheduleError("schedule: tasks are placed on the GPU but no gpu_device was given")
        # Data edges plus each processor's order must be acyclic, or some wait never returns.
        producer = {k: t.name for t in self.program.tasks.values() for k in t.outputs}
        g = nx.DiGraph()
        g.add_nodes_from(self.program.tasks)
        for t in self.program.tasks.values():
            for ref in t.inputs:
                if ref.offset == 0 and ref.key in producer:
                    g.add_edge(producer[ref.key], t.name)
        for p in self.processors:
            names = [t.name for t in self.queues[p]]
            g.add_edges_from(zip(names, names[1:]))
        if not nx.is_directed_acyclic_graph(g):
            cyc = " -> ".join(u for u, _ in nx.find_cycle(g))
            raise ScheduleError(f"schedule: processor orders contradict data dependencies "
                                f"(would deadlock): {cyc}")

    # ------------------------------------------------------------------ threads

    def _io(self) -> Transfers:
        io = getattr(self._local, "io", None)
        if io is None:
            io = self._local.io = Transfers(self.gpu_device)
        return io

    def _start(self):
        if self._threads:
            return
        if self.cuda:
            wp = _wp()
            self._stream = wp.Stream(self.gpu_device)
            self.reanchor()
        for p in self._active:
            th = threading.Thread(target=self._loop, args=(p,), name=f"warpvx-{self.name}-{p}",
                                  daemon=True)
            self._threads[p] = th
            th.start()

    def reanchor(self, max_age: float | None = None):
        """Tie the GPU clock to the host clock (CUDA only; call while no frame is in flight).

        With ``max_age`` (seconds), only when the last anchor is older than that.
        """
        if not self.cuda or self._stream is None:
            return
        if max_age is not None and self._anchor is not None and \
                time.perf_counter() - self._anchor[0] < max_age:
            return
        wp = _wp()
        wp.synchronize_stream(self._stream)
        ev = wp.Event(self.gpu_device, enable_timing=True)
        t_before = time.perf_counter()
        self._stream.record_event(ev)
        wp.synchronize_event(ev)
        t_after = time.perf_counter()
        self._anchor = (0.5 * (t_before + t_after), ev)

    def _loop(self, proc: str):
        gpu = _is_gpu_processor(proc)
        inbox = self._inbox[proc]
        while True:
            frame = inbox.get()
            if frame is None:
                return
            if gpu:
                if self._gpu_frames(proc, frame, inbox):
                    return
            else:
                self._one_frame(proc, frame, self._run_cpu)

    def _one_frame(self, proc: str, frame: Frame, run):
        try:
            if not frame.cancel.is_set():
                run(proc, frame)
        except BaseException as exc:  # noqa: BLE001 - an executor bug must not kill the thread
            self._fail(frame, "<executor>", proc, exc)
        finally:
            frame.processor_done()

    def _gpu_frames(self, proc: str, frame: Frame, inbox) -> bool:
        """Run ``frame`` and the frames queued behind it in one device/stream scope (entering
        and leaving the scope per frame costs host time on the critical thread). Returns True
        when the stop sentinel came."""
        wp = _wp()
        scope = (wp.ScopedStream(self._stream, sync_enter=False) if self.cuda
                 # sync_enter=False: the stream's order is ours; the user's stream is not a producer.
                 else contextlib.nullcontext())
        with wp.ScopedDevice(self.gpu_device), scope:
            while True:
                self._one_frame(proc, frame, self._run_gpu_tasks)
                try:
                    frame = inbox.get_nowait()
                except queue.Empty:
                    return False
                if frame is None:
                    return True

    def _slot(self, frame: Frame, ref: InputRef) -> Slot:
        if ref.offset == 0:
            return frame.slots[ref.key]
        return self.program.rings[ref.key].get(frame.index + ref.offset)

    def _publish(self, frame: Frame, task: ExecTask, result, where, event=None):
        n = len(task.outputs)
        if n == 1:
            values = (result,)
        else:
            if not isinstance(result, (tuple, list)) or len(result) != n:
                raise TypeError(f"expected {n} outputs {task.outputs}, got "
                                f"{type(result).__name__}")
            values = tuple(result)
        for key, value in zip(task.outputs, values):
            frame.slots[key].set(value, where, event)

    def _ready_inputs(self, frame: Frame, task: ExecTask):
        """``task``'s input slots once all are set, and whether any had to be waited for."""
        slots = [self._slot(frame, ref) for ref in task.inputs]
        waited = False
        for s in slots:
            if not s.done.is_set():
                waited = True
                frame.wait_slot(s, self._closing, self.spin)
        return slots, waited

    def _run_cpu(self, proc: str, frame: Frame):
        io = self._io()
        for task in self.queues[proc]:
            if frame.cancel.is_set():
                return
            try:
                slots, _ = self._ready_inputs(frame, task)
                remote = [s for s in slots if s.where == DEVICE]
                if self.cuda:
                    for s in remote:
                        ev = s.event
                        if ev is not None:
                            _sync_event(ev)
                t0 = time.perf_counter()
                t_mid = None
                if remote:
                    before = io.moved
                    values = [s.host(io, ready=True) for s in slots]
                    t_mid = time.perf_counter()
                    if io.moved > before:
                        frame.copied[task.name] = io.moved - before
                else:
                    values = [s.value for s in slots]
                result = task.cpu(*values)
                t1 = time.perf_counter()
                self._publish(frame, task, result, HOST)
            except _Cancelled:
                return
            except BaseException as exc:  # noqa: BLE001 - reported to the caller
                self._fail(frame, task.name, proc, exc)
                return
            frame.trace[task.name] = (proc, t0, t1, t_mid)

    def _run_gpu_tasks(self, proc: str, frame: Frame):
        io = self._io()
        cuda = self.cuda
        stream = self._stream
        pool = self._events
        prev_end = None  # the last task's end event while the thread has not waited since
        for task in self.queues[proc]:
            if frame.cancel.is_set():
                return
            try:
                slots, waited = self._ready_inputs(frame, task)
                if waited:
                    prev_end = None  # the stream may idle while we waited: a fresh start event
                h0 = time.perf_counter()
                if cuda:
                    for s in slots:
                        if s.external and s.event is not None:
                            stream.wait_event(s.event)
                            prev_end = None
                    if prev_end is None:
                        ev0 = pool.get()
                        frame.events.append(ev0)
                        _record(stream, ev0)
                    else:
                        ev0 = prev_end
                before = io.moved
                values = [s.value if s.where == DEVICE else
                          s.device(io, self._upload_into(frame, ref))
                          for ref, s in zip(task.inputs, slots)]
                mid = None
                moved = io.moved - before
                if moved:
                    frame.copied[task.name] = moved
                    if not cuda:
                        mid = time.perf_counter()
                    elif moved >= TIMED_COPY_MIN_BYTES:
                        mid = pool.get()
                        frame.events.append(mid)
                        _record(stream, mid)
                if task.name in self._out_pools:
                    result = task.gpu(*values, out=self._lease(frame, task))
                else:
                    result = task.gpu(*values)
                if cuda:
                    ev1 = pool.get()
                    frame.events.append(ev1)
                    _record(stream, ev1)
                    h1 = time.perf_counter()
                    frame.gpu_last_event = ev1
                    self._publish(frame, task, result, DEVICE, ev1)
                    frame.trace[task.name] = (proc, ev0, ev1, mid)
                    prev_end = ev1
                else:
                    h1 = time.perf_counter()
                    self._publish(frame, task, result, DEVICE)
                    frame.trace[task.name] = (proc, h0, h1, mid)
                frame.host_trace[task.name] = (h0, h1)
            except _Cancelled:
                return
            except BaseException as exc:  # noqa: BLE001 - reported to the caller
                self._fail(frame, task.name, proc, exc)
                return

    def _lease(self, frame: Frame, task: ExecTask):
        pool = self._out_pools[task.name]
        try:
            buf = pool.pop()
        except IndexError:
            buf = task.gpu_out()
        frame.leases.append((task, buf))
        return buf

    def _upload_into(self, frame: Frame, ref: InputRef):
        """``into`` for uploading input ``ref`` of a GPU task (see :meth:`Transfers.upload`):
        buffers from the key's pool, leased to ``frame``; None where its uploads cannot be
        pooled."""
        if ref.offset or ref.key not in self._up_pools:
            return None
        return functools.partial(self._lease_upload, frame, ref.key)

    def _lease_upload(self, frame: Frame, key: str, shape, dtype):
        pool = self._up_pools[key]
        buf = None
        with self._up_lock:
            for i in range(len(pool) - 1, -1, -1):  # the newest first
                b = pool[i]
                if b.shape == shape and b.dtype is dtype:
                    buf = b
                    del pool[i]
                    break
        if buf is None:
            buf = _wp().empty(shape, dtype=dtype, device=self.gpu_device)
        frame.uploads.append((key, buf))
        return buf

    def _graph(self):
        """(task DAG of this frame's data edges, key -> producing task)."""
        producer = {k: t.name for t in self.program.tasks.values() for k in t.outputs}
        g = nx.DiGraph()
        g.add_nodes_from(self.program.tasks)
        g.add_edges_from((producer[r.key], t.name) for t in self.program.tasks.values()
                         for r in t.inputs if r.offset == 0 and r.key in producer)
        return g

    def _reuse_rule(self, g, tasks, keys) -> str:
        """When a buffer that ``tasks`` may see (and ``keys`` may hold) can be reused after
        its frame: ``"never"`` when a delay may hold it, ``"host"`` when a graph output may
        be it (reusable only if outputs went to the host as copies), ``"always"`` otherwise.
        Any task may return its input or a view of it (a pyramid's level 0 is its source), so
        everything downstream of ``tasks`` counts."""
        reach = set(tasks)
        for t in tasks:
            reach |= nx.descendants(g, t)
        keys = set(keys) | {k for t in reach for k in self.program.tasks[t].outputs}
        if keys & set(self.program.rings):
            return "never"
        if keys & set(self.program.outputs.values()):
            return "host"
        return "always"

    def _pool_rules(self) -> dict:
        """task -> when its pooled output buffer may be reused (:meth:`_reuse_rule`)."""
        if not self._out_pools:
            return {}
        g = self._graph()
        return {name: self._reuse_rule(g, [name], ()) for name in self._out_pools}

    def _upload_rules(self) -> dict:
        """key -> when the device copy of that host value, uploaded for the GPU tasks that
        read it in its frame, may be reused (:meth:`_reuse_rule`; a delayed key's slot, and
        the copy cached in it, outlive the frame: never)."""
        gpu = {t.name for p in self.processors if _is_gpu_processor(p) for t in self.queues[p]}
        readers: dict = {}
        for name in gpu:
            for r in self.program.tasks[name].inputs:
                readers.setdefault(r.key, set()).add(name)
        if not readers:
            return {}
        g = self._graph()
        return {key: self._reuse_rule(g, tasks, [key]) for key, tasks in readers.items()}

    def _release(self, frame: Frame, host: bool):
        """Frame waited for: its output and upload buffers go back to their pools where
        nothing else can still hold them (see :meth:`_reuse_rule`)."""
        for task, buf in frame.leases:
            if self._pool_rule[task.name] == "host" and not host:
                continue
            pool = self._out_pools[task.name]
            if len(pool) < 16:
                pool.append(buf)
        frame.leases = []
        if frame.uploads:
            with self._up_lock:
                for key, buf in frame.uploads:
                    if self._upload_rule[key] == "host" and not host:
                        continue
                    pool = self._up_pools[key]
                    if len(pool) >= self.UPLOAD_POOL:  # shapes vary: the oldest go
                        del pool[0]
                    pool.append(buf)
            frame.uploads = []

    def _fail(self, frame: Frame, task: str, proc: str, exc: BaseException):
        with self._lock:
            if frame.error is None:
                frame.error = (task, proc, exc)
            later = [f for f in self._inflight if f.index >= frame.index]
        frame.cancel.set()
        for f in later:
            if f is not frame and f.cancelled_by is None:
                f.cancelled_by = frame.index
            f.cancel.set()

    # ------------------------------------------------------------------ API

    def submit(self, frame_index: int, inputs: Mapping) -> Frame:
        """Start frame ``frame_index`` with ``inputs``: key -> ``(value, "host" | "device")``.

        Returns at once; the processors pick the frame up after the frames before it.
        """
        if self._closing.is_set():
            raise RuntimeError(f"executor {self.name!r} is closed")
        self._start()
        missing = [k for k in self.program.inputs if k not in inputs]
        if missing:
            raise WarpvxValueError(f"inputs: missing {missing} for frame {frame_index}")
        slots = {}
        events = []
        for key in self.program.inputs:
            value, where = inputs[key]
            slot = slots[key] = Slot.ready(value, where)
            if where == DEVICE and self.cuda:
                # The caller's device data may still be in flight on any stream: an event on
                # the legacy default stream completes after all work queued so far.
                wp = _wp()
                slot.event = self._events.get()
                events.append(slot.event)
                wp.get_device(self.gpu_device).null_stream.record_event(slot.event)
                slot.external = True
        for task in self.program.tasks.values():
            for key in task.outputs:
                slots[key] = Slot()
        frame = Frame(frame_index, slots, len(self._active))
        frame.events.extend(events)
        for key, ring in self.program.rings.items():
            ring.reserve(frame_index, slots[key])
        with self._lock:
            failed = [f.index for f in self._inflight if f.error is not None]
            self._inflight.append(frame)
        if failed:
            frame.cancelled_by = failed[0]
            frame.cancel.set()
        for p in self._active:
            self._inbox[p].put(frame)
        return frame

    def wait(self, frame: Frame, *, host: bool = True) -> FrameResult:
        """Wait for ``frame`` and return its outputs (host data when ``host``) and timeline.

        Raises
        ------
        NodeExecutionError
            A task of this frame raised (``__cause__`` is its exception), or the frame was
            cancelled because an earlier frame failed.
        """
        while not frame.finished.wait(WAIT_SLICE):
            dead = [p for p, th in self._threads.items() if not th.is_alive()]
            if dead:
                raise NodeExecutionError(f"{self.name}: executor thread(s) {dead} died")
        try:
            if frame.error is not None or frame.cancel.is_set():
                for ring in self.program.rings.values():
                    ring.discard_pending(frame.index)
            if frame.error is not None:
                task, proc, exc = frame.error
                raise NodeExecutionError(
                    f"{self.name}: node {task!r} on {proc} failed in frame {frame.index}: "
                    f"{type(exc).__name__}: {exc}"
                ) from exc
            if frame.cancel.is_set():
                raise NodeExecutionError(
                    f"{self.name}: frame {frame.index} was cancelled after frame "
                    f"{frame.cancelled_by} failed"
                )
            if self.cuda and frame.gpu_last_event is not None:
                _wp().synchronize_event(frame.gpu_last_event)
            io = self._io()
            outputs = {}
            for name, key in self.program.outputs.items():
                slot = frame.slots[key]
                outputs[name] = slot.host(io) if host else slot.value
            result = self._result(frame, outputs)
            self._recycle(frame)
            self._release(frame, host)
            for ring in self.program.rings.values():
                ring.age(frame.index)
            return result
        finally:
            with self._lock:
                if frame in self._inflight:
                    self._inflight.remove(frame)

    def _recycle(self, frame: Frame):
        """Every GPU task of the frame has completed: its events go back to the pool. Slots
        that outlive the frame (delays) forget them: their data is ready for any reader."""
        if not frame.events:
            return
        mine = {id(e) for e in frame.events}
        for slot in frame.slots.values():
            if slot.event is not None and id(slot.event) in mine:
                if slot.external:  # the caller's copy, which no task of the frame may have awaited
                    _wp().synchronize_event(slot.event)
                slot.event = None
                slot.external = False
        self._events.put(frame.events)
        frame.events = []
        frame.gpu_last_event = None

    def _result(self, frame: Frame, outputs: dict) -> FrameResult:
        """Outputs plus the frame's measured timeline (ms from submission)."""
        timeline, transfers, host = {}, {}, {}
        t0 = frame.t0
        to_host = self._event_clock() if self.cuda else None
        for task, (proc, a, b, mid) in frame.trace.items():
            if to_host is not None and _is_gpu_processor(proc):
                a, b = to_host(a), to_host(b)
                mid = None if mid is None else to_host(mid)
            timeline[task] = ScheduledTask(task, proc, (a - t0) * 1e3, (b - t0) * 1e3)
            if mid is not None:
                transfers[task] = (mid - a) * 1e3
        for task, (a, b) in frame.host_trace.items():
            host[task] = ((a - t0) * 1e3, (b - t0) * 1e3)
        return FrameResult(frame.index, outputs, timeline, t0, transfers, dict(frame.copied), host)

    def _event_clock(self):
        """event -> host seconds, through the anchor; each event read once."""
        wp = _wp()
        base, anchor = self._anchor
        seen = {}

        def convert(ev):
            t = seen.get(id(ev))
            if t is None:
                t = seen[id(ev)] = base + wp.get_event_elapsed_time(anchor, ev, synchronize=False) / 1e3
            return t

        return convert

    def abort(self):
        """Cancel every frame in flight and wait until the processors have dropped them."""
        with self._lock:
            frames = list(self._inflight)
        for f in frames:
            f.cancel.set()
        for f in frames:
            while not f.finished.wait(WAIT_SLICE):
                if not any(th.is_alive() for th in self._threads.values()):
                    break
            for ring in self.program.rings.values():
                ring.discard_pending(f.index)
        with self._lock:
            self._inflight = [f for f in self._inflight if f not in frames]

    @property
    def in_flight(self) -> int:
        with self._lock:
            return len(self._inflight)

    def close(self):
        """Cancel what is in flight and stop the threads (idempotent)."""
        if self._closing.is_set():
            return
        self.abort()
        self._closing.set()
        for p in self._threads:
            self._inbox[p].put(None)
        for th in self._threads.values():
            th.join(timeout=5.0)
        self._threads.clear()


def run_schedule(schedule: Schedule, program: Program, inputs: Mapping, *, gpu_device=None,
                 frame_index: int = 0) -> FrameResult:
    """Run one frame of ``program`` with a throw-away :class:`Executor` (tests, examples)."""
    ex = Executor(schedule, program, gpu_device=gpu_device, name="run")
    try:
        return ex.wait(ex.submit(frame_index, inputs))
    finally:
        ex.close()

__all__ = [
    "EventPool",
    "Executor",
    "ExecTask",
    "Flag",
    "FrameResult",
    "InputRef",
    "Program",
    "Ring",
    "Slot",
    "Transfers",
    "SPIN_SECONDS",
    "WAIT_SLICE",
    "run_schedule",
    "tree_map",
]
