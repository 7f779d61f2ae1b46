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
frame in flight (:attr:`SegmentRunner.instances`, CUDA), each set's on streams of its own,
forked from the executor's, so frames overlap on the device where no data flows between them
(:attr:`SegmentRunner.linked`: a frame's readers of the previous frame's delayed values wait
for them inside the graph, through external event nodes). A value may be any tree of
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
import time
from dataclasses import dataclass

import numpy as np

from .._counted import is_counted
from ..check import check_bool, check_int
from .lanes import MAX_LANES, Lanes, lanes, noted, noting_conditionals
from .native_copy import (copy_device, is_warp_array, record_event, to_device, wait_event,
                          warp)
from .pinned import is_pinned
from .program import InputRef, Program
from .slots import DEVICE
from .timeline import Frame, proportional_shares
from .transfers import tree_map

#: Why a segment runs eagerly (``logging.getLogger("warpvx.capture")`` at DEBUG): every
#: capture failure falls back to eager silently otherwise.
_log = logging.getLogger("warpvx.capture")

#: Input signatures (shapes and dtypes of a frame's inputs) whose captures an executor keeps.
MAX_SIGNATURES = 4

#: Counted views of copy-out buffers a :class:`SegmentGraph` keeps (views cost ~10 us each).
MAX_VIEWS = 256

#: Buffer sets (and graphs) per captured segment on CUDA, frames going round them on streams
#: of their own (:attr:`SegmentRunner.instances`), for frames in flight to overlap on the
#: device. 1 by default: on the H100 (session 6, `capture_stream.py`, two-camera graph at
#: 1280x720, depth 3 and 6) 3 or 6 sets measured no overlap (frames' GPU intervals summed /
#: covered 1.00-1.01) and FPS within the runs' spread (pinned frames, depth 3: 408 with one
#: set, 399-402 with 3 or 6); the host, not the device, bounds that stream.
INSTANCES = 1


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


def _fits(values: list, bufs: list) -> bool:
    """Arrays ``values`` have the shapes of buffers ``bufs``, one for one."""
    return len(values) == len(bufs) and all(
        tuple(v.shape) == tuple(b.shape) for v, b in zip(values, bufs))


def _leaves(value) -> list:
    """The array leaves of a value (an array, or a tree of them: :func:`.transfers.tree_map`)
    in a fixed order; NotCapturable when it has none."""
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
    """

    __slots__ = ("outs", "outputs", "graph", "published", "warm", "inputs", "done")

    def __init__(self, tasks, inputs: dict):
        self.outs = {task.name: task.gpu_out() for task in tasks}
        self.outputs = {}
        self.graph = None
        self.published = {}
        self.warm = False
        self.inputs = inputs
        self.done = None


class SegmentGraph:
    """A :class:`Segment` captured for one input signature: fixed buffers and its graphs.

    Frames go round a ring of buffer sets, each with its own graph: frame *i* writes set
    ``i mod n``. A segment with swapped inputs (its own outputs one frame back, through a
    delay) reads the delayed values in the set the previous frame wrote, so a delay costs no
    copy in or out and no allocation; it has two sets at least. With ``sets`` > 1 each set
    has its own input buffers too, so that frames in flight may run on streams of their own
    (:attr:`SegmentRunner.instances`): frame *i+1*'s copies in and replay beside frame *i*'s
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
        wp = warp()
        b = self.sets[self.next]
        # The tasks launch on the device's current stream: the capture's (a set's own stream
        # need not be the current one; ScopedCapture does not make it so).
        dev = streams[0].device if streams else None
        current = dev.stream if dev is not None else None
        try:
            if dev is not None:
                dev.set_stream(streams[0], sync=False)
            with wp.ScopedCapture(device=device, stream=streams and streams[0]) as cap:
                self._run_tasks(self.next, streams=streams)
        except Exception as exc:  # noqa: BLE001 - any failure means: run eagerly
            raise NotCapturable(f"{type(exc).__name__}: {exc}") from exc
        finally:
            if dev is not None:
                dev.set_stream(current, sync=False)
        if cap.graph is None:
            raise NotCapturable("the capture produced no graph")
        b.graph = cap.graph
        self.scratch = _workspaces()

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
        other = self.previous(self.next).outputs if self.segment.swapped else {}
        if not other:
            return False
        published = self.sets[self.last].published  # (the usual value: no leaves to walk)
        return any(ref in self.segment.swapped and published.get(ref.key) is not v
                   and not _fits(_leaves(v), _leaves(other[ref.key]))
                   for ref, v in zip(self.segment.inputs, values))

    def fill(self, ref: InputRef, value, io, stream, fresh: bool = False):
        """Copy this frame's ``value`` of ``ref`` into the fixed buffers the next run reads
        (on ``stream``, which must be the device's current one: a pageable host array is
        staged on it; ``fresh``: see :meth:`reads_fresh`); nothing for a swapped input that
        is what the last run published. A host array in pinned memory
        (:func:`~.pinned.pinned_array`) is copied straight from there, asynchronously."""
        s = self.next
        if self.last >= 0 and ref in self.segment.swapped and not fresh and \
                self.sets[self.last].published.get(ref.key) is value:
            return
        bufs = _leaves(self.value(ref, s, {}, fresh))
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


class SegmentRunner:
    """The executor's captured segments: a mixin of :class:`~warpvx.runtime.Executor`, whose
    frames' slots, timing events, buffer pools and stream it uses.

    ``max_lanes`` (default :data:`MAX_LANES`): the streams a segment captured from now on
    spreads its tasks over (1: one chain on the executor's stream).

    ``instances`` (default :data:`INSTANCES` on CUDA, 1 elsewhere): buffer sets, and graphs,
    of each captured segment that frames go round (:class:`SegmentGraph`); with more than one,
    on CUDA, set *k* runs on streams of its own (its copies in, replay and copies out), forked
    from the executor's stream after the frame's work there and waiting only where data flows
    (the previous frame's run for the delayed values it reads, another stream's values): frames
    in flight overlap on the device. 1: every frame on the executor's stream, in order."""

    _max_lanes = MAX_LANES
    _instances = None
    _set_streams = None  # set index (-1: the executor's) -> its stream and lanes' (CUDA)
    _fork_events = None  # a set's stream -> the event it waits for on the executor's
    _recent = None  # segment index -> the SegmentGraph its last frame ran (_inputs_key)
    _linked = True

    @property
    def max_lanes(self) -> int:
        return self._max_lanes

    @max_lanes.setter
    def max_lanes(self, n: int):
        self._max_lanes = check_int(n, "max_lanes", min_value=1)

    @property
    def linked(self) -> bool:
        """With :attr:`instances` > 1 on CUDA, a run's tasks that read the previous frame's
        delayed values wait for those inside the graph, not the whole run for the previous
        run (:meth:`SegmentGraph.link`); False: the whole run waits (for comparisons). Set
        before frames are in flight: the segments' graphs are made again."""
        return self._linked

    @linked.setter
    def linked(self, on: bool):
        self._linked = check_bool(on, "linked")
        self._captured.clear()
        self._recent = None

    @property
    def instances(self) -> int:
        if self._instances is None:
            return INSTANCES if self.cuda else 1
        return self._instances

    @instances.setter
    def instances(self, n: int | None):
        """Set before frames are in flight: the segments' graphs are made again."""
        self._instances = None if n is None else check_int(n, "instances", min_value=1)
        self._captured.clear()
        self._recent = None

    def _streams(self, sg: SegmentGraph, s: int):
        """The streams of ``sg``'s lanes for a run of its set ``s``, the run's own first (the
        executor's with one instance; None off CUDA). Each set has lanes of its own, as two
        sets' graphs may run at once and the primitives' scratch is per stream."""
        if not self.cuda:
            return None
        key = s if self.instances > 1 else -1
        if self._set_streams is None:
            self._set_streams = {}
        streams = self._set_streams.get(key)
        if streams is None:
            first = self._stream if key < 0 else warp().Stream(self._stream.device)
            streams = (first,)
        extra = (sg.lanes.count if sg.lanes else 1) - len(streams)
        if extra > 0:
            wp = warp()
            streams += tuple(wp.Stream(self._stream.device) for _ in range(extra))
        self._set_streams[key] = streams
        return streams

    def _captures_of(self, frame: Frame) -> list:
        """The capture states of ``frame``'s input signature, one per segment: a dict of
        :meth:`_segment_graph`'s states by the shapes of the segment's own inputs, or None
        (not capturable)."""
        states = self._captured.get(frame.signature)
        if states is None:
            states = self._captured[frame.signature] = [{} for _ in self._segments]
            while len(self._captured) > MAX_SIGNATURES:
                self._captured.popitem(last=False)
        else:
            self._captured.move_to_end(frame.signature)
        return states

    @staticmethod
    def _forget(states: list, i: int, sg: SegmentGraph):
        """The input shapes ``sg`` was made for run segment ``i`` eagerly from now; its other
        shapes keep their graphs (``states``: a signature's capture states)."""
        by_shape = states[i]
        if by_shape is None:
            return
        for key, value in list(by_shape.items()):
            if value is sg:
                by_shape[key] = None

    def _segment_graph(self, states: list, i: int, seg: Segment, frame: Frame, state):
        """Segment ``i``'s :class:`SegmentGraph` for this frame's signature and the shapes of
        the segment's inputs (a value made in an earlier frame, such as its corners, may
        change them): made on the first sighting and run uncaptured on its fixed buffers (so
        its values have the captured form from the start, Counted corners included, and the
        primitives' caches are filled), captured on the second (with two buffer sets: the
        first three sightings run uncaptured, the first set's twice so that it has read the
        second's buffers, the next two capture); None: run the tasks eagerly.
        Each state: a SegmentGraph, or None (not capturable with these shapes); at most
        :data:`MAX_SIGNATURES` shapes per segment are kept."""
        by_shape = states[i]
        if by_shape is None:
            return None
        slots, waited = self._ready_inputs(frame, seg.inputs)
        if waited:
            state.prev_end = None  # the stream may idle while we waited: a fresh start event
        try:
            key = self._inputs_key(by_shape, i, seg, slots)
        except NotCapturable as exc:
            _log.debug("segment %s runs eagerly: %s", seg.tasks[0].name, exc)
            states[i] = None
            return None
        if key not in by_shape:
            try:
                sg = SegmentGraph(seg, [s.value for s in slots], self.gpu_device, self._spans,
                                  self.max_lanes, self.instances)
                if self.cuda and self.instances > 1 and self.linked:
                    sg.link(self._stream.device)
            except NotCapturable as exc:
                _log.debug("segment %s, inputs %s, runs eagerly: %s", seg.tasks[0].name, key, exc)
                sg = None
            by_shape[key] = sg
            while len(by_shape) > MAX_SIGNATURES:
                del by_shape[next(iter(by_shape))]
        else:
            sg = by_shape[key]
        if sg is not None:
            sg.key = key
            if self._recent is None:
                self._recent = {}
            self._recent[i] = sg
        if sg is None or not sg.due():
            return sg
        first = not sg.captured
        try:
            with self._capture_lock:
                while True:
                    try:
                        sg.capture(self.gpu_device, self._streams(sg, sg.next))
                        break
                    except NotCapturable as exc:  # refused: unlinked, then on one chain
                        how = "unlinked" if sg.unlink() else \
                            "on one lane" if sg.single_lane() else None
                        if how is None:
                            raise
                        _log.debug("segment %s, inputs %s, captured again %s: %s",
                                   seg.tasks[0].name, key, how, exc)
                        if not sg.due():  # (one lane: a run first makes this set's scratch)
                            return sg
        except NotCapturable as exc:  # a host sync or read-back inside, a caller's capture
            _log.debug("segment %s, inputs %s, not captured: %s", seg.tasks[0].name, key, exc)
            by_shape[key] = None
            return None
        self.captures += first
        state.prev_end = None  # the stream idled while the host captured
        return sg

    def _inputs_key(self, by_shape: dict, i: int, seg: Segment, slots) -> tuple:
        """The shapes of segment ``i``'s input values (``slots``): the key of ``by_shape``.
        Per frame on the GPU thread, so the last graph's key is taken as it is (no walk of
        the values' trees: ~20-40 us a frame) where nothing can have changed it: every input
        is a graph input (its shape is the signature's) or a delayed value that graph
        published, and those led to that graph once before (:attr:`SegmentGraph.self_keyed`).

        Raises
        ------
        NotCapturable
            An input holds no array.
        """
        last = self._recent.get(i) if self._recent is not None else None
        if last is not None and last.self_keyed and by_shape.get(last.key) is last and \
                self._reads_own(last, seg, slots):
            return last.key
        key = tuple(tuple(tuple(a.shape) for a in _leaves(s.value)) for s in slots)
        if last is not None and by_shape.get(key) is last and self._reads_own(last, seg, slots):
            last.self_keyed = True
        return key

    def _reads_own(self, sg: SegmentGraph, seg: Segment, slots) -> bool:
        """Every input of ``seg`` (``slots``) is a graph input or what ``sg``'s last run
        published for it."""
        published = sg.sets[sg.last].published if sg.last >= 0 else None
        if not published:
            return False
        inputs = self.program.inputs
        for ref, s in zip(seg.inputs, slots):
            graph_input = ref.offset == 0 and ref.key in inputs
            if not graph_input and published.get(ref.key) is not s.value:
                return False
        return True

    def _run_segment(self, frame: Frame, seg: Segment, sg: SegmentGraph, state):
        """Replay ``sg``: inputs copied into its fixed buffers, one graph launch, the values
        read outside it copied out into the frame's buffers; one timing interval, shared by
        its tasks in proportion to their scheduled durations. With its own stream (CUDA,
        :attr:`instances` > 1) all of it runs there (:meth:`_fork`)."""
        state.task = seg.tasks[0].name
        cuda = self.cuda
        slots, waited = self._ready_inputs(frame, seg.inputs)
        h0 = time.perf_counter()
        streams = self._streams(sg, sg.next)
        stream = streams[0] if cuda else None
        forked = cuda and stream is not self._stream
        if forked:
            ev0 = self._fork(frame, sg, slots, stream)
        else:
            ev0 = self._start_event(frame, state, slots, waited) if cuda else h0
        try:
            ev1 = self._replay(frame, seg, sg, state, slots, streams)
        finally:
            if forked:
                stream.device.set_stream(self._stream, sync=False)
        if ev1 is False:  # run eagerly
            return
        h1 = time.perf_counter()
        for task in seg.tasks:
            lo, hi = frame.shares[task.name] = self._shares[task.name]
            frame.trace[task.name] = (state.proc, ev0, ev1, None) if cuda else \
                (state.proc, h0, h1, None)
            frame.host_trace[task.name] = (h0 + lo * (h1 - h0), h0 + hi * (h1 - h0))
        # The next eager task's start event is on the executor's stream: not this one's.
        state.prev_end = None if forked else ev1

    def _fork(self, frame: Frame, sg: SegmentGraph, slots, stream):
        """Start a run of ``sg`` on its set's own ``stream``: after the frame's work so far on
        the executor's stream (an event there), the device values of other streams among
        ``slots`` (their producers' events) and, for delayed values in the previous set, the
        previous run; ``stream`` becomes the device's current one (the caller restores the
        executor's). Returns the run's start event (on ``stream``)."""
        forks = self._fork_events
        if forks is None:
            forks = self._fork_events = {}
        fork = forks.get(stream.cuda_stream)
        if fork is None:  # one per stream, reused: a wait takes the event's latest record
            fork = forks[stream.cuda_stream] = warp().Event(stream.device)
        self._record(fork)
        wait_event(stream, fork)
        swapped = sg.segment.swapped
        if swapped:
            published = sg.sets[sg.last].published if sg.last >= 0 else {}
            sg.wait_previous(stream, any(ref in swapped and published.get(ref.key) is not s.value
                                         for ref, s in zip(sg.segment.inputs, slots)))
        for ref, s in zip(sg.segment.inputs, slots):
            if s.external and s.event is not None and not (
                    swapped and published.get(ref.key) is s.value):  # (the previous run's)
                wait_event(stream, s.event)
        stream.device.set_stream(stream, sync=False)
        events = self._events
        ev0 = events.get()
        frame.events.append(ev0)
        record_event(stream, ev0)
        return ev0

    def _replay(self, frame: Frame, seg: Segment, sg: SegmentGraph, state, slots, streams):
        """:meth:`_run_segment`'s copies in, launch and copies out on ``streams`` (the first
        the run's; None off CUDA); its outputs published. Returns the end event (on CUDA;
        None elsewhere) or False: the segment's tasks ran eagerly instead."""
        io = state.io
        stream = streams[0] if streams else self._stream
        before = io.moved
        fresh = sg.reads_fresh([s.value for s in slots])
        for ref, s in zip(seg.inputs, slots):
            sg.fill(ref, s.value, io, stream, fresh)
        if io.moved > before:
            frame.copied[seg.tasks[0].name] = io.moved - before
        replay = sg.sets[sg.next].graph is not None and not fresh
        try:
            fixed = sg.launch(streams, fresh)
        except NotCapturable as exc:  # uncaptured first run: an out= did not fit these inputs
            _log.debug("segment %s runs eagerly: %s", seg.tasks[0].name, exc)
            self._forget(self._captures_of(frame), self._segments.index(seg), sg)
            if streams and stream is not self._stream:
                stream.device.set_stream(self._stream, sync=False)
                wait_event(self._stream, stream.record_event())
            for task in seg.tasks:  # eagerly, as the executor runs an uncaptured segment
                self._run_gpu_task(frame, task, state)
            return False
        self.replays += replay
        outs = dict(fixed)
        blocks = {}  # a node's Counted outputs share one block: copied once
        for key in seg.outputs:
            outs[key] = self._copy_out(frame, key, fixed[key], sg, blocks, stream)
        sg.publish(outs)
        ev1 = None
        if streams and stream is not self._stream:
            sg.finish(stream)
        if self.cuda:
            ev1 = self._end_event(frame) if stream is self._stream else \
                self._forked_end(frame, stream)
        external = ev1 is not None and stream is not self._stream
        for task in seg.tasks:
            for key in task.outputs:
                slot = frame.slots[key]
                slot.set(outs[key], DEVICE, ev1)
                # Made on another stream than the executor's: its readers there wait for it.
                slot.external = external
        return ev1

    def _forked_end(self, frame: Frame, stream):
        """The end event of a run on its own ``stream``, which the frame's wait joins."""
        ev1 = self._events.get()
        frame.events.append(ev1)
        record_event(stream, ev1)
        frame.forked.append(ev1)
        return ev1

    def _copy_out(self, frame: Frame, key: str, fixed, sg: SegmentGraph, blocks: dict, stream):
        """A copy of ``fixed`` (the value of ``key`` in ``sg``'s buffers) in buffers of
        ``frame``'s, on ``stream``: a Counted with a block as one copy of the block, shared
        with its node's other outputs whose copies are reused under the same rule
        (``blocks``: (id of a fixed block, rule) -> its copy in this frame); other values
        array by array."""
        if is_counted(fixed) and fixed.block is not None:
            rule = self._upload_rule.get(key)
            array = fixed.block.array
            buf = blocks.get((id(array), rule))
            if buf is None:
                buf = blocks[id(array), rule] = self._copy_array(frame, key, array, stream)
            return sg.block_view(fixed.block, buf, rule != "never")
        return tree_map(lambda a: self._copy_array(frame, key, a, stream), fixed)

    def _copy_array(self, frame: Frame, key: str, fixed, stream):
        """A copy of fixed array ``fixed`` (of value ``key``) into a buffer of ``frame``'s."""
        buf = self._lease_upload(frame, key, fixed.shape, fixed.dtype)
        copy_device(buf, fixed, stream)
        return buf

    def _copy_rule(self, seg: Segment, key: str) -> str:
        """When the copy of ``key`` a captured segment makes for its frame may be reused
        (:meth:`_reuse_rule` over the tasks outside ``seg`` that read it)."""
        inside = {t.name for t in seg.tasks}
        readers = [t.name for t in self.program.tasks.values() if t.name not in inside
                   and any(r.key == key for r in t.inputs)]
        return self._reuse_rule(self._data, readers, [key])

    def _segment_shares(self) -> dict:
        """task -> (start, end) fractions of its captured segment's measured interval, in
        proportion to the schedule's durations (a replay is timed as a whole)."""
        shares = {}
        for seg in self._segments:
            if seg.captured:
                names = [t.name for t in seg.tasks]
                shares.update(zip(names, proportional_shares([self._spans[n] for n in names])))
        return shares


__all__ = ["MAX_LANES", "MAX_SIGNATURES", "Lanes", "NotCapturable", "Segment", "SegmentGraph",
           "SegmentRunner", "lanes", "segments", "signature"]
