"""The graph runtime: run a :class:`~warpvx.sched.Schedule` for real, frame after frame, on CPU
worker threads beside one GPU queue (SPEC §7). It knows nothing of graphs: the graph layer
(:mod:`warpvx.graph`) builds a :class:`Program` and hands it over with a schedule.

- :mod:`.executor`: :class:`Executor` (threads, cross-queue edges, pipelining, errors, buffer
  pools) and :func:`run_schedule`.
- :mod:`.roles`: how it runs a one-frame schedule's processors: roles on threads, short units
  inline on the thread whose output they waited for.
- :mod:`.program`: :class:`Program`, :class:`ExecTask`, :class:`InputRef`: what it runs.
- :mod:`.slots`: :class:`Slot`, :class:`Ring`, :class:`Flag`: values of frames in flight.
- :mod:`.timeline`: :class:`Frame`, :class:`FrameResult`: what a frame measured.
- :mod:`.transfers`: :class:`Transfers` (host <-> device copies of whole values) and
  :func:`tree_map` (the flatten protocol for user data types).
- :mod:`.capture`: runs of consecutive GPU tasks captured as one CUDA graph and replayed.
- :mod:`.cycles`: K frames in flight: a K-frame schedule's slots and the batches of a cycle.
- :mod:`.native_copy`: the copies through Warp's native entry points, with a public-API fallback.
"""

from .executor import SPIN_SECONDS, Executor, run_schedule
from .pinned import is_pinned, pinned_array, pinned_copy
from .program import ExecTask, InputRef, Program, data_graph
from .slots import DEVICE, HOST, Flag, Ring, Slot
from .timeline import WAIT_SLICE, EventPool, Frame, FrameResult
from .transfers import Transfers, tree_map

__all__ = [
    "DEVICE",
    "HOST",
    "SPIN_SECONDS",
    "WAIT_SLICE",
    "EventPool",
    "ExecTask",
    "Executor",
    "Flag",
    "Frame",
    "FrameResult",
    "InputRef",
    "Program",
    "Ring",
    "Slot",
    "Transfers",
    "data_graph",
    "is_pinned",
    "pinned_array",
    "pinned_copy",
    "run_schedule",
    "tree_map",
]
