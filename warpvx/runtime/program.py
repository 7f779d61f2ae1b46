"""What the executor runs: tasks with named inputs and outputs and one callable per kind of
processing element (:class:`Program`). It knows nothing of graphs; the graph layer builds one."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import networkx as nx


@dataclass(frozen=True)
class InputRef:
    """A task input: value ``key`` of this frame (``offset=0``) or of ``-offset`` frames ago."""

    key: str
    offset: int = 0


@dataclass
class ExecTask:
    """One task: inputs, outputs and its callables.

    ``cpu(*host_values)`` and ``gpu(*device_values)`` return one value per output (a tuple
    when there are several); ``None`` marks a missing implementation. ``gpu_out``, when
    given, makes a fresh output buffer for the GPU callable, which then takes it as
    ``gpu(*device_values, out=buffer)`` (buffers are pooled across frames). ``capture``: the
    GPU callable, given ``out=``, only enqueues work on the current stream, so it may be
    captured into a CUDA graph with its neighbours (:mod:`.capture`); needs ``gpu_out``.
    ``output``: the key of its only output, else None (derived).
    """

    name: str
    inputs: tuple
    outputs: tuple
    cpu: Callable | None = None
    gpu: Callable | None = None
    gpu_out: Callable | None = None
    capture: bool = False
    output: str | None = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        # The usual task has one output: published without a length check per call.
        self.output = self.outputs[0] if len(self.outputs) == 1 else None


@dataclass
class Program:
    """What the executor runs each frame.

    Attributes
    ----------
    tasks : dict
        name -> :class:`ExecTask`.
    inputs : tuple of str
        Keys fed by :meth:`Executor.submit`.
    outputs : dict
        output name -> key, returned by :meth:`Executor.wait`.
    rings : dict
        key -> :class:`Ring` for every key read with a negative offset.
    """

    tasks: dict
    inputs: tuple
    outputs: dict
    rings: dict = field(default_factory=dict)


def data_graph(program: Program) -> nx.DiGraph:
    """The task DAG of one frame's data edges (producer -> consumer; delayed reads are not
    edges: they read an earlier frame)."""
    producer = {k: t.name for t in program.tasks.values() for k in t.outputs}
    g = nx.DiGraph()
    g.add_nodes_from(program.tasks)
    g.add_edges_from((producer[r.key], t.name) for t in program.tasks.values()
                     for r in t.inputs if r.offset == 0 and r.key in producer)
    return g


__all__ = ["InputRef", "ExecTask", "Program", "data_graph"]
