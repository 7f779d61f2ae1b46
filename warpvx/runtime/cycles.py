"""K frames in flight (see :mod:`.executor`): which slot of a K-frame schedule each task
of a schedule is (:func:`frames_of`), and the frames of one cycle that the processors' queues
run together (:class:`Batch`)."""

from __future__ import annotations

import threading

from ..sched.schedule import Schedule
from .timeline import WAIT_SLICE, Frame


def frames_of(schedule: Schedule):
    """K and scheduled key -> ``(task, slot)``: a schedule of an unrolled DAG names every task
    ``(task, f)`` with an int ``f`` (K = the largest ``f`` + 1); any other is one frame."""
    keys = list(schedule.tasks)
    if keys and all(isinstance(k, tuple) and len(k) == 2 and isinstance(k[1], int)
                    and not isinstance(k[1], bool) and k[1] >= 0 for k in keys):
        return max(f for _, f in keys) + 1, {k: k for k in keys}
    return 1, {k: (k, 0) for k in keys}


class Batch:
    """Consecutive frames of one cycle of a K-frame schedule, slots ``first``.. ``last``: what
    the processors run their ``(task, slot)`` queues over together (see
    :mod:`.executor`). Closed, it takes no more frames and its missing slots are skipped."""

    def __init__(self, cycle: int, first: int, k: int):
        self.cycle = cycle
        self.first = first
        self.last = first - 1
        self.closed = False
        self._frames = [None] * k
        self._cond = threading.Condition()

    def add(self, slot: int, frame: Frame):
        with self._cond:
            self._frames[slot] = frame
            self.last = slot
            self._cond.notify_all()

    def close(self):
        with self._cond:
            self.closed = True
            self._cond.notify_all()

    def __contains__(self, frame) -> bool:
        return any(f is frame for f in self._frames)

    def frame(self, slot: int, closing: threading.Event) -> Frame | None:
        """The frame of ``slot``, waiting for its submission; None once the batch closed
        without it (or the executor is closing)."""
        with self._cond:
            while self._frames[slot] is None:
                if self.closed or slot < self.first or closing.is_set():
                    return None
                self._cond.wait(WAIT_SLICE)
            return self._frames[slot]


__all__ = ["Batch", "frames_of"]
