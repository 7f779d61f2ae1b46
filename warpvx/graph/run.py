"""Running a graph: the runtime :class:`~warpvx.runtime.Program` of a plan, frames in
(:meth:`~Runner.process`, :meth:`~Runner.stream`) and outputs back.

:class:`Runner` is a part of :class:`~warpvx.graph.Graph` (a mixin: it uses the graph's
nodes, inputs, outputs, delays, plan and run lock). :func:`program` and :func:`gpu_device`
are what a :class:`~warpvx.graph.plan.Plan` builds its executor from.
"""

from __future__ import annotations

import dataclasses
from collections import deque

import numpy as np

from ..errors import GraphError, NodeExecutionError
from ..runtime import DEVICE, HOST, ExecTask, InputRef, Program
from .bind import bind
from .data import DelayRef
from .verify import check_input


def gpu_device(gpu_name: str | None) -> str | None:
    """The Warp device (``"cuda:0"``, ``"cpu"``) of a GPU role's backend name, None for none."""
    if gpu_name is None:
        return None
    from ..backend import resolve_backend

    return resolve_backend(gpu_name).device


def program(graph, gpu_name: str | None) -> Program:
    """What the executor runs for verified ``graph`` with GPU role ``gpu_name`` (a backend
    name or None): one task per node, each bound to its implementation (:func:`bind`)."""
    from ..backend import resolve_backend

    cpu_be = resolve_backend("cpu")
    gpu_be = resolve_backend(gpu_name) if gpu_name else None
    tasks = {}
    for node in graph.nodes.values():
        refs = tuple(InputRef(r.data.name, r.offset) if isinstance(r, DelayRef)
                     else InputRef(r.name) for r in node.inputs.values())
        pes = node.processing_elements
        on_gpu = "gpu" in pes and gpu_be is not None
        out_factory = getattr(node, "out_factory", None)
        tasks[node.name] = ExecTask(
            node.name, refs, tuple(d.name for d in node.outputs.values()),
            cpu=bind(node, "cpu", cpu_be) if "cpu" in pes else None,
            gpu=bind(node, "gpu", gpu_be) if on_gpu else None,
            gpu_out=out_factory(gpu_be) if on_gpu and out_factory is not None else None,
        )
    return Program(tasks, tuple(graph.inputs), {n: d.name for n, d in graph.outputs.items()},
                   {d.data.name: d for d in graph.delays})


class Runner:
    """Frames in, outputs out: the running half of :class:`~warpvx.graph.Graph`."""

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
            if self._plan is not None:
                self._plan.abort()
            for d in self.delays:
                d.reset()

    def close(self):
        """Stop the executor threads of the current plan (the graph stays usable)."""
        self._invalidate_plan()

    def _gpu_device(self) -> str | None:
        """The Warp device of the current plan's GPU role (None: no plan or no GPU role)."""
        plan = self._plan
        return gpu_device(plan.gpu) if plan is not None else None


def _timing_only(result):
    """A frame's result as a plan keeps it: the measurements, not the outputs (a plan keeps
    dozens of frames; their outputs, images among them, went to the caller)."""
    return dataclasses.replace(result, outputs={})


def _device_name(device):
    from ..backend import init_warp

    return str(init_warp().get_device(device))


__all__ = ["Runner", "program", "gpu_device"]
