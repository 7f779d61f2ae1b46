"""Geometric transforms: remap and perspective warp (OpenCV's ``remap``, ``warpPerspective``).

Both sample a uint8 image at real coordinates with the same code (OpenCV >= 4.11 semantics,
see :mod:`warpvx.kernels_warp._sampling`): pixel centres at integer coordinates; nearest
rounds half to even; linear blends the 2x2 neighbourhood in float32 and rounds half to even;
borders ``"constant"`` (``border_value``), ``"replicate"``, ``"reflect101"``. Interpolation and
border may also be given as cv2's integers (``cv2.INTER_LINEAR``, ``cv2.BORDER_REPLICATE``...).

Coordinates no pixel lies at are defined the same on every backend (where OpenCV itself
overflows an int, or loops for seconds to reflect a huge coordinate): a non-finite coordinate
(NaN, inf; W == 0 in a perspective warp) gives ``border_value`` under every border mode, and
a finite one beyond +-1e9 is clamped to +-1e9 before the border rule.
"""

from __future__ import annotations

import numbers

import numpy as np

from .backend import resolve_backend
from .callmemo import CallMemo
from .check import (check_array, check_bool, check_float, check_image, check_matrix, check_out,
                    check_size)
from .errors import ShapeError, WarpvxTypeError, WarpvxValueError
from .modes import SAMPLER_BORDERS, SAMPLER_INTERPOLATIONS, mode_code
from .registry import dispatch


# Frame after frame with the same arguments: validated once (see warpvx.callmemo).
_remap_memo = CallMemo("remap")
_warp_perspective_memo = CallMemo("warp_perspective")


def remap(src, map_x, map_y, interpolation="linear", border="constant", border_value=0, *, out=None,
          backend=None, stream=None):
    """Sample ``src`` at per-pixel coordinates: ``dst[y, x] = src(map_x[y, x], map_y[y, x])``.

    Parameters
    ----------
    src : array
        uint8 HxW, HxWx1 (treated as HxW) or HxWxC (C = 3, 4), C-contiguous.
    map_x, map_y : array
        float32 arrays of the output's shape (Ho x Wo): the source x (column) and y (row) of
        each output pixel, pixel centres at integers. Non-finite entries (NaN, inf) are not
        an error (checking would cost a pass over the maps): such a pixel has no source and
        takes ``border_value`` under every border mode (OpenCV gives the same under the
        constant border, and 0 for linear sampling under the others); entries beyond +-1e9
        are clamped to +-1e9 (see the module notes).
    interpolation : {"linear", "nearest"} or int
        Bilinear or nearest neighbour (``cv2.INTER_LINEAR``, ``cv2.INTER_NEAREST``).
    border : {"constant", "replicate", "reflect101"} or int
        Rule for taps outside ``src`` (``cv2.BORDER_CONSTANT``, ``BORDER_REPLICATE``,
        ``BORDER_REFLECT_101``).
    border_value : number or sequence of up to 4 numbers
        Constant-border value: a number applies to every channel; a sequence gives one value
        per channel (missing channels 0, as cv2's Scalar). Saturated to uint8 (half to even).
    out : array, optional
        uint8 writable output of shape Ho x Wo (x C), sharing no memory with ``src`` or the
        maps.
    backend, stream
        See :mod:`warpvx.backend`.

    Returns
    -------
    array
        uint8 Ho x Wo (x C), of the input's kind (NumPy or ``wp.array``).

    Raises
    ------
    DTypeError, ShapeError, WarpvxValueError, UnsupportedError
        Bad ``src``, ``map_x``/``map_y`` (dtype, ndim, shape mismatch, contiguity),
        ``interpolation``, ``border``, ``border_value`` or ``out``.

    Notes
    -----
    Matches ``cv2.remap(src, map_x, map_y, interpolation, borderMode=..., borderValue=...)``
    of OpenCV >= 4.11 exactly (both compute in float32); older OpenCV's 1/32-px fixed-point
    path differs by at most 1 on under 1% of pixels.
    """
    key = _remap_memo.key((src, map_x, map_y), (interpolation, border, border_value), out, backend,
                          stream)
    done = _remap_memo.replay(key, out)
    if done is not None:
        return done
    be = resolve_backend(backend, like=src)
    src = _as_hw(check_image(src, "src", dtypes=(np.uint8,), channels=(1, 3, 4)))
    map_x = check_array(map_x, "map_x", ndim=2, dtypes=(np.float32,))
    map_y = check_array(map_y, "map_y", shape=tuple(map_x.shape), dtypes=(np.float32,))
    if map_x.shape[0] == 0 or map_x.shape[1] == 0:
        raise _empty("map_x", map_x.shape)
    interp = mode_code(interpolation, "interpolation", SAMPLER_INTERPOLATIONS)
    bmode = mode_code(border, "border", SAMPLER_BORDERS)
    channels = 1 if src.ndim == 2 else src.shape[2]
    bval = _border_value(border_value)
    h, w = map_x.shape
    check_out(out, (h, w) if channels == 1 else (h, w, channels),
              inputs=(("src", src), ("map_x", map_x), ("map_y", map_y)))
    return _remap_memo.run(
        key, lambda: dispatch("remap", be, src, map_x, map_y, interp, bmode, bval, out=out, stream=stream),
        out)


def warp_perspective(src, M, dsize, interpolation="linear", inverse_map=False, border="constant",
                     border_value=0, *, out=None, backend=None, stream=None):
    """Warp ``src`` through a 3x3 homography.

    Each output pixel (x, y) samples the source at ``(X/W, Y/W)`` with
    ``(X, Y, W) = Minv @ (x, y, 1)``, where ``Minv`` is ``inv(M)`` (``M`` maps source to
    destination) or ``M`` itself when ``inverse_map`` is true (like ``cv2.WARP_INVERSE_MAP``).
    Sampling as :func:`remap`. Where W == 0 the coordinate is non-finite and the pixel takes
    ``border_value`` under every border mode (OpenCV: under the constant border only).

    Parameters
    ----------
    src : array
        uint8 HxW, HxWx1 or HxWxC (C = 3, 4), C-contiguous.
    M : array-like
        3x3 finite, invertible matrix (any real dtype; NumPy, list or ``wp.array``; a device
        array is read back to the host, which synchronises). Invertible means
        ``max |M @ inv(M) - I| <= 1e-6`` in float64. Inverted in float64, then rounded to
        float32 for the kernels: the dst->src matrix must be finite in float32.
    dsize : (int, int)
        Output (width, height), OpenCV order; at most 2^20 a side and 2^28 pixels
        (:data:`warpvx.check.MAX_OUTPUT_PIXELS`).
    interpolation, border, border_value
        As :func:`remap`.
    inverse_map : bool
        True when ``M`` already maps destination to source.
    out : array, optional
        uint8 writable output of shape (height, width[, C]), sharing no memory with ``src``.
    backend, stream
        See :mod:`warpvx.backend`.

    Returns
    -------
    array
        uint8 (height, width[, C]), of the input's kind.

    Raises
    ------
    DTypeError, ShapeError, WarpvxValueError, WarpvxTypeError, UnsupportedError
        Bad ``src``, ``M`` (shape, NaN/inf, singular), ``dsize``, ``inverse_map``,
        ``interpolation``, ``border``, ``border_value`` or ``out``.

    Notes
    -----
    Follows ``cv2.warpPerspective`` of OpenCV >= 4.11 (float32 coordinates: the matrix is
    rounded to float32, ``X = fma(m00, x, m01*y + m02)``, then divided by W). The Warp
    backends match it exactly on OpenCV's vector path; on the last ``width mod 16`` columns
    of each row (OpenCV's scalar tail, whose coordinate arithmetic differs) bilinear
    sampling differs by 1 on rare pixels (in tests, 1 to 2 pixels in some 5% of random mild
    homographies of 40x40 images; none on the photos of the test suite). The ``cpu`` backend
    is OpenCV itself, except for matrices whose coordinates reach a horizon (W near 0) or
    beyond the bounds above, which it samples as the Warp backends through :func:`remap`.
    """
    key = _warp_perspective_memo.key((src,), (M, dsize, interpolation, inverse_map, border,
                                             border_value), out, backend, stream)
    done = _warp_perspective_memo.replay(key, out)
    if done is not None:
        return done
    be = resolve_backend(backend, like=src)
    src = _as_hw(check_image(src, "src", dtypes=(np.uint8,), channels=(1, 3, 4)))
    m = check_matrix(M, "M", (3, 3), invertible=True)
    w, h = check_size(dsize, "dsize")
    check_bool(inverse_map, "inverse_map")
    interp = mode_code(interpolation, "interpolation", SAMPLER_INTERPOLATIONS)
    bmode = mode_code(border, "border", SAMPLER_BORDERS)
    channels = 1 if src.ndim == 2 else src.shape[2]
    bval = _border_value(border_value)
    check_out(out, (h, w) if channels == 1 else (h, w, channels), inputs=(("src", src),))
    coeffs = _dst_to_src(m, bool(inverse_map))
    return _warp_perspective_memo.run(
        key, lambda: dispatch("warp_perspective", be, src, coeffs, (w, h), interp, bmode, bval,
                              out=out, stream=stream), out)


def _as_hw(src):
    """An HxWx1 image as an HxW view (NumPy and ``wp.array`` alike)."""
    if src.ndim == 3 and src.shape[2] == 1:
        return src.reshape((src.shape[0], src.shape[1]))
    return src


_coeffs: dict = {}  # (matrix bytes, inverse_map) -> dst->src coefficients


def _dst_to_src(m: np.ndarray, inverse_map: bool) -> tuple:
    """The dst->src matrix (``inv(m)`` unless ``inverse_map``) as 9 floats, row order; it
    must be finite once rounded to float32, as the kernels take it."""
    key = (m.tobytes(), inverse_map)
    coeffs = _coeffs.get(key)
    if coeffs is None:
        m_inv = m if inverse_map else np.linalg.inv(m)
        if not np.all(np.abs(m_inv) <= np.finfo(np.float32).max):
            what = "M" if inverse_map else "inv(M)"
            raise WarpvxValueError(f"M: expected {what} finite in float32, got {m_inv.tolist()}")
        coeffs = tuple(float(v) for v in m_inv.ravel())
        if len(_coeffs) >= 64:
            _coeffs.clear()
        _coeffs[key] = coeffs
    return coeffs


def _empty(name, shape):
    return ShapeError(f"{name}: expected a non-empty array, got shape {tuple(shape)}")


_border_values: dict = {}  # (types, value) -> saturated border values


def _border_value(value) -> tuple:
    """Four border values saturated as ``saturate_cast<uchar>`` (round half to even, clip)."""
    t = type(value)
    if t is int or t is float or t is tuple:
        # Keyed with the element types too: True == 1 but a bool is rejected.
        key = (t, tuple(map(type, value)) if t is tuple else None, value)
        try:
            hit = _border_values.get(key)
        except TypeError:  # unhashable elements
            key = hit = None
        if hit is not None:
            return hit
        result = _saturated_border_value(value)
        if key is not None:
            if len(_border_values) >= 64:
                _border_values.clear()
            _border_values[key] = result
        return result
    return _saturated_border_value(value)


def _saturated_border_value(value) -> tuple:
    if isinstance(value, numbers.Real) and not isinstance(value, bool):
        vals = [check_float(value, "border_value")] * 4
    elif isinstance(value, (tuple, list, np.ndarray)):
        seq = np.asarray(value).ravel().tolist() if isinstance(value, np.ndarray) else list(value)
        if not 1 <= len(seq) <= 4:
            raise WarpvxTypeError(f"border_value: expected a number or 1 to 4 numbers, got {len(seq)}")
        vals = [check_float(v, f"border_value[{i}]") for i, v in enumerate(seq)]
        vals += [0.0] * (4 - len(vals))
    else:
        raise WarpvxTypeError(
            f"border_value: expected a number or a sequence of numbers, got {type(value).__name__}")
    # Python's round() is half to even, as cvRound.
    return tuple(float(min(255, max(0, round(v)))) for v in vals)


