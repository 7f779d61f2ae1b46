"""The executor's captured segments, run frame after frame (:class:`SegmentRunner`, a mixin of
:class:`~warpvx.runtime.Executor`): which :class:`~warpvx.runtime.capture.SegmentGraph` a
frame's segment replays (per input signature and shapes of the segment's own inputs, made on
the first sighting, captured on a later one, dropped to eager when capture fails), the copies
in and out around a replay, the buffer sets' streams and their forks from the executor's
stream. :mod:`warpvx.runtime.capture` holds the pure segment rule and the captured graph.
"""

from __future__ import annotations

import time

from .._counted import is_counted
from ..check import check_bool, check_int
from .capture import (MAX_LANES, MAX_SIGNATURES, NotCapturable, Segment, SegmentGraph,
                      _leaves, _log)
from .native_copy import (copier, copy_device, is_warp_array, record_event, wait_event,
                          warp)
from .timeline import Frame, proportional_shares
from .transfers import tree_map

#: Buffer sets (and graphs) per captured segment on CUDA, frames going round them on streams
#: of their own (:attr:`SegmentRunner.instances`), for frames in flight to overlap on the
#: device. 1 by default: on the H100 (session 6, `capture_stream.py`, two-camera graph at
#: 1280x720, depth 3 and 6) 3 or 6 sets measured no overlap (frames' GPU intervals summed /
#: covered 1.00-1.01) and FPS within the runs' spread (pinned frames, depth 3: 408 with one
#: set, 399-402 with 3 or 6); the host, not the device, bounds that stream.
INSTANCES = 1


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
    def serial_tasks(self) -> frozenset:
        """Names of the tasks that insert conditional graph nodes in the segments made so
        far: their lanes are joined before each (:class:`~.lanes.Lanes`; known from a
        segment's first run)."""
        return frozenset(sg.segment.tasks[i].name for states in self._captured.values()
                         for by_shape in states if by_shape for sg in by_shape.values()
                         if sg is not None and sg.lanes is not None for i in sg.lanes.serial)

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
            sg.ready = (frame, slots)  # for _run_segment, next on this thread
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
            sg.ready = None
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
        ready, sg.ready = sg.ready, None
        if ready is not None and ready[0] is frame:  # found by _segment_graph, all set
            slots, waited = ready[1], False
        else:
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
        shares = self._seg_info[id(seg)][0]
        frame.shares.update(shares)
        frame.trace.update(dict.fromkeys(shares, (state.proc, ev0, ev1, None) if cuda else
                                         (state.proc, h0, h1, None)))
        span = h1 - h0
        frame.host_trace.update({name: (h0 + lo * span, h0 + hi * span)
                                 for name, (lo, hi) in shares.items()})
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
        b = sg.sets[sg.last]
        plan = b.plan
        if plan is None or plan[0] is not fixed:
            plan = b.plan = (fixed, self._copy_plan(fixed, seg.outputs))
        for key, src, copy, block, rule in plan[1]:
            if src is None:
                outs[key] = tree_map(lambda a: self._copy_array(frame, key, a, stream), fixed[key])
            elif block is None:
                outs[key] = self._copy_array(frame, key, src, stream, copy)
            else:
                buf = blocks.get((id(src), rule))
                if buf is None:
                    buf = blocks[id(src), rule] = self._copy_array(frame, key, src, stream, copy)
                outs[key] = sg.block_view(block, buf, rule != "never")
        sg.publish(outs)
        ev1 = None
        if streams and stream is not self._stream:
            sg.finish(stream)
        if self.cuda:
            ev1 = self._end_event(frame) if stream is self._stream else \
                self._forked_end(frame, stream)
        external = ev1 is not None and stream is not self._stream
        # (external: made on another stream than the executor's; its readers there wait.)
        keys = self._seg_info[id(seg)][1]
        self._set_devices(frame, keys, [outs[key] for key in keys], ev1, state, external,
                          seg.tasks[0].name)
        return ev1

    def _forked_end(self, frame: Frame, stream):
        """The end event of a run on its own ``stream``, which the frame's wait joins."""
        ev1 = self._events.get()
        frame.events.append(ev1)
        record_event(stream, ev1)
        frame.forked.append(ev1)
        return ev1

    def _copy_plan(self, fixed: dict, keys) -> tuple:
        """How :meth:`_replay` copies values ``keys`` of ``fixed`` (a buffer set's outputs:
        key -> its value in the fixed buffers) into buffers of the frame's, each
        ``(key, src, copy, block, rule)``: a Counted with a block as one copy of the block
        (``src``, its array; ``block``), shared with its node's other outputs whose copies are
        reused under the same ``rule`` (a view of the copy made once per pooled buffer:
        :meth:`SegmentGraph.block_view`); a Warp array as one copy (``src``); ``copy``: the
        copy's :func:`~.native_copy.copier`; another tree array by array (all None). Made
        once per outputs dict, not per frame."""
        plan = []
        for key in keys:
            value = fixed[key]
            if is_counted(value) and value.block is not None:
                src = value.block.array
                plan.append((key, src, copier(src), value.block, self._upload_rule.get(key)))
            elif is_warp_array(value):
                plan.append((key, value, copier(value), None, None))
            else:
                plan.append((key, None, None, None, None))
        return tuple(plan)

    def _copy_array(self, frame: Frame, key: str, fixed, stream, copy=None):
        """A copy of fixed array ``fixed`` (of value ``key``) into a buffer of ``frame``'s
        (``copy``: its :func:`~.native_copy.copier`, if made)."""
        buf = self._lease_upload(frame, key, fixed.shape, fixed.dtype)
        if copy is None:
            copy_device(buf, fixed, stream)
        else:
            copy(buf, stream)
        return buf

    def _copy_rule(self, seg: Segment, key: str) -> str:
        """When the copy of ``key`` a captured segment makes for its frame may be reused
        (:meth:`_reuse_rule` over the tasks outside ``seg`` that read it)."""
        inside = {t.name for t in seg.tasks}
        readers = [t.name for t in self.program.tasks.values() if t.name not in inside
                   and any(r.key == key for r in t.inputs)]
        return self._reuse_rule(self._data, readers, [key])

    def _segment_info(self) -> dict:
        """id of each captured segment -> (task -> its (start, end) fractions of the segment's
        measured interval, in proportion to the schedule's durations (a replay is timed as a
        whole), in queue order; every key its tasks publish). The executor's segments live
        as long as it."""
        info = {}
        for seg in self._segments:
            if seg.captured:
                names = [t.name for t in seg.tasks]
                shares = proportional_shares([self._spans[n] for n in names])
                info[id(seg)] = (dict(zip(names, shares)),
                                 tuple(k for t in seg.tasks for k in t.outputs))
        return info


__all__ = ["SegmentRunner"]
