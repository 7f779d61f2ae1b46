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

Nodes take data objects where the primitive takes arrays and plain values for the other
arguments; they return the node's output data object (a tuple for several, see
:data:`~warpvx.graph.nodes.OUTPUTS`). Two keywords belong to the graph, not the primitive:
``name=`` (the node's name) and ``target=`` (``"cpu"``/``"gpu"`` pinning, also
``data.node.target = ...``).
"""

from __future__ import annotations

import dataclasses
import functools
import os
import threading
import weakref
from collections import deque

import numpy as np

from ..errors import GraphError, NodeExecutionError
from ..registry import REGISTRY
from ..runtime import DEVICE, HOST, ExecTask, InputRef, Program
from .data import INPUT, VIRTUAL, Data, Delay, DelayRef, nbytes
from .nodes import PrimitiveNode, UserNode
from .verify import check_input, verify as _verify


def default_n_cpus() -> int:
    """CPU workers by default: the cores minus one for the GPU host thread, 1 to 4."""
    return max(1, min(4, (os.cpu_count() or 2) - 1))


class Graph:
    """A data-flow graph of warpvx primitives and user nodes (OpenVX semantics, SPEC §5).

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
        self._run_lock = threading.RLock()
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
             target: str | None = None):
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
        """
        name = self._node_name(name, "user")
        ports = self._user_ports(fn if fn is not None else warp_fn, inputs, name)
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
        node = UserNode(self, name, fn, warp_fn, ports, tuple(out_ports))
        return self._register(node, target, existing)

    def delay(self, data, slots: int = 1, *, init=None) -> Delay:
        """A delay of ``data``: ``delay[-j]`` is its value ``j`` frames ago (``1 <= j <= slots``).

        See :class:`~warpvx.graph.data.Delay` for the initial values.
        """
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

    # ------------------------------------------------------------------ helpers

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

    def verify(self, inputs=None) -> "Graph":
        """Check the graph; raise one :class:`~warpvx.errors.GraphError` naming node and port.

        Checks missing inputs, cycles, pin feasibility, then types and shapes by running each
        node once on samples at the graph's real sizes (``inputs``, the inputs' values, or
        synthetic data from their shape and dtype). ``inputs`` may be a list of two input
        dicts, two consecutive frames: a graph with delays then runs its second verification
        frame on the second one, so the samples calibration times temporal nodes on (LK
        tracking from one frame to the next) show real motion. See :mod:`warpvx.graph.verify`.
        """
        with self._run_lock:
            self._order = _verify(self, inputs)
        return self

    @property
    def verified(self) -> bool:
        return self._order is not None

    # ------------------------------------------------------------------ calibrate / schedule

    @staticmethod
    def _gpu_backend(gpu):
        """``"cuda"``, ``"cuda:N"``, ``"warp-cpu"``, None (CUDA if present, else warp-cpu) or
        False (no GPU role) -> Backend or None."""
        from ..backend import cuda_available, resolve_backend

        if gpu is False:
            return None
        if gpu is None:
            gpu = "cuda" if cuda_available() else "warp-cpu"
        be = resolve_backend(gpu)
        if be.kind != "warp":
            raise GraphError(f"gpu: expected 'cuda', 'cuda:N', 'warp-cpu', None or False, got {gpu!r}")
        return be

    @staticmethod
    def _backend_device(gpu_name):
        if gpu_name is None:
            return None
        from ..backend import resolve_backend

        return resolve_backend(gpu_name).device

    def _gpu_device(self):
        plan = self._plan
        return self._backend_device(plan.gpu) if plan is not None else None

    def calibrate(self, inputs: dict | None = None, *, gpu=None, recalibrate: bool = False,
                  warmup: int = 2, repeats: int = 5):
        """Measure node and transfer costs on this machine (cached; see
        :mod:`warpvx.graph.calibration`). ``inputs`` re-verifies on real data first."""
        from .calibration import calibrate as _calibrate

        be = self._gpu_backend(gpu)
        with self._run_lock:
            if inputs is not None or not self.verified:
                self.verify(inputs)
            cal = _calibrate(self, be, recalibrate=recalibrate, warmup=warmup, repeats=repeats)
            self._calibrations[cal.gpu] = cal
        return cal

    def to_task_dag(self, n_cpus: int | None = None, *, gpu=None, calibration=None,
                    costs: str = "calibrated"):
        """The scheduler's task DAG of one frame (times in ms).

        Node costs come from calibration (run now if needed), narrowed by pins, plus the
        executor's dispatch cost per task on that kind of processor; each edge's ``comm`` is
        the transfer model's time for the bytes of its data plus the executor's hand-off
        between a CPU worker and the GPU thread (the scheduler charges ``comm`` only between
        them). A GPU node reading a graph input also pays that input's upload (frames arrive
        in host memory).

        ``costs="history"`` uses what running frames measured (:meth:`learn`) where known:
        those intervals already hold the executor's work inside a task, so only its cost
        between tasks is added. The executor makes a task's copies on the task's own
        processor (the GPU thread uploads, a CPU worker downloads), so history costs charge
        copies to the consumer, not to the edge: a node's measured copies where it ran, or,
        elsewhere, the transfer model's time for the inputs whose producers ran on the
        other side, scaled by what copies took in running frames
        (``calibration.transfer_scale``); an edge keeps only the hand-off.
        """
        from ..sched import cpu_gpu_dag

        if costs not in ("calibrated", "history"):
            raise GraphError(f"costs: expected 'calibrated' or 'history', got {costs!r}")
        n_cpus = default_n_cpus() if n_cpus is None else n_cpus
        be = self._gpu_backend(gpu)
        cal = calibration or self._calibrations.get(be.name if be else None)
        if cal is None or not self.verified:
            cal = self.calibrate(gpu=be.name if be else False)
        d = cal.dispatch or {}
        history = costs == "history"
        scale = cal.transfer_scale if history else 1.0
        tasks, edges = {}, {}
        for node in self.nodes.values():
            pes = node.processing_elements
            known = cal.history.get(node.name, {}) if history else {}

            def copies(pe):
                """Copies ``node`` makes on ``pe`` (graph inputs on the GPU; in history mode
                also inputs whose producers last ran on the other side)."""
                ms = 0.0
                for ref in node.inputs.values():
                    if not isinstance(ref, Data):
                        continue
                    if ref.kind == INPUT:
                        if pe == "gpu":
                            ms += scale * cal.transfer.upload(nbytes(ref.sample))
                    elif history and ref.producer is not None:
                        where = cal.placement.get(ref.producer.name)
                        if where is not None and where != pe:
                            n = nbytes(ref.sample)
                            ms += scale * (cal.transfer.upload(n) if pe == "gpu" else cal.transfer.download(n))
                return ms

            def cost(pe):
                if pe not in pes or (pe == "gpu" and be is None):
                    return None
                if pe in known:
                    return known[pe] + known.get(f"{pe}_copies", 0.0) + d.get(f"{pe}_gap", 0.0)
                return cal.nodes[node.name][pe] + d.get(f"{pe}_node", 0.0) + copies(pe)

            cpu_t, gpu_t = cost("cpu"), cost("gpu")
            if cpu_t is None and gpu_t is None:
                raise GraphError(f"node {node.name!r} ({node.kind}), port 'target': no processing "
                                 f"element of this plan can run it (pinned to {node.target!r}, "
                                 f"gpu={be.name if be else None})")
            tasks[node.name] = (cpu_t, gpu_t)
            for ref in node.inputs.values():
                if isinstance(ref, Data) and ref.producer is not None:
                    key = (ref.producer.name, node.name)
                    if key not in edges:
                        edges[key] = d.get("handoff", 0.0)
                    if not history:
                        edges[key] += cal.transfer.time(nbytes(ref.sample))
        return cpu_gpu_dag(tasks, edges, n_cpus)

    def schedule(self, policy="best", *, n_cpus: int | None = None, gpu=None,
                 recalibrate: bool = False, costs: str = "calibrated"):
        """Calibrate (cached), schedule with ``policy`` and make the result the current plan.

        Parameters
        ----------
        policy : str or callable
            ``"baseline"``, ``"heft"``, ``"xeft"``, ``"best"`` or ``policy(dag) -> Schedule``.
        n_cpus : int, optional
            CPU workers (default :func:`default_n_cpus`).
        gpu : str, None or False
            The GPU role: ``"cuda"``/``"cuda:N"``, ``"warp-cpu"`` (Warp's CPU device, for
            tests), None (CUDA if present, else warp-cpu) or False (CPU workers only).
        costs : str
            ``"calibrated"`` (nodes timed alone) or ``"history"`` (what running frames
            measured, after :meth:`learn`; calibrated costs where none was measured).

        Returns
        -------
        Plan
        """
        from .. import sched
        from .plan import Plan

        n_cpus = default_n_cpus() if n_cpus is None else n_cpus
        be = self._gpu_backend(gpu)
        with self._run_lock:
            if not self.verified:
                self.verify()
            cal = self._calibrations.get(be.name if be else None)
            if cal is None or recalibrate:
                cal = self.calibrate(gpu=be.name if be else False, recalibrate=recalibrate)
            dag = self.to_task_dag(n_cpus, gpu=be.name if be else False, calibration=cal,
                                   costs=costs)
            sch = sched.schedule(dag, policy)
            sched.validate_schedule(dag, sch)
            plan = Plan(weakref.ref(self), sch, dag, sched.metrics(dag, sch),
                        policy if isinstance(policy, str) else getattr(policy, "__name__", "custom"),
                        n_cpus, be.name if be else None, cal, costs=costs)
            self._invalidate_plan()
            self._plan = plan
            self._plan_box[0] = plan
        return plan

    def learn(self, plan=None, *, runs=None, skip: int = 1) -> dict:
        """Fold measured frames into the plan's calibration history (and the cache), for
        ``schedule(..., costs="history")``.

        ``runs``: the :class:`~warpvx.runtime.FrameResult` of frames run with ``plan``
        (default: the plan's ``last_run``; :meth:`process` keeps only its latest frame there,
        so collect them to learn from many). Each node's cost on the processing element it
        ran on becomes the median of its measured intervals without their transfers, over
        the frames after the first ``skip``. Returns node -> ``{pe: ms}`` learnt.
        """
        from .calibration import learn as _learn

        plan = plan or self._plan
        runs = list(plan.last_run) if runs is None and plan is not None else runs
        if plan is None or not runs:
            raise GraphError("learn: nothing measured yet; run g.process() or g.stream() first")
        return _learn(plan.calibration, runs, plan.placement, skip=skip)

    @property
    def plan(self):
        """The current :class:`Plan` (None until :meth:`schedule` or the first run)."""
        return self._plan

    # ------------------------------------------------------------------ running

    def _program(self) -> Program:
        from ..backend import resolve_backend

        plan = self._plan
        cpu_be = resolve_backend("cpu")
        gpu_be = resolve_backend(plan.gpu) if plan is not None and plan.gpu else None
        tasks = {}
        for node in self.nodes.values():
            refs = tuple(InputRef(r.data.name, r.offset) if isinstance(r, DelayRef)
                         else InputRef(r.name) for r in node.inputs.values())
            pes = node.processing_elements
            on_gpu = "gpu" in pes and gpu_be is not None
            out_factory = getattr(node, "out_factory", None)
            tasks[node.name] = ExecTask(
                node.name, refs, tuple(d.name for d in node.outputs.values()),
                cpu=node.callable("cpu", cpu_be) if "cpu" in pes else None,
                gpu=node.callable("gpu", gpu_be) if on_gpu else None,
                gpu_out=out_factory(gpu_be) if on_gpu and out_factory is not None else None,
            )
        return Program(tasks, tuple(self.inputs), {n: d.name for n, d in self.outputs.items()},
                       {d.data.name: d for d in self.delays})

    def _ensure_plan(self, inputs):
        if not self.verified:
            self.verify(inputs)
        if self._plan is None:
            self.schedule()
        return self._plan

    def _frame_inputs(self, inputs, device):
        if inputs is None:
            inputs = {}
        elif not isinstance(inputs, dict):
            if len(self.inputs) != 1:
                raise GraphError(f"inputs: expected a dict name -> value for inputs "
                                 f"{sorted(self.inputs)}, got {type(inputs).__name__}")
            inputs = {next(iter(self.inputs)): inputs}
        unknown = [k for k in inputs if k not in self.inputs]
        if unknown:
            raise GraphError(f"inputs: unknown input(s) {unknown}; the graph has {sorted(self.inputs)}")
        out, all_host = {}, True
        for name, data in self.inputs.items():
            if name in inputs:
                value = inputs[name]
            else:
                with data.lock:
                    if not data._has_value:
                        raise GraphError(f"input {name!r}: missing (no value given and none written)")
                    value = data._value
            check_input(data, value)
            where = HOST
            if not isinstance(value, np.ndarray) and hasattr(value, "device") and hasattr(value, "ptr"):
                all_host = False
                if device is not None and str(value.device) == str(device):
                    where = DEVICE
                else:
                    value = value.numpy()
            data._store(value)
            out[name] = (value, where)
        return out, all_host

    def _publish(self, result):
        for name, value in result.outputs.items():
            self.outputs[name]._store(value)

    def process(self, inputs=None, *, host: bool | None = None) -> dict:
        """Run one frame; return ``{output name: value}``.

        ``inputs`` maps input names to arrays (a bare array for a one-input graph); missing
        inputs use their written value. Verifies, calibrates and schedules (policy ``best``)
        first when needed. Outputs are host data when the inputs were, else left where they
        were produced (``host`` forces either).

        Raises
        ------
        GraphError
            A missing input or one of the wrong shape or dtype; verification errors.
        NodeExecutionError
            A node raised (its exception is ``__cause__``).
        """
        with self._run_lock:
            if inputs is not None and not self.verified:
                self.verify(inputs if isinstance(inputs, dict) else {next(iter(self.inputs)): inputs})
            plan = self._ensure_plan(None)
            ex = plan.executor()
            feed, all_host = self._frame_inputs(inputs, ex.gpu_device and _device_name(ex.gpu_device))
            ex.reanchor(max_age=5.0)
            frame = ex.submit(self._next_frame(), feed)
            try:
                result = ex.wait(frame, host=all_host if host is None else host)
            except NodeExecutionError:
                ex.abort()
                raise
            plan.last_run.clear()
            plan.last_run.append(_timing_only(result))
            self._publish(result)
            return result.outputs

    def stream(self, frames, *, depth: int = 2, host: bool | None = None):
        """Run many frames pipelined; a generator of output dicts, in frame order.

        Up to ``depth`` frames are in flight: frame *i+1*'s early nodes run while frame
        *i*'s late ones finish. Delays age in frame order. If a node fails, the frames before
        it are still yielded, then :class:`~warpvx.errors.NodeExecutionError` is raised and
        the frames after it are cancelled. Closing the generator early cancels what is in
        flight.
        """
        if isinstance(depth, bool) or not isinstance(depth, (int, np.integer)) or depth < 1:
            raise GraphError(f"depth: expected an int >= 1, got {depth!r}")
        with self._run_lock:
            pending = deque()
            plan = ex = None
            try:
                for item in frames:
                    if plan is None:
                        if not self.verified:
                            self.verify(item if isinstance(item, dict) or item is None
                                        else {next(iter(self.inputs)): item})
                        plan = self._ensure_plan(None)
                        ex = plan.executor()
                        ex.reanchor()
                        plan.last_run.clear()
                    feed, all_host = self._frame_inputs(item, ex.gpu_device and _device_name(ex.gpu_device))
                    pending.append((ex.submit(self._next_frame(), feed), all_host))
                    if len(pending) >= depth:
                        yield self._finish(plan, ex, *pending.popleft(), host)
                while pending:
                    yield self._finish(plan, ex, *pending.popleft(), host)
            finally:
                if ex is not None and pending:
                    ex.abort()

    def _finish(self, plan, ex, frame, all_host, host):
        try:
            result = ex.wait(frame, host=all_host if host is None else host)
        except NodeExecutionError:
            ex.abort()
            raise
        plan.last_run.append(_timing_only(result))
        self._publish(result)
        return result.outputs

    def _next_frame(self) -> int:
        i = self._frame
        self._frame += 1
        return i

    def reset(self):
        """Forget past frames: every delay reads its initial value again (as a new video)."""
        with self._run_lock:
            plan = self._plan
            if plan is not None and plan._executor is not None:
                plan._executor.abort()
            for d in self.delays:
                d.reset()

    def close(self):
        """Stop the executor threads of the current plan (the graph stays usable)."""
        self._invalidate_plan()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def __repr__(self):
        return (f"Graph({self.name!r}, {len(self.nodes)} nodes, inputs={list(self.inputs)}, "
                f"outputs={list(self.outputs)})")


def _timing_only(result):
    """A frame's result as a plan keeps it: the measurements, not the outputs (a plan keeps
    dozens of frames; their outputs, images among them, went to the caller)."""
    return dataclasses.replace(result, outputs={})


def _device_name(device):
    from ..backend import init_warp

    return str(init_warp().get_device(device))


__all__ = ["Graph", "default_n_cpus"]
