"""The one registry of primitives: implementations, output ports, size rule, benchmark cases.

Each primitive names its public function and its implementations as ``"module:function"``
strings, imported lazily so ``import warpvx`` stays light (no Warp import, no JIT) and the
CPU path works without touching Warp. The scheduler reads :attr:`Primitive.processing_elements`
and :attr:`Primitive.exclusive`; the graph reads :attr:`Primitive.outputs` (its nodes' output
ports) and :attr:`Primitive.sized_by_inputs` (whether it may preallocate ``out=``); the
benchmark harness reads :attr:`Primitive.bench` (``warpvx.bench.cases.<name>:cases``).

Public functions validate their arguments once, then call :func:`dispatch`, which converts the
inputs to what the chosen implementation takes (NumPy for ``"cpu"``, ``wp.array`` on the
backend's device for Warp), runs it on the right device and stream, and converts the result
back to the kind of the input (NumPy in, NumPy out; device array in, device array out).
"""

from __future__ import annotations

import contextlib
import importlib
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ._counted import Counted, row_arrays
from .arrays import _convert, is_warp_array, like_input
from .backend import Backend, init_warp
from .check import check_writable
from .errors import BackendError, WarpvxValueError


def _load(path: str) -> Callable:
    module, _, attr = path.partition(":")
    return getattr(importlib.import_module(module), attr)


@dataclass
class Primitive:
    """A registered primitive.

    Attributes
    ----------
    name : str
        Registry key, also the kernel module name in ``kernels_cpu``/``kernels_warp``.
    public : str
        ``"module:function"`` of the validating public function.
    impls : dict
        ``{"cpu": "module:function", "warp": "module:function"}``; a missing key means no
        implementation of that kind (an *exclusive* primitive, thesis §5.1).
    bench : str or None
        ``"module:function"`` returning benchmark cases for a BGR photo (a list of
        :class:`warpvx.bench.cases.BenchCase`).
    outputs : tuple of str
        Names of what the public function returns, in order: one name (default ``"out"``)
        for a single value, several for a tuple. A graph node's output ports.
    sized_by_inputs : bool
        True when the public function takes ``out=`` and its outputs' shapes and dtypes
        follow from its inputs' shapes and its constant arguments, never from pixel values
        (one array, a pyramid's list of levels, or one array per output): a graph may then
        allocate them once and reuse them frame after frame.
    capturable : bool
        True when the Warp implementation, given ``out=``, only enqueues work on the current
        stream (no allocation, host synchronisation or read-back once its caches are warm):
        a graph may then capture it into a CUDA graph (:mod:`warpvx.runtime.capture`).
    counted_rows : str or None
        For a data-dependent number of rows: the Warp implementation writes
        :class:`~warpvx._counted.Counted` outputs (fixed rows, a device count) given them
        as ``out=``, and this names where their capacity comes from: an input whose rows
        the outputs follow (``"prev_pts"``; when that input is itself Counted, with its
        capacity), or a ``"module:function"`` called with the public function's arguments
        (inputs as verification's samples, defaults applied) that returns it, None for
        none. A graph then allocates the Counteds once
        (:meth:`warpvx.graph.nodes.PrimitiveNode.out_factory`).
    """

    name: str
    public: str
    impls: dict = field(default_factory=dict)
    bench: str | None = None
    outputs: tuple = ("out",)
    sized_by_inputs: bool = False
    capturable: bool = False
    counted_rows: str | None = None
    _loaded: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def implementation(self, kind: str) -> Callable:
        impl = self._loaded.get(kind)
        if impl is not None:
            return impl
        if kind not in self.impls:
            raise BackendError(
                f"backend: {self.name} has no {kind!r} implementation "
                f"(available: {sorted(self.impls)})"
            )
        impl = self._loaded[kind] = _load(self.impls[kind])
        return impl

    def function(self) -> Callable:
        return _load(self.public)

    @property
    def processing_elements(self) -> frozenset:
        """``{"cpu", "gpu"}`` or a subset: which processing elements can run it."""
        pes = set()
        if "cpu" in self.impls:
            pes.add("cpu")
        if "warp" in self.impls:
            pes.add("gpu")
        return frozenset(pes)

    @property
    def exclusive(self) -> bool:
        """True when only one kind of processing element can run it."""
        return len(self.processing_elements) == 1


REGISTRY: dict[str, Primitive] = {}


def register(name, *, public, cpu=None, warp=None, bench=None, outputs=("out",),
             sized_by_inputs=False, capturable=False, counted_rows=None) -> Primitive:
    """Register (or replace) a primitive; implementations are ``"module:function"`` strings.
    See :class:`Primitive` for the other attributes."""
    impls = {}
    if cpu:
        impls["cpu"] = cpu
    if warp:
        impls["warp"] = warp
    prim = Primitive(name=name, public=public, impls=impls, bench=bench, outputs=tuple(outputs),
                     sized_by_inputs=sized_by_inputs, capturable=capturable,
                     counted_rows=counted_rows)
    REGISTRY[name] = prim
    return prim


def get_primitive(name: str) -> Primitive:
    try:
        return REGISTRY[name]
    except KeyError:
        raise WarpvxValueError(
            f"primitive: unknown {name!r}; registered: {sorted(REGISTRY)}"
        ) from None


def _std(name, public_module, **attrs):
    register(
        name,
        public=f"warpvx.{public_module}:{name}",
        cpu=f"warpvx.kernels_cpu.{name}:{name}",
        warp=f"warpvx.kernels_warp.{name}:{name}",
        bench=f"warpvx.bench.cases.{name}:cases",
        **attrs,
    )


# The built-in primitives: public module (by domain, as kornia), kernel modules by name.
# capturable: launches only, given out= (harris_response allocates its products outside the
# fused 3x3 path; scale pyramids, ORB, matching allocate or read counts back); FAST,
# harris_corners and LK are captured with Counted outputs (counted_rows).
_std("color_convert", "color", sized_by_inputs=True, capturable=True)
_std("remap", "geometry", sized_by_inputs=True, capturable=True)
_std("warp_perspective", "geometry", sized_by_inputs=True, capturable=True)
_std("gaussian_pyramid", "pyramid", sized_by_inputs=True, capturable=True)
_std("scale_pyramid", "pyramid")
_std("gaussian_blur", "filters", sized_by_inputs=True, capturable=True)
_std("fast_corners", "features", capturable=True,
     counted_rows="warpvx.kernels_warp.fast_corners:counted_capacity")
_std("harris_response", "features", sized_by_inputs=True)
_std("harris_corners", "features", capturable=True,
     counted_rows="warpvx.features:harris_corners_capacity")
_std("optical_flow_pyr_lk", "flow", outputs=("next_pts", "status", "err"), sized_by_inputs=True,
     capturable=True, counted_rows="prev_pts")
_std("orb", "orb_extractor", outputs=("keypoints", "descriptors"))
_std("match_hamming", "matching", outputs=("pairs", "distances"))
_std("find_homography", "homography", outputs=("H", "mask"))
# Primitives with no bench case of their own: resize shares the scale pyramid's kernel modules;
# orb_compute and knn_match_hamming are timed through orb and match_hamming.
register("resize", public="warpvx.pyramid:resize", sized_by_inputs=True, capturable=True,
         cpu="warpvx.kernels_cpu.scale_pyramid:resize", warp="warpvx.kernels_warp.scale_pyramid:resize")
register("orb_compute", public="warpvx.orb_extractor:orb_compute",
         cpu="warpvx.kernels_cpu.orb:orb_compute", warp="warpvx.kernels_warp.orb:orb_compute")
register("knn_match_hamming", public="warpvx.matching:knn_match_hamming",
         cpu="warpvx.kernels_cpu.match_hamming:knn_match_hamming",
         warp="warpvx.kernels_warp.match_hamming:knn_match_hamming",
         outputs=("indices", "distances"))


def dispatch(name: str, backend: Backend, *args, out=None, stream=None, template=None, **kwargs):
    """Run primitive ``name`` on ``backend`` and return a result of the template's kind.

    ``args`` may hold NumPy arrays, ``wp.array``s, :class:`warpvx.Keypoints` and scalars;
    arrays are moved to where the implementation runs. ``template`` (default: the first
    array argument) decides the kind of the result. ``out`` is handed to the implementation
    when it already lives where the implementation writes, otherwise the result is copied
    into it. ``stream`` (Warp backends) is made the device's current stream for the call;
    without it the implementation runs on the current stream.

    Warp implementations name their device on every allocation and launch, but a few Warp
    utilities (``wp.utils.radix_sort_pairs``, ``array_scan``) run in the current CUDA
    context, so the backend's device is made current (``wp.ScopedDevice``) unless it already
    is, which is the usual case and saves the scope's cost. When every array argument and
    ``out`` already are ``wp.array``s on the backend's device (the usual case in a
    pipeline), nothing is converted and the implementation is called directly.
    """
    prim = REGISTRY.get(name) or get_primitive(name)
    impl = prim.implementation(backend.kind)
    if backend.kind != "cpu" and template is None:
        device = _warp_device(backend.device)
        if _on_device(args, device) and _on_device(kwargs.values(), device) and _out_on_device(out, device):
            if stream is None and device.runtime.default_device is device:
                result = impl(*args, out=out, **kwargs)
            else:
                with _device_scope(backend, stream):
                    result = impl(*args, out=out, **kwargs)
            if type(result) in (_wp.array, Counted) or not any(_is_array(a) for a in args):
                return result
            return like_input(result, next(a for a in args if _is_array(a)))
    if out is not None:
        check_writable(out)  # before the kernel runs (a NumPy out is written last)
    if template is None:
        template = next((a for a in args if isinstance(a, np.ndarray) or is_warp_array(a)), None)
    host = backend.kind == "cpu"
    call_args = _convert(args, host, backend.device)
    call_kwargs = {k: _convert(v, host, backend.device) for k, v in kwargs.items()}
    native_out = out if _is_native(out, backend) else None
    with _device_scope(backend, stream):
        result = impl(*call_args, out=native_out, **call_kwargs)
    if template is not None:
        result = like_input(result, template)
    if out is not None and native_out is None:
        _copy_into(out, result)
        return out
    return result


# --- the fast path: Warp arrays already on the backend's device ------------------------------

_wp = None  # the warp module, once a Warp backend has been used
_devices: dict = {}  # device alias -> wp.Device
_SCALARS = frozenset((int, float, bool, str, type(None)))


def _warp_device(alias: str):
    global _wp
    device = _devices.get(alias)
    if device is None:
        _wp = init_warp()
        device = _devices[alias] = _wp.get_device(alias)
    return device


def _is_array(a) -> bool:
    return isinstance(a, np.ndarray) or is_warp_array(a)


def _on_device(values, device) -> bool:
    """True when ``values`` hold only scalars and ``wp.array``s on ``device`` (also inside
    tuples and lists): nothing to convert."""
    for v in values:
        t = type(v)
        if t in _SCALARS or isinstance(v, np.generic):
            continue
        if t is _wp.array:
            if v.device is not device:
                return False
        elif t is tuple or t is list:
            if not _on_device(v, device):
                return False
        elif t is Counted:
            if not _on_device(row_arrays(v.rows) + (v.count,), device):
                return False
        else:
            return False
    return True


def _out_on_device(out, device) -> bool:
    if out is None:
        return True
    if type(out) is _wp.array:
        return out.device is device
    if type(out) is Counted:
        return _on_device(row_arrays(out.rows) + (out.count,), device)
    if isinstance(out, (list, tuple)):
        return all(type(o) in (_wp.array, Counted) and _out_on_device(o, device) for o in out)
    return False


def _is_native(out, backend: Backend) -> bool:
    if out is None:
        return False
    if isinstance(out, (list, tuple)):
        return all(_is_native(o, backend) for o in out)
    if type(out) is Counted:
        return all(_is_native(a, backend) for a in row_arrays(out.rows) + (out.count,))
    if backend.kind == "cpu":
        return isinstance(out, np.ndarray)
    return is_warp_array(out) and str(out.device) == backend.device


def _copy_into(out, result):
    if isinstance(out, (list, tuple)):
        for o, r in zip(out, result):
            _copy_into(o, r)
        return
    if isinstance(out, np.ndarray):
        np.copyto(out, result if isinstance(result, np.ndarray) else result.numpy())
    else:
        wp = init_warp()
        src = result if is_warp_array(result) else wp.array(result, dtype=out.dtype, device=out.device)
        wp.copy(out, src)


@contextlib.contextmanager
def _device_scope(backend: Backend, stream):
    """On Warp backends: the backend's device made current (unless it is) and ``stream``,
    when given, made its current stream."""
    if backend.kind == "cpu":
        yield
        return
    device = _warp_device(backend.device)
    with contextlib.ExitStack() as scopes:
        if device.runtime.default_device is not device:
            scopes.enter_context(_wp.ScopedDevice(device))
        if stream is not None:
            scopes.enter_context(_wp.ScopedStream(stream))
        yield
