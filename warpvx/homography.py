"""Homography estimation from point correspondences: RANSAC (OpenCV's ``findHomography``).

:func:`find_homography` validates its arguments and dispatches to ``warpvx.kernels_cpu``
(``cv2.findHomography``) or ``warpvx.kernels_warp`` (every RANSAC hypothesis drawn and scored
in parallel on the device, then a least-squares refinement on the inliers); see
:mod:`warpvx.registry`.
"""

from __future__ import annotations

import numpy as np

from .arrays import numpy_dtype
from .backend import resolve_backend
from .check import check_array, check_choice, check_float, check_int, check_outs
from .errors import DTypeError, ShapeError, WarpvxValueError
from .registry import dispatch

MAX_ITERS_LIMIT = 100_000  # hypotheses per call at most (the Warp path keeps them all)
SEED_LIMIT = 2**31 - 1  # Warp's generator takes a 32-bit signed seed


def find_homography(src_pts, dst_pts, *, method="ransac", ransac_reproj_threshold=3.0,
                    max_iters=2000, confidence=0.995, seed=0, out=None, backend=None,
                    stream=None) -> tuple:
    """The homography H mapping ``src_pts`` onto ``dst_pts``, robust to outliers (RANSAC).

    A point p = (x, y) maps to H(p) = (h00 x + h01 y + h02, h10 x + h11 y + h12) /
    (h20 x + h21 y + h22). A correspondence is an inlier when its squared reprojection error
    |dst - H(src)|^2 <= ``ransac_reproj_threshold``^2 (pixels). RANSAC draws minimal samples
    of 4 correspondences (rejecting collinear ones and ones whose triangles flip orientation
    between the images), fits H to each, keeps the one with the most inliers, refits H to all
    its inliers by least squares and refines it by Levenberg-Marquardt on the reprojection
    error (Hartley & Zisserman, *Multiple View Geometry*, 2nd ed., §4.7-4.8).

    Parameters
    ----------
    src_pts, dst_pts : array
        float32 or float64 [N, 2] (or [N, 1, 2], OpenCV's layout) points (x, y) in pixels,
        both of one dtype, N >= 4, NumPy or device arrays. Host arrays must be finite;
        device arrays are not read back: a NaN or inf device point is never an inlier.
    method : str
        ``"ransac"`` (the only method).
    ransac_reproj_threshold : float
        Inlier threshold in pixels, > 0.
    max_iters : int
        RANSAC hypotheses, 1 to :data:`MAX_ITERS_LIMIT`. The CPU backend (OpenCV) stops
        early once ``confidence`` is reached; the Warp backends draw and score all of them at
        once, in parallel.
    confidence : float in (0, 1)
        OpenCV's stopping confidence (CPU backend only, see ``max_iters``).
    seed : int
        Seeds the Warp backends' sample generator (0 to 2^31 - 1): one seed, one result,
        on every run. OpenCV's RANSAC draws from a generator of its own with a fixed seed,
        so the CPU backend is deterministic and ignores it.
    out : tuple, optional
        (H float64 [3, 3], mask uint8 [N]) to fill, on the backend's side.
    backend, stream
        See :mod:`warpvx.backend`.

    Returns
    -------
    H : array
        float64 [3, 3], normalised so that H[2, 2] = 1. **No model** (every sample
        degenerate, e.g. all points collinear, or OpenCV finding none): H is all zeros
        (H[2, 2] == 0 tells it apart from any homography) and the mask is all 0. This result
        needs no host sync on the GPU and fits ``out=``; ``warpvx.cv.findHomography`` turns
        it into OpenCV's ``None``.
    mask : array
        uint8 [N], 1 for inliers. The CPU backend returns OpenCV's (the inliers of the best
        RANSAC sample); the Warp backends mark the inliers of the final, refined H.
        Of the kind of ``src_pts`` (NumPy or ``wp.array``).

    Raises
    ------
    DTypeError, ShapeError, WarpvxValueError
        Points not float32/float64 [N, 2], of two dtypes, of different counts, fewer than 4,
        or NaN/inf in host arrays; bad ``out``.
    UnsupportedError
        ``method`` other than ``"ransac"``.
    WarpvxTypeError, WarpvxValueError
        ``ransac_reproj_threshold`` <= 0, ``max_iters`` outside [1, MAX_ITERS_LIMIT],
        ``confidence`` outside (0, 1), ``seed`` outside [0, 2^31 - 1].

    Notes
    -----
    Reference: ``cv2.findHomography(src_pts, dst_pts, cv2.RANSAC, ransac_reproj_threshold,
    maxIters=max_iters, confidence=confidence)``, which the CPU backend calls. The Warp
    backends sample with a counter-based generator (``wp.rand_init(seed, hypothesis)``), so
    they draw other samples than OpenCV; on real matches their H agrees with OpenCV's within
    a pixel at the image corners (tests/kernels/test_find_homography.py).
    """
    be = resolve_backend(backend, like=src_pts)
    check_choice(method, "method", ("ransac",))
    threshold = check_float(ransac_reproj_threshold, "ransac_reproj_threshold", min_value=0.0,
                            strict_min=True)
    max_iters = check_int(max_iters, "max_iters", min_value=1, max_value=MAX_ITERS_LIMIT)
    confidence = check_float(confidence, "confidence", min_value=0.0, strict_min=True)
    if confidence >= 1.0:
        raise WarpvxValueError(f"confidence: expected a value < 1, got {confidence}")
    seed = check_int(seed, "seed", min_value=0, max_value=SEED_LIMIT)
    src = _check_points(src_pts, "src_pts")
    dst = _check_points(dst_pts, "dst_pts")
    if dst.shape[0] != src.shape[0]:
        raise ShapeError(f"dst_pts: expected {src.shape[0]} points (as src_pts), got {dst.shape[0]}")
    if dst.dtype != src.dtype:
        raise DTypeError(f"dst_pts: expected dtype {numpy_dtype(src)} (as src_pts), got "
                         f"{numpy_dtype(dst)}")
    if out is not None:
        out = _check_out(out, src.shape[0])
    return dispatch("find_homography", be, src, dst, threshold, max_iters, confidence, seed,
                    out=out, stream=stream, template=src_pts)


def _check_points(p, name):
    """float32/float64 [N, 2] or [N, 1, 2] with N >= 4, finite when on the host; as [N, 2]."""
    arr = check_array(p, name, dtypes=(np.float32, np.float64))
    shape = tuple(arr.shape)
    if not ((len(shape) == 2 and shape[1] == 2) or (len(shape) == 3 and shape[1:] == (1, 2))):
        raise ShapeError(f"{name}: expected shape Nx2 or Nx1x2, got {shape}")
    if shape[0] < 4:
        raise ShapeError(f"{name}: expected at least 4 points (a homography has 8 degrees of "
                         f"freedom), got {shape[0]}")
    if isinstance(arr, np.ndarray) and not np.all(np.isfinite(arr)):
        raise WarpvxValueError(f"{name}: contains NaN or inf")
    return arr.reshape((shape[0], 2)) if len(shape) == 3 else arr


def _check_out(out, n):
    try:
        h, mask = out
    except (TypeError, ValueError):
        raise WarpvxValueError(f"out: expected a pair (H, mask), got {type(out).__name__}") from None
    return check_outs((h, mask), [("H", (3, 3), (np.float64,)), ("mask", (n,), (np.uint8,))])


__all__ = ["find_homography", "MAX_ITERS_LIMIT"]
