"""Sparse optical flow: pyramidal Lucas-Kanade (OpenCV's ``calcOpticalFlowPyrLK``).

:func:`optical_flow_pyr_lk` tracks points from one gray frame to the next, coarse to fine
over a Gaussian pyramid; :func:`build_optical_flow_pyramid` builds that pyramid once per
frame so a video loop hands each frame's pyramid to two calls (as ``next``, then as ``prev``).
"""

from __future__ import annotations

import numpy as np

from .backend import resolve_backend
from .check import check_array, check_float, check_image, check_int, check_outs, check_size
from .errors import ShapeError, WarpvxValueError
from ._counted import Counted, check_counted, is_counted
from .registry import dispatch

MAX_ITERS_LIMIT = 100  # OpenCV clamps the iteration count to [0, 100] ...
EPS_LIMIT = 10.0  # ... and the step threshold to [0, 10]


def optical_flow_pyr_lk(
    prev,
    next,  # noqa: A002 - OpenCV's name
    prev_pts,
    next_pts=None,
    win_size=(21, 21),
    max_level=3,
    max_iters=30,
    eps=0.01,
    min_eig_threshold=1e-4,
    *,
    out=None,
    backend=None,
    stream=None,
):
    """Track points from ``prev`` to ``next`` with pyramidal Lucas-Kanade.

    Parameters
    ----------
    prev, next : array or list of arrays
        Gray uint8 HxW frames of one size, or their pyramids as returned by
        :func:`build_optical_flow_pyramid` (lists of levels, level 0 first, each level
        ``((w + 1) // 2, (h + 1) // 2)`` of the one before), so a video loop builds each
        frame's pyramid once.
    prev_pts : array
        float32 [N, 2] (or [N, 1, 2]) points (x, y) in ``prev``, pixel centres at integers;
        NaN/inf are rejected in host arrays (device arrays are not read back: such a point
        comes back lost). Points whose window lies entirely outside the image are not an
        error: they come back with status 0, as in OpenCV. Warp backends also take a device
        :class:`~warpvx._counted.Counted` (a graph's corners: fixed rows, a device count):
        every row is tracked and the results are Counteds of that count.
    next_pts : array, optional
        float32 initial guesses in ``next``, shaped as ``prev_pts`` (OpenCV's
        ``OPTFLOW_USE_INITIAL_FLOW``); by default the search starts at ``prev_pts``.
    win_size : (int, int)
        Integration window (width, height), each at least 3 and at most the image size.
    max_level : int
        Highest pyramid level (0 = no pyramid). Limited as OpenCV limits it: the pyramid
        stops before a level whose width or height would not exceed the window; and by the
        levels given when pyramids are passed.
    max_iters, eps : int, float
        Stop criteria per level (OpenCV's ``TermCriteria(COUNT | EPS, max_iters, eps)``): at
        most ``max_iters`` steps (clamped to [0, 100]), or a step shorter than ``eps`` pixels
        (clamped to [0, 10]).
    min_eig_threshold : float
        A point is lost when the smaller eigenvalue of its window's gradient matrix, divided
        by the window area (gradients scaled as OpenCV's: Scharr / 32), is below this.
    out : tuple, optional
        (next_pts float32 [N, 2], status uint8 [N], err float32 [N]) to fill, or three
        Counteds of those rows (Warp backends): their counts receive the points' count.
    backend, stream
        See :mod:`warpvx.backend`.

    Returns
    -------
    next_pts : array
        float32 [N, 2] tracked positions (for lost points: the last estimate).
    status : array
        uint8 [N]: 1 where the point was tracked, 0 where it was lost (window out of the
        image, too flat a window, or the track left the image).
    err : array
        float32 [N]: mean absolute difference (gray levels) between the window around the
        point in ``prev`` and the one around the tracked point in ``next`` (OpenCV's default
        error); 0 where status is 0. Of the kind of ``prev_pts`` (NumPy or ``wp.array``).

    Raises
    ------
    DTypeError, ShapeError, WarpvxValueError, WarpvxTypeError
        Bad frames (dtype, channels, sizes differing between ``prev`` and ``next``, a broken
        pyramid), points (dtype, shape, NaN/inf in host arrays, counts), ``win_size`` (too
        small, larger than the image), ``max_level`` < 0, ``max_iters`` < 0, ``eps`` < 0, or
        ``out``.

    Notes
    -----
    Reference: ``cv2.calcOpticalFlowPyrLK(prev, next, prev_pts, next_pts, winSize=win_size,
    maxLevel=max_level, criteria=(TERM_CRITERIA_COUNT | TERM_CRITERIA_EPS, max_iters, eps),
    flags=0 or OPTFLOW_USE_INITIAL_FLOW, minEigThreshold=min_eig_threshold)``. The CPU backend
    calls it; the Warp kernels reproduce its fixed-point arithmetic (Scharr derivatives,
    14-bit bilinear weights, BORDER_REFLECT_101 image padding). Device point arrays are not read
    back to the host: a device point that is NaN or inf is returned lost (status 0) instead
    of raising, as any point whose window leaves the image.
    """
    first = prev[0] if isinstance(prev, (list, tuple)) and len(prev) else prev
    be = resolve_backend(backend, like=first)
    win = _check_win_size(win_size)
    max_level = check_int(max_level, "max_level", min_value=0)
    max_iters = min(check_int(max_iters, "max_iters", min_value=0), MAX_ITERS_LIMIT)
    eps = min(check_float(eps, "eps", min_value=0.0), EPS_LIMIT)
    min_eig_threshold = check_float(min_eig_threshold, "min_eig_threshold")

    prev, size, prev_levels = _check_frame(prev, "prev")
    next, next_size, next_levels = _check_frame(next, "next")
    if next_size != size:
        raise ShapeError(
            f"next: expected a frame of prev's size {size[0]}x{size[1]} (WxH), "
            f"got {next_size[0]}x{next_size[1]}"
        )
    _check_window_fits(win, size)
    levels = min(max_level, _level_limit(size, win, max_level), prev_levels - 1, next_levels - 1)

    if is_counted(prev_pts):  # a graph's corners: every row tracked, the count kept
        pts = Counted(check_counted(prev_pts, "prev_pts", (None, 2), (np.float32,)).rows,
                      prev_pts.count)
        n = pts.capacity
    else:
        pts = _check_points(prev_pts, "prev_pts")
        n = pts.shape[0]
    guess = None if next_pts is None else _check_points(next_pts, "next_pts", n)
    if out is not None:
        specs = [("next_pts", (n, 2), (np.float32,)), ("status", (n,), (np.uint8,)),
                 ("err", (n,), (np.float32,))]
        if isinstance(out, (tuple, list)) and all(map(is_counted, out)) and len(out) == 3:
            out = tuple(check_counted(o, f"out[{i}] ({label})", (None,) + shape[1:], dtypes)
                        for i, (o, (label, shape, dtypes)) in enumerate(zip(out, specs)))
            if any(o.capacity < n for o in out):
                raise ShapeError(f"out: Counted rows for at least {n} points, got "
                                 f"{[o.capacity for o in out]}")
        else:
            out = check_outs(out, specs)
    return dispatch(
        "optical_flow_pyr_lk",
        be,
        prev,
        next,
        pts,
        guess,
        win,
        levels,
        max_iters,
        eps,
        min_eig_threshold,
        out=out,
        stream=stream,
        template=pts,
    )


def build_optical_flow_pyramid(img, win_size=(21, 21), max_level=3, *, backend=None, stream=None):
    """Gaussian pyramid of a gray frame for :func:`optical_flow_pyr_lk`.

    Parameters
    ----------
    img : array
        Gray uint8 HxW (or HxWx1) frame, C-contiguous.
    win_size : (int, int)
        The LK window (width, height) the pyramid is for; each at least 3, at most the image.
    max_level : int
        Highest level wanted (>= 0). As OpenCV's ``buildOpticalFlowPyramid``, the pyramid
        stops before a level whose width or height would not exceed the window.
    backend, stream
        See :mod:`warpvx.backend`.

    Returns
    -------
    list of arrays
        ``L + 1`` uint8 levels (L <= max_level), level 0 the image itself, level k the pyrDown
        of level k-1 (5x5 [1 4 6 4 1]^2/256, BORDER_REFLECT_101, size ((w+1)//2, (h+1)//2)),
        of the input's kind. Unlike OpenCV, levels carry no border padding: the LK kernels
        reflect (BORDER_REFLECT_101) at read time.

    Raises
    ------
    DTypeError, ShapeError, WarpvxValueError, WarpvxTypeError
        Bad ``img``, ``win_size`` or ``max_level``.
    """
    be = resolve_backend(backend, like=img)
    img = _as_hw(check_image(img, "img", dtypes=(np.uint8,), channels=(1,)))
    win = _check_win_size(win_size)
    max_level = check_int(max_level, "max_level", min_value=0)
    size = (img.shape[1], img.shape[0])
    _check_window_fits(win, size)
    levels = _level_limit(size, win, max_level)
    return _pyramid(img, levels, be, stream)


# ---------------------------------------------------------------------------------------------
# helpers


def _level_limit(size, win, max_level: int) -> int:
    """OpenCV's level limit: stop before a level whose width or height <= the window's."""
    w, h = size
    for level in range(max_level):
        w, h = (w + 1) // 2, (h + 1) // 2
        if w <= win[0] or h <= win[1]:
            return level
    return max_level


def _check_win_size(win_size) -> tuple[int, int]:
    w, h = check_size(win_size, "win_size")
    if w < 3 or h < 3:
        raise WarpvxValueError(f"win_size: expected a window of at least 3x3, got {w}x{h}")
    return w, h


def _check_window_fits(win, size):
    if win[0] > size[0] or win[1] > size[1]:
        raise ShapeError(
            f"win_size: window {win[0]}x{win[1]} is larger than the {size[0]}x{size[1]} (WxH) image"
        )


def _as_hw(img):
    """HxWx1 -> HxW (a view)."""
    if img.ndim == 3:
        return img.reshape((img.shape[0], img.shape[1]))
    return img


def _check_frame(x, name):
    """A gray frame or a pyramid: (image or list of levels, (w, h) of level 0, level count)."""
    if isinstance(x, (list, tuple)):
        if len(x) == 0:
            raise ShapeError(f"{name}: expected an image or a non-empty list of pyramid levels, got []")
        levels = []
        for k, level in enumerate(x):
            lv = _as_hw(check_image(level, f"{name}[{k}]", dtypes=(np.uint8,), channels=(1,)))
            if k > 0:
                ph, pw = levels[-1].shape
                want = ((pw + 1) // 2, (ph + 1) // 2)
                got = (lv.shape[1], lv.shape[0])
                if got != want:
                    raise ShapeError(
                        f"{name}[{k}]: expected a pyramid level of {want[0]}x{want[1]} (WxH, half "
                        f"of level {k - 1} rounded up), got {got[0]}x{got[1]}"
                    )
            levels.append(lv)
        return levels, (levels[0].shape[1], levels[0].shape[0]), len(levels)
    img = _as_hw(check_image(x, name, dtypes=(np.uint8,), channels=(1,)))
    return img, (img.shape[1], img.shape[0]), 1 << 30


def _check_points(p, name, n=None):
    """float32 [N, 2] or [N, 1, 2], finite (checked for host arrays; device arrays are not
    read back: a non-finite device point comes back lost); returned as [N, 2]."""
    arr = check_array(p, name, dtypes=(np.float32,))
    if isinstance(arr, np.ndarray) and not np.all(np.isfinite(arr)):
        raise WarpvxValueError(f"{name}: contains NaN or inf")
    shape = tuple(arr.shape)
    if not ((len(shape) == 2 and shape[1] == 2) or (len(shape) == 3 and shape[1:] == (1, 2))):
        raise ShapeError(f"{name}: expected shape Nx2 or Nx1x2, got {shape}")
    if n is not None and shape[0] != n:
        raise ShapeError(f"{name}: expected {n} points (as prev_pts), got {shape[0]}")
    if len(shape) == 3:
        arr = arr.reshape((shape[0], 2))
    return arr


def _pyramid(img, max_level: int, be, stream) -> list:
    """Levels 0..max_level of ``img`` (level 0 is ``img`` itself) via :func:`warpvx.gaussian_pyramid`."""
    from .pyramid import gaussian_pyramid

    return gaussian_pyramid(img, max_level + 1, backend=be, stream=stream)
