"""OpenVX-style graphs over warpvx primitives, scheduled on CPU workers and a GPU (SPEC §5, §7).

- :class:`Graph`: build (inputs, nodes per registered primitive, user nodes, delays,
  outputs), :meth:`~Graph.verify`, :meth:`~Graph.calibrate`, :meth:`~Graph.schedule`,
  :meth:`~Graph.process` one frame, :meth:`~Graph.stream` many, pipelined.
- :class:`Data`, :class:`Delay`: data objects; parameters and delays are readable and
  writable from other threads while graphs run (``data.read()``, ``data.write(v)``,
  ``with data.lock:``).
- :class:`Plan`: a schedule with its DAG, metrics and measured timelines (``plan.gantt``).
- :mod:`.graph` builds and verifies, :mod:`.costs` is the cost model (calibrate, task DAG,
  schedule, learn), :mod:`.run` runs frames through :mod:`warpvx.runtime`, :mod:`.bind` binds
  each node to its implementation once after verification.
- :mod:`.calibration`: measured node and transfer costs, cached per machine.
- :mod:`.diagnostics`: executor overhead and soak measurements.
"""

from .data import Data, Delay, DelayRef
from .costs import NoCudaWarning
from .graph import Graph, default_n_cpus
from .nodes import Node, PrimitiveNode, UserNode
from .plan import Plan

__all__ = [
    "Graph",
    "Data",
    "Delay",
    "DelayRef",
    "Node",
    "PrimitiveNode",
    "UserNode",
    "Plan",
    "NoCudaWarning",
    "default_n_cpus",
]
