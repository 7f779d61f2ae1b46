"""Frames in flight and what they measured: :class:`Frame` (slots, cancel flag, the raw trace
of host times or CUDA events), :class:`FrameResult` (the timeline in ms) and the pool of CUDA
timing events the trace is made of."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field

from ..sched.schedule import ScheduledTask
from .native_copy import elapsed_ms, warp
from .slots import Slot

#: Seconds between cancellation checks of a blocked wait.
WAIT_SLICE = 0.02


class Cancelled(Exception):
    """The frame a wait belongs to was cancelled (caught inside the executor)."""


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
        return warp().Event(self.device, enable_timing=True)

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
        self.staged = []  # staged downloads (Transfers.stage_download), freed when it is over
        self.capture = False  # replay captured GPU segments
        self.signature = None  # the capture key of its inputs' shapes and dtypes
        self.shares = {}  # captured task -> (start, end) fractions of its segment's interval
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
                raise Cancelled()


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


def frame_result(frame: Frame, outputs: dict, to_host=None) -> FrameResult:
    """``frame``'s outputs plus its measured timeline (ms from submission).

    ``to_host``: event -> host seconds (:func:`event_clock`) when GPU tasks were timed with
    CUDA events; None when every time is a host time.
    """
    timeline, transfers, host = {}, {}, {}
    t0 = frame.t0
    shares = frame.shares
    for task, (proc, a, b, mid) in frame.trace.items():
        if to_host is not None and proc.startswith("gpu"):
            a, b = to_host(a), to_host(b)
            mid = None if mid is None else to_host(mid)
        share = shares.get(task)
        if share is not None:  # a task of a captured segment: its part of the replay
            a, b = a + share[0] * (b - a), a + share[1] * (b - a)
        timeline[task] = ScheduledTask(task, proc, (a - t0) * 1e3, (b - t0) * 1e3)
        if mid is not None:
            transfers[task] = (mid - a) * 1e3
    for task, (a, b) in frame.host_trace.items():
        host[task] = ((a - t0) * 1e3, (b - t0) * 1e3)
    return FrameResult(frame.index, outputs, timeline, t0, transfers, dict(frame.copied), host)


def event_clock(anchor):
    """event -> host seconds through ``anchor`` (``(host seconds, timing event)`` recorded
    while the stream was idle); each event read once."""
    base, anchor_event = anchor
    seen = {}

    def convert(ev):
        t = seen.get(id(ev))
        if t is None:
            t = seen[id(ev)] = base + elapsed_ms(anchor_event, ev) / 1e3
        return t

    return convert


__all__ = ["WAIT_SLICE", "Cancelled", "EventPool", "Frame", "FrameResult", "frame_result",
           "event_clock"]
