"""Run a :class:`~warpvx.sched.schedule.Schedule` for real: CPU worker threads beside one GPU queue.

The executor is the runtime half of SPEC §7. It knows nothing of graphs: it runs a
:class:`Program` (tasks with named inputs and outputs and one callable per processing
element) according to a schedule, frame after frame.

Roles and threads
    Each processor of the schedule is a *role* with a thread of its own. A CPU worker
    (``"cpu<i>"``) runs its tasks' CPU callables in schedule order on host data (NumPy/OpenCV
    release the GIL, so workers overlap). The GPU role (``"gpu"``) runs the GPU callables in
    schedule order with the device's current stream set to the executor's ``wp.Stream``; on
    CUDA the calls only enqueue kernels, so its thread runs ahead of the device. With a
    one-frame schedule a role's next unit (a task, or a GPU segment) runs on whichever thread
    holds the role's token: its own thread while it has ready work, or *inline* on the
    thread whose output made it ready when that thread's own role has nothing ready and the
    unit is short (:attr:`Executor.INLINE_MAX_MS`): a serial chain alternating CPU and GPU
    tasks then runs on one thread, with no thread wake-up per hand-off (10-30 us each under
    the GIL), and keeps the GPU role's device and stream current across its short CPU units
    (:class:`~.roles.DeviceScope`: no stream and context switch per hand-off). Nobody blocks on a value: a role's thread sleeps on its signal until a producer
    finds the role ready and not taken; a producer going on with its own work wakes the
    ready readers of what it published at once. A caller waiting for a frame alone in
    flight runs its ready units itself first (:meth:`Executor._help`), so a frame run one at
    a time needs no thread wake-up at its start or end. With a K-frame schedule each thread
    runs its own role and blocks on each value it needs.
Cross-queue edges
    Every (frame, value) pair is a :class:`Slot`, set when its producer has finished (CPU) or
    enqueued (GPU). GPU -> CPU: the producer's end event is recorded on the stream; on
    CUDA, where a CPU task of the frame or of a later one (a delay's value) or the caller (a
    graph output) reads the value, the GPU role then starts its download at once
    (:meth:`Transfers.stage_download`: pinned buffers of the executor's
    :class:`~.pinned.HostPool`, on the GPU role's copy stream after the producer's event, or
    for a value under
    :attr:`Transfers.SAME_STREAM_MAX_BYTES` on the compute stream right behind its
    producer), so the compute stream runs on while the DMA runs and the reader waits for
    the copy's event only, then gets NumPy views of the pinned buffers (no
    host copy; a buffer returns to the pool once every array on it is garbage). A download
    nobody read is waited for and dropped when its frame is waited for, or for a delay's
    value when the ring drops its slot (aged out, reset, cancelled, or the executor closes):
    the next frame's reader of ``delay[-1]`` finds it staged. Otherwise (the pool full, a
    vector dtype) the reader waits for the producer's event and downloads on its thread's
    copy stream.
    CPU -> GPU: the GPU role uploads on the GPU stream (stream-ordered, so the kernel after
    it sees the data; large arrays go through reusable pinned staging buffers, so the copy is
    asynchronous and the host does not wait for the kernels queued before it). Between two
    GPU tasks data stays on the device: one in-order stream needs no synchronisation at all.
Timing
    CPU tasks: host ``time.perf_counter`` before the task's downloads and after its call
    (waiting for a producer is not counted). GPU tasks on CUDA: timing events recorded on the
    stream before the task's uploads and after its kernels, mapped to the host clock through
    an anchor event recorded while the stream was idle (:meth:`Executor.reanchor`), so a GPU
    interval is when the device ran it, not when the host enqueued it. When the GPU role
    did not have to wait between two tasks, the first one's end event is the second one's
    start (one event per task, not two). Events come from a pool (a frame's worth made at
    its submission when short, never inside a timed GPU call) and return to it once their
    frame has been waited for and its timeline read: the timeline is read lazily (a native
    call per event, on the caller's thread at the end of every frame otherwise, while most
    timelines are never read; see :meth:`~.timeline.EventPool.lend`). The host-side time of each GPU call (enqueue plus any host
    syncs inside the primitive) is kept too (:attr:`FrameResult.host`), and so is the time
    each task spent on transfers (:attr:`FrameResult.transfers`). Without CUDA (the
    ``"warp-cpu"`` GPU role) calls are synchronous and host times are used; events are not
    used at all. An event costs host time twice, its record and its conversion when the
    frame's timeline is made (a few us each on an H100's host): with ``timing="bursts"``
    (:class:`Executor`; by default for frames submitted behind others still in flight) a
    run of GPU tasks gets one end event, recorded where a value leaves the GPU stream (a
    CPU task, the caller or a delay reads it), before a task with uploads, at the end of
    the frame's GPU queue or when its thread leaves the GPU role; the tasks in between
    share the interval by scheduled durations, as a captured segment's do.
Buffers
    A task may come with ``gpu_out``, a factory of its output buffer: the executor then calls
    ``gpu(*values, out=buffer)`` with a buffer from the task's pool and returns the buffer to
    the pool once the frame has been waited for (unless a delay keeps the value or it was
    handed to the caller on the device), so steady-state frames allocate nothing for it.
    Uploads on CUDA work the same way: each host value a GPU task reads is copied into a
    device buffer from a pool of that edge (allocating a ``wp.array`` costs more host time
    than a small copy), returned under the same rules (:meth:`Executor._reuse_rule`).
Capture
    The GPU queue is cut into segments (:func:`~warpvx.runtime.capture.segments`): runs of
    consecutive capturable tasks between CPU hand-offs, and single eager tasks. With capture
    on (CUDA by default; ``capture=`` per executor or per frame), each segment is captured
    as one graph per input signature on its second frame of that signature and replayed
    after: its inputs copied into fixed buffers, one launch, the values read outside it
    copied out into the frame's buffers, one pair of timing events around it (its tasks
    share the interval in proportion to their scheduled durations). A segment that cannot
    be captured runs eagerly; capture is never an error.
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
K frames in flight
    A schedule of a DAG unrolled over K frames (:func:`warpvx.sched.frames.unroll`: tasks
    ``(task, f)``, f < K) is run cyclically: frame *i* takes slot ``f = i mod K``, so frames
    0..K-1 run with the K-frame schedule's placement, K..2K-1 again with the same one. Each
    processor's queue is the K-frame schedule's order of ``(task, f)`` entries and runs on a
    :class:`~.cycles.Batch`, consecutive frames of one cycle: an entry waits until its frame is
    submitted, or is skipped once the batch is closed without it (a cycle is closed when its
    K frames are in, when the caller waits for one of its frames, or on abort), so a run that
    is not a multiple of K frames, one :meth:`Executor.wait` at a time, never waits for
    frames that will not come. Captured segments need one frame's GPU tasks consecutive on
    the queue, which a K-frame order interleaves: with K > 1 GPU tasks run eagerly.
Errors
    A task that raises fails its frame: that frame and every later frame in flight are
    cancelled (the roles are woken and skip their remaining units; a K-frame schedule's waits
    see the cancel flag within :data:`WAIT_SLICE` seconds), earlier frames complete, and :meth:`Executor.wait` raises
    :class:`~warpvx.errors.NodeExecutionError` with the task's exception as ``__cause__``. No
    wait is unbounded: each checks its frame's cancel flag and the executor's shutdown flag.
"""

from __future__ import annotations

import collections
import functools
import queue
import threading
import time
from time import perf_counter
from collections import OrderedDict
from collections.abc import Mapping

import networkx as nx

from ..check import check_bool
from ..errors import NodeExecutionError, ScheduleError, WarpvxValueError
from ..sched.schedule import Schedule
from .capture import segments, signature
from .segment_runner import SegmentRunner
from .cycles import Batch, frames_of
from .native_copy import recorder, synchronize_event, warp
from .pinned import HostPool
from .program import ExecTask, InputRef, Program, data_graph
from .roles import DeviceScope, GpuState, RoleRunner, is_gpu_processor
from .slots import DEVICE, HOST, Slot
from .timeline import (WAIT_SLICE, Cancelled, EventPool, Frame, FrameResult, frame_result,
                       proportional_shares)
from .transfers import Transfers

#: Default of :class:`Executor`'s ``spin``: seconds a thread polls for a value (yielding the
#: GIL between polls) before it blocks on it. Blocking costs a thread wake-up per hand-off.
SPIN_SECONDS = 0.0

#: A GPU task's uploads of this many bytes or more get a timing event of their own (the
#: task's transfer time); a smaller copy is not worth an event.
TIMED_COPY_MIN_BYTES = 1 << 16


class Executor(RoleRunner, SegmentRunner):
    """Run ``program`` according to ``schedule`` on CPU worker threads and a GPU host thread.

    Parameters
    ----------
    schedule : Schedule
        Every task of ``program`` placed once; processors ``"cpu<i>"`` and ``"gpu"``. Or a
        K-frame schedule (of :func:`warpvx.sched.frames.unroll`'s DAG): every ``(task, f)``,
        f < K, placed once; frame *i* then runs as ``f = i mod K`` (see the module docstring).
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
    capture : bool, optional
        Replay GPU segments from captured graphs (:mod:`.capture`) by default: None (the
        default) on CUDA only; True also on Warp's CPU device; False never.
        :meth:`submit` can turn it off (or on) per frame. Never with K > 1 frames.
    timing : {"tasks", "bursts"}, optional
        How eager GPU tasks are timed on CUDA (:attr:`timing`; see the module docstring):
        ``"tasks"``, an end event per task (each task's own device interval: what the cost
        model learns a node's GPU time from); ``"bursts"``, an end event only where a value
        leaves the GPU stream or a run of tasks ends, the tasks between two events sharing
        that interval in proportion to their scheduled durations (a captured segment's
        rule; host times stay per task). None (default): ``"tasks"`` for a frame submitted
        alone (``Graph.process``), ``"bursts"`` for one submitted behind frames still in
        flight (a pipelined stream).

    Raises
    ------
    ScheduleError
        A task unscheduled or scheduled twice, a task on a processor it has no callable for,
        an unknown processor, or per-processor orders that contradict the data dependencies
        (running them would deadlock; with K frames, also the delays' reads across frames).
    """

    #: Device buffers kept per pooled upload edge (a few frames in flight, several leaves).
    UPLOAD_POOL = 16
    #: Output buffers kept per pooled GPU task (a few frames in flight).
    OUT_POOL = 16
    #: Bytes of pinned host memory for staged downloads (:class:`~.pinned.HostPool`), free
    #: and lent to the caller's outputs together; past it, downloads are synchronous.
    HOST_POOL_BYTES = 256 << 20
    #: Stage downloads on Warp's CPU device too, into plain host buffers (the copies are
    #: synchronous there: no gain; for tests of the staged path without CUDA).
    STAGE_ON_HOST = False

    def __init__(self, schedule: Schedule, program: Program, *, gpu_device: str | None = None,
                 name: str = "graph", spin: float | None = None, capture: bool | None = None,
                 timing: str | None = None):
        self.spin = SPIN_SECONDS if spin is None else float(spin)
        self.schedule = schedule
        self.program = program
        self.name = name
        self.processors = list(schedule.processors)
        self.gpu_device = gpu_device
        self.cuda = bool(gpu_device) and str(gpu_device).startswith("cuda")
        #: K: frames of the schedule's cycle (1 for a one-frame schedule).
        self.frames, keys = frames_of(schedule)
        unknown = [k for k, (t, _) in keys.items() if t not in program.tasks]
        if unknown:
            raise ScheduleError(f"schedule: places unknown task {unknown[0]!r}")
        self.placed = {keys[k]: st for k, st in schedule.tasks.items()}  # (task, slot) -> when
        self._data = data_graph(program)
        try:
            self._topo = {n: i for i, n in enumerate(nx.topological_sort(self._data))}
        except nx.NetworkXUnfeasible:
            raise ScheduleError("program: its data dependencies have a cycle") from None
        # processor -> its (task, slot) entries in schedule order; queues: their tasks (the
        # one-frame order when K == 1).
        self.entries = {p: [(program.tasks[t], f) for t, f in self._order(p)] for p in self.processors}
        self.queues = {p: [t for t, _ in self.entries[p]] for p in self.processors}
        self._check()
        # The GPU thread first: it hands frames out in this order, and the threads woken
        # first take Python's GIL first; the GPU thread (Python-heavy, usually the critical
        # path) should not start its frame behind every CPU worker's Python prologue.
        self._active = sorted((p for p in self.processors if self.queues[p]),
                              key=lambda p: not is_gpu_processor(p))
        # slot -> processors a frame of that slot waits for; processor -> slot -> its last entry.
        self._slot_procs = [sum(any(f == s for _, f in self.entries[p]) for p in self._active)
                            for s in range(self.frames)]
        self._last = {p: {f: i for i, (_, f) in enumerate(self.entries[p])} for p in self._active}
        self._batch: Batch | None = None  # the open batch (K > 1)
        self._inbox = {p: queue.SimpleQueue() for p in self._active}
        self._threads: dict[str, threading.Thread] = {}
        self._closing = threading.Event()
        self._inflight: list[Frame] = []
        self._lock = threading.Lock()
        self._local = threading.local()
        self._stream = None
        self._record = None  # event -> recorded on _stream (CUDA)
        self._anchor = None  # (host seconds, timing event) on CUDA
        self._events = EventPool(gpu_device) if self.cuda else None
        self._gpu_tasks = {t.name for p in self.processors if is_gpu_processor(p)
                           for t in self.queues[p]}
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
        self._up_lock = threading.Lock()  # the GPU role leases, wait() returns
        # (frame index, [(an output pool's?, task or key, buffer)]) of frames waited for whose
        # buffers a delay may still hold, oldest first (_recycle_ring_held).
        self._ring_held: collections.deque = collections.deque()
        gpu_queue = [t.name for p in self.processors if is_gpu_processor(p) for t in self.queues[p]]
        # Timing events a frame may take at most (CUDA): a start, an end and an upload's per
        # GPU task, one per device input; made ahead at submission (EventPool.reserve).
        self._events_per_frame = 3 * len(gpu_queue) + len(program.inputs)
        # A captured segment is one frame's consecutive GPU tasks; a K-frame order interleaves
        # frames on the GPU queue, so with K > 1 nothing is captured (every task runs eagerly).
        self._segments = segments(program, gpu_queue) if self.frames == 1 else []
        # Every task's scheduled duration: its share of a captured segment's or a timing
        # burst's measured interval.
        self._spans = {t: st.finish - st.start for (t, f), st in self.placed.items() if f == 0}
        self._seg_info = self._segment_info()  # captured segments' shares and keys
        self.timing = timing
        # Timing "bursts": GPU tasks whose end needs an event of its own (a value read off
        # the GPU stream: by a CPU task, the caller, a delay; or the GPU queue's last task).
        self._leaves_stream = self._off_stream_tasks(gpu_queue)
        capture = check_bool(capture, "capture", allow_none=True)
        self.capture = bool(gpu_device) and self.frames == 1 and \
            (self.cuda if capture is None else capture)
        # A one-frame GPU queue with a segment that may be captured (a frame's capture flag is
        # False without one).
        self._capturable = bool(gpu_device) and self.frames == 1 and \
            any(seg.captured for seg in self._segments)
        self.captures = 0  # segments captured so far (each signature's once)
        #: Device buffers allocated so far for pooled GPU outputs, uploads and captured
        #: segments' copies out (a steady stream allocates none).
        self.fresh_buffers = 0
        self.replays = 0  # captured graphs launched (frames x segments)
        self._captured: OrderedDict = OrderedDict()  # input signature -> per-segment state
        # Held while capturing and while recording on the legacy stream (submit): that
        # stream synchronises with ours, which a capture forbids. One lock for the process,
        # shared with the recorded launches' own captures (kernels_warp._launch).
        from ..kernels_warp._launch import capture_lock

        self._capture_lock = capture_lock
        for seg in self._segments:  # copy-out buffers of captured segments: pooled per key
            for key in seg.outputs:
                rule = self._upload_rule[key] = self._copy_rule(seg, key)
                if rule != "never":
                    self._up_pools.setdefault(key, [])
                else:
                    self._up_pools.pop(key, None)
        self._null_stream = None  # the device's legacy stream (CUDA), looked up once
        self._task_keys = [k for t in program.tasks.values() for k in t.outputs]
        self._host_alone = self._sole_host_readers()
        # The slots a frame's events may outlive it in (_forget_events): the caller's inputs and
        # the delays' (kept by their rings); the others go with the frame.
        self._outliving = list(dict.fromkeys([*program.inputs, *program.rings]))
        stage = self.cuda or (bool(gpu_device) and self.STAGE_ON_HOST)
        self._host_pool = HostPool(self.HOST_POOL_BYTES, pinned=self.cuda) if stage else None
        self._roles = self._make_roles() if self.frames == 1 else {}
        self._scope: DeviceScope | None = None  # the GPU role's device/stream (set by _start)

    # ------------------------------------------------------------------ checks

    def _order(self, proc: str) -> list:
        """``(task, slot)`` entries on ``proc`` by start time; ties (zero-cost tasks) by frame,
        then in dependency order."""
        on = [(st, e) for e, st in self.placed.items() if st.processor == proc]
        on.sort(key=lambda x: (x[0].start, x[0].finish, x[1][1], self._topo.get(x[1][0], 0)))
        return [e for _, e in on]

    def _sole_host_readers(self) -> set:
        """CPU tasks each of whose inputs no one else reads on the host (no other CPU task,
        not the caller: not a graph output, not a delay's value): they download their device
        inputs without a copy lock (:meth:`Slot.host`'s ``alone``)."""
        cpu_tasks = {t.name: t for p in self.processors if not is_gpu_processor(p)
                     for t in self.queues[p]}
        reads = collections.Counter(r.key for t in cpu_tasks.values() for r in t.inputs)
        shared = set(self.program.outputs.values()) | set(self.program.rings)
        return {name for name, t in cpu_tasks.items()
                if all(r.offset == 0 and reads[r.key] == 1 and r.key not in shared
                       for r in t.inputs)}

    def _label(self, task: str, slot: int):
        """How messages name entry ``(task, slot)``: the task alone for one frame."""
        return task if self.frames == 1 else (task, slot)

    def _check(self):
        placed = {}
        for p in self.processors:
            for task, f in self.entries[p]:
                label = self._label(task.name, f)
                if label in placed:
                    raise ScheduleError(f"schedule: task {label!r} is placed on both "
                                        f"{placed[label]!r} and {p!r}")
                placed[label] = p
                kind = "gpu" if is_gpu_processor(p) else "cpu"
                if getattr(task, kind) is None:
                    raise ScheduleError(f"schedule: task {label!r} is placed on {p!r} but has "
                                        f"no {kind.upper()} implementation")
        missing = [self._label(t, f) for f in range(self.frames) for t in self.program.tasks
                   if self._label(t, f) not in placed]
        if missing:
            raise ScheduleError(f"schedule: tasks {missing!r} are not scheduled")
        gpus = [p for p in self.processors if is_gpu_processor(p)]
        if len(gpus) > 1:
            raise ScheduleError(f"schedule: one GPU processor is supported, got {gpus}")
        if any(is_gpu_processor(p) and self.queues[p] for p in self.processors) and not self.gpu_device:
            raise ScheduleError("schedule: tasks are placed on the GPU but no gpu_device was given")
        # Data edges (each slot's, and delayed reads of an earlier slot of the cycle) plus
        # each processor's order must be acyclic, or some wait never returns. A later cycle
        # reads only earlier ones and every processor ends a cycle before the next: acyclic.
        g = nx.DiGraph()
        k = self.frames
        producer = {key: t.name for t in self.program.tasks.values() for key in t.outputs}
        for f in range(k):
            g.add_edges_from(((u, f), (v, f)) for u, v in self._data.edges)
            g.add_edges_from(((producer[r.key], f + r.offset), (t.name, f))
                             for t in self.program.tasks.values() for r in t.inputs
                             if r.offset < 0 and f + r.offset >= 0 and r.key in producer)
        for p in self.processors:
            names = [(t.name, f) for t, f in self.entries[p]]
            g.add_edges_from(zip(names, names[1:]))
        if not nx.is_directed_acyclic_graph(g):
            cyc = " -> ".join(str(self._label(*u)) for u, _ in nx.find_cycle(g))
            raise ScheduleError(f"schedule: processor orders contradict data dependencies "
                                f"(would deadlock): {cyc}")

    # ------------------------------------------------------------------ threads

    def _io(self) -> Transfers:
        io = getattr(self._local, "io", None)
        if io is None:
            io = self._local.io = Transfers(self.gpu_device, self._host_pool)
        return io

    def _start(self):
        if self._threads:
            return
        if self.gpu_device:
            wp = warp()
            device = wp.get_device(self.gpu_device)
            if self.cuda:
                self._stream = wp.Stream(device)
                self._record = recorder(self._stream)
                self.reanchor()
            self._scope = DeviceScope(device, self._stream)
        loop = self._role_loop if self._roles else self._loop
        for p in self._active:
            th = threading.Thread(target=loop, args=(p,), name=f"warpvx-{self.name}-{p}",
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
        wp = warp()
        wp.synchronize_stream(self._stream)
        ev = wp.Event(self.gpu_device, enable_timing=True)
        t_before = time.perf_counter()
        self._stream.record_event(ev)
        wp.synchronize_event(ev)
        t_after = time.perf_counter()
        self._anchor = (0.5 * (t_before + t_after), ev)

    def _loop(self, proc: str):
        """A processor's thread with a K-frame schedule: batches from its inbox."""
        gpu = is_gpu_processor(proc)
        inbox = self._inbox[proc]
        while True:
            item = inbox.get()
            if item is None:
                return
            if gpu:
                if self._gpu_frames(proc, item, inbox):
                    return
            else:
                self._run_batch(proc, item)

    def _run_batch(self, proc: str, batch: Batch):
        """``proc``'s ``(task, slot)`` entries for the frames of ``batch``, in the K-frame
        schedule's order; a frame is done on ``proc`` after its slot's last entry there."""
        gpu = is_gpu_processor(proc)
        io = self._io()
        state = GpuState(proc, io) if gpu else None
        last = self._last[proc]
        current = None
        for i, (task, slot) in enumerate(self.entries[proc]):
            frame = batch.frame(slot, self._closing)
            if frame is None:
                continue
            try:
                if frame.cancel.is_set():
                    continue
                if not gpu:
                    self._run_cpu_task(proc, frame, task, io)
                    continue
                if frame is not current:
                    # A fresh start event: the last end event is another frame's (pooled with
                    # it) and the stream ran that frame's work in between.
                    state.prev_end, current = None, frame
                self._run_gpu_task(frame, task, state)
            except Cancelled:
                pass
            except BaseException as exc:  # noqa: BLE001 - reported to the caller
                self._fail(frame, task.name, proc, exc)
            finally:
                if i == last[slot]:
                    frame.processor_done()

    def _gpu_frames(self, proc: str, item, inbox) -> bool:
        """Run ``item`` (a batch) and those queued behind it in one device/stream
        scope (entering and leaving the scope per frame costs host time on the critical
        thread). Returns True when the stop sentinel came."""
        with self._scope:
            while True:
                self._run_batch(proc, item)
                try:
                    item = inbox.get_nowait()
                except queue.Empty:
                    return False
                if item is None:
                    return True

    def _slot(self, frame: Frame, ref: InputRef) -> Slot:
        if ref.offset == 0:
            return frame.slots[ref.key]
        return self.program.rings[ref.key].get(frame.index + ref.offset)

    def _publish(self, frame: Frame, task: ExecTask, result, where, event=None, state=None):
        """Set ``task``'s output slots of ``frame`` to ``result``; a GPU task's (``state``:
        the GPU role's) through :meth:`_set_devices`, which stages the downloads due."""
        if task.output is not None:
            frame.slots[task.output].set(result, where, event)
            return
        n = len(task.outputs)
        if not isinstance(result, (tuple, list)) or len(result) != n:
            raise TypeError(f"expected {n} outputs {task.outputs}, got {type(result).__name__}")
        if state is not None:
            self._set_devices(frame, task.outputs, result, event, state, unit=task.name)
            return
        for key, value in zip(task.outputs, result):
            frame.slots[key].set(value, where, event)

    def _ready_inputs(self, frame: Frame, refs):
        """The slots of input references ``refs`` (a task's or a captured segment's) once all
        are set, and whether any had to be waited for."""
        fs = frame.slots
        slots = [fs[ref.key] if ref.offset == 0 else self._slot(frame, ref) for ref in refs]
        waited = False
        for s in slots:
            if not s.ready:
                waited = True
                frame.wait_slot(s, self._closing, self.spin)
        return slots, waited

    def _run_cpu_task(self, proc: str, frame: Frame, task: ExecTask, io: Transfers,
                      slots: list | None = None) -> bool:
        """One CPU task: waits for its inputs (unless given their ``slots``, all set),
        downloads device ones, calls, publishes. False when the frame was cancelled
        meanwhile or the task failed (reported)."""
        try:
            if slots is None:
                slots, _ = self._ready_inputs(frame, task.inputs)
            remote = False
            for s in slots:
                if s.where == DEVICE:
                    remote = True
                    break
            t_mid = None
            if not remote:
                t0 = perf_counter()
                # (A comprehension: no call from Python 3.12 (PEP 709), one before, as one
                # append would be.)
                values = [s.value for s in slots]
            elif self.cuda:
                # Waiting for the producer (or its staged download) is not the task's time.
                waited = [s.ready_event() if s.where == DEVICE else None for s in slots]
                for ev in waited:
                    if ev is not None:
                        synchronize_event(ev)
                t0 = perf_counter()
                before = io.moved
                alone = task.name in self._host_alone
                values = [s.host(io, waited=ev, alone=alone) for s, ev in zip(slots, waited)]
            else:  # (Warp's CPU device: nothing to wait for)
                t0 = perf_counter()
                before = io.moved
                alone = task.name in self._host_alone
                values = [s.host(io, alone=alone) for s in slots]
            if remote:
                t_mid = perf_counter()
                if io.moved > before:
                    frame.copied[task.name] = io.moved - before
            result = task.cpu(*values)
            t1 = perf_counter()
            if task.output is not None:  # the usual task: _publish's one-output case, inline
                frame.slots[task.output].set(result, HOST)
            else:
                self._publish(frame, task, result, HOST)
        except Cancelled:
            return False
        except BaseException as exc:  # noqa: BLE001 - reported to the caller
            self._fail(frame, task.name, proc, exc)
            return False
        frame.trace[task.name] = (proc, t0, t1, t_mid)
        return True

    def _start_event(self, frame: Frame, state: "GpuState", slots, waited: bool):
        """The timing event a GPU task (or segment) starts at, after making the stream wait
        for the caller's device inputs among ``slots`` (CUDA)."""
        if waited:
            state.prev_end = None  # the stream may idle while we waited: a fresh start event
        stream = self._stream
        for s in slots:
            if s.external and s.event is not None:
                stream.wait_event(s.event)
                state.prev_end = None
        if state.prev_end is not None:
            return state.prev_end
        ev0 = self._events.get()
        frame.events.append(ev0)
        self._record(ev0)
        return ev0

    def _end_event(self, frame: Frame):
        ev1 = self._events.get()
        frame.events.append(ev1)
        self._record(ev1)
        frame.gpu_last_event = ev1
        return ev1

    def _off_stream_tasks(self, gpu_queue: list) -> set:
        """GPU tasks of ``gpu_queue`` with an output read off the GPU stream, plus the last."""
        gpu = set(gpu_queue)
        off = {r.key for t in self.program.tasks.values() if t.name not in gpu for r in t.inputs}
        off |= set(self.program.outputs.values()) | set(self.program.rings)
        leaves = {t for t in gpu_queue if off.intersection(self.program.tasks[t].outputs)}
        return leaves | set(gpu_queue[-1:])

    def _close_burst(self, state: "GpuState"):
        """Timing ``"bursts"``: one end event (on Warp's CPU device, a host time) for the
        tasks run since the burst's start (``state.burst``); they share the interval in
        proportion to their scheduled durations, as a captured segment's tasks do. Returns
        the event: the next task's start."""
        names, frame = state.burst, state.burst_frame
        state.burst = []
        if self.cuda:
            ev1 = state.prev_end = self._end_event(frame)
        else:
            ev1 = perf_counter()
        trace = frame.trace
        proc, ev0, _, mid = trace[names[0]]  # the burst's start (on CUDA every task's)
        if len(names) == 1:
            trace[names[0]] = (proc, ev0, ev1, mid)
            return ev1
        for n, share in zip(names, proportional_shares([self._spans[n] for n in names])):
            trace[n] = (proc, ev0, ev1, trace[n][3])
            frame.shares[n] = share
        return ev1

    def _run_gpu_task(self, frame: Frame, task: ExecTask, state: "GpuState",
                      slots: list | None = None):
        """One GPU task, enqueued eagerly: waits for its inputs (unless given their
        ``slots``, all set), uploads, the call (into a pooled output buffer where it has
        one), timing events (CUDA) and its outputs published."""
        name = state.task = task.name
        cuda = self.cuda
        io = state.io
        if slots is None:
            slots, waited = self._ready_inputs(frame, task.inputs)
        else:
            waited = False
        if state.burst:  # a task with uploads or a wait starts at an event of its own
            close = waited
            for s in slots:  # (a loop: no generator call per task)
                if s.where != DEVICE or s.external:
                    close = True
                    break
            if close:
                self._close_burst(state)
        h0 = perf_counter()
        if cuda:
            ev0 = state.prev_end  # the usual start: the last task's end, nothing to wait for
            for s in slots:
                if s.external:
                    ev0 = None
                    break
            if ev0 is None or waited:
                ev0 = self._start_event(frame, state, slots, waited)
        else:
            ev0 = h0
        before = io.moved
        up_pools = self._up_pools  # (none for a delay's value, nor on Warp's CPU device)
        values = [s.value if s.where == DEVICE else s.device(
                      io, None if ref.offset or ref.key not in up_pools else
                      functools.partial(self._lease_upload, frame, ref.key))
                  for ref, s in zip(task.inputs, slots)]
        mid = None
        moved = io.moved - before
        if moved:
            frame.copied[name] = moved
            if not cuda:
                mid = perf_counter()
            elif moved >= TIMED_COPY_MIN_BYTES:
                mid = self._events.get()
                frame.events.append(mid)
                self._record(mid)
        if name in self._out_pools:
            result = task.gpu(*values, out=self._lease(frame, task))
        else:
            result = task.gpu(*values)
        if frame.bursts:
            frame.trace[name] = (state.proc, ev0, None, mid)  # its end: the burst's
            if not state.burst:
                state.burst_frame = frame
                if cuda:
                    state.prev_end = ev0  # the next tasks start at the burst's start event
            state.burst.append(name)
            # An end event only where a reader off the stream needs one (or the frame ends).
            ev1 = self._close_burst(state) if name in self._leaves_stream else None
            h1 = perf_counter()
            if not cuda:
                ev1 = None
        elif cuda:
            ev1 = state.prev_end = self._end_event(frame)
            h1 = perf_counter()
            frame.trace[name] = (state.proc, ev0, ev1, mid)
        else:
            ev1 = None
            h1 = perf_counter()
            frame.trace[name] = (state.proc, h0, h1, mid)
        frame.host_trace[name] = (h0, h1)
        if task.output is None:
            self._publish(frame, task, result, DEVICE, ev1, state)
        elif state.stage:
            self._set_devices(frame, (task.output,), (result,), ev1, state, unit=name)
        else:  # the usual task: _publish's one-output case, inline
            frame.slots[task.output].set(result, DEVICE, ev1)

    def _lease(self, frame: Frame, task: ExecTask):
        pool = self._out_pools[task.name]
        try:
            buf = pool.pop()
        except IndexError:
            buf = task.gpu_out()
            self.fresh_buffers += 1
        frame.leases.append((task, buf))
        return buf

    def _lease_upload(self, frame: Frame, key: str, shape, dtype):
        """A device buffer for value ``key`` of ``frame`` (an upload or a captured segment's
        copy-out): from the key's pool when it has one, else fresh."""
        pool = self._up_pools.get(key)
        if pool is None:
            self.fresh_buffers += 1
            return warp().empty(shape, dtype=dtype, device=self.gpu_device)
        buf = None
        with self._up_lock:
            for i in range(len(pool) - 1, -1, -1):  # the newest first
                b = pool[i]
                if b.shape == shape and b.dtype is dtype:
                    buf = b
                    del pool[i]
                    break
        if buf is None:
            buf = warp().empty(shape, dtype=dtype, device=self.gpu_device)
            self.fresh_buffers += 1
        frame.uploads.append((key, buf))
        return buf

    def _reuse_rule(self, g, tasks, keys) -> str:
        """When a buffer that ``tasks`` may see (and ``keys`` may hold) can be reused after
        its frame: ``"ring"`` when a delay may hold it (once every delay has let the frame
        go: :meth:`_recycle_ring_held`), ``"never"`` when a graph output may be it too,
        ``"host"`` when a graph output may be it (reusable only if outputs went to the host
        as copies), ``"always"`` otherwise. Any GPU task may return its input or a view of it
        (a pyramid's level 0 is its source), so every GPU task downstream of ``tasks`` through
        GPU tasks counts; a CPU task gets host copies, so what it makes never holds the buffer."""
        gpu = self._gpu_tasks
        tasks_of = self.program.tasks
        keys = set(keys)
        reach: set = set()
        todo = [t for t in tasks if t in gpu]
        while todo:  # GPU tasks reached through this frame's edges, then the delays' reads
            while todo:
                t = todo.pop()
                if t not in reach:
                    reach.add(t)
                    keys.update(tasks_of[t].outputs)
                    todo += [u for u in g.successors(t) if u in gpu]
            todo = [u for u in gpu if u not in reach and
                    any(r.offset < 0 and r.key in keys for r in tasks_of[u].inputs)]
        output = bool(keys & set(self.program.outputs.values()))
        rings = set(self.program.rings)
        if not keys & rings:
            return "host" if output else "always"
        # A GPU task reading an earlier frame's value may pass it on (a keyframe kept): if
        # what it or its GPU successors make is a delay's, the buffer outlives its frame's
        # slot in the rings, and no frame index says when it is free.
        carried = [u for u in reach if any(r.offset < 0 and r.key in keys
                                           for r in tasks_of[u].inputs)]
        seen: set = set()
        while carried:
            t = carried.pop()
            if t in seen:
                continue
            seen.add(t)
            if rings.intersection(tasks_of[t].outputs):
                return "never"
            carried += [u for u in g.successors(t) if u in gpu]
        return "never" if output else "ring"

    def _pool_rules(self) -> dict:
        """task -> when its pooled output buffer may be reused (:meth:`_reuse_rule`)."""
        if not self._out_pools:
            return {}
        g = self._data
        return {name: self._reuse_rule(g, [name], ()) for name in self._out_pools}

    def _upload_rules(self) -> dict:
        """key -> when the device copy of that host value, uploaded for the GPU tasks that
        read it in its frame, may be reused (:meth:`_reuse_rule`; a delayed key's slot, and
        the copy cached in it, outlive the frame: once the delays let it go, "ring")."""
        readers: dict = {}
        for name in self._gpu_tasks:
            for r in self.program.tasks[name].inputs:
                readers.setdefault(r.key, set()).add(name)
        if not readers:
            return {}
        g = self._data
        return {key: self._reuse_rule(g, tasks, [key]) for key, tasks in readers.items()}

    def _release(self, frame: Frame, host: bool):
        """Frame waited for: its output and upload buffers go back to their pools where
        nothing else can still hold them (see :meth:`_reuse_rule`); those a delay may hold
        wait for the delays to let the frame go (:meth:`_recycle_ring_held`)."""
        held = []
        for task, buf in frame.leases:
            rule = self._pool_rule[task.name]
            if rule == "ring":
                held.append((True, task.name, buf))
                continue
            if rule == "host" and not host:
                continue
            self._give_out(task.name, buf)
        frame.leases = []
        if frame.uploads:
            with self._up_lock:
                for key, buf in frame.uploads:
                    rule = self._upload_rule[key]
                    if rule == "ring":
                        held.append((False, key, buf))
                        continue
                    if rule == "host" and not host:
                        continue
                    self._give_up(key, buf)
            frame.uploads = []
        if held:
            self._ring_held.append((frame.index, held))

    def _give_out(self, task: str, buf):
        pool = self._out_pools[task]
        if len(pool) < self.OUT_POOL:
            pool.append(buf)

    def _give_up(self, key: str, buf):
        """(``_up_lock`` held.)"""
        pool = self._up_pools[key]
        if len(pool) >= self.UPLOAD_POOL:  # shapes vary: the oldest go
            del pool[0]
        pool.append(buf)

    def _recycle_ring_held(self):
        """Buffers of frames no delay holds any more (every ring has aged past them: a ring
        keeps its last ``slots + 1`` frames) go back to their pools. A frame's values reach
        the delays' readers only through the rings (:meth:`Ring.get`; ``Delay.read`` copies
        under the ring's lock), so once dropped there nothing reads them (a value a GPU task
        passes on into a later frame's delay slot is never pooled: :meth:`_reuse_rule`; a
        delay kept inside one captured segment lives in its buffer set, not in these
        buffers). A staged download
        of such a value (:meth:`_stage`) was queued when it was published and is waited for
        by its reader or by the ring dropping the slot (``Ring.age``, called before this):
        no copy from a buffer given back here is still running."""
        held = self._ring_held
        if not held:
            return
        rings = self.program.rings.values()
        oldest_kept = min(r.last_aged - r.slots for r in rings)
        while held and held[0][0] < oldest_kept:
            _, bufs = held.popleft()
            with self._up_lock:
                for out, name, buf in bufs:
                    if out:
                        self._give_out(name, buf)
                    else:
                        self._give_up(name, buf)

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
        self._wake_all()  # their roles skip the cancelled frames

    # ------------------------------------------------------------------ API

    def submit(self, frame_index: int, inputs: Mapping, *, capture: bool | None = None,
               wake: bool = True) -> Frame:
        """Start frame ``frame_index`` with ``inputs``: key -> ``(value, "host" | "device")``.

        ``wake=False``: the caller calls :meth:`wait` at once, which runs the frame's ready
        units on its own thread when the frame is alone in flight (and wakes the role threads
        otherwise): no role thread is woken here to contend for the GIL meanwhile.

        ``capture``: replay captured GPU segments in this frame (None: the executor's
        :attr:`capture`; True where the GPU role's device can capture). Returns at once; the
        processors pick the frame up after the frames before it.
        """
        if self._closing.is_set():
            raise RuntimeError(f"executor {self.name!r} is closed")
        self._start()
        if self._events is not None:
            self._events.reserve(self._events_per_frame)
        slots = {}
        events = []
        # A caller passing device inputs gets device outputs (Graph.process, stream): no
        # downloads of them to stage.
        stage_outputs = True
        for key in self.program.inputs:
            try:
                value, where = inputs[key]
            except KeyError:
                missing = [k for k in self.program.inputs if k not in inputs]
                raise WarpvxValueError(f"inputs: missing {missing} for frame {frame_index}") from None
            slot = slots[key] = Slot.holding(value, where)
            if where != HOST:
                stage_outputs = False
            if where == DEVICE and self.cuda:
                # The caller's device data may still be in flight on any stream: an event on
                # the legacy default stream completes after all work queued so far.
                if self._null_stream is None:
                    self._null_stream = warp().get_device(self.gpu_device).null_stream
                slot.event = self._events.get()
                events.append(slot.event)
                with self._capture_lock:
                    self._null_stream.record_event(slot.event)
                slot.external = True
        for key in self._task_keys:
            slots[key] = Slot()
        frame = Frame(frame_index, slots, self._slot_procs[frame_index % self.frames])
        if events:
            frame.events.extend(events)
        frame.stage_outputs = stage_outputs
        if self.frames == 1 and self.gpu_device:
            timing = self._timing
            frame.bursts = timing == "bursts" or (timing is None and self.cuda and bool(self._inflight))
        if capture is not None:
            capture = check_bool(capture, "capture", allow_none=True)
        # (Nothing capturable: no signature to make, no capture state to look up per frame.)
        frame.capture = self._capturable and (self.capture if capture is None else capture)
        if frame.capture:
            frame.signature = signature(inputs)
        for key, ring in self.program.rings.items():
            ring.reserve(frame_index, slots[key])
        with self._lock:
            failed = [f.index for f in self._inflight if f.error is not None]
            self._inflight.append(frame)
            batch = self._join_batch(frame) if self.frames > 1 else None
        if failed:
            frame.cancelled_by = failed[0]
            frame.cancel.set()
        for role in self._roles.values():
            role.frames.append(frame)
            if wake and self._ready(role):
                role.wake()
        if batch is not None:
            for p in self._active:
                self._inbox[p].put(batch)
        return frame

    def _join_batch(self, frame: Frame) -> Batch | None:
        """Put ``frame`` in the open batch of its cycle, or in a new one (returned, for the
        processors' inboxes; None when it joined the open one). Call with the lock held."""
        k = self.frames
        slot, cycle = frame.index % k, frame.index // k
        batch, new = self._batch, None
        if batch is None or batch.closed or batch.cycle != cycle or batch.last >= slot:
            if batch is not None:
                batch.close()
            batch = new = self._batch = Batch(cycle, slot, k)
        batch.add(slot, frame)
        if slot == k - 1:  # the cycle is complete
            batch.close()
        return new

    def _close_batch(self, frame: Frame | None = None):
        """Close the open batch (if it holds ``frame``, when given): its processors skip the
        slots no frame came for."""
        with self._lock:
            batch = self._batch
            if batch is not None and (frame is None or frame in batch):
                batch.close()

    def wait(self, frame: Frame, *, host: bool = True) -> FrameResult:
        """Wait for ``frame`` and return its outputs (host data when ``host``) and timeline.

        Raises
        ------
        NodeExecutionError
            A task of this frame raised (``__cause__`` is its exception), or the frame was
            cancelled because an earlier frame failed.
        """
        if self.frames > 1:  # no frame joins its batch while the caller waits for this one
            self._close_batch(frame)
        elif not frame.finished.is_set():
            self._help(frame)
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
                synchronize_event(frame.gpu_last_event)
            for ev in frame.forked:  # (the events of a captured segment's own stream)
                synchronize_event(ev)
            io = self._io()
            outputs = {}
            for name, key in self.program.outputs.items():
                slot = frame.slots[key]
                outputs[name] = slot.host(io) if host else slot.value
            self._forget_events(frame)
            # The events go back to the pool once the timeline is read (or never will be).
            if self.cuda:
                result = frame_result(frame, outputs, self._anchor, self._events.put)
                self._events.lend(result)
            else:
                result = frame_result(frame, outputs)
            # Staged downloads nobody read waited for first: their copies read device
            # buffers _release may hand to the next frame.
            self._unstage(frame)
            self._release(frame, host)
            for ring in self.program.rings.values():
                ring.age(frame.index)
            self._recycle_ring_held()
            return result
        finally:
            self._unstage(frame)
            with self._lock:
                if frame in self._inflight:
                    self._inflight.remove(frame)

    def _help(self, frame: Frame):
        """The caller's thread, about to block on ``frame`` alone in flight (one-frame
        schedules), runs the ready units itself first, as the thread of the first ready role
        would (:meth:`_drive`): a frame run one at a time then wakes no role thread and needs
        no wake-up of the caller at its end (each 10-30 us under the GIL). With other frames
        in flight it only waits: its role would go on into their units."""
        with self._lock:
            alone = len(self._inflight) == 1
        ready = [r for r in self._roles.values() if self._ready(r) and not r.token.locked()]
        if not alone:
            for role in ready:  # (a frame submitted without waking them)
                role.wake()
            return
        for role in ready[1:]:  # more than one role with ready units: theirs run beside
            role.wake()
        if ready:
            try:
                self._drive(ready[0])
            except BaseException as exc:  # noqa: BLE001 - an executor bug, reported
                self._fail(frame, "<executor>", ready[0].proc, exc)

    @staticmethod
    def _unstage(frame: Frame):
        """Frame over: its staged downloads' buffers not read yet may be reused (once their
        copy is done)."""
        for slot in frame.staged:
            slot.release_staged()
        frame.staged = []

    def _forget_events(self, frame: Frame):
        """Every GPU task of the frame has completed: slots that outlive the frame (delays,
        the caller's inputs) forget its events, which go back to the pool with its timeline
        (:func:`~.timeline.frame_result`): their data is ready for any reader."""
        if not frame.events:
            return
        mine = None  # the frame's events by id, made only when an outliving slot holds one
        slots = frame.slots
        for key in self._outliving:
            slot = slots[key]
            if slot.event is None:
                continue
            if mine is None:
                mine = {id(e) for e in frame.events}
            if id(slot.event) in mine:
                if slot.external:  # the caller's copy, which no task of the frame may have awaited
                    synchronize_event(slot.event)
                slot.event = None
                slot.external = False
        frame.forked = []
        frame.gpu_last_event = None

    def abort(self):
        """Cancel every frame in flight and wait until the processors have dropped them."""
        self._close_batch()
        with self._lock:
            frames = list(self._inflight)
        for f in frames:
            f.cancel.set()
        self._wake_all()
        for f in frames:
            while not f.finished.wait(WAIT_SLICE):
                if not any(th.is_alive() for th in self._threads.values()):
                    break
            for ring in self.program.rings.values():
                ring.discard_pending(f.index)
            self._unstage(f)
        with self._lock:
            self._inflight = [f for f in self._inflight if f not in frames]

    @property
    def timing(self) -> str | None:
        """GPU timing of the frames submitted from now: ``"tasks"``, ``"bursts"`` or None
        (see the ``timing`` parameter)."""
        return self._timing

    @timing.setter
    def timing(self, value: str | None):
        self._timing = _check_timing(value)

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
        self._wake_all()
        for p in self._threads:
            self._inbox[p].put(None)
        for th in self._threads.values():
            th.join(timeout=5.0)
        self._threads.clear()
        if self._host_pool is not None:
            for ring in self.program.rings.values():  # (the graph's: they outlive us)
                ring.release_staged()
            self._host_pool.close()


#: Values of :class:`Executor`'s ``timing``.
TIMINGS = ("tasks", "bursts")


def _check_timing(timing):
    if timing is not None and timing not in TIMINGS:
        raise WarpvxValueError(f"timing: expected one of {TIMINGS} or None, got {timing!r}")
    return timing


def run_schedule(schedule: Schedule, program: Program, inputs: Mapping, *, gpu_device=None,
                 frame_index: int = 0) -> FrameResult:
    """Run one frame of ``program`` with a throw-away :class:`Executor` (tests, examples)."""
    ex = Executor(schedule, program, gpu_device=gpu_device, name="run")
    try:
        return ex.wait(ex.submit(frame_index, inputs))
    finally:
        ex.close()

__all__ = ["Executor", "SPIN_SECONDS", "TIMINGS", "run_schedule"]
