"""Frames in flight and what they measured: :class:`Frame` (slots, cancel flag, the raw trace
of host times or CUDA events), :class:`FrameResult` (the timeline in ms) and the pool of CUDA
timing events the trace is made of."""

from __future__ import annotations

import threading
import time
import weakref
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field

from ..sched.schedule import ScheduledTask
from .native_copy import elapsed_since, warp
from .slots import Flag, Slot

#: Seconds between cancellation checks of a blocked wait.
WAIT_SLICE = 0.02

_BUILD_LOCK = threading.Lock()  # see _Trace.build


def proportional_shares(spans) -> list:
    """(start, end) fractions of one measured interval for tasks run back to back in it, in
    proportion to ``spans`` (their scheduled durations; equal parts when all are 0)."""
    spans = [max(0.0, s) for s in spans]
    total = sum(spans)
    if total <= 0:
        spans, total = [1.0] * len(spans), float(len(spans))
    out, at = [], 0.0
    for span in spans:
        out.append((at / total, (at + span) / total))
        at += span
    return out


class Cancelled(Exception):
    """The frame a wait belongs to was cancelled (caught inside the executor)."""


class EventPool:
    """Reusable CUDA timing events of one device (creating events per task costs more than
    recording them). :meth:`get` hands out a free one; :meth:`put` takes back events whose
    frame is over and whose timeline has been read (:meth:`lend`); :meth:`reserve` makes
    events ahead, where their creation is timed by nobody. No lock: a list's ``pop`` and
    ``extend`` are atomic (one per GPU task on the critical thread; ``MAX_FREE`` is a soft
    bound)."""

    MAX_FREE = 8192
    #: Unread timelines that may hold their frame's events; past it, the oldest one's events
    #: are read and go back: a caller keeping every result must not make the pool create
    #: events for every frame (creating one costs more than reading one). Above a plan's
    #: window of kept results (``Plan.last_run``, 64 frames) plus frames in flight: a stream
    #: then reads no event on its frames' critical path (a result leaving the window is
    #: garbage, its events go back unread); below it, every frame read an old frame's
    #: events (a native call each) before returning.
    MAX_UNREAD = 96

    def __init__(self, device: str):
        self.device = device
        self._free: list = []
        self._unread: deque = deque()  # weak references to the timelines lent events, oldest first

    def get(self):
        try:
            return self._free.pop()
        except IndexError:
            return self._make()

    def reserve(self, n: int):
        """At least ``n`` free events: the executor asks for a frame's worth at its
        submission, so that no event is made inside a GPU task's timed host call (one
        creation, a few us, is more than the task's own enqueue of an identity node), as
        happened on every frame while the kept timelines held the pool's events."""
        free = self._free
        while len(free) < n:
            free.append(self._make())

    def _make(self):
        return warp().Event(self.device, enable_timing=True)

    def put(self, events):
        room = self.MAX_FREE - len(self._free)
        if room > 0:
            self._free.extend(events[:room])

    def lend(self, result: "FrameResult"):
        """``result``'s unread timeline holds its frame's events (:func:`frame_result`): they
        come back when it is read or garbage, or here once :attr:`MAX_UNREAD` newer results
        hold theirs (their times read into the trace, the timeline still built lazily)."""
        unread = self._unread
        unread.append(weakref.ref(result.timeline._trace))
        while len(unread) > self.MAX_UNREAD:
            trace = unread.popleft()()
            if trace is not None:
                trace.read_events()

    def __len__(self):
        return len(self._free)


# --------------------------------------------------------------------------- frames


class Frame:
    """A frame in flight: its slots, cancel flag, completion and timeline."""

    def __init__(self, index: int, slots: dict, n_procs: int):
        self.index = index
        self.slots = slots
        # One-shot flags (set, is_set, wait): a lock only when a thread blocks on one.
        self.cancel = Flag()
        self.finished = Flag()
        self.error = None  # (task, processor, exception)
        self.cancelled_by = None
        # task -> (processor, start, end, after_transfers or None): host seconds, or CUDA
        # events for GPU tasks on CUDA.
        self.trace = {}
        self.host_trace = {}  # GPU task -> (start, end) host seconds of its call
        self.copied = {}  # task -> bytes it moved between host and device
        self.t0 = time.perf_counter()
        self.gpu_last_event = None
        self.forked = []  # end events of its work on other streams (captured segments' sets)
        self.events = []  # pooled CUDA events this frame recorded
        self.leases = []  # (task, buffer) output buffers taken from the pools
        self.uploads = []  # (key, buffer) upload buffers taken from the pools
        self.staged = []  # slots with a staged download (Transfers.stage_download), freed by then
        self.stage_outputs = True  # the caller reads host outputs: stage their downloads
        self.capture = False  # replay captured GPU segments
        self.signature = None  # the capture key of its inputs' shapes and dtypes
        self.shares = {}  # task -> (start, end) fractions of its segment's or burst's interval
        self.bursts = False  # CUDA timing "bursts" (Executor.timing)
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
        if slot.ready:
            return
        if spin > 0:
            deadline = time.perf_counter() + spin
            while time.perf_counter() < deadline:
                time.sleep(0)  # lets the producer have the GIL
                if slot.ready:
                    return
        while not slot.wait(WAIT_SLICE):
            if self.cancel.is_set() or closing.is_set():
                raise Cancelled()


class _Trace:
    """A frame's raw trace (host seconds, or CUDA events for GPU tasks), turned into its
    result's dicts (ms from submission) on the first read: results are kept by the dozen
    (``Plan.last_run``) and most are never read, while building one :class:`ScheduledTask`
    per task cost ~1 us a task, and reading a CUDA event's time a native call per event, on
    the critical path of every frame.

    ``anchor``: the ``(host seconds, timing event)`` the GPU events are read against
    (:func:`event_clock`; None when every time is a host time). ``events``: the frame's
    pooled CUDA events, handed to ``recycle`` once read, or once the trace is garbage
    unread: a pooled event is never recorded again while a trace may still read it."""

    __slots__ = ("t0", "trace", "host", "shares", "built", "anchor", "events", "recycle",
                 "__weakref__")

    def __init__(self, t0: float, trace: dict, host: dict, shares: dict, anchor=None,
                 events: list | None = None, recycle=None):
        self.t0, self.trace, self.host, self.shares = t0, trace, host, shares
        self.anchor, self.events, self.recycle = anchor, events, recycle
        self.built = None

    def build(self) -> tuple:
        """``(timeline, transfers, host)`` (built once)."""
        built = self.built
        if built is not None:
            return built
        with _BUILD_LOCK:  # events go back to their pool after one read: one build at a time
            if self.built is None:
                self._read_events()
                self.built = self._build()
        return self.built

    def read_events(self):
        """Read the GPU events' times into the trace (host seconds) and let the events go."""
        with _BUILD_LOCK:
            self._read_events()

    def _read_events(self):
        if self.anchor is None:
            return
        to_host = event_clock(self.anchor)
        trace = self.trace
        for task, (proc, a, b, mid) in trace.items():
            if proc[0] == "g":  # "gpu": events
                trace[task] = (proc, to_host(a), to_host(b), mid if mid is None else to_host(mid))
        self.anchor = None
        self._recycle()

    def _build(self) -> tuple:
        timeline, transfers, host = {}, {}, {}
        trace = self.trace
        t0, shares = self.t0, self.shares
        for task, (proc, a, b, mid) in trace.items():
            share = shares.get(task)
            if share is not None:  # a task of a captured segment: its part of the replay
                a, b = a + share[0] * (b - a), a + share[1] * (b - a)
            timeline[task] = ScheduledTask(task, proc, (a - t0) * 1e3, (b - t0) * 1e3)
            if mid is not None:
                transfers[task] = (mid - a) * 1e3
        for task, (a, b) in self.host.items():
            host[task] = ((a - t0) * 1e3, (b - t0) * 1e3)
        return timeline, transfers, host

    def _recycle(self):
        events, self.events = self.events, None
        if events:
            self.recycle(events)


class _EventTrace(_Trace):
    """A :class:`_Trace` holding CUDA events: garbage unread, it lets them go (a ``__del__``
    only where there are events: it costs every other frame's result too)."""

    __slots__ = ()

    def __del__(self):
        self._recycle()


class _Lazy(Mapping):
    """One of a :class:`_Trace`'s dicts (``part``: 0 timeline, 1 transfers, 2 host), built
    when first read: a read-only mapping like the dict it stands for."""

    __slots__ = ("_trace", "_part")

    def __init__(self, trace: _Trace, part: int):
        self._trace, self._part = trace, part

    def _dict(self) -> dict:
        return self._trace.build()[self._part]

    def __getitem__(self, key):
        return self._dict()[key]

    def __iter__(self):
        return iter(self._dict())

    def __len__(self):
        return len(self._dict())

    def __contains__(self, key):
        return key in self._dict()

    def get(self, key, default=None):
        return self._dict().get(key, default)

    def items(self):
        return self._dict().items()

    def values(self):
        return self._dict().values()

    def keys(self):
        return self._dict().keys()

    def __repr__(self):
        return repr(self._dict())


@dataclass
class FrameResult:
    """What :meth:`Executor.wait` returns: outputs, the measured timeline and the makespan.

    ``timeline`` maps task -> :class:`ScheduledTask` with times in ms from the frame's
    submission (``t0``, host ``perf_counter`` seconds); ``makespan`` is the latest finish.
    ``transfers``: task -> ms of its interval spent on host <-> device copies (uploads of a
    GPU task, downloads of a CPU task); ``copied``: task -> bytes it copied; ``host``: GPU
    task -> (start, finish) ms of the GPU thread's call (enqueue plus host syncs inside it),
    on the same axis as ``timeline``. The executor's ``timeline``, ``transfers`` and ``host``
    are read-only mappings built on their first read.
    """

    index: int
    outputs: dict
    timeline: Mapping
    t0: float
    transfers: Mapping = field(default_factory=dict)
    copied: dict = field(default_factory=dict)
    host: Mapping = field(default_factory=dict)

    def compute_ms(self, task) -> float:
        """The task's measured time without its transfers (ms)."""
        t = self.timeline[task]
        return max(0.0, t.finish - t.start - self.transfers.get(task, 0.0))

    @property
    def makespan(self) -> float:
        return max((t.finish for t in self.timeline.values()), default=0.0)


def frame_result(frame: Frame, outputs: dict, anchor=None, recycle=None) -> FrameResult:
    """``frame``'s outputs plus its measured timeline (ms from submission), built lazily.

    ``anchor``: ``(host seconds, timing event)`` (:func:`event_clock`) when GPU tasks were
    timed with CUDA events, read when the timeline is first read (None when every time is a
    host time); the frame's events (``frame.events``, taken from it) go to ``recycle`` (a
    pool's ``put``) then, or once the result is garbage unread.
    """
    if anchor is None:
        raw = _Trace(frame.t0, frame.trace, frame.host_trace, frame.shares)
    else:
        events, frame.events = frame.events, []
        raw = _EventTrace(frame.t0, frame.trace, frame.host_trace, frame.shares, anchor, events,
                          recycle)
    return FrameResult(frame.index, outputs, _Lazy(raw, 0), frame.t0, _Lazy(raw, 1),
                       frame.copied, _Lazy(raw, 2))


def event_clock(anchor):
    """event -> host seconds through ``anchor`` (``(host seconds, timing event)`` recorded
    while the stream was idle); each event read once."""
    base, anchor_event = anchor
    elapsed = elapsed_since(anchor_event)
    seen = {}  # Warp events hash by identity

    def convert(ev):
        t = seen.get(ev)
        if t is None:
            t = seen[ev] = base + elapsed(ev) * 1e-3
        return t

    return convert


__all__ = ["WAIT_SLICE", "Cancelled", "EventPool", "Frame", "FrameResult", "frame_result",
           "event_clock", "proportional_shares"]
