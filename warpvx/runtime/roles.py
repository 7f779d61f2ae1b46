"""Roles: how an :class:`~warpvx.runtime.Executor` runs a one-frame schedule's processors
(see its module docstring). A :class:`Role` is one processor's progress through its frames;
:class:`RoleRunner` (a mixin of the executor) runs roles on threads, inline where it pays;
:class:`DeviceScope` makes the GPU role's device and stream current on whichever thread runs it."""

from __future__ import annotations

import threading
import time
from collections import deque

from .capture import NotCapturable, _log
from .slots import DEVICE
from .timeline import WAIT_SLICE, Cancelled, Frame
from .transfers import Transfers


def is_gpu_processor(name: str) -> bool:
    """Whether processor ``name`` of a schedule is the GPU role (``"gpu"``)."""
    return name.startswith("gpu")


class GpuState:
    """The GPU role's state through a frame (whichever thread runs it)."""

    __slots__ = ("proc", "io", "prev_end", "task", "burst", "burst_frame", "stage")

    def __init__(self, proc: str, io: Transfers):
        self.proc = proc
        self.io = io
        # The event the next task starts at: the last one recorded while the thread has not
        # waited since (with timing "bursts", the open burst's start).
        self.prev_end = None
        self.task = "<executor>"  # the task running, for error reports
        self.burst: list = []  # timing "bursts": tasks enqueued since prev_end, no end event yet
        self.burst_frame = None  # their frame
        # The running unit's outputs to stage (key -> held by a delay's ring; one of
        # Role.stage's maps, read only): their downloads start as they are published, before
        # a reader can see them (RoleRunner._set_devices).
        self.stage: dict = {}


class DeviceScope:
    """The GPU role's device, and on CUDA its stream, made current around runs of its units
    on whichever threads run them: the stream set with ``sync=False`` (the stream's order is
    ours; the user's stream is no producer), or on Warp's CPU device only the default
    device, without saving the thread's CUDA context (~4 us a run).

    Warp's current device and stream are the process's, so the scope is shared: the first
    holder (:meth:`acquire`) makes them current, the last to :meth:`release` restores the
    previous ones; each holding thread pushes the device's CUDA context (thread-local). A
    thread running an alternating chain inline holds it across its short CPU units
    (:meth:`RoleRunner._drive`): without it, every hand-off to a GPU unit paid setting and
    restoring the stream and context (four native calls)."""

    __slots__ = ("device", "stream", "saved", "holders", "_lock")

    def __init__(self, device, stream):
        self.device = device
        self.stream = stream
        self.saved = None
        self.holders = 0
        self._lock = threading.Lock()

    def acquire(self):
        dev = self.device
        stream = self.stream
        if stream is not None:
            dev.context_guard.__enter__()
        with self._lock:
            if not self.holders:
                runtime = dev.runtime
                if stream is None:
                    self.saved = (runtime.default_device, None)
                else:
                    self.saved = (runtime.default_device, dev.stream)
                    dev.set_stream(stream, sync=False)
                runtime.default_device = dev
            self.holders += 1

    def release(self):
        dev = self.device
        with self._lock:
            self.holders -= 1
            if not self.holders:
                default, stream = self.saved
                if stream is not None:
                    dev.set_stream(stream, sync=False)
                dev.runtime.default_device = default
        if self.stream is not None:
            dev.context_guard.__exit__(None, None, None)

    def __enter__(self):
        self.acquire()

    def __exit__(self, *exc):
        self.release()


class Role:
    """One processor's progress through its frames (one-frame schedules): the thread holding
    ``token`` runs its next units, its own thread or another one inline (see
    :meth:`RoleRunner._drive`). ``units``: its queue (CPU tasks, or the GPU queue's segments as
    ``(index, segment)``); ``refs``: each unit's input references (what makes it ready);
    ``frames``: the frames it has still to run, oldest first, ``pos`` the next unit of the
    oldest; ``signal``: released to wake its thread; ``short``: which units may run inline
    (:attr:`RoleRunner.INLINE_MAX_MS`); ``one``: per unit, the key of its only input when it
    reads one value of its own frame (the usual unit: its readiness is one slot's flag), else
    None."""

    __slots__ = ("proc", "gpu", "units", "refs", "one", "last", "short", "frames", "pos",
                 "token", "signal", "state", "captures", "touch", "stage")

    def __init__(self, proc: str, units: list, refs: list, short: list, state: "GpuState | None"):
        self.proc = proc
        self.gpu = state is not None
        self.units = units
        self.refs = refs
        self.one = [r[0].key if len(r) == 1 and r[0].offset == 0 else None for r in refs]
        self.last = len(units) - 1  # the frame's last unit here
        self.short = short  # per unit: short enough to run inline on another role's thread
        self.frames: deque = deque()
        self.pos = 0
        self.token = threading.Lock()
        self.signal = threading.Lock()
        self.signal.acquire()
        self.state = state
        self.captures = None  # the oldest frame's capture states (GPU role)
        self.touch: list = []  # per unit: the other roles that read what it publishes
        # Per GPU unit: its outputs whose download starts at once, key -> held (a delay's
        # value, its download kept in the ring's slot for a later frame's reader), as two
        # maps: [0] for a frame whose caller wants no host outputs, [1] for one that does.
        self.stage: list = []

    def wake(self):
        try:
            self.signal.release()
        except RuntimeError:  # already awake
            pass


class RoleRunner:
    """The executor's roles (one-frame schedules): a mixin of
    :class:`~warpvx.runtime.Executor`, whose tasks, segments, frames and transfers it runs.

    A role's units run on whichever thread holds its token. A thread runs its own role while
    the next unit is ready; when it is not, a short unit its output made ready on another
    role, whose thread would otherwise be woken, runs inline (a serial chain alternating CPU
    and GPU tasks then never wakes a thread). Nobody blocks on a value: a role's thread
    sleeps on its signal until a producer finds the role ready and not taken. No lost
    wake-up: a producer publishes before it looks at the token, and a token holder looks at
    readiness again after letting the token go.
    """

    #: A unit (a task, or a GPU segment) scheduled to take this long or less (ms) may run
    #: inline on the thread of the role whose output it waited for, instead of waking its
    #: own role's thread (a wake-up, 10-30 us, is worth saving on short units only: a long
    #: one inline would hold that thread's own role back).
    INLINE_MAX_MS = 0.1

    def _make_roles(self) -> dict:
        """processor -> its :class:`Role`: units, what makes each ready, which may run inline,
        which roles read what each publishes, which outputs to stage."""

        def short(tasks) -> bool:
            ms = sum(self.placed[t.name, 0].finish - self.placed[t.name, 0].start for t in tasks)
            return ms <= self.INLINE_MAX_MS

        staged, outputs_staged = self._staged_keys()
        rings = self.program.rings
        roles = {}
        for p in self._active:
            if is_gpu_processor(p):
                units = list(enumerate(self._segments))
                refs = [seg.inputs if seg.captured else seg.tasks[0].inputs for seg in self._segments]
                roles[p] = Role(p, units, refs, [short(seg.tasks) for seg in self._segments],
                                GpuState(p, Transfers(self.gpu_device, self._host_pool)))
            else:
                units = self.queues[p]
                roles[p] = Role(p, units, [t.inputs for t in units], [short([t]) for t in units],
                                None)
        reading: dict = {}  # key -> roles with a unit reading it (at any frame offset)
        for role in roles.values():
            for refs in role.refs:
                for ref in refs:
                    reading.setdefault(ref.key, {})[id(role)] = role
        for role in roles.values():
            for unit in role.units:
                keys = [k for t in (unit[1].tasks if role.gpu else [unit]) for k in t.outputs]
                touch = {id(r): r for k in keys for r in reading.get(k, {}).values() if r is not role}
                role.touch.append(tuple(touch.values()))
                held = {k: k in rings for k in keys if k in staged}
                role.stage.append(({k: h for k, h in held.items() if k not in outputs_staged},
                                   held))
        return roles

    def _staged_keys(self) -> tuple:
        """(keys whose download starts as soon as the GPU role publishes them (with a host
        pool), the graph outputs among them no CPU task reads): read by a CPU task, of the
        same frame or (a delay's value, ``delay[-j]``) of a later one, or by the caller (a
        graph output; staged only in frames whose caller wants host data:
        ``Frame.stage_outputs``). A delay's staged download lives in its ring's slot until a
        reader takes it or the ring drops the slot (:class:`~.slots.Ring`), not until its
        frame is waited for: the reader of frame *i+j* may run after frame *i*'s wait."""
        if self._host_pool is None:
            return set(), set()
        reads = {r.key for p in self._active if not is_gpu_processor(p)
                 for t in self.queues[p] for r in t.inputs}
        outputs = set(self.program.outputs.values())
        return reads | outputs, outputs - reads

    def _role_loop(self, proc: str):
        home = self._roles[proc]
        closing = self._closing
        spin = self.spin
        while not closing.is_set():
            if self._ready(home) and not home.token.locked():
                try:
                    self._drive(home)
                except BaseException as exc:  # noqa: BLE001 - an executor bug must not kill the thread
                    frame = home.frames[0] if home.frames else None
                    if frame is None:
                        raise
                    self._fail(frame, "<executor>", proc, exc)
                continue
            if spin > 0:
                deadline = time.perf_counter() + spin
                while time.perf_counter() < deadline and not self._ready(home):
                    time.sleep(0)  # lets the producer have the GIL
                if self._ready(home):
                    continue
            # Frames waiting: a time-out, as a delay's value may come without a producer (a
            # user's write, a cancelled frame's slot dropped). None: until submit or close.
            home.signal.acquire(timeout=WAIT_SLICE if home.frames else -1)

    def _drive(self, home: Role):
        """Run ``home``'s ready units on this thread, then (while ``home`` waits) those of a
        role that this thread's work made ready, inline; wake the roles it made ready and
        does not run."""
        role = home
        scoped = False  # this thread holds the GPU role's DeviceScope
        idle = False  # home had nothing ready at this thread's last look
        io = None  # this thread's transfers, for CPU units
        try:
            while True:
                if io is None and not role.gpu:
                    io = self._io()
                touched: list = []
                scoped = self._advance(role, home, touched, scoped, idle, io)
                if role is not home and self._ready(role):
                    role.wake()  # left for a ready home unit, or a long one
                role = None
                idle = not self._ready(home)
                if not idle and not home.token.locked():
                    role = home
                for r in touched:
                    if r is role or r is home or r.token.locked() or not self._ready(r):
                        continue
                    if role is None and r.short[r.pos]:
                        role = r
                    else:
                        r.wake()
                if role is None:
                    return
                if scoped and not role.gpu and not role.short[role.pos]:
                    scoped = False  # kept across short CPU units only
                    self._scope.release()
        finally:
            if scoped:
                self._scope.release()

    def _ready(self, role: Role) -> bool:
        """``role`` has work: its next unit's inputs are all set, or its frame was cancelled.
        Read without the token (a hint, checked again under it)."""
        try:
            frame = role.frames[0]
        except IndexError:
            return False
        if frame.cancel.ready:
            return True
        pos = role.pos
        key = role.one[pos]
        if key is not None:  # the usual unit: one flag
            return frame.slots[key].ready
        fs = frame.slots
        for ref in role.refs[pos]:  # no list: several checks per hand-off
            if not (fs[ref.key] if ref.offset == 0 else self._slot(frame, ref)).ready:
                return False
        return True

    def _inputs_if_ready(self, role: Role, frame: Frame):
        """The slots of ``role``'s next unit's inputs in ``frame`` when all are set, else None."""
        fs = frame.slots
        slots = []
        for ref in role.refs[role.pos]:  # a loop, not a comprehension: no function call
            s = fs[ref.key] if ref.offset == 0 else self._slot(frame, ref)
            if not s.ready:
                return None
            slots.append(s)
        return slots

    def _advance(self, role: Role, home: Role, touched: list, scoped: bool, idle: bool,
                 io: "Transfers | None") -> bool:
        """Holding ``role``'s token (if free), run its units while they may run here: its
        next unit is ready, and ``role`` is ``home`` or the unit is short while ``home`` has
        nothing ready (``idle``: the caller just found it so; looked at again before each
        later unit). After a unit, the roles that read what it published are woken when this
        thread goes on with ``role`` (at once: a producer does not sit on a ready consumer
        while it runs its next unit), else appended to ``touched`` (the caller may run one of
        them inline). ``scoped``: this thread holds the GPU role's :class:`DeviceScope`;
        returned, acquired here before a GPU unit if not (the caller releases it). ``io``:
        this thread's transfers (CPU units)."""
        if not role.token.acquire(False):
            return scoped
        held = scoped
        gpu = role.gpu
        try:
            frames = role.frames
            if gpu:
                io = role.state.io
                role.state.prev_end = None  # the stream may have idled since the last unit
            inline = role is not home
            one = role.one
            readers = ()  # of the unit just run, not told yet
            while frames:
                frame = frames[0]
                if frame.cancel.ready:
                    self._end_frame(role, frame)
                    continue
                # Checked under the token: another thread may have run what made the caller
                # come (and running a unit not ready would block holding the token).
                pos = role.pos
                key = one[pos]
                if key is None:
                    slots = self._inputs_if_ready(role, frame)
                else:  # the usual unit: one input of its own frame, no call
                    s = frame.slots[key]
                    slots = [s] if s.ready else None
                go = slots is not None and (not inline or (
                    role.short[pos] and (idle or not self._ready(home))))
                idle = False
                for r in readers:
                    if r is home or r in touched:
                        continue
                    if not go:
                        touched.append(r)
                    elif not r.token.locked() and self._ready(r):
                        r.wake()
                readers = ()
                if not go:
                    break
                if gpu:
                    if not scoped and self._scope is not None:
                        self._scope.acquire()
                        scoped = True
                    ok = self._run_unit(role, frame, slots)
                else:
                    ok = self._run_cpu_task(role.proc, frame, role.units[pos], io, slots)
                if pos == role.last:
                    self._end_frame(role, frame)
                else:
                    role.pos = pos + 1
                if ok:
                    readers = role.touch[pos]
            for r in readers:  # no unit left here for now: the caller looks at them
                if r is not home and r not in touched:
                    touched.append(r)
        except BaseException:
            if scoped and not held:
                self._scope.release()  # raising: the caller never learns it holds the scope
            raise
        finally:
            if gpu and role.state.burst:  # another thread may run the next units
                self._close_burst(role.state)
            role.token.release()
        return scoped

    def _end_frame(self, role: Role, frame: Frame):
        role.pos = 0
        role.captures = None
        role.frames.popleft()
        frame.processor_done()

    def _run_unit(self, role: Role, frame: Frame, slots: list) -> bool:
        """Run the GPU role's next unit of ``frame`` (``slots``: its inputs, all set); False
        when it failed (the frame is cancelled)."""
        i, seg = role.units[role.pos]
        state = role.state
        if role.pos == 0:
            state.prev_end = None  # a fresh start event: the last end event is another frame's
            state.burst = []  # (a cancelled frame's tasks, never reported)
            role.captures = self._captures_of(frame) if frame.capture else None
        try:
            state.stage = role.stage[role.pos][frame.stage_outputs]
            if seg.captured:
                if state.burst:  # a segment's replay is timed on its own
                    self._close_burst(state)
                self._run_segment_or_tasks(frame, i, seg, state, role.captures)
            else:
                self._run_gpu_task(frame, seg.tasks[0], state, slots)
        except Cancelled:
            return False
        except BaseException as exc:  # noqa: BLE001 - reported to the caller
            self._fail(frame, state.task, role.proc, exc)
            return False
        return True

    def _set_devices(self, frame: Frame, keys, values, event, state: GpuState,
                     external: bool = False, unit: str | None = None):
        """Publish a GPU unit's outputs ``keys`` (``values``, all ready after CUDA ``event``;
        ``external``: made on another stream than the executor's, a captured segment's
        set's). The downloads of those the running unit stages (``state.stage``: read by a
        CPU task or the caller) are queued first, as one batch
        (:meth:`Transfers.stage_downloads`: one wait, one event, one pool lease for
        ``unit``), so a reader woken by the publication always finds its download (else it
        copied on its own when it ran before the staging: a wasted copy, and a count of
        downloads that varied with thread timing).

        A staged value ``held`` (a delay's) keeps its download in its ring's slot for a later
        frame's reader, which releases it (:class:`~.slots.Ring`); any other is released by
        the frame's wait if unread (``Executor._unstage``). A delay's device buffer goes back
        to its pool only once every ring has dropped its frame (``Executor._recycle_ring_held``,
        after ``Ring.age``): its download is queued here, before that; and the ring, dropping
        the slot, waits for the copy (:meth:`Slot.release_staged`) before the buffer is
        recycled."""
        fs = frame.slots
        stage = state.stage
        if stage:
            batch = []
            for key, value in zip(keys, values):
                held = stage.get(key)
                if held is not None and fs[key].staged is None:
                    batch.append((fs[key], value, held))
            if batch:
                downloads = state.io.stage_downloads(
                    [value for _, value, _ in batch], event,
                    after=None if external else self._stream, unit=unit)
                for (slot, _, held), staged in zip(batch, downloads):
                    if staged is not None:
                        slot.staged = staged
                        if not held:
                            frame.staged.append(slot)
        for key, value in zip(keys, values):
            slot = fs[key]
            slot.external = external
            slot.set(value, DEVICE, event)

    def _run_segment_or_tasks(self, frame: Frame, i: int, seg, state: "GpuState", captures):
        """Capturable GPU segment ``i`` of ``frame``: replayed from its captured graph where
        there is one (``captures``: the frame's capture states, or None), else task by task."""
        sg = self._segment_graph(captures, i, seg, frame, state) if captures is not None else None
        if sg is not None:
            try:
                self._run_segment(frame, seg, sg, state)
                return
            except NotCapturable as exc:
                # An input unlike the buffers: e.g. a delay's initial value after a reset where
                # the graph's own output swaps in. These shapes run eagerly from now, the
                # segment's other shapes (every later frame's) still replay.
                _log.debug("segment %s, these inputs run eagerly from now: %s",
                           seg.tasks[0].name, exc)
                self._forget(captures, i, sg)
        for task in seg.tasks:
            if frame.cancel.is_set():
                return
            self._run_gpu_task(frame, task, state)

    def _wake_all(self):
        for role in self._roles.values():
            role.wake()


__all__ = ["DeviceScope", "GpuState", "Role", "RoleRunner", "is_gpu_processor"]
