"""One checker for every public entry point: typed warpvx errors naming the argument.

Each function raises a :mod:`warpvx.errors` error whose message reads
``"<name>: expected <what>, got <actual>"``.

Output sizes are bounded (:func:`check_output_size`): at most :data:`MAX_OUTPUT_SIDE` pixels
a side and :data:`MAX_OUTPUT_PIXELS` pixels in all, so that a typo in ``dsize`` or ``fx``
is refused before anything is allocated, the kernels' 32-bit byte offsets (4 channels at
most) cannot overflow and pixel coordinates stay exact in float32.
"""

from __future__ import annotations

import math
import numbers
import threading
from collections import OrderedDict

import numpy as np

from .arrays import as_input, byte_range, is_contiguous, is_warp_array, numpy_dtype
from .errors import DTypeError, ShapeError, UnsupportedError, WarpvxTypeError, WarpvxValueError


def check_image(
    x,
    name: str = "src",
    *,
    dtypes=(np.uint8,),
    channels=(1, 3, 4),
    min_size: tuple[int, int] = (1, 1),
):
    """Validate an image and return it as a NumPy array or ``wp.array``.

    Parameters
    ----------
    x : array-like
        HxW (one channel) or HxWxC image, C-contiguous.
    dtypes : tuple of dtypes
        Accepted element types.
    channels : tuple of int
        Accepted channel counts; 1 means an HxW array (an HxWx1 array is accepted too).
    min_size : (int, int)
        Smallest accepted (height, width).
    """
    arr = as_input(x, name)
    shape = tuple(arr.shape)
    if len(shape) == 2:
        c = 1
    elif len(shape) == 3:
        c = shape[2]
    else:
        raise ShapeError(f"{name}: expected an HxW or HxWxC image, got an array of shape {shape}")
    if c not in channels:
        want = " or ".join(str(k) for k in channels)
        raise ShapeError(f"{name}: expected {want} channel(s), got {c} (shape {shape})")
    _check_dtype(arr, name, dtypes)
    h, w = shape[0], shape[1]
    if h == 0 or w == 0:
        raise ShapeError(f"{name}: image is empty (shape {shape})")
    if h < min_size[0] or w < min_size[1]:
        raise ShapeError(
            f"{name}: image of {w}x{h} (WxH) is smaller than the {min_size[1]}x{min_size[0]} minimum"
        )
    if not is_contiguous(arr):
        raise WarpvxValueError(
            f"{name}: expected a C-contiguous array (use np.ascontiguousarray), got strides "
            f"{getattr(arr, 'strides', None)}"
        )
    return arr


def check_array(x, name: str, *, shape=None, dtypes=None, ndim=None, finite=False):
    """Validate a general array (maps, matrices, point sets).

    ``shape`` may hold None for a free dimension. ``finite`` rejects NaN/inf (host copy for
    device arrays, so use it only on small arrays).
    """
    arr = as_input(x, name)
    s = tuple(arr.shape)
    if ndim is not None and len(s) != ndim:
        raise ShapeError(f"{name}: expected {ndim} dimension(s), got shape {s}")
    if shape is not None:
        ok = len(s) == len(shape) and all(e is None or e == a for e, a in zip(shape, s))
        if not ok:
            want = "x".join("N" if e is None else str(e) for e in shape)
            raise ShapeError(f"{name}: expected shape {want}, got {s}")
    if dtypes is not None:
        _check_dtype(arr, name, dtypes)
    if not is_contiguous(arr):
        raise WarpvxValueError(f"{name}: expected a C-contiguous array")
    if finite:
        host = arr if isinstance(arr, np.ndarray) else arr.numpy()
        if not np.all(np.isfinite(host)):
            raise WarpvxValueError(f"{name}: contains NaN or inf")
    return arr


#: Largest output side, in pixels (x < 2^24 keeps float32 pixel coordinates exact).
MAX_OUTPUT_SIDE = 1 << 20
#: Largest output, in pixels: 2^28 pixels of 4 bytes keep byte offsets below 2^31 (1 GiB).
MAX_OUTPUT_PIXELS = 1 << 28
#: ``max |m @ inv(m) - I|`` above which a matrix counts as singular (float64 arithmetic).
INVERSE_TOLERANCE = 1e-6


def check_matrix(m, name: str = "M", shape=(3, 3), *, invertible=False) -> np.ndarray:
    """A small host matrix as float64; finite, and invertible when asked.

    Invertibility is judged by what the inverse does, not by the condition number (a pure
    translation by 1e6 px is well invertible): ``inv(m)`` must exist, be finite, and
    ``max |m @ inv(m) - I| <= INVERSE_TOLERANCE``.

    The result is read-only: validated NumPy matrices are remembered (a few dozen), since a
    warp is often called frame after frame with the same matrix and the invertibility test
    costs microseconds.
    """
    if isinstance(m, (list, tuple)):
        m = np.asarray(m)
    key = None
    if type(m) is np.ndarray and m.size <= 16:
        key = (m.dtype.str, m.shape, m.tobytes(), tuple(shape), invertible)
        hit = _matrices.get(key)
        if hit is not None:
            return hit
    arr = as_input(m, name)
    host = np.asarray(arr if isinstance(arr, np.ndarray) else arr.numpy())
    if host.shape != tuple(shape):
        raise ShapeError(f"{name}: expected a {shape[0]}x{shape[1]} matrix, got shape {host.shape}")
    if not np.issubdtype(host.dtype, np.number):
        raise DTypeError(f"{name}: expected a numeric matrix, got dtype {host.dtype}")
    host = host.astype(np.float64)
    if not np.all(np.isfinite(host)):
        raise WarpvxValueError(f"{name}: matrix contains NaN or inf")
    if invertible:
        _check_invertible(host, name)
    host.setflags(write=False)
    if key is not None:
        with _matrices_lock:
            _matrices[key] = host
            while len(_matrices) > 64:
                _matrices.popitem(last=False)
    return host


_matrices: OrderedDict = OrderedDict()
_matrices_lock = threading.Lock()


def _check_invertible(m: np.ndarray, name: str) -> None:
    try:
        with np.errstate(all="ignore"):
            inv = np.linalg.inv(m)
            residual = float(np.abs(m @ inv - np.eye(m.shape[0])).max())
    except np.linalg.LinAlgError:
        residual = math.inf
    if not residual <= INVERSE_TOLERANCE:  # also NaN: a non-finite inverse
        raise WarpvxValueError(
            f"{name}: matrix is singular (max |M @ inv(M) - I| = {residual:.3g}, expected <= "
            f"{INVERSE_TOLERANCE:g})")


def check_int(v, name: str, *, min_value=None, max_value=None) -> int:
    if isinstance(v, bool) or not isinstance(v, numbers.Integral):
        raise WarpvxTypeError(f"{name}: expected an integer, got {type(v).__name__} {v!r}")
    v = int(v)
    _check_range(v, name, min_value, max_value)
    return v


def check_float(v, name: str, *, min_value=None, max_value=None, strict_min=False) -> float:
    if isinstance(v, bool) or not isinstance(v, numbers.Real):
        raise WarpvxTypeError(f"{name}: expected a number, got {type(v).__name__} {v!r}")
    v = float(v)
    if not math.isfinite(v):
        raise WarpvxValueError(f"{name}: expected a finite number, got {v}")
    if strict_min and min_value is not None and v <= min_value:
        raise WarpvxValueError(f"{name}: expected a value > {min_value}, got {v}")
    _check_range(v, name, None if strict_min else min_value, max_value)
    return v


def check_size(dsize, name: str = "dsize") -> tuple[int, int]:
    """A (width, height) pair of positive integers, OpenCV order, within the output bounds
    (:func:`check_output_size`)."""
    try:
        w, h = dsize
    except (TypeError, ValueError):
        raise WarpvxTypeError(f"{name}: expected (width, height), got {dsize!r}") from None
    w = check_int(w, f"{name}[0] (width)", min_value=1, max_value=MAX_OUTPUT_SIDE)
    h = check_int(h, f"{name}[1] (height)", min_value=1, max_value=MAX_OUTPUT_SIDE)
    check_output_size(w, h, name)
    return w, h


def check_output_size(width: int, height: int, name: str) -> None:
    """Refuse an output of ``width`` x ``height`` pixels over :data:`MAX_OUTPUT_SIDE` a side
    or :data:`MAX_OUTPUT_PIXELS` in all (``name``: the argument that set the size)."""
    if width > MAX_OUTPUT_SIDE or height > MAX_OUTPUT_SIDE or width * height > MAX_OUTPUT_PIXELS:
        raise WarpvxValueError(
            f"{name}: expected an output of at most {MAX_OUTPUT_SIDE} pixels a side and "
            f"{MAX_OUTPUT_PIXELS} in all, got {width}x{height} (WxH)")


def check_out(out, shape, *, inputs=(), in_place=False, dtypes=(np.uint8,), name="out"):
    """Validate an ``out=`` array (None passes: no output given): shape, dtype, C-contiguity,
    writable, and no memory shared with the ``inputs`` (``(name, array)`` pairs), which a
    kernel would read after writing. ``name`` is the argument named in errors.

    ``in_place``: ``out`` may be exactly an input (same address and shape), for kernels that
    support it; a partial overlap (a shifted view) is refused all the same.
    """
    if out is None:
        return None
    out = check_array(out, name, shape=shape, dtypes=dtypes)
    check_writable(out, name)
    for name, a in inputs:
        if not _overlap(out, a):
            continue
        if in_place and tuple(out.shape) == tuple(a.shape) and byte_range(out) == byte_range(a):
            continue
        what = "is" if byte_range(out) == byte_range(a) else "overlaps"
        raise WarpvxValueError(
            f"out: expected memory apart from {name}, got an array that {what} {name} "
            f"(pass a separate array{'' if not in_place else ' or ' + name + ' itself'})")
    return out


def check_outs(out, specs):
    """Validate an ``out=`` tuple of arrays, one per ``(label, shape, dtypes)`` in ``specs``,
    each with :func:`check_out` under the name ``out[i] (label)``; returns the tuple."""
    labels = ", ".join(label for label, _, _ in specs)
    if not isinstance(out, (tuple, list)) or len(out) != len(specs):
        raise WarpvxTypeError(f"out: expected a tuple ({labels}) of arrays, got "
                              f"{type(out).__name__}")
    checked = []
    for i, (a, (label, shape, dtypes)) in enumerate(zip(out, specs)):
        name = f"out[{i}] ({label})"
        if not (isinstance(a, np.ndarray) or is_warp_array(a)):
            raise WarpvxTypeError(f"{name}: expected a NumPy or Warp array, got {type(a).__name__}")
        checked.append(check_out(a, shape, dtypes=dtypes, name=name))
    return tuple(checked)


def check_writable(out, name: str = "out") -> None:
    """Refuse a read-only NumPy output (or a list/tuple holding one)."""
    if isinstance(out, (list, tuple)):
        for i, o in enumerate(out):
            check_writable(o, f"{name}[{i}]")
    elif isinstance(out, np.ndarray) and not out.flags.writeable:
        raise WarpvxValueError(f"{name}: expected a writable array, got a read-only one")


def _overlap(a, b) -> bool:
    """Whether two validated (C-contiguous) arrays share memory."""
    if isinstance(a, np.ndarray) and isinstance(b, np.ndarray):
        return np.may_share_memory(a, b)  # bounds only: exact for contiguous arrays
    ra, rb = byte_range(a), byte_range(b)
    return ra[0] == rb[0] and ra[1] < rb[2] and rb[1] < ra[2]


def check_bool(v, name: str, *, allow_none: bool = False):
    """``v`` as a bool (NumPy bools accepted; None too when ``allow_none``); 1 and "yes" are
    refused rather than read as True."""
    if v is None and allow_none:
        return None
    if not isinstance(v, (bool, np.bool_)):
        what = "a bool or None" if allow_none else "a bool"
        raise WarpvxTypeError(f"{name}: expected {what}, got {type(v).__name__} {v!r}")
    return bool(v)


def check_choice(v, name: str, choices):
    """``v`` must be one of ``choices`` (a dict maps accepted names to canonical values)."""
    if isinstance(choices, dict):
        if v in choices:
            return choices[v]
    elif v in choices:
        return v
    opts = ", ".join(repr(c) for c in choices)
    raise UnsupportedError(f"{name}: expected one of {opts}, got {v!r}")


# (array dtype, accepted dtypes) pairs seen to pass: every public call checks its arrays'
# dtypes, and NumPy dtype construction and comparison cost microseconds each time.
_dtype_ok: set = set()


def _check_dtype(arr, name: str, dtypes) -> None:
    """``arr``'s dtype (NumPy or Warp) must be one of ``dtypes``."""
    try:
        key = (arr.dtype, dtypes)
        if key in _dtype_ok:
            return
    except TypeError:  # unhashable dtypes (a list): check without the cache
        key = None
    dt = numpy_dtype(arr)
    accepted = [np.dtype(d) for d in dtypes]
    if dt not in accepted:
        want = " or ".join(str(d) for d in accepted)
        raise DTypeError(f"{name}: expected dtype {want}, got {dt}")
    if key is not None:
        _dtype_ok.add(key)


def _check_range(v, name, lo, hi):
    if lo is not None and v < lo:
        raise WarpvxValueError(f"{name}: expected a value >= {lo}, got {v}")
    if hi is not None and v > hi:
        raise WarpvxValueError(f"{name}: expected a value <= {hi}, got {v}")
