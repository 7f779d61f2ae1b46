"""Lanes of a captured segment: its tasks spread over streams by their data dependencies, so
that the CUDA graph captured from them runs independent branches concurrently
(:mod:`.capture` forks the lanes from the executor's stream and joins them back).

:func:`lanes` is the pure rule (list scheduling over the scheduled durations, serial tasks
after a join); :func:`noting_conditionals` finds the serial tasks: those that insert
conditional graph nodes, where Warp pauses a capture (``cudaStreamEndCapture``, refused
while a forked stream has unjoined work).
"""

from __future__ import annotations

import threading
from contextlib import contextmanager
from dataclasses import dataclass, field

from ..check import check_int
from .native_copy import warp

#: Streams a captured segment's tasks are spread over by default (1: one chain, as one stream
#: captures it); an executor's ``max_lanes`` overrides it for the captures it makes after.
MAX_LANES = 4


@dataclass(frozen=True)
class Lanes:
    """Where and in which order a segment's tasks are enqueued: lane 0 is the executor's
    stream, the others are forked from it and joined back.

    A *serial* task (one that inserts a conditional graph node: ``wp.capture_if``,
    ``wp.capture_while``) runs on lane 0 with every lane joined before it, as Warp pauses
    the capture there (``cudaStreamEndCapture``, refused while a forked stream has unjoined
    work); the lanes fork again after it. Serial tasks and what depends on them are
    enqueued after the others, so that one such barrier serves them all.

    Attributes
    ----------
    of : tuple of int
        The lane of each task (segment order).
    waits : tuple of tuple of int
        For each task, the tasks on other lanes (indices) whose events its lane waits for
        before it: its producers since the last serial task, less those an earlier wait of
        its lane already covers (a fork covers everything before it).
    count : int
        Lanes used.
    order : tuple of int
        The tasks (indices) in the order they are enqueued: a dependency order.
    serial : frozenset of int
        The serial tasks (indices).
    span : float
        When the list scheduling expects the segment's last task to end, its serial
        tasks' joins included, in the unit of ``durations`` (1 a task without them).
    """

    of: tuple
    waits: tuple
    count: int
    order: tuple
    serial: frozenset = frozenset()
    span: float = field(default=0.0, compare=False)  # an estimate, not where tasks go

    @property
    def signals(self) -> frozenset:
        """Tasks after which an event is recorded (another lane waits for them)."""
        return frozenset(p for w in self.waits for p in w)


def lanes(tasks, durations=None, max_lanes: int = MAX_LANES, serial=()) -> Lanes:
    """Assign a segment's ``tasks`` (an :class:`ExecTask` sequence in a dependency order) to
    at most ``max_lanes`` streams by list scheduling: each task, in order, goes to the lane
    where it could start first (its lane free and its producers in the segment finished,
    estimated from ``durations``: task name -> seconds, 1 each when None), a lane whose last
    task is one of its producers first on ties (no event), then an open lane before a new one.
    Tasks named in ``serial`` run on lane 0 after everything enqueued before them
    (:class:`Lanes`).

    Only this frame's reads (offset 0) of values made inside the segment are dependencies: a
    delayed read of its own output reads the other buffer set, written a replay earlier.

    Raises
    ------
    WarpvxTypeError, WarpvxValueError
        ``max_lanes`` is not an integer, or is < 1.
    """
    max_lanes = check_int(max_lanes, "max_lanes", min_value=1)
    made, prods = {}, []
    for task in tasks:
        prods.append({made[r.key] for r in task.inputs if r.offset == 0 and r.key in made})
        made.update((k, len(prods) - 1) for k in task.outputs)
    barriers = frozenset(i for i, t in enumerate(tasks) if t.name in serial)
    after = set()  # serial tasks and what depends on them: enqueued last
    for i, ps in enumerate(prods):
        if i in barriers or ps & after:
            after.add(i)
    order = [i for i in range(len(tasks)) if i not in after] + sorted(after)
    of, waits, finish, epoch = [0] * len(tasks), [()] * len(tasks), [0.0] * len(tasks), {}
    free, tail, covered = [], [], []  # per lane: estimated end, last task, waited per lane
    start0, count, e = 0.0, 1, 0  # where this epoch (since the last serial task) starts
    for i in order:
        d = float(durations.get(tasks[i].name, 1.0)) if durations else 1.0
        if i in barriers:  # every lane joined, then it alone on lane 0, then a new fork
            finish[i] = start0 = max([start0, *free]) + d
            epoch[i], e = e, e + 1
            free, tail, covered = [], [], []
            continue
        inner = sorted(p for p in prods[i] if epoch[p] == e)  # earlier ones: the fork's
        ready = max([start0, *(finish[p] for p in inner)])
        options = [(max(end, ready), last not in inner, 0, k)
                   for k, (end, last) in enumerate(zip(free, tail))]
        if len(free) < max_lanes:
            options.append((ready, True, 1, len(free)))
        start, _, new, lane = min(options)
        if new:
            free.append(start0)
            tail.append(-1)
            covered.append({})
        latest = {}  # other lane -> its latest producer of this task
        for p in inner:
            if of[p] != lane:
                latest[of[p]] = max(p, latest.get(of[p], -1))
        wait = tuple(sorted(p for m, p in latest.items() if covered[lane].get(m, -1) < p))
        covered[lane].update((of[p], p) for p in wait)
        finish[i] = start + d
        free[lane], tail[lane] = finish[i], i
        of[i], waits[i], epoch[i] = lane, wait, e
        count = max(count, len(free))
    return Lanes(tuple(of), tuple(waits), count, tuple(order), barriers, max(finish, default=0.0))


#: Warp's functions that insert a conditional graph node (pausing a capture).
_CONDITIONALS = ("capture_if", "capture_while")
noted = threading.local()
_noting_lock = threading.Lock()


@contextmanager
def noting_conditionals():
    """Count this thread's calls of Warp's conditional-node functions in the block
    (``noted.calls``): they are wrapped for the block (other threads' calls pass through),
    one block at a time."""
    wp = warp()
    with _noting_lock:
        saved = {name: getattr(wp, name) for name in _CONDITIONALS}

        def wrap(fn):
            def call(*args, **kwargs):
                if getattr(noted, "on", False):
                    noted.calls += 1
                return fn(*args, **kwargs)
            return call

        for name, fn in saved.items():
            setattr(wp, name, wrap(fn))
        noted.on, noted.calls = True, 0
        try:
            yield
        finally:
            noted.on = False
            for name, fn in saved.items():
                setattr(wp, name, fn)


__all__ = ["MAX_LANES", "Lanes", "lanes", "noted", "noting_conditionals"]
