"""Graph nodes: registered primitives and user callables, their ports and their callables.

A node's *input ports* are named after the parameters of the function it calls (``src``,
``prev_pts``, ...), its *output ports* after what the function returns (the registry's
:attr:`~warpvx.registry.Primitive.outputs`; one output named ``out`` by default). A node runs
the public function of its primitive with ``backend="cpu"`` on a CPU worker and with the GPU
role's backend on the GPU, so arguments are validated by the primitive's own checks and each
implementation gets what it takes.
"""

from __future__ import annotations

import functools
import importlib
import inspect
import re
import threading
import weakref

import numpy as np

from .._counted import Block, is_counted, row_arrays
from ..errors import GraphError, WarpvxError
from ..runtime.processes import ProcessCall
from ..registry import REGISTRY, get_primitive
from .data import Data, DelayRef

#: Arguments the runtime owns: a node may not set them.
RESERVED = ("backend", "stream", "out")

TARGETS = ("cpu", "gpu")


def _is_data(x) -> bool:
    return isinstance(x, (Data, DelayRef))


# The user nodes this thread is running, innermost last, as (graph weakref, node name): a
# node calling its own graph's process() would wait for the frame that runs it (forever).
_running = threading.local()


def running_node(graph) -> str | None:
    """The name of the user node of ``graph`` this thread is running, or None."""
    for ref, name in reversed(getattr(_running, "nodes", ())):
        if ref() is graph:
            return name
    return None


def _marked(node, fn):
    """``fn`` recording on the thread, while it runs, that ``node`` is running."""
    where = (node._graph, node.name)

    @functools.wraps(fn)
    def run(*args, **kwargs):
        try:
            stack = _running.nodes
        except AttributeError:  # this thread's first node (an attribute read, not a call, after)
            stack = _running.nodes = []
        stack.append(where)
        try:
            return fn(*args, **kwargs)
        finally:
            stack.pop()

    return run


class Node:
    """A node of a :class:`~warpvx.graph.Graph`.

    Attributes
    ----------
    name : str
        Unique within the graph (``"color_convert_0"`` unless named).
    kind : str
        The primitive's registry name, or ``"user"``.
    inputs : dict
        port -> :class:`Data` or :class:`DelayRef`.
    outputs : dict
        port -> :class:`Data`.
    target : str or None
        ``"cpu"`` or ``"gpu"`` pins the node to that kind of processing element
        (``vxSetNodeTarget``); None lets the scheduler choose.
    capturable : bool
        Its GPU callable, given ``out=``, may be captured into a CUDA graph.
    """

    kind = "node"
    capturable = False

    def __init__(self, graph, name: str):
        self._graph = weakref.ref(graph)
        self.name = name
        self.inputs: dict = {}
        self.outputs: dict = {}
        self._target = None

    @property
    def graph(self):
        return self._graph()

    @property
    def target(self):
        return self._target

    @target.setter
    def target(self, value):
        if value is not None and value not in TARGETS:
            raise GraphError(f"node {self.name!r}, port 'target': expected 'cpu', 'gpu' or None, "
                             f"got {value!r}")
        if value is not None and value not in self.implementations:
            raise GraphError(f"node {self.name!r} ({self.kind}), port 'target': pinned to "
                             f"{value!r} but it has only {sorted(self.implementations)} "
                             f"implementation(s)")
        self.graph._check_building(f"node {self.name!r}, port 'target'")
        self._target = value
        self.graph._invalidate_plan()

    @property
    def implementations(self) -> frozenset:
        """``{"cpu", "gpu"}`` or a subset: the processing elements that can run it."""
        raise NotImplementedError

    @property
    def processing_elements(self) -> frozenset:
        """The implementations, narrowed to the pinned target."""
        if self._target is not None:
            return frozenset({self._target})
        return self.implementations

    @property
    def exclusive(self) -> bool:
        return len(self.implementations) == 1

    def callable(self, pe: str, backend):
        """``fn(*input_values) -> output value(s)`` running on ``pe`` (``"cpu"``/``"gpu"``)."""
        raise NotImplementedError

    def cache_key(self) -> str:
        """What identifies this node's work for the calibration cache (kind and constants)."""
        raise NotImplementedError

    def error(self, port, message) -> GraphError:
        where = f", port {port!r}" if port else ""
        return GraphError(f"node {self.name!r} ({self.kind}){where}: {message}")

    def __repr__(self):
        return f"{type(self).__name__}({self.name!r})"

    def _fits(self):
        """``fits(values)``: whether input values have the shapes verification saw, so the
        node's ``out=`` buffers (sized from its samples) fit them."""
        shapes = []
        for port in self.input_ports:
            ref = self.inputs[port]
            # A delayed input's: the previous frame's value the output sample came from.
            sample = _delayed_sample(ref) if isinstance(ref, DelayRef) else ref.sample
            shapes.append(tuple(sample.shape) if isinstance(sample, np.ndarray) else None)

        def fits(values):
            # A Counted input has its producer's capacity, which sized the Counted out=.
            return all(s is None or is_counted(v) or tuple(getattr(v, "shape", ())) == s
                       for v, s in zip(values, shapes))

        return fits


class PrimitiveNode(Node):
    """A node calling a registered primitive's public function."""

    def __init__(self, graph, name: str, primitive: str, args: tuple, kwargs: dict):
        super().__init__(graph, name)
        self.kind = primitive
        try:
            self.primitive = get_primitive(primitive)
        except WarpvxError:
            raise GraphError(f"node {name!r}: unknown primitive {primitive!r}; registered: "
                             f"{sorted(REGISTRY)}") from None
        try:
            self.function = self.primitive.function()
        except (ImportError, AttributeError) as exc:
            raise GraphError(f"node {name!r}: primitive {primitive!r} is registered but its "
                             f"function cannot be imported ({exc})") from exc
        for key in RESERVED:
            if key in kwargs:
                raise self.error(key, f"{key!r} is set by the graph runtime, not by the node")
        self.signature = inspect.signature(self.function)
        try:
            bound = self.signature.bind(*args, **kwargs)
        except TypeError as exc:
            found = re.search(r"'(\w+)'", str(exc))
            raise self.error(found.group(1) if found else None, str(exc)) from None
        self.arguments = dict(bound.arguments)
        self.input_ports = []
        for pname, value in self.arguments.items():
            kind = self.signature.parameters[pname].kind
            if kind in (inspect.Parameter.VAR_POSITIONAL, inspect.Parameter.VAR_KEYWORD):
                if any(_is_data(v) for v in (value if kind == inspect.Parameter.VAR_POSITIONAL
                                             else value.values())):
                    raise self.error(pname, "data objects must be passed to named parameters")
                continue
            if _is_data(value):
                self.inputs[pname] = value
                self.input_ports.append(pname)
        self.output_ports = self.primitive.outputs

    @property
    def implementations(self) -> frozenset:
        return self.primitive.processing_elements

    def bind_values(self, values) -> tuple:
        arguments = dict(self.arguments)
        for port, value in zip(self.input_ports, values):
            arguments[port] = value
        ba = inspect.BoundArguments(self.signature, arguments)
        return ba.args, ba.kwargs

    def callable(self, pe: str, backend):
        """``fn(*input_values, out=None)``; ``out`` (a buffer from :meth:`out_factory`) is
        used only while the inputs have the shapes verification saw, so it fits."""
        fn = self.function
        ports = self.input_ports
        base = dict(self.arguments)
        sig = self.signature
        simple = all(sig.parameters[p].kind in (inspect.Parameter.POSITIONAL_OR_KEYWORD,
                                                inspect.Parameter.KEYWORD_ONLY)
                     for p in base)
        fits = self._fits()
        if simple:
            # Hot path: keyword call, no BoundArguments per frame.
            def run(*values, out=None):
                kw = dict(base)
                for p, v in zip(ports, values):
                    kw[p] = v
                if out is not None and fits(values):
                    kw["out"] = out
                return fn(**kw, backend=backend)
        else:
            def run(*values, out=None):
                args, kwargs = self.bind_values(values)
                if out is not None and fits(values):
                    kwargs["out"] = out
                return fn(*args, **kwargs, backend=backend)

        return run

    def out_factory(self, backend):
        """A maker of this node's output buffers on ``backend``'s device, for the executor's
        buffer pools; None unless the registry says the primitive's outputs are sized by its
        inputs (:attr:`~warpvx.registry.Primitive.sized_by_inputs`; verification's samples
        then fix shapes and dtypes). One output: its buffer (an array, or a list of arrays
        for a pyramid); several: a tuple, one per output. A sample leaf that is an input's
        own sample (a pyramid's level 0 is its source) is None: the call fills it in."""
        if backend is None or backend.kind != "warp":
            return None
        counted = self._counted_factory(backend.device)
        if counted is not None or not self.primitive.sized_by_inputs:
            return counted
        return _sized_factory(self, backend.device)

    @property
    def capturable(self) -> bool:
        """The registry's :attr:`~warpvx.registry.Primitive.capturable`."""
        return self.primitive.capturable

    def row_capacity(self) -> int | None:
        """Rows of this node's Counted outputs in a graph
        (:attr:`~warpvx.registry.Primitive.counted_rows`): the capacity of the node producing
        the input it names, or what the function it names gives for the node's arguments
        (inputs as verification's samples); None when there is none."""
        source = self.primitive.counted_rows
        if source is None:
            return None
        if ":" in source:
            module, attr = source.split(":")
            samples = {p: _delayed_sample(ref) if isinstance(ref, DelayRef) else ref.sample
                       for p, ref in self.inputs.items()}
            if any(v is None for v in samples.values()):
                return None
            bound = self.signature.bind_partial(**{**self.arguments, **samples})
            bound.apply_defaults()
            value = getattr(importlib.import_module(module), attr)(**bound.arguments)
            return None if value is None else int(value)
        ref = self.inputs[source]
        producer = ref.data.producer if isinstance(ref, DelayRef) else ref.producer
        return producer.row_capacity() if isinstance(producer, PrimitiveNode) else None

    def _counted_factory(self, device):
        """A maker of this node's Counted outputs (one count buffer shared by them), or None
        (no capacity, or outputs that are not numeric arrays in verification)."""
        capacity = self.row_capacity()
        samples = [self.outputs[p].sample for p in self.output_ports]
        arrays = [a for s in samples for a in row_arrays(s)]
        if capacity is None or not arrays or not all(
                isinstance(a, np.ndarray) and a.ndim >= 1 and a.dtype.kind in "uif"
                for a in arrays):
            return None

        def make():
            # One allocation for the count and every rows array: one copy moves them all.
            bufs = Block.layout(samples, capacity, device)
            return bufs[0] if len(bufs) == 1 else tuple(bufs)

        return make

    def constants(self) -> dict:
        return {k: v for k, v in self.arguments.items() if k not in self.inputs}

    def cache_key(self) -> str:
        return self.kind + "|" + _const_text(self.constants())


def _sized_factory(node, device):
    """A maker of ``node``'s output buffers shaped as verification's samples (see
    :meth:`PrimitiveNode.out_factory`), or None when a sample is not a numeric array or a
    list of them."""
    samples = [node.outputs[p].sample for p in node.output_ports]
    inputs = [_delayed_sample(ref) if isinstance(ref, DelayRef) else ref.sample
              for ref in node.inputs.values()]
    specs = [_buffer_spec(s, inputs) for s in samples]
    if any(s is None for s in specs):
        return None

    def make():
        from ..backend import init_warp

        wp = init_warp()

        def build(spec):
            if isinstance(spec, list):
                return [build(s) for s in spec]
            return None if spec == "input" else \
                wp.empty(spec[0], dtype=wp.dtype_from_numpy(spec[1]), device=device)

        bufs = [build(s) for s in specs]
        return bufs[0] if len(bufs) == 1 else tuple(bufs)

    return make


def _delayed_sample(ref):
    """What a delayed input read in verification's last frame (its data's sample before
    verification has run two frames)."""
    previous = getattr(ref.delay, "sample_previous", None)
    return ref.data.sample if previous is None else previous


def _buffer_spec(sample, inputs):
    """(shape, dtype) of an output buffer for ``sample``, a list of specs for a list of
    arrays, "input" for an input's own sample; None when it has none (not numeric arrays)."""
    if isinstance(sample, list) and sample:
        specs = [_buffer_spec(s, inputs) for s in sample]
        return None if any(s is None for s in specs) else specs
    if any(sample is i for i in inputs):
        return "input"
    if not isinstance(sample, np.ndarray) or sample.ndim == 0 or sample.dtype.kind not in "uif":
        return None
    return tuple(sample.shape), sample.dtype


class UserNode(Node):
    """A node running a Python callable (and optionally a Warp implementation of it).

    ``fn(*inputs)`` runs on a CPU worker with host (NumPy) inputs; ``warp_fn(*inputs)``, when
    given, runs in the GPU role with ``wp.array`` inputs on the GPU device (inside
    ``wp.ScopedDevice`` with the executor's stream current). With one of the two the node is
    *exclusive* (thesis §5.1).
    """

    kind = "user"

    def __init__(self, graph, name: str, fn, warp_fn, inputs: dict, n_outputs_ports: tuple, *,
                 capturable: bool = False):
        super().__init__(graph, name)
        if fn is None and warp_fn is None:
            raise GraphError(f"node {name!r} (user): give fn, warp_fn or both")
        for label, f in (("fn", fn), ("warp_fn", warp_fn)):
            if f is not None and not callable(f):
                raise GraphError(f"node {name!r} (user), port {label!r}: expected a callable, "
                                 f"got {type(f).__name__}")
        self.fn = fn
        self.warp_fn = warp_fn
        self.capturable = bool(capturable) and warp_fn is not None
        self.inputs = dict(inputs)
        self.input_ports = list(inputs)
        self.output_ports = tuple(n_outputs_ports)

    @property
    def implementations(self) -> frozenset:
        pes = set()
        if self.fn is not None:
            pes.add("cpu")
        if self.warp_fn is not None:
            pes.add("gpu")
        return frozenset(pes)

    def callable(self, pe: str, backend):
        fn = self.fn if pe == "cpu" else self.warp_fn
        if fn is None:
            return None
        fn = _marked(self, fn)
        if pe == "cpu" or not self.capturable:
            return fn
        fits = self._fits()

        def run(*values, out=None):
            return fn(*values, out=out) if out is not None and fits(values) else fn(*values)

        return run

    def out_factory(self, backend):
        """A capturable node's output buffers, shaped as verification's samples (see
        :meth:`PrimitiveNode.out_factory`); None otherwise."""
        if not self.capturable or backend is None or backend.kind != "warp":
            return None
        return _sized_factory(self, backend.device)

    def cache_key(self) -> str:
        parts = []
        for f in (self.fn, self.warp_fn):
            if f is None:
                parts.append("-")
                continue
            # A worker process's call costs its round trip: not the in-process function's.
            process = isinstance(f, ProcessCall)
            if process:
                f = f.fn
            code = getattr(f, "__code__", None)
            where = f"@{code.co_filename}:{code.co_firstlineno}" if code is not None else ""
            parts.append(f"{getattr(f, '__module__', '?')}.{getattr(f, '__qualname__', repr(f))}"
                         f"{where}{'[process]' if process else ''}")
        return "user:" + "/".join(parts)


def _const_text(consts: dict) -> str:
    import zlib

    out = []
    for k in sorted(consts):
        v = consts[k]
        if isinstance(v, np.ndarray):
            text = f"{v.dtype}[{'x'.join(map(str, v.shape))}]#{zlib.crc32(v.tobytes()):08x}"
        else:
            text = repr(v)
            if len(text) > 80:
                text = text[:60] + f"...#{zlib.crc32(text.encode()):08x}"
        out.append(f"{k}={text}")
    return ",".join(out)


def port_of(message: str, ports) -> str | None:
    """The argument a warpvx error names (its messages start with ``"<argument>: "``)."""
    head = message.split(":", 1)[0].strip()
    head = re.split(r"[\[\s(]", head)[0]
    return head if head in ports else None


__all__ = ["Node", "PrimitiveNode", "UserNode", "TARGETS", "port_of", "running_node"]
