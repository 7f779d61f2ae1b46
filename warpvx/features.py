"""Corner detectors: FAST-9/16, Harris / minimum-eigenvalue responses, goodFeaturesToTrack.

Public functions validate their arguments and dispatch to ``warpvx.kernels_cpu`` (OpenCV)
or ``warpvx.kernels_warp`` (Warp kernels on the CPU or a CUDA device); see
:mod:`warpvx.registry`. Pixel centres are at integer coordinates (OpenCV's convention).
"""

from __future__ import annotations

import math

import numpy as np

from .backend import resolve_backend
from .check import check_bool, check_choice, check_float, check_image, check_int, check_out
from ._counted import check_counted, check_counted_keypoints
from .errors import UnsupportedError, WarpvxTypeError
from .keypoints import Keypoints
from .registry import dispatch

KSIZES = (1, 3, 5, 7)
SCORES = ("harris", "min_eigen")


def _gray(src, name: str = "src"):
    """A gray uint8 image as an HxW array (an HxWx1 one is viewed as HxW)."""
    src = check_image(src, name, dtypes=(np.uint8,), channels=(1,))
    if len(src.shape) == 3:
        src = src.reshape(tuple(src.shape[:2]))
    return src


def fast_corners(src, threshold: int = 10, nonmax: bool = True, *, out=None, backend=None,
                 stream=None) -> Keypoints:
    """FAST-9/16 corners with OpenCV's score, strongest first.

    A pixel is a corner when 9 contiguous pixels of the 16-pixel circle of radius 3 around it
    are all brighter than ``centre + threshold`` or all darker than ``centre - threshold``;
    its score is OpenCV's ``cornerScore<16>`` (the largest threshold at which it stays a
    corner, ``>= threshold``). With ``nonmax``, a corner is kept when its score is strictly
    greater than those of its 8 neighbours (OpenCV's rule). Pixels within 3 px of the edge
    are never corners; an image smaller than 7x7 gives no keypoints.

    Parameters
    ----------
    src : uint8 HxW (or HxWx1)
        Gray image (NumPy or device array).
    threshold : int in [0, 255]
        Intensity difference to the centre pixel.
    nonmax : bool
        3x3 non-maximum suppression on the score.
    out : warpvx._counted.Counted, optional
        Warp backends, device ``src``: Keypoints of
        :func:`~warpvx.kernels_warp.fast_corners.max_fast_corners` rows (the most corners
        the image can hold) and an int32 [1] count (a graph's fixed buffers, so the call can
        be captured): the same keypoints written there and their number, with no host sync.
    backend, stream
        See :mod:`warpvx.backend`.

    Returns
    -------
    Keypoints
        On the input's device (host arrays for NumPy input), sorted by score descending, then
        y, then x (deterministic). ``x``, ``y`` integer pixel positions, ``response`` the
        score, ``size`` 7, ``angle`` -1, ``octave`` 0, as ``cv2.FastFeatureDetector``
        gives, except that cv2 returns raster order and leaves ``response`` 0 when
        ``nonmax`` is False (here the score is reported either way).

    Raises
    ------
    DTypeError, ShapeError
        ``src`` not a gray uint8 image, or empty.
    WarpvxValueError
        ``threshold`` outside [0, 255].

    References
    ----------
    Rosten and Drummond 2006; OpenCV ``cv::FAST`` (``features2d/src/fast.cpp``).
    """
    be = resolve_backend(backend, like=src)
    src = _gray(src)
    threshold = check_int(threshold, "threshold", min_value=0, max_value=255)
    nonmax = check_bool(nonmax, "nonmax")
    if out is not None:
        if be.kind == "cpu":
            raise UnsupportedError("out: a Counted result needs a Warp backend")
        from .kernels_warp.fast_corners import max_fast_corners

        check_counted_keypoints(out, "out", max_fast_corners(src.shape[0], src.shape[1], nonmax))
    return dispatch("fast_corners", be, src, threshold, nonmax, out=out, stream=stream)


def harris_response(src, block_size: int = 2, ksize: int = 3, k: float = 0.04, *,
                    score: str = "harris", out=None, backend=None, stream=None):
    """Harris corner response (or the minimum eigenvalue) of a gray image, as cv2.cornerHarris.

    With Sobel derivatives ``dx``, ``dy`` (aperture ``ksize``, scaled by
    ``1 / (2^(ksize-1) * block_size * 255)``, OpenCV's factor for 8-bit input) and the
    unnormalised sums ``a = S(dx^2)``, ``b = S(dx dy)``, ``c = S(dy^2)`` over a
    ``block_size`` x ``block_size`` window (anchor ``block_size // 2``),
    ``R = a c - b^2 - k (a + c)^2`` (``score="harris"``) or the smaller eigenvalue of
    ``[[a, b], [b, c]]`` (``score="min_eigen"``, ``cv2.cornerMinEigenVal``). Both the Sobel
    and the box filter use BORDER_REFLECT_101.

    Parameters
    ----------
    src : uint8 HxW (or HxWx1)
        Gray image.
    block_size : int >= 1
        Window of the structure tensor.
    ksize : {1, 3, 5, 7}
        Sobel aperture.
    k : float
        Harris free parameter (ignored for ``"min_eigen"``).
    score : {"harris", "min_eigen"}
    out : float32 HxW, optional
        Written and returned.

    Returns
    -------
    float32 HxW, of the input's kind (NumPy or a ``wp.array`` on its device).
        Accuracy (SPEC section 4 promises a relative error under 1e-3 of the largest
        ``|R|`` against OpenCV): the ``cpu`` backend is OpenCV; Warp sums in another order,
        within 1e-5 of the largest ``|R|`` on photos (about 1e-6 measured on Warp's CPU
        device) and under 1e-4 on synthetic images, for both scores. One exception: with
        ``score="min_eigen"`` and ``block_size=1`` the tensor has rank 1, the true value is
        0 everywhere and both OpenCV and Warp return float rounding noise (under 1e-6 of the
        largest eigenvalue), which relative to its own maximum differs entirely between
        backends; there the bound holds relative to the largest eigenvalue.

    Raises
    ------
    UnsupportedError
        ``ksize`` not in {1, 3, 5, 7} (Scharr, ``ksize=-1``, is not offered) or unknown score.
    DTypeError, ShapeError, WarpvxValueError
        Bad image, ``block_size`` < 1, non-finite ``k``, bad ``out``.

    References
    ----------
    Harris and Stephens 1988; OpenCV ``cornerEigenValsVecs`` (``imgproc/src/corner.cpp``).
    """
    be = resolve_backend(backend, like=src)
    src = _gray(src)
    block_size = check_int(block_size, "block_size", min_value=1)
    if not isinstance(ksize, (int, np.integer)) or isinstance(ksize, bool):
        raise WarpvxTypeError(f"ksize: expected an integer, got {type(ksize).__name__} {ksize!r}")
    ksize = check_choice(int(ksize), "ksize", KSIZES)
    k = check_float(k, "k")
    score = check_choice(score, "score", SCORES)
    check_out(out, tuple(src.shape[:2]), inputs=(("src", src),), dtypes=(np.float32,))
    return dispatch("harris_response", be, src, block_size, ksize, k, score=score, out=out,
                    stream=stream)


def _no_limit_distance(h: int, w: int) -> float:
    """A ``min_distance`` (px) beyond any two pixels of an HxW image (its diagonal, rounded
    up): with it, or anything larger, every corner suppresses all weaker ones."""
    return float(math.ceil(math.hypot(w, h)))


def _corner_limits(h: int, w: int, max_corners: int, min_distance: float) -> tuple:
    """``(max_corners, min_distance)`` as computed for an HxW image: a limit of at least H*W
    is none (0: no image has more corners than pixels); a ``min_distance`` from the diagonal
    on keeps the strongest corner alone, which is what ``max_corners=1`` without suppression
    gives on both backends and in OpenCV."""
    if max_corners >= h * w:
        max_corners = 0
    if min_distance >= _no_limit_distance(h, w):
        max_corners, min_distance = 1, 0.0
    return max_corners, min_distance


def harris_corners_capacity(src, max_corners, min_distance, **_) -> int | None:
    """Rows of a graph node's Counted corners (:attr:`warpvx.registry.Primitive.counted_rows`):
    the corner limit :func:`harris_corners` computes for ``src``'s size, None without one."""
    limit, _ = _corner_limits(int(src.shape[0]), int(src.shape[1]), int(max_corners),
                              float(min_distance))
    return limit if limit > 0 else None


def harris_corners(src, max_corners: int = 1000, quality_level: float = 0.01,
                   min_distance: float = 10, block_size: int = 3, k: float = 0.04, *,
                   ksize: int = 3, score: str = "harris", out=None, backend=None, stream=None):
    """Strongest corners, as cv2.goodFeaturesToTrack(useHarrisDetector=True).

    The response (:func:`harris_response`, or the minimum eigenvalue with
    ``score="min_eigen"``) is thresholded at ``quality_level * max`` (values at or below go to
    0), pixels 1 px inside the image that equal the 3x3 maximum of the thresholded map and are
    non-zero are candidates, sorted strongest first (ties: later raster position first, as
    OpenCV), and taken greedily unless a taken corner lies closer than ``min_distance``
    (OpenCV's grid of cells ``round(min_distance)`` wide bounds the search), up to
    ``max_corners``.

    On Warp every step runs on the device; the greedy pass is computed exactly by parallel
    rounds (see :mod:`warpvx.kernels_warp.harris_corners`), with a host sync per few rounds.

    Parameters
    ----------
    src : uint8 HxW (or HxWx1)
    max_corners : int
        At most this many corners; ``<= 0`` means no limit, and so does any value of at least
        H*W (OpenCV would refuse those from 2^31).
    quality_level : float > 0
    min_distance : float >= 0
        In pixels. Below 1, no distance suppression (as OpenCV). From the image diagonal
        (rounded up) on, every value means "the strongest corner alone" and is computed as
        such (``max_corners=1``, no suppression): what OpenCV returns for the diagonal, on
        both backends, in constant time (OpenCV itself crashes from about 2.2e9).
    block_size : int >= 1
    k : float
    ksize : {1, 3, 5, 7}
        Sobel aperture (OpenCV's ``gradientSize``).
    score : {"harris", "min_eigen"}
    out : warpvx._counted.Counted, optional
        Warp backends, device ``src``: float32 [max_corners, 2] rows and an int32 [1] count
        (a graph's fixed buffers, so the call can be captured): the same corners written
        there and their number, at most ``max_corners`` (the count is clamped to the rows),
        with no host sync. Needs a limit (``0 < max_corners < H*W``).

    Returns
    -------
    float32 [N, 2]
        (x, y) per corner, strongest first, of the input's kind (cv2 returns [N, 1, 2] or
        None; :func:`warpvx.cv.goodFeaturesToTrack` does too); ``out`` when given.

    Raises
    ------
    DTypeError, ShapeError, WarpvxValueError, UnsupportedError
        As :func:`harris_response`; ``quality_level <= 0``; ``min_distance < 0``.
    """
    be = resolve_backend(backend, like=src)
    src = _gray(src)
    max_corners = check_int(max_corners, "max_corners")
    quality_level = check_float(quality_level, "quality_level", min_value=0.0, strict_min=True)
    min_distance = check_float(min_distance, "min_distance", min_value=0.0)
    block_size = check_int(block_size, "block_size", min_value=1)
    k = check_float(k, "k")
    if not isinstance(ksize, (int, np.integer)) or isinstance(ksize, bool):
        raise WarpvxTypeError(f"ksize: expected an integer, got {type(ksize).__name__} {ksize!r}")
    ksize = check_choice(int(ksize), "ksize", KSIZES)
    score = check_choice(score, "score", SCORES)
    h, w = int(src.shape[0]), int(src.shape[1])
    # "No limit" values are clamped, never iterated over or passed on as they come: OpenCV
    # takes int32 counts and rounds min_distance to an int32 cell size (it crashes from
    # 2^31), and the Warp search window grows with min_distance.
    max_corners, min_distance = _corner_limits(h, w, max_corners, min_distance)
    if out is not None:
        if be.kind == "cpu" or max_corners <= 0:
            raise UnsupportedError("out: a Counted result needs a Warp backend and a corner "
                                   "limit (0 < max_corners < H*W)")
        check_counted(out, "out", (max_corners, 2), (np.float32,))
    return dispatch("harris_corners", be, src, max_corners, quality_level, min_distance,
                    block_size, k, ksize=ksize, score=score, out=out, stream=stream)


__all__ = [
    "fast_corners",
    "harris_response",
    "harris_corners",
]
