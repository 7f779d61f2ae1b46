"""Running a graph: the runtime :class:`~warpvx.runtime.Program` of a plan, frames in
(:meth:`~Runner.process`, :meth:`~Runner.stream`) and outputs back.

:class:`Runner` is a part of :class:`~warpvx.graph.Graph` (a mixin: it uses the graph's
nodes, inputs, outputs, delays, plan and run lock). :func:`program` and :func:`gpu_device`
are what a :class:`~warpvx.graph.plan.Plan` builds its executor from.

One run at a time: :class:`RunLock` serialises ``process``, ``stream``, ``verify``,
``calibrate``, ``schedule``, ``reset`` and ``close``, and refuses, with a
:class:`~warpvx.errors.GraphError`, what would otherwise wait forever: a user node calling
its own graph (the call would wait for the frame that runs it), and a call made while a
``stream()`` generator is live (it holds the lock between frames, until it is exhausted,
closed or garbage-collected): from the stream's own thread at once, from another thread
after :attr:`Runner.stream_wait` seconds.
"""

from __future__ import annotations

import functools
import threading
import time
import weakref
from collections import deque

import numpy as np

from ..errors import GraphError, NodeExecutionError
from ..runtime import DEVICE, HOST, WAIT_SLICE, ExecTask, InputRef, Program
from ..runtime.processes import ProcessCall
from .bind import bind
from .data import DelayRef
from .nodes import running_node
from .verify import check_input, check_input_names, contiguous


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
        gpu_out = out_factory(gpu_be) if on_gpu and out_factory is not None else None
        tasks[node.name] = ExecTask(
            node.name, refs, tuple(d.name for d in node.outputs.values()),
            cpu=bind(node, "cpu", cpu_be) if "cpu" in pes else None,
            gpu=bind(node, "gpu", gpu_be) if on_gpu else None,
            gpu_out=gpu_out,
            capture=gpu_out is not None and node.capturable,
        )
    return Program(tasks, tuple(graph.inputs), {n: d.name for n, d in graph.outputs.items()},
                   {d.data.name: d for d in graph.delays})


class RunLock:
    """A graph's run lock: re-entrant, refusing the calls that would wait forever.

    ``with lock:`` raises :class:`~warpvx.errors.GraphError` when this thread is running a
    user node of the graph, when this thread's ``stream()`` generator is suspended at a frame,
    or when another thread's live stream has not ended after the graph's ``stream_wait``
    seconds; a ``process()`` of another thread is waited for (its frame bounds it).

    A live stream holds a token (``stream``, the text naming it), not the lock itself: it
    takes the lock while it runs and lets it go while suspended at a yield, so a generator
    resumed, closed or garbage-collected on another thread than the one that started it
    frees the graph all the same.
    """

    def __init__(self, graph):
        self._graph = weakref.ref(graph)
        self._lock = threading.RLock()
        self.stream = None   # the live stream's name, or None
        self.owner = None    # the thread that last ran the live stream
        self.running = False  # the live stream holds the lock (not suspended at a yield)

    def refuse(self, what: str = "a call that runs the graph"):
        """Raise GraphError if ``what`` must not run now on this thread: it is inside one of
        the graph's user nodes, or the graph's stream is suspended here."""
        graph = self._graph()
        node = running_node(graph)
        if node is not None:
            raise GraphError(f"graph {graph.name!r}: {what} from inside its own node {node!r} "
                             f"would wait forever for the frame that runs the node (use another "
                             f"graph, or make the value an output)")
        if self.stream is not None and not self.running and self.owner == threading.get_ident():
            raise GraphError(f"graph {graph.name!r}: {what} while {self.stream} is live in this "
                             f"thread; exhaust it or call its close() first")

    def _free_for(self, me) -> bool:
        return self.stream is None or (self.running and self.owner == me)

    def __enter__(self):
        self.refuse()
        # The usual case first: no stream, the lock free (or this thread's): taken at once.
        if self.stream is None and self._lock.acquire(False):
            if self.stream is None:
                return self
            self._lock.release()  # a stream started meanwhile
        me, waited_from = threading.get_ident(), None
        while True:
            if self._free_for(me):
                waited_from = None
                if self._lock.acquire(timeout=WAIT_SLICE):
                    if self._free_for(me):
                        return self
                    self._lock.release()  # a stream started meanwhile
                continue
            now = time.monotonic()
            waited_from = waited_from or now
            graph = self._graph()
            if now - waited_from > graph.stream_wait:
                raise GraphError(f"graph {graph.name!r}: waited {graph.stream_wait:g} s for "
                                 f"{self.stream} to end; exhaust it or close() it, or run this "
                                 f"thread's frames on another graph")
            time.sleep(WAIT_SLICE)

    def __exit__(self, *exc):
        self._lock.release()

    def start_stream(self, name: str):
        """Take the lock and the stream token (the generator's first step)."""
        self.__enter__()
        self.stream, self.owner, self.running = name, threading.get_ident(), True

    def suspend(self):
        """The stream yields a frame: let the lock go, keep the token."""
        self.running = False
        self._lock.release()

    def resume(self):
        """The stream's consumer asks for the next frame (on whatever thread)."""
        self._lock.acquire()
        self.owner, self.running = threading.get_ident(), True

    def end_stream(self):
        """The stream is exhausted, failed, closed or collected: give the token (and the lock,
        if it holds it) back."""
        held, self.running = self.running, False
        self.stream = self.owner = None
        if held:
            self._lock.release()


class Runner:
    """Frames in, outputs out: the running half of :class:`~warpvx.graph.Graph`."""

    #: Seconds a call from another thread waits for a live ``stream()`` generator to end
    #: before it raises :class:`~warpvx.errors.GraphError` (see :class:`RunLock`).
    stream_wait = 10.0

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
            inputs = self._as_dict(inputs)
        check_input_names(self, inputs)
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
            value = contiguous(value)
            where = HOST
            if not isinstance(value, np.ndarray) and hasattr(value, "device") and hasattr(value, "ptr"):
                all_host = False
                if device is not None and str(value.device) == _device_name(device):
                    where = DEVICE
                else:
                    value = value.numpy()
            data._store(value)
            out[name] = (value, where)
        return out, all_host

    def _as_dict(self, inputs) -> dict:
        """A frame's inputs as a dict: a bare value is the one input of a one-input graph."""
        if len(self.inputs) != 1:
            raise GraphError(f"inputs: expected a dict name -> value for inputs "
                             f"{sorted(self.inputs)}, got {type(inputs).__name__}")
        return {next(iter(self.inputs)): inputs}

    def _publish(self, result):
        for name, value in result.outputs.items():
            self.outputs[name]._store(value)

    def process(self, inputs=None, *, host: bool | None = None, capture: bool | None = None) -> dict:
        """Run one frame; return ``{output name: value}``.

        ``inputs`` maps input names to arrays (a bare array for a one-input graph); missing
        inputs use their written value. Verifies, calibrates and schedules (policy ``best``)
        first when needed. Outputs are host data when the inputs were, else left where they
        were produced (``host`` forces either). A non-contiguous input array (a strided view)
        is copied once to a contiguous one, as the nodes take contiguous arrays.

        With a plan of K frames in flight (:meth:`schedule`), the frame runs with the
        placement of its index mod K.

        ``capture``: replay runs of consecutive capturable GPU nodes from CUDA graphs
        (:mod:`warpvx.runtime.capture`; captured on the second frame, or on the fourth and
        fifth where the run's own delays swap between two buffer sets). None (default): on
        CUDA; False: never; True: also on Warp's CPU device. A plan of K > 1 frames in
        flight never captures (its GPU queue interleaves frames). Where a capture fails (a node
        synchronising, a caller's own capture, inputs of another shape than verification's,
        for which the nodes' output buffers are not sized) those nodes run eagerly, never
        an error.

        Raises
        ------
        GraphError
            A missing or unknown input, one of the wrong shape or dtype; verification errors;
            a call from inside one of the graph's own user nodes; a call while a ``stream()``
            generator of the graph is live (see :class:`RunLock`).
        NodeExecutionError
            A node raised (its exception is ``__cause__``).
        """
        with self._run_lock:
            if inputs is not None and not self.verified:
                self.verify(inputs if isinstance(inputs, dict) else self._as_dict(inputs))
            plan = self._ensure_plan(None)
            ex = plan.executor()
            feed, all_host = self._frame_inputs(inputs, ex.gpu_device)
            ex.reanchor(max_age=5.0)
            frame = ex.submit(self._next_frame(), feed, capture=capture, wake=False)
            try:
                result = ex.wait(frame, host=all_host if host is None else host)
            except NodeExecutionError:
                ex.abort()
                raise
            plan.last_run.clear()
            return self._keep(plan, result)

    def stream(self, frames, *, depth: int | None = None, host: bool | None = None,
               capture: bool | None = None):
        """Run many frames pipelined; a generator of output dicts, in frame order.

        ``frames`` is an iterable of frames, each what :meth:`process` takes. Up to ``depth``
        frames are in flight (default: 2, or K for a plan of K frames in flight, see
        :meth:`schedule`): frame *i+1*'s early nodes run while frame *i*'s late ones
        finish. Delays age in frame order. If a node fails, the frames before it are still
        yielded, then :class:`~warpvx.errors.NodeExecutionError` is raised and the frames
        after it are cancelled. If ``frames`` itself raises (or a frame is refused: a wrong
        shape, a missing input), the frames submitted before it are still yielded, then that
        exception is raised. Closing the generator early cancels what is in flight.
        ``capture`` as in :meth:`process`.

        While the generator is live (started, not exhausted, closed or garbage-collected) it
        holds the graph: this thread's calls that run or change the graph raise
        :class:`~warpvx.errors.GraphError` at once, other threads' wait at most
        :attr:`stream_wait` seconds, then raise it (see :class:`RunLock`).

        Raises
        ------
        GraphError
            ``frames`` is not iterable, ``depth`` is not None or an int >= 1 (both at the call).
        """
        if depth is not None and (isinstance(depth, bool) or not isinstance(depth, (int, np.integer))
                                  or depth < 1):
            raise GraphError(f"depth: expected an int >= 1, got {depth!r}")
        try:
            if isinstance(frames, dict):  # one frame's inputs: iterating gives their names
                raise TypeError
            frames = iter(frames)
        except TypeError:
            raise GraphError(f"frames: expected an iterable of frames (input dicts or arrays), "
                             f"got {type(frames).__name__}; use process() for one frame") from None
        return self._stream(frames, depth, host, capture)

    def _stream(self, frames, depth, host, capture):
        lock = self._run_lock
        lock.start_stream(f"the stream() generator of graph {self.name!r} (started in thread "
                          f"{threading.current_thread().name!r})")
        pending = deque()
        plan = ex = error = None
        try:
            while True:
                try:
                    item = next(frames)
                    if plan is None:
                        if not self.verified:
                            self.verify(item if isinstance(item, dict) or item is None
                                        else self._as_dict(item))
                        plan = self._ensure_plan(None)
                        ex = plan.executor()
                        ex.reanchor()
                        plan.last_run.clear()
                        depth = int(depth) if depth is not None else max(2, ex.frames)
                    feed, all_host = self._frame_inputs(item, ex.gpu_device)
                    pending.append((ex.submit(self._next_frame(), feed, capture=capture), all_host))
                except StopIteration:
                    break
                except Exception as exc:  # noqa: BLE001 - raised after the frames submitted
                    error = exc
                    break
                if len(pending) >= depth:
                    yield from self._hand_over(self._finish(plan, ex, *pending.popleft(), host))
            while pending:
                yield from self._hand_over(self._finish(plan, ex, *pending.popleft(), host))
            if error is not None:
                raise error
        finally:
            try:
                if ex is not None and pending:
                    ex.abort()
            finally:
                lock.end_stream()

    def _hand_over(self, outputs):
        """Yield ``outputs`` with the graph's lock let go (the stream keeps its token); take
        it again when the consumer asks for the next frame. Closed or thrown into at the
        yield, the stream ends without it."""
        lock = self._run_lock
        lock.suspend()
        yield outputs
        lock.resume()

    def _finish(self, plan, ex, frame, all_host, host):
        try:
            result = ex.wait(frame, host=all_host if host is None else host)
        except NodeExecutionError:
            ex.abort()
            raise
        return self._keep(plan, result)

    def _keep(self, plan, result) -> dict:
        """Publish ``result``'s outputs (the graph's output data) and return them; the plan
        keeps the result without them: its measurements, not its outputs (a plan keeps
        dozens of frames; their outputs, images among them, went to the caller). The
        executor's result is this frame's alone: emptied in place, not copied."""
        outputs = result.outputs
        self._publish(result)
        result.outputs = {}
        plan.last_run.append(result)
        return outputs

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
        """Stop the executor threads of the current plan and the worker processes of its
        ``process=True`` nodes (the graph stays usable: they start again when needed)."""
        self._invalidate_plan()
        for node in self.nodes.values():
            fn = getattr(node, "fn", None)
            if isinstance(fn, ProcessCall):
                fn.close()

    def _gpu_device(self) -> str | None:
        """The Warp device of the current plan's GPU role (None: no plan or no GPU role)."""
        plan = self._plan
        return gpu_device(plan.gpu) if plan is not None else None


@functools.lru_cache(maxsize=None)
def _device_name(device) -> str:
    """Warp's name of ``device`` (``"cuda"`` -> ``"cuda:0"``), resolved once per device."""
    from ..backend import init_warp

    return str(init_warp().get_device(device))


__all__ = ["Runner", "RunLock", "program", "gpu_device"]
