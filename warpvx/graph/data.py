"""Graph data objects: parameters, virtual intermediates, delays, and value helpers.

A :class:`Data` is an edge of the graph: a graph input parameter (``g.input``), or the output
of a node (*virtual*: the runtime owns it, may keep it on the GPU and gives no access to it
between frames). :class:`Delay` (OpenVX ``vx_delay``) keeps the values of a data object from
past frames. Parameters and delays carry a ``lock`` that the executor takes too, so other
threads may read and write them while graphs run (thesis §4.2, the communication wrapper).
"""

from __future__ import annotations

import threading
import weakref

import numpy as np

from ..errors import GraphError
from ..keypoints import FIELDS, Keypoints
from ..runtime import HOST, Ring, Transfers, tree_map

INPUT = "input"
VIRTUAL = "virtual"


class Data:
    """A data object of a :class:`~warpvx.graph.Graph`.

    Attributes
    ----------
    name : str
        Unique within the graph: the input's name, or ``"<node>.<port>"`` for a node output.
    kind : str
        ``"input"`` (a graph input parameter) or ``"virtual"`` (produced by a node).
    producer : Node or None
        The node that writes it (None for inputs and for an unproduced virtual).
    output_name : str or None
        Its name as a graph output parameter, once :meth:`Graph.output` named it.
    lock : threading.RLock
        Shared with the executor: hold it to read or write the value from another thread.
    sample : object
        The value :meth:`Graph.verify` computed on synthetic (or given) data, at the graph's
        real sizes; what calibration times nodes on.
    """

    def __init__(self, graph, name: str, kind: str, *, shape=None, dtype=None, value=None):
        self._graph = weakref.ref(graph)
        self.name = name
        self.kind = kind
        self.producer = None
        self.port = None
        self.output_name = None
        self.shape = None if shape is None else tuple(shape)
        self.dtype = None if dtype is None else np.dtype(dtype)
        self.lock = threading.RLock()
        self.sample = None
        self._value = value
        self._has_value = value is not None

    # ------------------------------------------------------------ communication wrapper

    def read(self):
        """The current value, under the lock.

        Input parameter: the value written last (or the last frame's input). Output
        parameter: the last completed frame's value (host data). Raises GraphError for a
        virtual intermediate (the runtime owns it, as in OpenVX).
        """
        if self.kind == VIRTUAL and self.output_name is None:
            raise GraphError(f"data {self.name!r}: a virtual intermediate cannot be read; "
                             f"make it a graph output with g.output(name, data)")
        with self.lock:
            return self._value

    def write(self, value):
        """Set an input parameter's value for the frames that follow (under the lock)."""
        if self.kind != INPUT:
            raise GraphError(f"data {self.name!r}: only graph input parameters can be written")
        with self.lock:
            self._value = value
            self._has_value = True

    def _store(self, value):
        with self.lock:
            self._value = value
            self._has_value = True

    @property
    def graph(self):
        return self._graph()

    @property
    def node(self):
        """The producing node (``None`` for an input parameter)."""
        return self.producer

    def __repr__(self):
        return f"Data({self.name!r}, {self.kind})"


class DelayRef:
    """``delay[-j]``: the value of the delayed data ``j`` frames ago, usable as a node input."""

    def __init__(self, delay: "Delay", offset: int):
        self.delay = delay
        self.offset = offset

    @property
    def data(self) -> Data:
        return self.delay.data

    @property
    def name(self) -> str:
        return f"{self.delay.data.name}[{self.offset}]"

    def __repr__(self):
        return f"DelayRef({self.name})"


class Delay(Ring):
    """A ring of the past values of one data object, aged once per frame (OpenVX ``vx_delay``).

    Made by :meth:`Graph.delay`. ``delay[0]`` is the data object itself (this frame's value),
    ``delay[-j]`` for ``1 <= j <= slots`` its value ``j`` frames ago; both are node inputs.
    A node reading ``delay[-j]`` in frame *i* waits for frame *i-j*'s producer, so pipelined
    frames see the same values as frames run one by one.

    Initial values: before frame *j* has run, ``delay[-j]`` reads ``init`` — by default zeros of
    the data's type as :meth:`Graph.verify` found it (a zero image of the same shape and dtype,
    an empty :class:`~warpvx.Keypoints`, a list of zero levels, 0 for a number). Give ``init``
    when zeros make no sense (an identity homography, say); it is required when the data is
    produced after its reader in the frame (a feedback loop), since verify cannot see its type
    before the reader runs. A frame that fails leaves no value: later frames read the latest
    value before it.
    """

    def __init__(self, graph, data: Data, slots: int, init=None):
        super().__init__(slots, init, lock=data.lock)
        self._graph = weakref.ref(graph)
        self.data = data
        self.init = init
        # The previous verification frame's value (what delay[-1] read in verification's
        # second frame): what calibration times readers of delay slots on.
        self.sample_previous = None
        self._local = threading.local()

    def _index(self, index, low: int, high: int) -> int:
        """``index`` as an int in ``[low, high]``, else GraphError naming it."""
        if isinstance(index, bool) or not isinstance(index, (int, np.integer)):
            raise GraphError(f"delay {self.data.name!r}, index: expected an int in "
                             f"[{low}, {high}], got {type(index).__name__} {index!r}")
        if not low <= index <= high:
            raise GraphError(f"delay {self.data.name!r}, index: {index} is outside [{low}, {high}]")
        return int(index)

    def __getitem__(self, index):
        index = self._index(index, -self.slots, 0)
        return self.data if index == 0 else DelayRef(self, index)

    # ------------------------------------------------------------ communication wrapper

    def read(self, index: int = 0):
        """Host value of slot ``index`` as of the last completed frame (0: newest, -j older).

        Before frame *j* has run, slot ``-j`` (and 0, before any frame) holds the initial
        value: what ``delay[-j]`` reads in the next frame, as an OpenVX delay's slots hold
        their initial contents until aged.

        Read between frames: during a pipelined ``stream`` with captured GPU segments, a
        delay made and read inside one captured segment lives in that segment's own buffers,
        which the frames in flight rewrite, so a read then may see a later frame's value.

        Raises
        ------
        GraphError
            ``index`` not an int in ``[-slots, 0]``; no value yet (before verification, with
            no ``init`` given nor value written).
        """
        index = self._index(index, -self.slots, 0)
        graph = self._graph()
        io = getattr(self._local, "io", None)
        if io is None:
            io = self._local.io = Transfers(graph._gpu_device() if graph is not None else None)
        # The copy is made under the lock: once a frame ages out of the ring, the runtime
        # reuses its device buffers (Executor._recycle_ring_held), and aging takes the lock.
        with self.lock:
            slot = self.get(self.last_aged + index)
            if slot is self._initial and slot.value is None and not (graph and graph.verified):
                raise GraphError(f"delay {self.data.name!r}, index: slot {index} has no value "
                                 f"yet; verify or run the graph first, or give "
                                 f"g.delay(..., init=)")
            if not slot.ready:
                raise GraphError(f"delay {self.data.name!r}: slot {index} is not computed yet")
            return slot.host(io)

    def write(self, value, index: int = -1):
        """Replace slot ``index`` (``-slots <= index <= -1``) as seen by the next frame.

        ``value`` is host data of the delayed data's type: what verification found it to be
        (else ``init``). See :func:`mismatch` for what must agree.

        Raises
        ------
        GraphError
            ``index`` not an int in ``[-slots, -1]``; ``value`` of another type, dtype or
            shape than the data's.
        """
        index = self._index(index, -self.slots, -1)
        expected = self.data.sample if self.data.sample is not None else self.init
        if expected is not None:
            why = mismatch(expected, value)
            if why is not None:
                raise GraphError(f"delay {self.data.name!r}, value: {why} (the data is "
                                 f"{describe(expected)})")
        with self.lock:
            self.put(self.last_aged + 1 + index, value, HOST)

    def __repr__(self):
        return f"Delay({self.data.name!r}, slots={self.slots})"


# --------------------------------------------------------------------------- values


def describe(value) -> str:
    """A short type-and-size text of a value: ``uint8[480x640x3]``, ``kp[812]``, ``[...]``."""
    if isinstance(value, np.ndarray):
        return f"{value.dtype}[{'x'.join(str(s) for s in value.shape)}]"
    if isinstance(value, Keypoints):
        return f"kp[{len(value)}]"
    if isinstance(value, (list, tuple)):
        inner = ",".join(describe(v) for v in value)
        return f"[{inner}]" if isinstance(value, list) else f"({inner})"
    if hasattr(value, "shape") and hasattr(value, "dtype"):  # wp.array
        return f"{value.dtype.__name__ if hasattr(value.dtype, '__name__') else value.dtype}" \
               f"[{'x'.join(str(s) for s in value.shape)}]"
    if isinstance(value, (int, float, bool, np.generic)):
        return type(value).__name__
    return type(value).__name__


def mismatch(expected, value) -> str | None:
    """Why ``value`` cannot stand for data whose value was ``expected``, or None if it can.

    Arrays: a NumPy array of the same dtype and dimensions and the same size on every axis
    but the first (a point set's length changes from frame to frame, so the first axis is
    free). Keypoints: Keypoints. Lists and tuples: the same kind and length, item by item.
    Numbers: a number. Any other object: the same type.
    """
    if isinstance(expected, np.ndarray):
        if not isinstance(value, np.ndarray):
            return f"expected a NumPy array, got {type(value).__name__}"
        if value.dtype != expected.dtype:
            return f"expected dtype {expected.dtype}, got {value.dtype}"
        if value.ndim != expected.ndim or value.shape[1:] != expected.shape[1:]:
            want = "x".join(["N", *map(str, expected.shape[1:])]) if expected.ndim else "()"
            return f"expected shape {want}, got {value.shape}"
        return None
    if isinstance(expected, (list, tuple)):
        if type(value) is not type(expected) or len(value) != len(expected):
            return f"expected a {type(expected).__name__} of {len(expected)}, got {describe(value)}"
        for i, (e, v) in enumerate(zip(expected, value)):
            why = mismatch(e, v)
            if why is not None:
                return f"item {i}: {why}"
        return None
    if isinstance(expected, (int, float, np.number)) and not isinstance(expected, (bool, np.bool_)):
        ok = isinstance(value, (int, float, np.number)) and not isinstance(value, (bool, np.bool_))
        return None if ok else f"expected a number, got {type(value).__name__}"
    if not isinstance(value, type(expected)):
        return f"expected {type(expected).__name__}, got {type(value).__name__}"
    return None


def nbytes(value) -> int:
    """Bytes of every array leaf of ``value`` (what a host <-> device transfer moves)."""
    total = 0

    def add(a):
        nonlocal total
        if isinstance(a, np.ndarray):
            total += a.nbytes
        else:
            import warp as wp

            total += int(a.size) * wp.types.type_size_in_bytes(a.dtype)
        return a

    tree_map(add, value)
    return total


def zeros_like(value):
    """Zeros of the same type: arrays zeroed, Keypoints empty, numbers 0, other objects None."""
    if isinstance(value, Keypoints):
        return Keypoints.empty()
    if isinstance(value, np.ndarray):
        return np.zeros_like(value)
    if isinstance(value, (list, tuple)):
        z = [zeros_like(v) for v in value]
        return z if isinstance(value, list) else tuple(z)
    if isinstance(value, (bool, np.bool_)):
        return False
    if isinstance(value, (int, float, np.number)):
        return type(value)(0)
    return None


def synth(shape, dtype, seed: int = 0) -> np.ndarray:
    """A deterministic sample of ``shape`` and ``dtype`` for verification and calibration.

    Images (uint8 HxW or HxWxC) get a textured pattern (smooth blobs plus fine noise) so
    detectors find a realistic number of corners; other arrays get uniform [0, 1) values.
    """
    rng = np.random.default_rng(seed)
    dtype = np.dtype(dtype)
    shape = tuple(int(s) for s in shape)
    if dtype == np.uint8 and len(shape) in (2, 3):
        import cv2

        h, w = shape[:2]
        c = shape[2] if len(shape) == 3 else 1
        coarse = rng.integers(0, 256, (max(2, h // 16), max(2, w // 16), c)).astype(np.float32)
        big = cv2.resize(coarse, (w, h), interpolation=cv2.INTER_CUBIC).reshape(h, w, c)
        img = np.clip(big + rng.normal(0, 12, (h, w, c)), 0, 255).astype(np.uint8)
        return np.ascontiguousarray(img.reshape(shape))
    if np.issubdtype(dtype, np.integer):
        return rng.integers(0, 2, shape).astype(dtype)
    return rng.random(shape).astype(dtype)


__all__ = ["Data", "Delay", "DelayRef", "describe", "mismatch", "nbytes", "zeros_like", "synth",
           "FIELDS"]
