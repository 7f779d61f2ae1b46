"""warpvx.cv.video: OpenCV's sparse optical flow (``calcOpticalFlowPyrLK``,
``buildOpticalFlowPyramid``) with cv2's names, arguments and return shapes (see warpvx.cv;
strided views are copied once)."""

from __future__ import annotations

import numbers

import numpy as np

from ..arrays import as_input, is_warp_array
from ..errors import UnsupportedError, WarpvxTypeError, WarpvxValueError
from ..flow import build_optical_flow_pyramid, optical_flow_pyr_lk
from ._arrays import contiguous
from ._fallback import function

TERM_CRITERIA_COUNT = 1
TERM_CRITERIA_MAX_ITER = 1
TERM_CRITERIA_EPS = 2
OPTFLOW_USE_INITIAL_FLOW = 4
OPTFLOW_LK_GET_MIN_EIGENVALS = 8

_BORDER_CONSTANT = 0
_BORDER_REFLECT_101 = 4
_DEFAULT_ITERS = 30  # what OpenCV uses when the criteria lack COUNT ...
_DEFAULT_EPS = 0.01  # ... or EPS


@function
def calcOpticalFlowPyrLK(
    prevImg,
    nextImg,
    prevPts,
    nextPts,
    status=None,
    err=None,
    winSize=(21, 21),
    maxLevel=3,
    criteria=(TERM_CRITERIA_COUNT | TERM_CRITERIA_EPS, 30, 0.01),
    flags=0,
    minEigThreshold=1e-4,
    *,
    backend=None,
):
    """``cv2.calcOpticalFlowPyrLK``: returns (nextPts, status, err).

    ``nextPts`` has the shape of ``prevPts`` ([N, 1, 2] or [N, 2], float32), ``status``
    uint8 [N, 1], ``err`` float32 [N, 1] (mean absolute window difference; 0 where status is
    0); (None, None, None) for no points, as cv2. ``prevImg``/``nextImg`` may be images or
    pyramids from :func:`buildOpticalFlowPyramid` (derivative levels, if any, are skipped).
    ``flags``: 0 or ``OPTFLOW_USE_INITIAL_FLOW`` (then ``nextPts`` holds the initial
    guesses); ``OPTFLOW_LK_GET_MIN_EIGENVALS`` runs on cv2 (see :mod:`warpvx.cv`).
    Arrays given as ``nextPts``/``status``/``err`` of the right shape are filled as cv2
    fills them. See :func:`warpvx.optical_flow_pyr_lk`.
    """
    flags = _check_flags(flags)
    max_iters, eps = _criteria(criteria)
    prevPts = contiguous(prevPts)
    pts_in = as_input(prevPts, "prevPts")
    shape = tuple(pts_in.shape)
    if len(shape) >= 1 and shape[0] == 0:
        return None, None, None
    guess = None
    if flags & OPTFLOW_USE_INITIAL_FLOW:
        if nextPts is None:
            raise WarpvxValueError("nextPts: OPTFLOW_USE_INITIAL_FLOW needs the initial guesses, got None")
        guess = contiguous(nextPts)
    tracked, st, er = optical_flow_pyr_lk(
        _levels(prevImg),
        _levels(nextImg),
        prevPts,
        guess,
        win_size=winSize,
        max_level=maxLevel,
        max_iters=max_iters,
        eps=eps,
        min_eig_threshold=minEigThreshold,
        backend=backend,
    )
    n = tracked.shape[0]
    tracked = tracked.reshape(shape if len(shape) == 3 else (n, 2))
    st = st.reshape((n, 1))
    er = er.reshape((n, 1))
    return _fill(nextPts, tracked), _fill(status, st), _fill(err, er)


@function
def buildOpticalFlowPyramid(
    img,
    winSize,
    maxLevel,
    pyramid=None,
    withDerivatives=False,
    pyrBorder=_BORDER_REFLECT_101,
    derivBorder=_BORDER_CONSTANT,
    tryReuseInputImage=True,
    *,
    backend=None,
):
    """``cv2.buildOpticalFlowPyramid``: returns (retval, pyramid).

    ``retval`` is the highest level built (``maxLevel`` limited as OpenCV limits it),
    ``pyramid`` a tuple of ``retval + 1`` uint8 levels (no border padding). Only
    ``withDerivatives=False`` is supported (cv2 defaults to True; the derivative levels are
    of no use to :func:`calcOpticalFlowPyrLK` here, which differentiates on the fly),
    ``pyrBorder=BORDER_REFLECT_101`` and ``derivBorder=BORDER_CONSTANT``; others raise
    :class:`warpvx.UnsupportedError`. ``pyramid`` and ``tryReuseInputImage`` are accepted and
    ignored.
    """
    if withDerivatives:
        raise UnsupportedError(
            "withDerivatives: only False is supported (pyramids without derivative levels)"
        )
    if pyrBorder != _BORDER_REFLECT_101:
        raise UnsupportedError(f"pyrBorder: only BORDER_REFLECT_101 (4) is supported, got {pyrBorder!r}")
    if derivBorder != _BORDER_CONSTANT:
        raise UnsupportedError(f"derivBorder: only BORDER_CONSTANT (0) is supported, got {derivBorder!r}")
    levels = build_optical_flow_pyramid(contiguous(img), winSize, maxLevel, backend=backend)
    return len(levels) - 1, tuple(levels)


def _check_flags(flags) -> int:
    if isinstance(flags, bool) or not isinstance(flags, numbers.Integral):
        raise WarpvxTypeError(f"flags: expected an integer, got {type(flags).__name__} {flags!r}")
    flags = int(flags)
    if flags & OPTFLOW_LK_GET_MIN_EIGENVALS:
        raise UnsupportedError("flags: OPTFLOW_LK_GET_MIN_EIGENVALS is not supported (err is the mean difference)")
    if flags & ~OPTFLOW_USE_INITIAL_FLOW:
        raise UnsupportedError(f"flags: expected 0 or OPTFLOW_USE_INITIAL_FLOW (4), got {flags}")
    return flags


def _criteria(criteria):
    """OpenCV's reading of (type, maxCount, epsilon): defaults for the parts not flagged."""
    try:
        kind, count, eps = criteria
    except (TypeError, ValueError):
        raise WarpvxTypeError(f"criteria: expected (type, maxCount, epsilon), got {criteria!r}") from None
    if isinstance(kind, bool) or not isinstance(kind, numbers.Integral) or not 0 <= int(kind) <= 3:
        raise WarpvxValueError(f"criteria: type must be a combination of TERM_CRITERIA_COUNT and _EPS, got {kind!r}")
    max_iters = min(max(int(count), 0), 100) if kind & TERM_CRITERIA_COUNT else _DEFAULT_ITERS
    if kind & TERM_CRITERIA_EPS:
        if not isinstance(eps, numbers.Real) or not np.isfinite(eps):
            raise WarpvxValueError(f"criteria: epsilon must be a finite number, got {eps!r}")
        eps = min(max(float(eps), 0.0), 10.0)
    else:
        eps = _DEFAULT_EPS
    return max_iters, eps


def _levels(x):
    """An image, or the image levels of a pyramid (derivative levels, int16 HxWx2, dropped)."""
    if isinstance(x, (list, tuple)):
        levels = [contiguous(as_input(v, "pyramid level")) for v in x]
        return [v for v in levels if not (len(v.shape) == 3 and v.shape[2] == 2)]
    return contiguous(x)


def _fill(dst, value):
    """Write into cv2-style output arguments when given with the right shape (else return)."""
    if isinstance(dst, np.ndarray) and isinstance(value, np.ndarray) and dst.shape == value.shape \
            and dst.dtype == value.dtype:
        np.copyto(dst, value)
        return dst
    if is_warp_array(dst) and is_warp_array(value) and tuple(dst.shape) == tuple(value.shape) \
            and dst.dtype == value.dtype:
        import warp as wp

        wp.copy(dst, value)
        return dst
    return value


__all__ = [
    "calcOpticalFlowPyrLK",
    "buildOpticalFlowPyramid",
    "TERM_CRITERIA_COUNT",
    "TERM_CRITERIA_MAX_ITER",
    "TERM_CRITERIA_EPS",
    "OPTFLOW_USE_INITIAL_FLOW",
    "OPTFLOW_LK_GET_MIN_EIGENVALS",
]
