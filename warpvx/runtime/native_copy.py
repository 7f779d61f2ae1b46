"""The runtime's host <-> device copies and event calls: Warp's native entry points, with
Warp's public API as the fallback.

Through ``wp.copy``, ``wp.empty(device="cpu")`` and ``array.numpy()`` a 16-byte download costs
tens of microseconds of Python, paid on every edge between a GPU task and a CPU task. The fast
path calls the same native functions ``wp.copy`` ends in (``wp_memcpy_h2d``/``d2h``/``h2h``,
``wp_cuda_event_record``, ...), found in ``warp._src.context.runtime.core``: Warp's private
API. This module is the only place that touches it; when a Warp release moves or renames
those functions, :func:`native_entry_points` returns None and every call here takes the public
path, which gives the same bytes (``tests/graph/test_native_copy.py``).

Only contiguous arrays of scalar dtypes take the fast path; vectors, matrices, structs and
strided views always go through the public API.
"""

from __future__ import annotations

import ctypes
from types import SimpleNamespace

import numpy as np

_WP = None
_NATIVE: object = False  # False: not looked up yet; None: not available
_NP_DTYPES: dict = {}


def warp():
    """The initialised ``warp`` module (cached: an import statement per copy costs ~1 us)."""
    global _WP
    if _WP is None:
        from ..backend import init_warp

        _WP = init_warp()
    return _WP


_ARRAY_TYPES: set = set()  # the types is_warp_array found to be Warp arrays


def is_warp_array(x) -> bool:
    """True for a ``wp.array`` (checked by module name, so NumPy-only callers never import
    Warp; a type once found is remembered: a check per value on every hand-off)."""
    t = type(x)
    if t in _ARRAY_TYPES:
        return True
    if t.__module__.startswith("warp") and hasattr(x, "device") and hasattr(x, "ptr"):
        _ARRAY_TYPES.add(t)
        return True
    return False


def address(a: np.ndarray) -> int:
    """The address of contiguous NumPy array ``a``'s first byte: through the buffer protocol
    for a writable, non-empty array (~0.3 us), else ``a.ctypes.data`` (~1 us: it makes a
    helper object per call; once per copy, on every hand-off)."""
    try:
        return ctypes.addressof(ctypes.c_char.from_buffer(a))
    except (TypeError, ValueError):  # read-only, or no bytes
        return a.ctypes.data


def native_entry_points():
    """Warp's native copy, sync and event functions (a namespace), or None when this Warp
    lacks them."""
    global _NATIVE
    if _NATIVE is False:
        try:
            warp()
            from warp._src import context as ctx

            core = ctx.runtime.core
            _NATIVE = SimpleNamespace(
                h2d=core.wp_memcpy_h2d, d2h=core.wp_memcpy_d2h, h2h=core.wp_memcpy_h2h,
                d2d=core.wp_memcpy_d2d,
                stream_sync=core.wp_cuda_stream_synchronize,
                event_record=core.wp_cuda_event_record,
                stream_wait_event=core.wp_cuda_stream_wait_event,
                event_sync=core.wp_cuda_event_synchronize,
                event_elapsed=core.wp_cuda_event_elapsed_time)
        except (ImportError, AttributeError):
            _NATIVE = None
    return _NATIVE


def numpy_dtype(dtype):
    """The NumPy dtype of a scalar Warp dtype, None for vectors, matrices and structs."""
    try:
        return _NP_DTYPES[dtype]
    except KeyError:
        pass
    try:
        np_dtype = warp().dtype_to_numpy(dtype)  # scalar types only; TypeError for the others
    except (TypeError, KeyError):
        np_dtype = None
    _NP_DTYPES[dtype] = np_dtype
    return np_dtype


def _fast(native: bool, a):
    """The native entry points when ``native`` and ``a`` can take them, else None."""
    if not native or not a.is_contiguous or numpy_dtype(a.dtype) is None:
        return None
    return native_entry_points()


def to_host(a, stream=None, *, native: bool = True) -> np.ndarray:
    """A new NumPy array with the contents of ``wp.array`` ``a`` (never a view of it).

    On CUDA the copy runs on ``stream`` (a ``wp.Stream`` of the calling thread), which is then
    synchronised: it waits for this copy and what the caller queued on that stream only.
    ``native=False`` takes Warp's public API (the fallback, for tests).
    """
    fast = _fast(native, a)
    if fast is None:
        if not a.device.is_cuda:
            return a.numpy().copy()
        wp = warp()
        host = wp.empty(a.shape, dtype=a.dtype, device="cpu")
        wp.copy(host, a, stream=stream)
        wp.synchronize_stream(stream)
        return host.numpy()
    out = np.empty(a.shape, dtype=numpy_dtype(a.dtype))
    bytes_to_host_async(address(out), a.device, a.ptr, out.nbytes, stream, fast)
    if a.device.is_cuda and out.nbytes:
        synchronize_stream(stream)
    return out


def to_host_async(dst, a, stream=None, *, native: bool = True):
    """Queue a copy of contiguous ``wp.array`` ``a`` into ``dst``, host memory of the same
    size and dtype (a host ``wp.array`` or a NumPy array; pinned, for the copy to be
    asynchronous), on ``stream`` (a ``wp.Stream``; CUDA), without waiting for it: the caller
    records an event after it. On Warp's CPU device the copy is done on return.
    ``native=False`` takes ``wp.copy``."""
    host = isinstance(dst, np.ndarray)
    fast = _fast(native, a)
    if fast is None:
        wp = warp()
        if host:
            dst = wp.array(ptr=dst.ctypes.data, shape=dst.shape, dtype=a.dtype, device="cpu")
        wp.copy(dst, a, stream=stream if a.device.is_cuda else None)
        return
    ptr, n = (address(dst), dst.nbytes) if host else (dst.ptr, dst.capacity)
    bytes_to_host_async(ptr, a.device, a.ptr, n, stream, fast)


def bytes_to_host_async(dst_ptr: int, device, src_ptr: int, n: int, stream=None, fast=None):
    """Queue a copy of ``n`` bytes at ``src_ptr`` in the memory of Warp device ``device`` into
    host memory at ``dst_ptr`` (pinned, for it to be asynchronous) on ``stream`` (CUDA), as
    :func:`to_host_async` does for whole arrays: for a part of an allocation without making a
    ``wp.array`` of it (~10 us of Python). ``fast``: the native entry points (looked up when
    None; without them, Warp's public API)."""
    if not n:
        return
    fast = fast if fast is not None else native_entry_points()
    if fast is None:
        wp = warp()
        src = wp.array(ptr=src_ptr, shape=(n,), dtype=wp.uint8, device=device)
        dst = wp.array(ptr=dst_ptr, shape=(n,), dtype=wp.uint8, device="cpu")
        wp.copy(dst, src, stream=stream if device.is_cuda else None)
        return
    if device.is_cuda:
        ok = fast.d2h(device.context, dst_ptr, src_ptr, n, stream.cuda_stream)
    else:
        ok = fast.h2h(dst_ptr, src_ptr, n)
    if not ok:
        raise RuntimeError(f"download of {n} bytes failed")


def synchronize_stream(stream):
    """Wait on the host for what is queued on ``stream`` (a ``wp.Stream``)."""
    fast = native_entry_points()
    if fast is None or not fast.stream_sync(stream.cuda_stream):
        warp().synchronize_stream(stream)


def to_device(dst, src, stream=None, *, native: bool = True):
    """Copy host data ``src`` into the contiguous ``wp.array`` ``dst`` (same size and dtype).

    ``src``: a contiguous NumPy array (pageable: the driver stages it before returning) or a
    ``wp.array`` in pinned host memory (asynchronous). On CUDA the copy is queued on
    ``stream`` (a ``wp.Stream``; the device's current one when None); on Warp's CPU device it
    is done on return. ``native=False`` takes Warp's public API (the fallback, for tests).
    """
    fast = _fast(native, dst)
    if fast is None:
        wp = warp()
        if isinstance(src, np.ndarray):
            src = wp.array(src, dtype=dst.dtype, device="cpu", copy=False)
        if dst.device.is_cuda:
            wp.copy(dst, src, stream=stream if stream is not None else dst.device.stream)
        else:
            wp.copy(dst, src)
        return
    ptr = address(src) if isinstance(src, np.ndarray) else src.ptr
    n = src.nbytes if isinstance(src, np.ndarray) else src.capacity
    if not n:
        return
    dev = dst.device
    if dev.is_cuda:
        s = stream if stream is not None else dev.stream
        ok = fast.h2d(dev.context, dst.ptr, ptr, n, s.cuda_stream)
    else:
        ok = fast.h2h(dst.ptr, ptr, n)
    if not ok:
        raise RuntimeError(f"upload of {n} bytes failed")


def copy_device(dst, src, stream=None, *, native: bool = True):
    """Copy ``wp.array`` ``src`` into ``dst`` on the same device (same shape and dtype, both
    contiguous). On CUDA the copy is queued on ``stream`` (the device's current one when
    None); on Warp's CPU device it is done on return. ``native=False`` takes ``wp.copy``."""
    fast = _fast(native, dst)
    n = dst.capacity
    dev = dst.device
    if fast is None or not src.is_contiguous:
        warp().copy(dst, src, stream=stream if dev.is_cuda else None)
        return
    if not n:
        return
    if dev.is_cuda:
        s = stream if stream is not None else dev.stream
        ok = fast.d2d(dev.context, dst.ptr, src.ptr, n, s.cuda_stream)
    else:
        ok = fast.h2h(dst.ptr, src.ptr, n)
    if not ok:
        raise RuntimeError(f"device copy of {n} bytes failed")


def copier(src):
    """``(dst, stream) -> None``: :func:`copy_device` of ``src`` into ``dst`` (an array of
    ``src``'s shape and dtype) with the checks and look-ups done once: a captured segment's
    fixed buffers are copied out into a fresh buffer every frame, on its thread's
    critical path."""
    fast = _fast(True, src)
    n, dev, ptr = src.capacity, src.device, src.ptr
    if fast is None or not n:
        return lambda dst, stream: copy_device(dst, src, stream)
    if dev.is_cuda:
        d2d, context = fast.d2d, dev.context

        def copy(dst, stream):
            s = stream if stream is not None else dev.stream
            if not d2d(context, dst.ptr, ptr, n, s.cuda_stream):
                raise RuntimeError(f"device copy of {n} bytes failed")
    else:
        h2h = fast.h2h

        def copy(dst, stream):
            if not h2h(dst.ptr, ptr, n):
                raise RuntimeError(f"device copy of {n} bytes failed")
    return copy


def record_event(stream, event):
    """``stream.record_event(event)`` (a timing event) without Warp's Python checks."""
    fast = native_entry_points()
    if fast is None:
        stream.record_event(event)
    else:
        fast.event_record(event.cuda_event, stream.cuda_stream, True)


def recorder(stream):
    """``event -> record_event(stream, event)`` with the native entry point and the stream
    looked up once: the executor records an event per GPU task on its critical thread."""
    fast = native_entry_points()
    if fast is None:
        return stream.record_event
    native, cuda_stream = fast.event_record, stream.cuda_stream
    return lambda event: native(event.cuda_event, cuda_stream, True)


def wait_event(stream, event):
    """``stream.wait_event(event)`` (the stream's later work waits for the event, on the
    device) without Warp's Python checks."""
    fast = native_entry_points()
    if fast is None:
        stream.wait_event(event)
    else:
        fast.stream_wait_event(stream.cuda_stream, event.cuda_event, False)


def synchronize_event(event):
    """``wp.synchronize_event(event)`` without Warp's capture checks: the executor's GPU
    thread may be capturing a CUDA graph on its own stream while another thread waits for an
    event of an earlier frame, which Warp's check would refuse (the capture is thread-local:
    the wait is legal)."""
    fast = native_entry_points()
    if fast is None or not fast.event_sync(event.cuda_event):
        warp().synchronize_event(event)  # the checked path, which also reports errors


def elapsed_since(start):
    """``end -> ms`` from completed timing event ``start`` to completed ``end``
    (``wp.get_event_elapsed_time(start, end, synchronize=False)``) without Warp's Python
    checks, the entry point looked up once: the executor converts every GPU timing event of
    a frame against one anchor."""
    fast = native_entry_points()
    if fast is None:
        wp = warp()
        return lambda end: wp.get_event_elapsed_time(start, end, synchronize=False)
    native, cuda_start = fast.event_elapsed, start.cuda_event
    return lambda end: native(cuda_start, end.cuda_event)


__all__ = ["warp", "is_warp_array", "address", "native_entry_points", "numpy_dtype", "to_host",
           "to_host_async", "bytes_to_host_async", "synchronize_stream", "to_device",
           "copy_device", "copier", "record_event", "recorder", "wait_event", "synchronize_event",
           "elapsed_since"]
