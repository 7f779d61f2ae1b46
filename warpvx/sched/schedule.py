"""The schedule data type every policy returns and the executor runs."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Hashable


@dataclass(frozen=True)
class ScheduledTask:
    """One task placed on a processor: it runs on ``processor`` from ``start`` to ``finish``."""

    task: Hashable
    processor: str
    start: float
    finish: float


@dataclass
class Schedule:
    """A complete schedule of a task DAG.

    Attributes
    ----------
    tasks : dict
        task -> :class:`ScheduledTask`.
    processors : list of str
        All processors, e.g. ``["cpu0", "cpu1", "gpu"]`` (``"cpu<i>"`` CPU workers, ``"gpu"``).
    policy : str
        Name of the policy that produced it.
    priority : list
        The task order the policy placed tasks in (HEFT's rank list, XEFT's reordered list).
    info : dict
        Policy extras, e.g. ``{"chosen": "xeft"}`` from the ``best`` policy.
    """

    tasks: dict
    processors: list
    policy: str = ""
    priority: list = field(default_factory=list)
    info: dict = field(default_factory=dict)

    @property
    def makespan(self) -> float:
        return max((t.finish for t in self.tasks.values()), default=0.0)

    def order(self, processor: str) -> list:
        """Tasks on ``processor`` sorted by start time (the queue the executor runs)."""
        on = [t for t in self.tasks.values() if t.processor == processor]
        return [t.task for t in sorted(on, key=lambda t: (t.start, t.finish))]

    def __getitem__(self, task) -> ScheduledTask:
        return self.tasks[task]
