"""Image pyramids and bilinear resize: Gaussian pyramid (``cv2.pyrDown``), ORB-SLAM2's scale
pyramid and ``cv2.resize`` INTER_LINEAR, all bit-exact with OpenCV on uint8.
"""

from __future__ import annotations

import numpy as np

from ._pyramid_sizes import gaussian_pyramid_sizes, resize_scales, scale_pyramid_sizes  # noqa: F401
from .backend import resolve_backend
from .check import (MAX_OUTPUT_SIDE, check_array, check_float, check_image, check_int,
                    check_output_size, check_size)
from .errors import ShapeError, WarpvxTypeError, WarpvxValueError
from .registry import dispatch

MAX_LEVELS = 64


def gaussian_pyramid(src, levels, *, out=None, backend=None, stream=None):
    """Gaussian pyramid: ``src`` then ``levels - 1`` successive ``cv2.pyrDown`` reductions.

    Each reduction convolves with the 5x5 kernel [1 4 6 4 1]^T [1 4 6 4 1] / 256 on every second
    pixel, pixels beyond the image mirrored as ``BORDER_REFLECT_101``, rounding half up:
    ``dst[y, x] = (sum_ij k[i] k[j] src[2y+j-2, 2x+i-2] + 128) >> 8``; a level of W x H becomes
    ``((W + 1) // 2) x ((H + 1) // 2)``.

    Parameters
    ----------
    src : array
        uint8 HxW, HxWx1 (treated as HxW) or HxWxC (C = 3, 4), C-contiguous.
    levels : int
        Number of images returned, >= 1, and at most one more than the reductions that
        bring the image to 1x1 (a further level could not shrink).
    out : list of arrays, optional
        ``levels`` arrays: ``out[0]`` must be ``src`` itself or None (it is not written; the
        graph's buffers leave it None), ``out[l]`` receives level ``l``. A level may take any size that ``cv2.pyrDown``'s ``dstsize``
        allows from the previous one (``|2 * w_l - w_{l-1}| <= 2``, same for heights).
    backend, stream
        See :mod:`warpvx.backend`.

    Returns
    -------
    list of arrays
        ``levels`` uint8 images of the input's kind; ``[0]`` is ``src`` itself (not a copy).

    Raises
    ------
    DTypeError, ShapeError, WarpvxValueError, WarpvxTypeError
        Bad ``src``, ``levels`` (not an int, < 1, or too many for the image) or ``out``.

    References
    ----------
    OpenCV ``pyrDown`` (``pyramids.cpp``, ``pyrDown_`` with ``FixPtCast<uchar, int, 8>``).
    """
    be = resolve_backend(backend, like=src)
    original = src
    src = _as_hw(check_image(src, "src", dtypes=(np.uint8,), channels=(1, 3, 4)))
    levels = check_int(levels, "levels", min_value=1, max_value=MAX_LEVELS)
    h, w = src.shape[0], src.shape[1]
    sizes = gaussian_pyramid_sizes(w, h, levels)
    limit = _max_gaussian_levels(w, h)
    if levels > limit:
        raise WarpvxValueError(
            f"levels: expected at most {limit} for a {w}x{h} (WxH) image (level {limit - 1} is "
            f"already 1x1), got {levels}"
        )
    kwargs = {}
    if out is not None:
        out_sizes = _check_pyramid_out(out, original, src, levels, sizes, flexible=True)
        if out_sizes != sizes:
            kwargs["sizes"] = out_sizes
        out = [src] + list(out[1:])  # level 0 as the implementation sees it (HxWx1 -> HxW)
    result = dispatch("gaussian_pyramid", be, src, levels, out=out, stream=stream, **kwargs)
    return [original] + list(result[1:])


def scale_pyramid(src, levels, scale_factor=1.2, *, out=None, backend=None, stream=None):
    """ORB-SLAM2's scale pyramid: level ``l`` is level ``l - 1`` resized bilinearly.

    Level ``l`` has size :func:`scale_pyramid_sizes` ``(cvRound(w / s^l), cvRound(h / s^l))``
    in float32 as ``ORBextractor::ComputePyramid`` and is ``cv2.resize(level[l-1], size,
    interpolation=INTER_LINEAR)`` (OpenCV's 11-bit fixed-point weights, reproduced exactly).

    Parameters
    ----------
    src : array
        uint8 HxW, HxWx1 (treated as HxW) or HxWxC (C = 3, 4), C-contiguous.
    levels : int
        Number of images returned, >= 1; every level must be at least 1x1.
    scale_factor : float
        Scale between levels, > 1 (ORB-SLAM2: 1.2).
    out : list of arrays, optional
        ``levels`` arrays of the level shapes; ``out[0]`` must be ``src`` itself or None.
    backend, stream
        See :mod:`warpvx.backend`.

    Returns
    -------
    list of arrays
        ``levels`` uint8 images of the input's kind; ``[0]`` is ``src`` itself.

    Raises
    ------
    DTypeError, ShapeError, WarpvxValueError, WarpvxTypeError
        Bad ``src``, ``levels`` (< 1, or a level smaller than 1x1), ``scale_factor`` (<= 1)
        or ``out``.

    References
    ----------
    ORB-SLAM2 ``ORBextractor::ComputePyramid``; OpenCV ``resize`` (``resize.cpp``).
    """
    be = resolve_backend(backend, like=src)
    original = src
    src = _as_hw(check_image(src, "src", dtypes=(np.uint8,), channels=(1, 3, 4)))
    levels = check_int(levels, "levels", min_value=1, max_value=MAX_LEVELS)
    scale_factor = check_float(scale_factor, "scale_factor", min_value=1.0, strict_min=True)
    h, w = src.shape[0], src.shape[1]
    sizes = scale_pyramid_sizes(w, h, levels, scale_factor)
    for lvl, (lw, lh) in enumerate(sizes):
        if lw < 1 or lh < 1:
            raise WarpvxValueError(
                f"levels: level {lvl} of a {w}x{h} (WxH) image at scale_factor {scale_factor} "
                f"would be {lw}x{lh} (empty); expected at most {lvl} levels, got {levels}"
            )
    if out is not None:
        _check_pyramid_out(out, original, src, levels, sizes, flexible=False)
        out = [src] + list(out[1:])
    result = dispatch("scale_pyramid", be, src, levels, scale_factor, out=out, stream=stream)
    return [original] + list(result[1:])


def resize(src, dsize=None, fx=0.0, fy=0.0, *, out=None, backend=None, stream=None):
    """Bilinear resize, bit-exact with ``cv2.resize(src, dsize, fx=fx, fy=fy,
    interpolation=cv2.INTER_LINEAR)`` on uint8.

    Pixel centres are aligned (``src_x = (x + 0.5) * scale - 0.5``); weights are rounded to
    1/2048 as OpenCV does (see :mod:`warpvx.kernels_warp.scale_pyramid`).

    Parameters
    ----------
    src : array
        uint8 HxW, HxWx1 (treated as HxW) or HxWxC (C = 3, 4), C-contiguous.
    dsize : (int, int) or None
        Output (width, height). None or (0, 0): ``(round(w * fx), round(h * fy))``. At
        most 2^20 a side and 2^28 pixels (:func:`warpvx.check.check_output_size`).
    fx, fy : float
        Scale factors, used (and required > 0) when ``dsize`` is None or (0, 0).
    out : array, optional
        uint8 output of the target shape.
    backend, stream
        See :mod:`warpvx.backend`.

    Returns
    -------
    array
        uint8 (height, width[, C]) image of the input's kind.

    Raises
    ------
    DTypeError, ShapeError, WarpvxValueError, WarpvxTypeError
        Bad ``src``, ``dsize``, ``fx``/``fy`` (<= 0 without dsize, or an empty result) or
        ``out``.
    """
    be = resolve_backend(backend, like=src)
    src = _as_hw(check_image(src, "src", dtypes=(np.uint8,), channels=(1, 3, 4)))
    h, w = src.shape[0], src.shape[1]
    if dsize is None or (isinstance(dsize, (tuple, list)) and tuple(dsize) == (0, 0)):
        fx = check_float(fx, "fx", min_value=0.0, strict_min=True, max_value=MAX_OUTPUT_SIDE)
        fy = check_float(fy, "fy", min_value=0.0, strict_min=True, max_value=MAX_OUTPUT_SIDE)
        dsize = None
    else:
        dsize = check_size(dsize, "dsize")
        fx = fy = 0.0
    (dw, dh), _ = resize_scales((w, h), dsize, fx, fy)
    check_output_size(dw, dh, "fx, fy")  # dsize itself was checked above
    if dw < 1 or dh < 1:
        raise WarpvxValueError(
            f"fx, fy: a {w}x{h} (WxH) image scaled by ({fx}, {fy}) is empty ({dw}x{dh})")
    if out is not None:
        check_array(out, "out", shape=(dh, dw) + tuple(src.shape[2:]), dtypes=(np.uint8,))
    return dispatch("resize", be, src, dsize, fx, fy, out=out, stream=stream)


# --- sizes ----------------------------------------------------------------------------------


def _max_gaussian_levels(width: int, height: int) -> int:
    levels, w, h = 1, width, height
    while w > 1 or h > 1:
        w, h = (w + 1) // 2, (h + 1) // 2
        levels += 1
    return levels


def _as_hw(src):
    """An HxWx1 image as an HxW view."""
    if src.ndim == 3 and src.shape[2] == 1:
        return src.reshape((src.shape[0], src.shape[1]))
    return src


def _check_pyramid_out(out, original, src, levels, sizes, *, flexible):
    if not isinstance(out, (list, tuple)):
        raise WarpvxTypeError(f"out: expected a list of {levels} arrays, got {type(out).__name__}")
    if len(out) != levels:
        raise ShapeError(f"out: expected {levels} arrays (one per level), got {len(out)}")
    if out[0] is not None and out[0] is not original and out[0] is not src:
        raise WarpvxValueError("out[0]: expected src itself or None (level 0 is the input)")
    tail = tuple(src.shape[2:])
    prev_w, prev_h = sizes[0]
    got = [sizes[0]]
    for lvl in range(1, levels):
        arr = out[lvl]
        if flexible:
            arr = check_array(arr, f"out[{lvl}]", dtypes=(np.uint8,), ndim=src.ndim)
            oh, ow = arr.shape[0], arr.shape[1]
            ok = (tuple(arr.shape[2:]) == tail and ow >= 1 and oh >= 1
                  and abs(2 * ow - prev_w) <= 2 and abs(2 * oh - prev_h) <= 2)
            if not ok:
                want = (sizes[lvl][1], sizes[lvl][0]) + tail
                raise ShapeError(
                    f"out[{lvl}]: expected shape {want} (or a pyrDown dstsize within 2 of half "
                    f"the previous level), got {tuple(arr.shape)}"
                )
            prev_w, prev_h = ow, oh
            got.append((ow, oh))
        else:
            check_array(arr, f"out[{lvl}]", shape=(sizes[lvl][1], sizes[lvl][0]) + tail,
                        dtypes=(np.uint8,))
            got.append(sizes[lvl])
    return got
