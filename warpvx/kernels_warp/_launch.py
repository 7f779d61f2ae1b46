"""Recorded kernel launches: replay ``wp.launch`` calls without re-packing their arguments.

``wp.launch`` spends tens of microseconds of Python per call checking and packing every
argument; for a small image on a GPU that is most of a primitive call. Warp can record a
launch (``wp.launch(..., record_cmd=True)`` returns a ``wp.Launch``) whose ``.launch()`` only
hands the packed parameters to the driver. :func:`run_recorded` keeps the recorded launches
of recent calls, keyed by everything their kernels see, and replays them;
:func:`launch_cached` does it for one launch.

A replayed ``wp.Launch`` runs on the device's *current* stream (``Launch.launch`` reads
``device.stream`` at every call), so ``wp.ScopedStream`` and CUDA-graph capture
(``wp.ScopedCapture``) see it as they see any launch.

The cache holds what the recorded launches hold. Callers that pass non-owning views
(:func:`view`, :func:`as_view`, :func:`as_words`) keep no image alive: a stale entry is only
ever replayed for arrays at the same address with the same shape and strides, which is
exactly what it was recorded for.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from contextlib import contextmanager, nullcontext

import warp as wp

from ..errors import CaptureAllocationError, caused_by

_RECORDED: OrderedDict = OrderedDict()
_RECORDED_MAX = 64
_recorded_lock = threading.Lock()


def array_key(a) -> tuple:
    """What a kernel sees of an array: pointer, shape, strides."""
    return (a.ptr, a.shape, a.strides)


def view(a, dtype, shape, strides):
    """A ``wp.array`` over ``a``'s memory with another element type or layout (byte
    ``strides``), owning nothing: it does not keep ``a`` alive."""
    return wp.array(ptr=a.ptr, dtype=dtype, shape=shape, strides=strides, device=a.device)


def as_view(a):
    """A non-owning view of ``a`` itself."""
    return view(a, a.dtype, a.shape, a.strides)


def as_words(a, rows: int | None = None):
    """The first ``rows`` rows (default: all) of a C-contiguous uint8 image as a non-owning
    ``rows x (row bytes / 4)`` uint32 view; the row size must be a multiple of 4 bytes and
    the image must start on a 4-byte boundary."""
    row_bytes = a.strides[0]
    return view(a, wp.uint32, (a.shape[0] if rows is None else rows, row_bytes // 4), (row_bytes, 4))


def run_recorded(key, build, device) -> None:
    """Run a sequence of launches, recorded on first use and replayed afterwards.

    ``build()`` returns ``[(kernel, dim, inputs, outputs), ...]``; it is called only when
    ``key`` is new on ``device``, so it may do the costly work (views, look-ups). ``key`` must
    determine every parameter value (array pointers, shapes and strides, scalars, struct
    contents, and the stream when a per-stream scratch buffer is involved).

    On CUDA a sequence replayed a second time is captured as a CUDA graph (on a private
    stream, so nothing else is captured with it) and from then on launched as that graph on
    the current stream: a graph launch costs the host about a third of a kernel launch
    through ``wp.Launch`` (measured on an H100: 4.4 us against 12.6). Inside a caller's own
    capture the recorded launches are replayed one by one, so they land in the caller's graph.
    """
    full_key = (device.alias, key)
    plan = _RECORDED.get(full_key)
    if plan is None:
        cmds = (wp.launch(kernel, dim=dim, inputs=inputs, outputs=outputs, device=device, record_cmd=True)
                for kernel, dim, inputs, outputs in build())
        plan = _Plan(tuple(cmd for cmd in cmds if cmd is not None))  # None: an empty grid
        with _recorded_lock:
            _RECORDED[full_key] = plan
            while len(_RECORDED) > _RECORDED_MAX:
                _RECORDED.popitem(last=False)
    plan.run(device)
    plans = getattr(_tapped, "plans", None)
    if plans is not None:
        plans.append((plan, device))


_tapped = threading.local()


@contextmanager
def tap():
    """Collect ``(plan, device)`` of every :func:`run_recorded` call made by this thread in
    the block (a list; :class:`warpvx.callmemo.CallMemo` replays a call that ran one)."""
    outer = getattr(_tapped, "plans", None)
    _tapped.plans = plans = []
    try:
        yield plans
    finally:
        _tapped.plans = outer
        if outer is not None:
            outer.extend(plans)


class _Plan:
    """Recorded launches of one key, and (CUDA) the graph they were captured into."""

    __slots__ = ("cmds", "graph", "replays")

    def __init__(self, cmds: tuple):
        self.cmds = cmds
        self.graph = None  # a wp.Graph; False when capture is not possible
        self.replays = 0

    def run(self, device) -> None:
        graph = self.graph
        if graph and not device.is_capturing:
            wp.capture_launch(graph)
            return
        for cmd in self.cmds:
            cmd.launch()
        if graph is None and not device.is_cpu and self.cmds:
            self.replays += 1
            if self.replays >= 2:  # a one-off call never pays for a capture
                self.graph = _capture(self.cmds, device)


_capture_streams: dict = {}
#: Held around every capture the package makes and around the executor's records on the
#: legacy stream, which a capture in progress on a blocking stream forbids (CUDA error 906).
#: Reentrant: a segment capture runs its tasks uncaptured under it first where their scratch
#: was missing (:meth:`~warpvx.runtime.capture.SegmentGraph.capture`), and a recorded launch
#: replayed a second time there captures itself (:func:`_capture`) on the same thread.
capture_lock = threading.RLock()


def _capture(cmds, device):
    """``cmds`` captured as one CUDA graph on a stream of their own, or False (already inside
    a capture, or a driver that refuses)."""
    if device.is_capturing:
        return None  # try again on a later replay outside the caller's capture
    with capture_lock:
        stream = _capture_streams.get(device.alias)
        if stream is None:
            stream = _capture_streams[device.alias] = wp.Stream(device)
        try:
            with wp.ScopedCapture(device=device, stream=stream) as capture:
                for cmd in cmds:
                    cmd.launch(stream=stream)
            return capture.graph
        except Exception:  # noqa: BLE001 - keep replaying launches one by one
            return False


class CapturedProgram:
    """A program of launches (no host sync, no allocation it keeps), run eagerly on its first
    call (its modules load, its primitives make their scratch) and from then on from a CUDA
    graph captured once on ``stream`` (None: the device's current stream) and launched there.

    Eager for good where Warp refuses or fails the capture (a host sync inside: :attr:`error`
    says why); eager for one more call where only a primitive's scratch was missing
    (:class:`CaptureAllocationError`: made by that call, captured on the next); eager, without
    giving up, inside a caller's capture (its launches join the caller's graph). On Warp's
    CPU device a capture records every launch of the process, other threads' too: capture
    there only where nothing else launches (the tests). ``warm``:
    the program's modules are loaded and its scratch made already (by another program of the
    same launches): capture on the first call. ``enabled=False``: always eager.
    """

    def __init__(self, program, device, stream=None, *, enabled: bool = True, warm: bool = False):
        self.program = program
        self.device = device
        self.stream = stream
        self.enabled = bool(enabled)
        self.graph = None
        self.error = None  # repr of the failure that turned capture off
        self.runs = int(bool(warm))
        self._scratch_retry = True

    def __call__(self) -> None:
        if self.graph is None and self.enabled and self.runs > 0 and not self.device.is_capturing:
            self.graph = self._capture()
        if self.graph is not None:
            wp.capture_launch(self.graph, stream=self.stream)
        else:
            with self._on_stream():
                self.program()
        self.runs += 1

    def _on_stream(self):
        """The program's launches go to the device's current stream: ``stream`` made current
        (eager runs and the capture alike), when given."""
        if self.stream is None:
            return nullcontext()
        return wp.ScopedStream(self.stream, sync_enter=False)

    def _capture(self):
        try:
            with capture_lock, self._on_stream(), \
                    wp.ScopedCapture(device=self.device, stream=self.stream) as capture:
                self.program()
        except Exception as exc:  # noqa: BLE001 - the program runs eagerly instead
            if caused_by(exc, CaptureAllocationError) and self._scratch_retry:
                self._scratch_retry = False
            else:
                self.enabled = False
                self.error = repr(exc)
            return None
        return capture.graph


def run_direct(launches, device) -> None:
    """Run ``[(kernel, dim, inputs, outputs), ...]`` without recording."""
    for kernel, dim, inputs, outputs in launches:
        wp.launch(kernel, dim=dim, inputs=inputs, outputs=outputs, device=device)


def run_pyramid_into(tag: str, src, out, levels: int, launches) -> list:
    """Fill the caller's pyramid buffers: ``[src] + out[1:levels]``, computed by the launches
    ``launches(pyramid)`` returns, recorded once per set of buffers (``tag`` names the kind of
    pyramid in the key) and replayed. Returns that list."""
    pyramid = [src] + list(out[1:levels])
    key = (tag, array_key(src)) + tuple(array_key(a) for a in pyramid[1:])
    run_recorded(key, lambda: launches(pyramid), src.device)
    return pyramid


def launch_cached(kernel, dim, inputs, outputs, device, key) -> None:
    """One ``wp.launch`` through :func:`run_recorded` (``key`` as there).

    ``inputs`` may be a zero-argument callable returning ``(inputs, outputs)`` (``outputs``
    is then ignored), so the arguments (views, structs) are built only when the launch is
    recorded.
    """
    if callable(inputs):
        make = inputs

        def build():
            ins, outs = make()
            return [(kernel, dim, ins, outs)]
    else:
        def build():
            return [(kernel, dim, inputs, outputs)]

    # The kernel object itself, not its name: kernels made by one factory share a name.
    run_recorded((kernel, key), build, device)


def clear_recorded() -> None:
    """Drop every recorded launch (and whatever arrays they hold)."""
    with _recorded_lock:
        _RECORDED.clear()


__all__ = [
    "array_key",
    "as_view",
    "as_words",
    "clear_recorded",
    "launch_cached",
    "run_direct",
    "run_pyramid_into",
    "run_recorded",
    "tap",
    "view",
]


# --- per-call workspaces: scratch buffers and recorded launches kept per size, device, stream
# and thread (the feature kernels: FAST, Harris, LK, matching) -------------------------------

_WORKSPACES: OrderedDict = OrderedDict()
# (A captured segment's buffer sets each run on streams of their own, warpvx.runtime.capture:
# one workspace per set, lane and kind; an eviction before the set's capture fails it.)
_WORKSPACES_MAX = 256
_workspaces_lock = threading.Lock()


def workspace(kind: str, key: tuple, device, build):
    """Scratch state of one kind of call, built once by ``build()`` and reused.

    Reused by calls with the same ``kind`` and ``key`` (sizes) on the same device, current
    stream and thread, so two calls sharing it always run one after the other on one stream
    (a call may keep scratch buffers and recorded launches in it, never its results). The
    least recently used of :data:`_WORKSPACES_MAX` are dropped. Never built inside a CUDA
    graph capture (:class:`CaptureAllocationError`).
    """
    stream = None if device.is_cpu else device.stream
    full = (kind, key, str(device), None if stream is None else stream.cuda_stream,
            threading.get_ident())
    with _workspaces_lock:
        ws = _WORKSPACES.get(full)
        if ws is not None:
            _WORKSPACES.move_to_end(full)
            return ws
    if stream is not None and stream.is_capturing:
        # Built here, its buffers would be the capture's graph memory: valid only inside that
        # graph, yet kept and reused by later calls outside it (CUDA error 700, an illegal
        # address, on the H100). Fail the capture instead: the caller runs the call uncaptured,
        # which builds the workspace, and captures after that.
        raise CaptureAllocationError(
            f"{kind}: its workspace would be allocated inside a CUDA graph capture")
    ws = build()
    with _workspaces_lock:
        _WORKSPACES[full] = ws
        while len(_WORKSPACES) > _WORKSPACES_MAX:
            _WORKSPACES.popitem(last=False)
    return ws


def drop_workspace(kind: str, key: tuple, device) -> None:
    """Forget a workspace (after an error left its buffers in an unknown state)."""
    stream = None if device.is_cpu else device.stream.cuda_stream
    with _workspaces_lock:
        _WORKSPACES.pop((kind, key, str(device), stream, threading.get_ident()), None)


class Recorded:
    """A recorded launch of ``kernel`` whose parameters are given, and updated, by name.

    ``Recorded(kernel, dim, device, name=value, ...)`` records ``wp.launch(kernel, dim,
    inputs=[...], record_cmd=True)`` (``wp.launch_tiled`` with ``block_dim``) with every
    parameter of the kernel named; ``launch(name=value, ...)`` re-packs the named parameters
    that changed (another object, or another scalar value) and replays it on the current
    stream: a few microseconds instead of the tens of ``wp.launch``. Naming the parameters
    keeps a call right when a kernel gains, loses or reorders parameters: a missing or unknown
    name raises ``TypeError`` at recording, an unknown one ``KeyError`` at a launch.

    A ``@wp.struct`` parameter is treated as a value, like an array: to change it, pass a new
    instance (assigning the fields of the recorded one is not a supported way to update it).
    """

    def __init__(self, kernel, dim, device, *, block_dim=None, **params):
        names = [a.label for a in kernel.adj.args]
        if set(params) != set(names):
            raise TypeError(f"{kernel.key}: expected parameters {names}, got {sorted(params)}")
        self.index = {name: i for i, name in enumerate(names)}
        self.args = params
        inputs = [params[name] for name in names]
        if block_dim is None:
            self.cmd = wp.launch(kernel, dim=dim, inputs=inputs, device=device, record_cmd=True)
        else:
            self.cmd = wp.launch_tiled(kernel, dim=dim, inputs=inputs, device=device,
                                       block_dim=block_dim, record_cmd=True)
        self.block_dim = block_dim

    def set(self, **params) -> None:
        """Re-pack the named parameters whose value changed."""
        for name, value in params.items():
            old = self.args[name]
            if value is old:
                continue
            if type(value) in (int, float) and type(old) is type(value) and value == old:
                continue
            self.cmd.set_param_at_index(self.index[name], value)
            self.args[name] = value

    def set_dim(self, dim) -> None:
        """New launch size (grid size for a tiled launch)."""
        dims = list(dim) if isinstance(dim, (list, tuple)) else [dim]
        if self.block_dim is not None:
            dims.append(self.cmd.block_dim)
        self.cmd.set_dim(dims)

    def launch(self, **params) -> None:
        """Launch on the current stream after :meth:`set` of ``params``."""
        if params:
            self.set(**params)
        self.cmd.launch()


class HostReadback:
    """A small device array read back through a pinned host buffer (the one host sync)."""

    def __init__(self, n: int, dtype, device):
        self.device = device
        if not device.is_cpu and device.stream.is_capturing:
            # CUDA refuses a page-locked allocation inside a capture and Warp then hands back a
            # null buffer, which a later read-back would write through: fail the capture
            # instead (the executor runs the call uncaptured, which builds this, and captures
            # the next frame).
            # (Not CaptureAllocationError: the read-back's host sync fails a capture anyway,
            # so a segment capture's retry would only fail again.)
            raise RuntimeError("a read-back buffer cannot be allocated inside a CUDA graph capture")
        self.host = wp.empty(n, dtype=dtype, device="cpu", pinned=not device.is_cpu)
        if n and not self.host.ptr:
            raise RuntimeError(f"pinned allocation of a {n}-element read-back buffer failed")
        self.view = self.host.numpy()

    def read(self, src):
        """``src`` (on the device) as a NumPy array; waits for the current stream."""
        if self.device.is_cpu:
            return src.numpy()
        wp.copy(self.host, src)
        wp.synchronize_stream(self.device.stream)
        return self.view
