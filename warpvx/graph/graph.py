"""The OpenVX-style graph: build, verify, calibrate, schedule, process and stream.

Usage::

    g = warpvx.Graph("corners")
    frame = g.input("frame", shape=(480, 640, 3), dtype=np.uint8)
    gray = g.color_convert(frame, code="BGR2GRAY")     # the same as g.add("color_convert", ...)
    kps = g.fast_corners(gray, threshold=20)
    g.output("keypoints", kps)
    out = g.process({"frame": image})                  # verifies, calibrates, schedules (best)
    for out in g.stream(video_frames, depth=3):        # pipelined
        ...
    g.schedule("heft", frames=4)                       # 4 frames in flight, each its placement
    for out in g.stream(video_frames):                 # runs that 4-frame schedule cyclically
        ...

Nodes take data objects where the primitive takes arrays and plain values for the other
arguments; they return the node's output data object (a tuple for several, see
:attr:`~warpvx.registry.Primitive.outputs`). Two keywords belong to the graph, not the primitive:
``name=`` (the node's name) and ``target=`` (``"cpu"``/``"gpu"`` pinning, also
``data.node.target = ...``).
"""

from __future__ import annotations

import functools
import weakref

import numpy as np

from ..check import check_bool, check_int
from ..errors import GraphError
from ..registry import REGISTRY
from ..runtime.processes import ProcessCall
from .costs import CostModel, default_n_cpus
from .data import INPUT, VIRTUAL, Data, Delay, DelayRef, nbytes
from .nodes import PrimitiveNode, UserNode
from .run import Runner, RunLock
from .verify import verify as _verify


class Graph(CostModel, Runner):
    """A data-flow graph of warpvx primitives and user nodes (OpenVX semantics, SPEC §5).

    This module builds and verifies; the cost model (:meth:`calibrate`, :meth:`to_task_dag`,
    :meth:`schedule`, :meth:`learn`) is :class:`~warpvx.graph.costs.CostModel`, running
    (:meth:`process`, :meth:`stream`, :meth:`reset`, :meth:`close`) is
    :class:`~warpvx.graph.run.Runner`.

    Parameters
    ----------
    name : str
        Used in messages, thread names and figures.
    """

    def __init__(self, name: str = "graph"):
        self.name = name
        self.nodes: dict = {}
        self.data: dict = {}
        self.inputs: dict = {}
        self.outputs: dict = {}
        self.delays: list = []
        self._node_index: dict = {}
        self._order = None
        self._plan = None
        self._calibrations: dict = {}
        self._frame = 0
        self._run_lock = RunLock(self)
        # The executor's threads must not keep the graph alive; when the graph goes, its
        # plan's threads stop (data objects and delays hold the graph weakly).
        self._plan_box = [None]
        weakref.finalize(self, Graph._close_plan, self._plan_box)

    # ------------------------------------------------------------------ building

    def input(self, name: str, *, shape=None, dtype=None, value=None) -> Data:
        """A graph input parameter.

        Parameters
        ----------
        name : str
            Key of the input in :meth:`process`'s dict.
        shape, dtype : optional
            Expected shape (None for a free dimension) and dtype, checked every frame;
            verification synthesises a sample from them when no value is given.
        value : array, optional
            Default value (used when a frame omits the input) and verification sample.
        """
        self._check_building(f"input {name!r}")
        self._check_new_name(name, "input")
        if value is not None and hasattr(value, "shape"):
            shape = tuple(value.shape) if shape is None else shape
            if dtype is None:
                dtype = value.dtype if isinstance(value, np.ndarray) else None
        data = Data(self, name, INPUT, shape=shape, dtype=dtype, value=value)
        self.data[name] = data
        self.inputs[name] = data
        self._changed()
        return data

    def output(self, name: str, data) -> Data:
        """Name ``data`` as a graph output: :meth:`process` returns it under ``name``."""
        self._check_building(f"output {name!r}")
        data = self._own(data, f"output {name!r}")
        if isinstance(data, DelayRef):
            raise GraphError(f"output {name!r}: a delay slot cannot be an output; output the data")
        if name in self.outputs:
            raise GraphError(f"output {name!r}: already defined")
        self.outputs[name] = data
        data.output_name = name
        self._changed()
        return data

    def virtual(self, name: str | None = None) -> Data:
        """A virtual data object with no producer yet: give it as a user node's output."""
        self._check_building("virtual")
        name = name or f"v{len(self.data)}"
        self._check_new_name(name, "data")
        data = Data(self, name, VIRTUAL)
        self.data[name] = data
        return data

    def add(self, primitive: str, *args, name: str | None = None, target: str | None = None,
            **kwargs):
        """Add a node running registered ``primitive``; returns its output data object(s).

        Data objects (and delay slots) may be given for any named parameter; everything else
        is a constant argument. Unknown primitives and arguments raise GraphError now.
        """
        self._check_building(f"node {name or primitive!r}")
        for a in list(args) + list(kwargs.values()):
            if isinstance(a, (Data, DelayRef)):
                self._own(a, f"node {name or primitive!r}")
        name = self._node_name(name, primitive)
        node = PrimitiveNode(self, name, primitive, args, kwargs)
        return self._register(node, target)

    def __getattr__(self, attr):
        # g.color_convert(...) == g.add("color_convert", ...) for every registered primitive.
        if not attr.startswith("_") and attr in REGISTRY:
            return functools.partial(self.add, attr)
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {attr!r}")

    def __dir__(self):
        return sorted(set(super().__dir__()) | set(REGISTRY))

    def user(self, fn, inputs, outputs=("out",), *, warp_fn=None, name: str | None = None,
             target: str | None = None, capturable: bool = False, process: bool = False):
        """Add a node running a Python callable.

        Parameters
        ----------
        fn : callable or None
            ``fn(*host_inputs)`` on a CPU worker (NumPy in, the outputs out: one value, or a
            tuple for several outputs). None for a GPU-only node.
        inputs : list or dict
            Data objects (or delay slots); a dict names the ports, a list takes the names of
            ``fn``'s parameters.
        outputs : str, int, or list of str / Data
            Output port names (an int n gives ``out0``..``out{n-1}``); an existing data object
            from :meth:`virtual` becomes that output.
        warp_fn : callable, optional
            The same computation on ``wp.array`` inputs on the GPU role's device, run inside
            ``wp.ScopedDevice`` with the executor's stream current. Without it the node is
            CPU-only (exclusive); with only it, GPU-only.
        capturable : bool
            ``warp_fn`` also takes ``out=`` (an array per output, of the shapes and dtypes
            verification gave, a tuple for several) and, given it, writes it and only
            enqueues Warp work on the current stream (no allocation, host sync or read-back
            once warm): the runtime may then capture the node with its GPU neighbours
            (:mod:`warpvx.runtime.capture`).
        process : bool
            Run ``fn`` in a worker process (one per CPU worker thread that runs it), off this
            process's GIL: for a CPU node whose native work is long beside its Python (an
            OpenCV call) in a pipelined graph whose threads contend for the GIL. ``fn`` and
            its inputs and outputs must pickle (``fn`` a module-level function); each call
            pays a pickled round trip (~0.1 ms); a script guards its entry point with
            ``if __name__ == "__main__":`` (the workers are spawned). :meth:`close` ends the
            processes (:mod:`warpvx.runtime.processes`).
        """
        self._check_building(f"node {name or 'user'!r}")
        name = self._node_name(name, "user")
        ports = self._user_ports(fn if fn is not None else warp_fn, inputs, name)
        if check_bool(process, "process"):
            if fn is None:
                raise GraphError(f"node {name!r} (user), port 'process': runs fn in a worker "
                                 "process, and the node has no fn")
            try:
                fn = ProcessCall(fn, f"node {name!r}")
            except TypeError as exc:
                raise GraphError(f"node {name!r} (user), port 'fn': {exc}") from None
        for port, ref in ports.items():
            self._own(ref, f"node {name!r}, port {port!r}")
        if isinstance(outputs, str):
            outputs = [outputs]
        elif isinstance(outputs, int) and not isinstance(outputs, bool):
            outputs = [f"out{i}" for i in range(outputs)] if outputs != 1 else ["out"]
        outputs = list(outputs)
        if not outputs:
            raise GraphError(f"node {name!r} (user), port 'outputs': at least one output is needed")
        out_ports, existing = [], {}
        for i, o in enumerate(outputs):
            if isinstance(o, Data):
                self._own(o, f"node {name!r}, output {i}")
                if o.kind == INPUT or o.producer is not None:
                    raise GraphError(f"node {name!r} (user), port {o.name!r}: data {o.name!r} "
                                     f"already has a producer")
                out_ports.append(o.name)
                existing[o.name] = o
            elif isinstance(o, str):
                out_ports.append(o)
            else:
                raise GraphError(f"node {name!r} (user), port 'outputs': expected names or data "
                                 f"objects, got {o!r}")
        node = UserNode(self, name, fn, warp_fn, ports, tuple(out_ports),
                        capturable=check_bool(capturable, "capturable"))
        return self._register(node, target, existing)

    def delay(self, data, slots: int = 1, *, init=None) -> Delay:
        """A delay of ``data``: ``delay[-j]`` is its value ``j`` frames ago (``1 <= j <= slots``).

        See :class:`~warpvx.graph.data.Delay` for the initial values.
        """
        self._check_building("delay")
        data = self._own(data, "delay")
        if isinstance(data, DelayRef):
            raise GraphError("delay: give the data object, not a delay slot")
        if isinstance(slots, bool) or not isinstance(slots, (int, np.integer)) or slots < 1:
            raise GraphError(f"delay: slots must be an int >= 1, got {slots!r}")
        if any(d.data is data for d in self.delays):
            raise GraphError(f"delay: {data.name!r} already has a delay; use more slots")
        d = Delay(self, data, int(slots), init=init)
        self.delays.append(d)
        self._changed()
        return d

    def node(self, name: str):
        """The node called ``name``."""
        try:
            return self.nodes[name]
        except KeyError:
            raise GraphError(f"node {name!r}: no such node in graph {self.name!r}") from None

    def schedule(self, policy="best", *, frames: int = 1, **kwargs):
        """:meth:`CostModel.schedule <warpvx.graph.costs.CostModel.schedule>` (the same
        arguments), with ``frames`` in flight.

        Parameters
        ----------
        frames : int
            K >= 1. With K > 1 the plan also holds ``policy``'s schedule of the task DAG
            unrolled over K frames, with the inter-frame edges of the graph's delays
            (:func:`warpvx.sched.schedule` with ``frames=K``), as ``plan.frame_schedule``;
            :meth:`process` and :meth:`stream` run it cyclically: frame *i* with the
            placement and order of its frame ``i mod K``, so consecutive frames may run a
            node on different processors. ``plan.schedule`` stays the one-frame schedule
            (metrics, charts, learning).

        Returns
        -------
        Plan

        Raises
        ------
        WarpvxTypeError, WarpvxValueError
            ``frames`` is not an int >= 1.
        """
        from .. import sched

        frames = check_int(frames, "frames", min_value=1)
        with self._run_lock:
            plan = CostModel.schedule(self, policy, **kwargs)
            if frames > 1:
                ksched = sched.schedule(plan.dag, policy, frames=frames,
                                        delays=self._delay_edges(plan.calibration))
                sched.validate_schedule(ksched.info["dag"], ksched)
                plan.frame_schedule = ksched
                plan.close()  # a trial ("best") may have started one on the one-frame schedule
        return plan

    def _delay_edges(self, cal) -> dict:
        """``{(producer, reader): ms}``: the inter-frame edges of the delays (producer of
        frame f-1 -> reader of frame f), each costing the transfer of its data as a data
        edge does (:meth:`to_task_dag`). A read ``j >= 2`` frames back also chains the
        producer's frames (``(producer, producer): 0``), so its frame f-j comes before
        frame f-1, hence before the reader of frame f."""
        handoff = (cal.dispatch or {}).get("handoff", 0.0)
        edges = {}
        for node in self.nodes.values():
            for ref in node.inputs.values():
                if isinstance(ref, DelayRef) and ref.data.producer is not None:
                    u = ref.data.producer.name
                    edges[u, node.name] = handoff + cal.transfer.time(nbytes(ref.data.sample))
                    if ref.offset < -1:
                        edges.setdefault((u, u), 0.0)
        return edges

    # ------------------------------------------------------------------ helpers

    def _check_building(self, where):
        """Refuse to change the graph from inside one of its nodes or while a ``stream()``
        generator is live: the new plan would lose the frames in flight."""
        lock = self._run_lock
        lock.refuse(f"{where}: changing the graph")
        if lock.stream is not None:
            raise GraphError(f"{where}: cannot change graph {self.name!r} while {lock.stream} is "
                             f"live (its frames in flight would be lost); exhaust it or close() "
                             f"it first")

    def _check_new_name(self, name, what):
        if not isinstance(name, str) or not name:
            raise GraphError(f"{what}: name must be a non-empty string, got {name!r}")
        if name in self.data or name in self.nodes:
            raise GraphError(f"{what} {name!r}: the name is already used in graph {self.name!r}")

    def _own(self, ref, where):
        if not isinstance(ref, (Data, DelayRef)):
            raise GraphError(f"{where}: expected a data object of this graph, got {type(ref).__name__}")
        data = ref.data if isinstance(ref, DelayRef) else ref
        if data.graph is not self:
            raise GraphError(f"{where}: {data.name!r} belongs to another graph")
        return ref

    def _node_name(self, name, base):
        if name is None:
            k = 0
            while f"{base}_{k}" in self.nodes:
                k += 1
            return f"{base}_{k}"
        if not isinstance(name, str) or not name:
            raise GraphError(f"node: name must be a non-empty string, got {name!r}")
        if name in self.nodes:
            raise GraphError(f"node {name!r}: a node of that name exists")
        return name

    def _user_ports(self, fn, inputs, name):
        if isinstance(inputs, (Data, DelayRef)):
            inputs = [inputs]
        if isinstance(inputs, dict):
            return dict(inputs)
        inputs = list(inputs)
        names = []
        try:
            import inspect

            params = [p for p in inspect.signature(fn).parameters.values()
                      if p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD)]
            names = [p.name for p in params]
        except (TypeError, ValueError):
            pass
        if len(names) < len(inputs):
            names = [f"in{i}" for i in range(len(inputs))]
        return {names[i]: ref for i, ref in enumerate(inputs)}

    def _register(self, node, target, existing=None):
        existing = existing or {}
        self.nodes[node.name] = node
        self._node_index[node.name] = len(self._node_index)
        outs = []
        for port in node.output_ports:
            data = existing.get(port)
            if data is None:
                dname = f"{node.name}.{port}"
                self._check_new_name(dname, "data")
                data = Data(self, dname, VIRTUAL)
                self.data[dname] = data
            data.producer = node
            data.port = port
            node.outputs[port] = data
            outs.append(data)
        if target is not None:
            node.target = target
        self._changed()
        return outs[0] if len(outs) == 1 else tuple(outs)

    def _changed(self):
        self._order = None
        # A calibration covers the nodes it measured: a changed graph calibrates again (from
        # the cache for the nodes it already had).
        self._calibrations.clear()
        self._invalidate_plan()

    def _invalidate_plan(self):
        with self._run_lock:
            if self._plan is not None:
                self._plan.close()
                self._plan = None
                self._plan_box[0] = None

    @staticmethod
    def _close_plan(box):
        if box[0] is not None:
            box[0].close()

    # ------------------------------------------------------------------ verify

    def verify(self, inputs=None, *, gpu=None) -> "Graph":
        """Check the graph; raise one :class:`~warpvx.errors.GraphError` naming node and port.

        Checks missing inputs, cycles, pin feasibility, then types and shapes by running each
        node once on samples at the graph's real sizes (``inputs``, the inputs' values, or
        synthetic data from their shape and dtype). ``inputs`` may be a list of two input
        dicts, two consecutive frames: a graph with delays then runs its second verification
        frame on the second one, so the samples calibration times temporal nodes on (LK
        tracking from one frame to the next) show real motion. ``gpu`` (a backend name such as
        ``"cuda"``): nodes pinned to the GPU run their check there instead of on the CPU (a
        heavy GPU-only node on Warp's CPU device can take seconds). See
        :mod:`warpvx.graph.verify`.
        """
        if gpu is not None:
            from ..backend import resolve_backend

            gpu = resolve_backend(gpu)
            if gpu.kind != "warp":
                raise GraphError(f"gpu: expected a Warp backend ('cuda', 'warp-cpu'), got {gpu.name!r}")
        with self._run_lock:
            self._order = _verify(self, inputs, gpu)
        return self

    @property
    def verified(self) -> bool:
        return self._order is not None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def __repr__(self):
        return (f"Graph({self.name!r}, {len(self.nodes)} nodes, inputs={list(self.inputs)}, "
                f"outputs={list(self.outputs)})")


__all__ = ["Graph", "default_n_cpus"]
