"""Array interop: NumPy arrays, ``wp.array``s and foreign GPU arrays.

Public functions accept NumPy arrays, ``wp.array``s, and objects exposing
``__cuda_array_interface__`` or DLPack (PyTorch, CuPy, JAX). Output kind follows input:
NumPy in, NumPy out; a device array in, a ``wp.array`` on that device out, with no host
round trip.
"""

from __future__ import annotations

import numpy as np

from .backend import _is_warp_array, init_warp
from .errors import DTypeError, WarpvxTypeError


def is_warp_array(x) -> bool:
    """True for a ``wp.array`` (any dimensionality)."""
    return _is_warp_array(x)


def is_host(x) -> bool:
    """True when ``x`` is host data (NumPy), False for device arrays."""
    return isinstance(x, np.ndarray)


def as_input(x, name: str):
    """Normalise an input to a NumPy array or a ``wp.array`` (no copy where possible).

    Foreign GPU arrays become ``wp.array`` views through DLPack or the CUDA array interface.
    Raises a warpvx error naming ``name`` for anything else (lists, scalars, None), for an
    ``np.matrix`` (its operators are not elementwise: pass ``np.asarray(x)``), for a
    ``wp.array`` of vectors or matrices (pass one of scalars, the components as the last
    axis), and when the object's own ``__array__`` / ``__dlpack__`` conversion fails.
    """
    if type(x) is np.ndarray:
        return x
    if isinstance(x, np.matrix):
        raise WarpvxTypeError(f"{name}: expected a NumPy array, got an np.matrix (pass np.asarray(...))")
    if isinstance(x, np.ndarray):
        return x
    if _is_warp_array(x):
        return _scalar_warp_array(x, name)
    try:
        if hasattr(x, "__cuda_array_interface__") or hasattr(x, "__dlpack__"):
            return _scalar_warp_array(_from_gpu_array(x), name)
        if hasattr(x, "__array_interface__") or hasattr(x, "__array__"):
            return np.asarray(x)
    except (WarpvxTypeError, DTypeError):
        raise
    except Exception as e:  # noqa: BLE001 - any failure of the object's own conversion
        raise WarpvxTypeError(
            f"{name}: could not convert the {type(x).__name__} to an array "
            f"({type(e).__name__}: {e})") from e
    raise WarpvxTypeError(
        f"{name}: expected a NumPy array, a wp.array or a GPU array (DLPack / "
        f"__cuda_array_interface__), got {type(x).__name__}"
    )


def _from_gpu_array(x):
    """A ``wp.array`` view of a foreign array, through DLPack or the CUDA array interface."""
    wp = init_warp()
    if hasattr(x, "__dlpack__"):
        try:
            return wp.from_dlpack(x)
        except Exception:  # noqa: BLE001 - fall through to the interface
            if not hasattr(x, "__cuda_array_interface__"):
                raise
    iface = x.__cuda_array_interface__
    dtype = np.dtype(iface["typestr"])
    return wp.array(
        ptr=iface["data"][0],
        dtype=wp.dtype_from_numpy(dtype),
        shape=tuple(iface["shape"]),
        strides=iface.get("strides"),
        device=wp.get_cuda_device(),
    )


def _scalar_warp_array(x, name: str):
    """``x`` itself when its elements are scalars; a vector/matrix dtype raises."""
    if getattr(x.dtype, "_wp_scalar_type_", None) is not None:  # wp.vec3, wp.mat33, ...
        raise DTypeError(
            f"{name}: expected a wp.array of scalars, got one of {x.dtype.__name__} "
            f"(view it as scalars with the components as the last axis)")
    return x


def byte_range(x) -> tuple:
    """``(device, first byte, end byte)`` of a C-contiguous NumPy or Warp array (NumPy
    arrays live on ``"cpu"``), for overlap tests."""
    if isinstance(x, np.ndarray):
        start = x.__array_interface__["data"][0]
        return "cpu", start, start + x.nbytes
    return str(x.device), x.ptr, x.ptr + x.size * _itemsize(x)


def _itemsize(x) -> int:
    return numpy_dtype(x).itemsize


_numpy_dtypes: dict = {}  # Warp scalar type -> NumPy dtype


def numpy_dtype(x) -> np.dtype:
    """The NumPy dtype of a NumPy or Warp array."""
    if isinstance(x, np.ndarray):
        return x.dtype
    dt = _numpy_dtypes.get(x.dtype)
    if dt is None:
        wp = init_warp()
        dt = _numpy_dtypes[x.dtype] = np.dtype(wp.dtype_to_numpy(x.dtype))
    return dt


def is_contiguous(x) -> bool:
    """True for a C-contiguous NumPy or Warp array. An empty array counts as contiguous
    (NumPy says so; Warp reports empty arrays as non-contiguous)."""
    if isinstance(x, np.ndarray):
        return x.flags.c_contiguous
    return x.size == 0 or bool(x.is_contiguous)


def to_numpy(x) -> np.ndarray:
    """Host copy (or the array itself when already NumPy)."""
    if isinstance(x, np.ndarray):
        return x
    return x.numpy()


def to_warp(x, device: str):
    """A ``wp.array`` on ``device`` holding ``x`` (no copy when it already lives there)."""
    wp = init_warp()
    if _is_warp_array(x):
        if str(x.device) == str(wp.get_device(device)):
            return x
        return x.to(device)
    arr = np.ascontiguousarray(x)
    return wp.array(arr, dtype=wp.dtype_from_numpy(arr.dtype), device=device)


def like_input(result, template):
    """Convert ``result`` (arrays, tuples, lists, objects with ``.to()``) to the template's kind.

    NumPy template: every array leaf becomes NumPy. Warp template: every leaf becomes a
    ``wp.array`` on the template's device.
    """
    host = isinstance(template, np.ndarray)
    device = None if host else str(template.device)
    return _convert(result, host, device)


def _convert(obj, host: bool, device):
    if obj is None or isinstance(obj, (int, float, str, bool, np.generic)):
        return obj
    if isinstance(obj, np.ndarray):
        return obj if host else to_warp(obj, device)
    if _is_warp_array(obj):
        if host:
            return obj.numpy()
        return obj if str(obj.device) == device else obj.to(device)
    if isinstance(obj, tuple):
        return tuple(_convert(o, host, device) for o in obj)
    if isinstance(obj, list):
        return [_convert(o, host, device) for o in obj]
    if hasattr(obj, "to") and callable(obj.to):
        return obj.to("host" if host else device)
    return obj


def contiguous(x):
    """``x``, or one C-contiguous copy of it when it is a strided NumPy view or ``wp.array``
    (on its own device); anything else (None, lists, contiguous arrays) unchanged.

    cv2 reads ROI slices and negative strides (``bgr[:, :, ::-1]``) directly and graph inputs
    may be views; warpvx's kernels take C-contiguous arrays, so such a view is copied once.
    """
    if isinstance(x, np.ndarray):
        return x if x.flags.c_contiguous else np.ascontiguousarray(x)
    if is_warp_array(x) and not is_contiguous(x):
        return x.contiguous()
    return x
