"""CUDA-graph capture of GPU segments: consecutive GPU tasks enqueued as one graph launch.

A *segment* is a run of consecutive tasks of the GPU queue (schedule order) that may be
captured (:attr:`ExecTask.capture`: given ``out=``, the task only enqueues work on the
current stream), cut wherever a task reads a value a CPU task produces (a CPU hand-off: the
segment is replayed once all its inputs are there, so a hand-off inside it would hold the
earlier tasks back). Every other GPU task is a segment of its own, run eagerly.
:func:`segments` is the pure rule; :class:`SegmentGraph` is one segment captured for one
input signature (the shapes and dtypes of a frame's inputs): fixed buffers and the graph.

Buffers are static, as a CUDA graph holds pointers: each input the segment reads from
outside (a graph input, a CPU task's output, an eager GPU task's, a delay's) is copied into
a fixed device buffer before the replay, each task writes a fixed output buffer
(``gpu_out``), and each value that leaves the segment (read by another task, as a graph
output, by a delay read elsewhere) is copied out into a buffer of the frame's after it, as
frames in flight share the fixed buffers. A segment's own delays (a pyramid, corners: read
by the segment one frame later) are neither copied in nor out: the segment has two buffer
sets, and a frame reads the set the previous frame wrote and writes the other (two captures
per signature, on the fourth and fifth sightings); a delayed value read elsewhere too is
still copied out for those readers.
Copies and replay run on the executor's stream, in frame order; or, with buffer sets per
frame in flight (``instances`` of :class:`~warpvx.runtime.segment_runner.SegmentRunner`,
which runs the segments frame after frame; CUDA), each set's on streams of its own, forked
from the executor's, so frames overlap on the device where no data flows between them (its
``linked``: a frame's readers of the previous frame's delayed values wait for them inside
the graph, through external event nodes). A value may be any tree of
arrays (:func:`.transfers.tree_map`): a pyramid's list of levels, a task's several outputs,
a :class:`~warpvx._counted.Counted` (corners, keypoints, tracked points: fixed rows and a
device count, so data-dependent results need no host sync; a node's Counted outputs are
views of one :class:`~warpvx._counted.Block`, copied out in one device copy).

A segment is captured per input signature and per shapes of its own inputs (a value made in
an earlier frame, such as the previous frame's corners, may change them), each buffer set
on its second sighting of that pair; on the first, its tasks run uncaptured on the same
fixed buffers (:meth:`SegmentGraph.launch`), so values have the captured form from the
first frame (a corner count changing between eager frames would otherwise change the next
segment's input shapes) and nothing allocates inside the capture.

Lanes: a segment's tasks are spread over up to :data:`MAX_LANES` streams by its own data
dependencies (:mod:`.lanes`: list scheduling over the scheduled durations), forked from
the executor's stream after the copies in and joined back before the copies out; a task waits
(a device event) for its producers on other lanes. CUDA stream capture follows those events,
so the graph holds the segment's true dependencies and independent branches (two cameras,
a detector beside the features) run concurrently. A task that inserts a conditional node
(``wp.capture_if``/``capture_while``: Harris's selection rounds, FAST's counted sort) runs
with every lane joined, as Warp pauses the capture there; the first run of a segment's
:class:`SegmentGraph` runs on the one stream and finds those tasks. Later uncaptured runs
take the lanes, so the primitives' per-stream scratch (:func:`~warpvx.kernels_warp._launch.
workspace`) exists before the capture and is never shared by concurrent tasks (on CUDA a
one-set segment is captured on its third sighting, not its second). On Warp's CPU device
every lane is the one stream.

Warp 1.19 captures on its CPU device too (an operation stream replayed in C++), so the same
code runs there when asked (``capture=True``), which is how it is tested without a GPU.

Limits: Warp's current stream belongs to the device, not the thread, so Warp work another
thread enqueues on the GPU role's device while a segment is being captured (once per
segment and signature, on the GPU thread) would land in the graph; the executor's own
threads enqueue none then (their copies use their own streams and Warp's native entry
points, and the legacy-stream event of a device input waits for the capture to end). On
Warp's CPU device a capture is process-wide, hence opt-in there.
"""

from __future__ import annotations

import logging
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from ..check import check_int
from ..errors import CaptureAllocationError, caused_by
from .lanes import MAX_LANES, Lanes, lanes, noted, noting_conditionals
from .native_copy import (copy_device, is_warp_array, record_event, to_device, wait_event,
                          warp)
from .pinned import is_pinned
from .program import InputRef, Program
from .transfers import tree_map

#: Why a segment runs eagerly (``logging.getLogger("warpvx.capture")`` at DEBUG): every
#: capture failure falls back to eager silently otherwise.
_log = logging.getLogger("warpvx.capture")

#: Input signatures (shapes and dtypes of a frame's inputs) whose captures an executor keeps.
MAX_SIGNATURES = 4

#: Counted views of copy-out buffers a :class:`SegmentGraph` keeps (views cost ~10 us each).
MAX_VIEWS = 256


class NotCapturable(Exception):
    """A segment cannot be captured (a value is no single array, a task allocated its result
    or a capture failed); the executor runs it eagerly."""


@dataclass(frozen=True)
class Segment:
    """GPU tasks run together.

    Attributes
    ----------
    tasks : tuple of ExecTask
        In GPU queue order.
    captured : bool
        A capture candidate; False: one task, run eagerly.
    inputs : tuple of InputRef
        What its tasks read from outside it, each once, in order of first use.
    outputs : tuple of str
        Keys it produces that leave it (read by another task, as graph outputs, by a delay
        read outside it): copied out of the fixed buffers each frame.
    swapped : tuple of InputRef
        Its inputs that are its own outputs of the previous frame (offset -1): read straight
        from the other of two buffer sets (:class:`SegmentGraph`), not copied in.
    """

    tasks: tuple
    captured: bool
    inputs: tuple = ()
    outputs: tuple = ()
    swapped: tuple = ()


def segments(program: Program, gpu_order) -> list:
    """Split the GPU queue ``gpu_order`` (task names in schedule order) into :class:`Segment`s.

    A task with ``capture`` joins the current segment unless it reads (at any frame offset)
    a key produced by a task outside the GPU queue (a CPU hand-off), which starts a new one;
    a task without ``capture`` is an eager segment of its own and ends the current one.
    """
    on_gpu = set(gpu_order)
    cpu_keys = {k for t in program.tasks.values() if t.name not in on_gpu for k in t.outputs}
    groups, current = [], []
    for name in gpu_order:
        task = program.tasks[name]
        if not _capturable(task):
            if current:
                groups.append(current)
                current = []
            groups.append([task])
            continue
        if current and any(r.key in cpu_keys for r in task.inputs):
            groups.append(current)
            current = []
        current.append(task)
    if current:
        groups.append(current)
    return [_segment(program, g) for g in groups]


def _capturable(task) -> bool:
    return task.capture and task.gpu_out is not None


def _segment(program: Program, tasks: list) -> Segment:
    first = tasks[0]
    if not _capturable(first):
        return Segment((first,), False)
    names = {t.name for t in tasks}
    made = {k for t in tasks for k in t.outputs}
    inputs = []
    for t in tasks:
        for r in t.inputs:
            if (r.offset or r.key not in made) and r not in inputs:
                inputs.append(r)
    outside = {r.key for t in program.tasks.values() if t.name not in names for r in t.inputs}
    outside |= set(program.outputs.values())
    # A delay read only by the segment itself, one frame back, stays in its buffer set: the
    # next frame's replay writes the other set (stream order keeps the two frames apart).
    far = {r.key for t in tasks for r in t.inputs if r.offset not in (0, -1)}
    outside |= {k for k in program.rings if k not in made or k in far}
    outputs = tuple(k for t in tasks for k in t.outputs if k in outside)
    swapped = tuple(r for r in inputs if r.offset == -1 and r.key in made)
    return Segment(tuple(tasks), True, tuple(inputs), outputs, swapped)


def signature(inputs) -> tuple:
    """The capture key of a frame's inputs (key -> ``(value, where)``): shapes and dtypes
    (the dtype objects, hashable: ``str`` of a NumPy dtype costs ~4 us, per input and frame)."""
    return tuple((k, getattr(v, "shape", None), getattr(v, "dtype", type(v)))
                 for k, (v, _) in inputs.items())


def _workspaces() -> list:
    """The kernels' cached scratch state (buffers, recorded launches) alive now. A graph holds
    the raw pointers its kernels were captured with, so it keeps these alive: the kernels'
    cache may drop them (least recently used) while the graph still replays."""
    from ..kernels_warp import _launch

    with _launch._workspaces_lock:
        return list(_launch._WORKSPACES.values())


@contextmanager
def _failing_capture():
    """Any failure inside fails the capture: :class:`NotCapturable` (the segment runs eagerly),
    the failure chained as its cause."""
    try:
        yield
    except Exception as exc:  # noqa: BLE001 - any failure means: run eagerly
        raise NotCapturable(f"{type(exc).__name__}: {exc}") from exc


def _fits(values: list, bufs: list) -> bool:
    """Arrays ``values`` have the shapes of buffers ``bufs``, one for one."""
    return len(values) == len(bufs) and all(
        tuple(v.shape) == tuple(b.shape) for v, b in zip(values, bufs))


def _leaves(value) -> list:
    """The array leaves of a value (an array, or a tree of them: :func:`.transfers.tree_map`)
    in a fixed order; NotCapturable when it has none."""
    if isinstance(value, np.ndarray) or is_warp_array(value):  # the usual value: no walk
        return [value]
    leaves = []

    def take(a):
        leaves.append(a)
        return a  # the tree is rebuilt around the leaves (Keypoints validate theirs)

    tree_map(take, value)
    if not leaves:
        raise NotCapturable(f"a segment value is a {type(value).__name__} holding no array")
    return leaves


def _per_output(task, result) -> dict:
    """A task's call result as output key -> value (a tuple when it has several outputs)."""
    if len(task.outputs) == 1:
        return {task.outputs[0]: result}
    if not isinstance(result, (tuple, list)) or len(result) != len(task.outputs):
        raise NotCapturable(f"task {task.name!r}: expected {len(task.outputs)} outputs")
    return dict(zip(task.outputs, result))


class _BufferSet:
    """One set of a segment's task output buffers and the graph that writes it.

    Attributes
    ----------
    outs : dict
        task name -> its ``gpu_out()`` buffers.
    outputs : dict
        key -> the value its task returned (the fixed buffers; a tree may also hold a
        buffer the task read: a pyramid's level 0 is its source); empty before the first run.
    graph : wp.Graph or None
        The capture of the tasks writing this set; None before it.
    published : dict
        Key of each swapped input -> the object the last run of this set published for it
        (the fixed value, or its copy): how the next frame knows its delay holds this set.
    warm : bool
        An uncaptured run read the buffers a capture of this set reads (the previous set's,
        for swapped inputs), so the primitives' per-buffer state exists: it may be captured.
    inputs : dict
        InputRef -> the fixed buffers its run's inputs are copied into (one dict shared by
        every set of a segment whose runs share one stream; a set's own where frames overlap).
    done : wp.Event or None
        Recorded after this set's last run and its copies out (CUDA, overlapping frames):
        the runs that read or write its buffers next wait for it on the device
        (:meth:`SegmentGraph.wait_previous`).
    plan : tuple or None
        ``(outputs, plan)``: what the executor copies out of ``outputs`` after each run,
        listed once for that dict (a replay returns the same one; an uncaptured run makes
        another); see :meth:`~warpvx.runtime.segment_runner.SegmentRunner._copy_plan`.
    """

    __slots__ = ("outs", "outputs", "graph", "published", "warm", "inputs", "done", "plan")

    def __init__(self, tasks, inputs: dict):
        self.outs = {task.name: task.gpu_out() for task in tasks}
        self.outputs = {}
        self.graph = None
        self.published = {}
        self.warm = False
        self.inputs = inputs
        self.done = None
        self.plan = None  # (outputs, the executor's copy-out plan of them: SegmentRunner)


class SegmentGraph:
    """A :class:`Segment` captured for one input signature: fixed buffers and its graphs.

    Frames go round a ring of buffer sets, each with its own graph: frame *i* writes set
    ``i mod n``. A segment with swapped inputs (its own outputs one frame back, through a
    delay) reads the delayed values in the set the previous frame wrote, so a delay costs no
    copy in or out and no allocation; it has two sets at least. With ``sets`` > 1 each set
    has its own input buffers too, so that frames in flight may run on streams of their own
    (:attr:`~warpvx.runtime.segment_runner.SegmentRunner.instances`): frame *i+1*'s copies in
    and replay beside frame *i*'s
    (a captured graph per set: ``n`` captures per signature).

    Parameters
    ----------
    segment : Segment
    values : list
        The current frame's values of ``segment.inputs`` (arrays: host or device), which
        fix the input buffers' shapes and dtypes.
    device : str
        Warp device of the GPU role.
    durations : dict, optional
        Task name -> scheduled duration, to spread the tasks over lanes (:func:`lanes`).
    max_lanes : int
        Streams the tasks may take (1: one chain).
    sets : int
        Buffer sets with input buffers of their own (1: the sets share theirs, frames run
        one after the other); a segment with swapped inputs has two at least.
    """

    def __init__(self, segment: Segment, values, device: str, durations=None,
                 max_lanes: int = MAX_LANES, sets: int = 1):
        wp = warp()
        self.segment = segment
        for v in values:
            _leaves(v)

        def input_buffers() -> dict:
            return {ref: tree_map(lambda a: wp.zeros(
                a.shape, dtype=a.dtype if is_warp_array(a) else wp.dtype_from_numpy(a.dtype),
                device=device), v) for ref, v in zip(segment.inputs, values)}

        own = check_int(sets, "sets", min_value=1) > 1
        shared = None if own else input_buffers()
        n = max(sets, 2 if segment.swapped else 1)
        self.sets = [_BufferSet(segment.tasks, input_buffers() if own else shared)
                     for _ in range(n)]
        self.last = -1  # the set the last run wrote (the next frame's delayed values)
        self._lane_args = (durations, check_int(max_lanes, "max_lanes", min_value=1))
        self.lanes = None  # Lanes, from the first run on (which finds the serial tasks)
        self._events = {}  # (kind, index) -> a wp.Event of the lanes' forks, joins, signals
        self.scratch = ()
        self.links = None  # per set: producing task -> its event (link)
        self.key = None  # the shapes of its inputs it was found by last (SegmentRunner)
        #: Its own published delayed values (and the graph inputs) led to it: a frame reading
        #: those finds it without its inputs' shapes (SegmentRunner._inputs_key).
        self.self_keyed = False
        self._producer = {}  # swapped InputRef -> the task making it
        self._views = {}  # (id of a copy buffer, part) -> a Counted of views of it
        self._swapped = frozenset(segment.swapped)
        #: (frame, the slots of its inputs, all set) from the executor's look-up of this
        #: graph to its run of it (SegmentRunner), None otherwise.
        self.ready = None
        self._input_leaves = {}  # (InputRef, set) -> the leaves of its input buffers (fill)

    @property
    def next(self) -> int:
        """The buffer set the next run writes: the other one than the last run's."""
        return 0 if self.last < 0 else (self.last + 1) % len(self.sets)

    def previous(self, s: int) -> _BufferSet:
        """The set the run before a run of set ``s`` wrote (its delayed values)."""
        return self.sets[(s - 1) % len(self.sets)]

    @property
    def captured(self) -> bool:
        return any(b.graph is not None for b in self.sets)

    def due(self) -> bool:
        """The next run's set is warm (:class:`_BufferSet`) and not captured yet."""
        b = self.sets[self.next]
        return b.graph is None and b.warm

    def value(self, ref: InputRef, s: int, outputs: dict, fresh: bool = False):
        """The fixed buffer(s) a task of the segment writing set ``s`` reads for ``ref``
        (``outputs``: the values of the tasks before it in this run; ``fresh``: swapped inputs
        read from the set's input buffers)."""
        if ref.offset == 0 and ref.key in outputs:
            return outputs[ref.key]
        if ref in self.segment.swapped and not fresh:
            other = self.previous(s).outputs
            if other:
                return other[ref.key]
        return self.sets[s].inputs[ref]

    def capture(self, device: str, streams):
        """Capture the tasks writing the next run's buffer set (``streams``: the lanes' streams,
        the first the capture's; CUDA only, else None), once an uncaptured run has written it.
        Each task writes its ``gpu_out()`` buffers; its result may also hold a buffer it read
        (a pyramid's level 0 is its source), but nothing else.

        Raises
        ------
        NotCapturable
            A task returned memory it allocated, or Warp refused or failed the capture (a
            host sync or read-back inside, a caller's capture).
        """
        b = self.sets[self.next]
        # The tasks launch on the device's current stream: the capture's (a set's own stream
        # need not be the current one; ScopedCapture does not make it so).
        dev = streams[0].device if streams else None
        current = dev.stream if dev is not None else None
        try:
            if dev is not None:
                dev.set_stream(streams[0], sync=False)
            try:
                graph = self._record(device, streams)
            except NotCapturable as exc:
                if not caused_by(exc, CaptureAllocationError):
                    raise
                # A primitive's scratch (kept per stream and thread) was missing: the runs
                # before were on another thread. Made uncaptured here, then captured.
                _log.debug("segment %s: scratch made before capture (%s)",
                           self.segment.tasks[0].name, exc)
                self._scratch_run(streams)
                graph = self._record(device, streams)
        finally:
            if dev is not None:
                dev.set_stream(current, sync=False)
        b.graph = graph
        self.scratch = _workspaces()

    def _scratch_run(self, streams):
        """The tasks writing the next run's set, run uncaptured on ``streams`` (real work, before
        the frame's own run): after the runs its set's buffers are read or written by (on
        streams of their own with several sets); a task's failure is :class:`NotCapturable`,
        as inside the capture."""
        if streams:
            self.wait_previous(streams[0], rewrites=True)
        with _failing_capture():
            self._run_tasks(self.next, streams=streams)

    def _record(self, device: str, streams):
        """The tasks writing the next run's set, captured (on the current stream): the graph."""
        with _failing_capture():
            with warp().ScopedCapture(device=device, stream=streams and streams[0]) as cap:
                self._run_tasks(self.next, streams=streams)
        if cap.graph is None:
            raise NotCapturable("the capture produced no graph")
        return cap.graph

    def single_lane(self) -> bool:
        """Run on one lane from now on (after a capture on several failed); False if it
        already does. The first run, on that one stream, made its scratch; where the sets
        have streams of their own (own input buffers), the others' first run on one lane
        makes theirs: they are not warm (:meth:`due`) until then."""
        if self.lanes is None or self.lanes.count == 1:
            return False
        tasks = self.segment.tasks
        self.lanes = lanes(tasks, self._lane_args[0], 1, {tasks[i].name for i in self.lanes.serial})
        if self.sets[0].inputs is not self.sets[-1].inputs:
            for b in self.sets:
                b.warm = b.warm and b.graph is not None
        return True

    def _event(self, kind: str, i: int, device):
        """The lanes' event ``(kind, i)`` on CUDA ``device``, made on first use (reused by
        every run: a wait takes the event's state when it is enqueued)."""
        ev = self._events.get((kind, i))
        if ev is None:
            ev = self._events[kind, i] = warp().Event(device)
        return ev

    def _run_tasks(self, s: int, fresh: bool = False, streams=None):
        """Enqueue the tasks, each into its buffers of set ``s`` and on its lane's stream of
        ``streams`` (:attr:`lanes`; None: all on the current stream, as on Warp's CPU
        device); their results become the set's outputs. Uncaptured this also builds
        whatever a primitive makes per set of buffers and stream (workspaces, recorded
        launches), so nothing allocates inside the capture that follows. The first run
        enqueues every task on the current stream and notes which ones insert conditional
        graph nodes (the serial tasks of :class:`Lanes`), which fixes :attr:`lanes`.

        Raises
        ------
        NotCapturable
            A task returned memory it allocated (its out= did not fit); a task's own error
            propagates.
        """
        b = self.sets[s]
        # Warm: read what a capture of this set reads (the previous set's outputs).
        warm = not self.segment.swapped or (bool(self.previous(s).outputs) and not fresh)
        outputs = {}
        fixed = {a.ptr for ref in self.segment.inputs
                 for a in _leaves(self.value(ref, s, outputs, fresh))}
        tasks = self.segment.tasks
        links = self.links
        if links is not None:
            device, producer = streams[0].device, self._producer
            made, reads = links[s], links[(s - 1) % len(self.sets)]

        def run(task):
            out = b.outs[task.name]
            mine = {a.ptr for a in _leaves(out)}
            if links is not None:
                stream = device.stream  # the task's lane
                if not fresh:
                    for r in task.inputs:
                        if r in producer:
                            stream.wait_event(reads[producer[r]], external=True)
            result = task.gpu(*[self.value(r, s, outputs, fresh) for r in task.inputs], out=out)
            if any(a.ptr not in mine and a.ptr not in fixed for a in _leaves(result)):
                raise NotCapturable(f"task {task.name!r} did not write its out= buffer")
            if links is not None and task.name in made:
                stream.record_event(made[task.name], external=True)
            fixed.update(mine)
            outputs.update(_per_output(task, result))

        if self.lanes is None:
            serial = set()
            with noting_conditionals():
                for task in tasks:
                    before = noted.calls
                    run(task)
                    if noted.calls > before:
                        serial.add(task.name)
            self.lanes = lanes(tasks, *self._lane_args, serial=serial)
            # Its scratch is the one stream's: warm only where the lanes are that stream.
            warm = warm and (streams is None or self.lanes.count == 1)
        elif streams is None or self.lanes.count == 1:
            for i in self.lanes.order:
                run(tasks[i])
        else:
            self._run_on_lanes(run, streams)
        b.outputs = outputs
        b.warm = warm

    def _run_on_lanes(self, run, streams):
        """``run(task)`` for each task in :attr:`lanes` order, on its lane's stream of
        ``streams`` (the first, the current one, is the fork's and the join's): a lane waits
        for the fork when it first runs in an epoch (since the run's start or the last serial
        task), then for its producers' events on other lanes; the lanes are joined before a
        serial task and at the end, even on an error (a capture ends only with every lane
        joined)."""
        device = streams[0].device
        main = streams[0]
        lanes_, signals, active = self.lanes, self.lanes.signals, set()
        tasks = self.segment.tasks

        def join():
            for k in sorted(active):
                main.wait_event(streams[k].record_event(self._event("join", k, device)))
            active.clear()

        fork = main.record_event(self._event("fork", 0, device))
        try:
            for i in lanes_.order:
                if i in lanes_.serial:
                    join()
                    device.set_stream(main, sync=False)
                    run(tasks[i])
                    fork = main.record_event(self._event("fork", 0, device))
                    continue
                k = lanes_.of[i]
                lane = streams[k]
                if k and k not in active:
                    lane.wait_event(fork)
                    active.add(k)
                for p in lanes_.waits[i]:
                    lane.wait_event(self._event("done", p, device))
                device.set_stream(lane, sync=False)
                run(tasks[i])
                if i in signals:
                    lane.record_event(self._event("done", i, device))
        finally:
            device.set_stream(main, sync=False)
            join()

    def reads_fresh(self, values) -> bool:
        """Whether the next run, given the frame's ``values`` of ``segment.inputs``, reads
        its swapped inputs from its input buffers (``fresh`` of :meth:`fill` and
        :meth:`launch`): one of them is unlike the previous set's outputs (a delay's initial
        value after a reset, where this segment's own outputs swap in later); that run is not
        captured."""
        other = self.previous(self.next).outputs if self.segment.swapped else None
        if not other:
            return False
        published = self.sets[self.last].published  # (the usual value: no leaves to walk)
        swapped = self._swapped
        for ref, v in zip(self.segment.inputs, values):
            if ref.offset == -1 and ref in swapped and published.get(ref.key) is not v and \
                    not _fits(_leaves(v), _leaves(other[ref.key])):
                return True
        return False

    def fill(self, ref: InputRef, value, io, stream, fresh: bool = False):
        """Copy this frame's ``value`` of ``ref`` into the fixed buffers the next run reads
        (on ``stream``, which must be the device's current one: a pageable host array is
        staged on it; ``fresh``: see :meth:`reads_fresh`); nothing for a swapped input that
        is what the last run published. A host array in pinned memory
        (:func:`~.pinned.pinned_array`) is copied straight from there, asynchronously."""
        s = self.next
        # (A swapped input is a delay of one frame: no hash of the others' refs.)
        swapped = ref.offset == -1 and not fresh and ref in self._swapped
        if swapped:
            if self.last >= 0 and self.sets[self.last].published.get(ref.key) is value:
                return
            bufs = _leaves(self.value(ref, s, {}, fresh))
        else:  # the set's own input buffers, fixed for its life: their leaves listed once
            bufs = self._input_leaves.get((ref, s))
            if bufs is None:
                bufs = self._input_leaves[ref, s] = _leaves(self.sets[s].inputs[ref])
        values = _leaves(value)
        if len(values) != len(bufs):
            raise NotCapturable(f"input {ref.key!r}: {len(values)} arrays, not {len(bufs)}")
        for buf, v in zip(bufs, values):
            if tuple(v.shape) != tuple(buf.shape):
                raise NotCapturable(f"input {ref.key!r}: shape {v.shape} != {buf.shape}")
            if is_warp_array(v) and v.device != buf.device:
                v = v.numpy()
            if is_warp_array(v):
                if v.ptr != buf.ptr:
                    copy_device(buf, v, stream)
            elif buf.device.is_cuda and is_pinned(v):  # a DMA straight from the caller's
                to_device(buf, v, stream)
                io.moved += v.nbytes
            elif buf.device.is_cuda:  # pageable: through the transfers' pinned staging
                io.upload(v, lambda shape, dtype, buf=buf: buf)
            else:  # Warp's CPU device: uploads alias host data; the buffer must be written
                to_device(buf, np.ascontiguousarray(v))
                io.moved += v.nbytes

    def launch(self, streams, fresh: bool = False) -> dict:
        """Replay the next run's captured graph on ``streams[0]`` (or run its tasks uncaptured
        on the lanes' ``streams``, as :meth:`capture`, before it is captured, or when
        ``fresh``: :meth:`reads_fresh`); returns the set's outputs (key -> fixed value)."""
        s = self.next
        b = self.sets[s]
        if b.graph is None or fresh:
            self._run_tasks(s, fresh, streams)
        else:
            warp().capture_launch(b.graph, stream=streams and streams[0])
        self.last = s
        return b.outputs

    def link(self, device):
        """Mark, in each run (inside its graph), when each delayed value the next run reads
        is made: an event per set and producing task, recorded right after the task (an
        external event node of the graph); the next run's tasks that read the value wait for
        that event (an external wait node) rather than the whole run for the previous one
        (:meth:`wait_previous`), so the tasks before them (a frame's grays, pyramids, corners)
        run beside the previous frame's. Needs swapped inputs and three sets or more (with
        two, a run writes the set the previous run is still reading); CUDA ``device``."""
        if not self.segment.swapped or len(self.sets) < 3 or self.links is not None:
            return
        made_by = {k: t.name for t in self.segment.tasks for k in t.outputs}
        self._producer = {r: made_by[r.key] for r in self.segment.swapped}
        wp = warp()
        self.links = [{name: wp.Event(device) for name in set(self._producer.values())}
                      for _ in self.sets]

    def unlink(self) -> bool:
        """Undo :meth:`link` (a capture with its event nodes failed); False if not linked.
        Safe with sets already captured linked: every run now waits for the whole previous
        one before it starts, so their waits inside the graph are met already."""
        if self.links is None:
            return False
        self.links = None
        return True

    def wait_previous(self, stream, rewrites: bool):
        """Make ``stream`` (the next run's, CUDA) wait on the device for the runs on other
        streams it depends on. Unlinked (:meth:`link`): the previous run, whose set holds
        the delayed values the next run reads, and which waited for the run before it, the
        last to read the next run's set. Linked: that last reader only (its tasks wait for
        the delayed values themselves), and the previous run too where the next run
        ``rewrites`` the previous set's delayed values (:meth:`fill`: a frame run eagerly
        left its own). :meth:`finish` marks a run's end."""
        s = self.next
        if self.last >= 0:
            n = len(self.sets)
            waits = (self.previous(s),) if self.links is None else \
                (self.sets[(s + 1) % n], self.previous(s)) if rewrites else \
                (self.sets[(s + 1) % n],)
            for b in waits:
                if b.done is not None:
                    wait_event(stream, b.done)
        b = self.sets[s]
        if b.done is None:
            b.done = warp().Event(stream.device)

    def finish(self, stream):
        """The last run, on ``stream``, is over once what is queued there now is: its copies
        out included, which read its set (see :meth:`wait_previous`)."""
        done = self.sets[self.last].done
        if done is not None:
            record_event(stream, done)

    def block_view(self, block, array, pooled: bool):
        """The Counted of ``block`` as views of ``array`` (a copy of its allocation); made
        once per copy buffer when ``pooled`` (the executor's pools hand the same buffers out
        again; a cached view keeps its buffer alive, so its id stays its own)."""
        if not pooled:
            return block.view(array)
        key = (id(array), block.part)
        view = self._views.get(key)
        if view is None:
            view = self._views[key] = block.view(array)
            while len(self._views) > MAX_VIEWS:
                del self._views[next(iter(self._views))]
        return view

    def publish(self, values: dict):
        """Remember what this frame published for the swapped inputs' keys (``values``: key
        -> the object set in its slot), so the next frame skips their copy in."""
        b = self.sets[self.last]
        b.published = {r.key: values[r.key] for r in self.segment.swapped}


__all__ = ["MAX_LANES", "MAX_SIGNATURES", "Lanes", "NotCapturable", "Segment", "SegmentGraph",
           "lanes", "segments", "signature"]
