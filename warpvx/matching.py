"""Descriptor matching: brute-force Hamming distance (binary descriptors such as ORB's).

The public function validates its arguments and dispatches to ``warpvx.kernels_cpu`` (OpenCV's
``batchDistance``, what ``cv2.BFMatcher`` runs) or ``warpvx.kernels_warp`` (Warp kernels);
see :mod:`warpvx.registry`.
"""

from __future__ import annotations

import numbers

import numpy as np

from .backend import resolve_backend
from .check import check_array, check_bool, check_float, check_int, check_outs
from .errors import ShapeError, UnsupportedError, WarpvxTypeError
from .registry import dispatch

def _descriptors(desc1, desc2) -> tuple:
    desc1 = check_array(desc1, "desc1", dtypes=(np.uint8,), ndim=2)
    desc2 = check_array(desc2, "desc2", dtypes=(np.uint8,), ndim=2)
    if desc1.shape[1] == 0:
        raise ShapeError(f"desc1: expected descriptors of at least 1 byte, got shape "
                         f"{tuple(desc1.shape)}")
    if desc2.shape[1] != desc1.shape[1]:
        raise ShapeError(f"desc2: expected rows of {desc1.shape[1]} bytes like desc1, got shape "
                         f"{tuple(desc2.shape)}")
    return desc1, desc2


def match_hamming(desc1, desc2, cross_check: bool = False, ratio=None, *, backend=None,
                  stream=None) -> tuple:
    """Match each row of ``desc1`` (query) to a row of ``desc2`` (train) by Hamming distance.

    Brute force over every pair. The best train row of a query has the smallest distance, the
    lowest train index on a tie (as ``cv2.BFMatcher``). Without options every query is
    matched to its best train row.

    Parameters
    ----------
    desc1 : uint8 [N1, B]
        Query descriptors (ORB: B = 32), NumPy or device array.
    desc2 : uint8 [N2, B]
        Train descriptors, same B.
    cross_check : bool
        Keep only mutual best matches: query q's best train row t has q as its own best query
        (ties to the lowest index both ways), as ``cv2.BFMatcher(NORM_HAMMING,
        crossCheck=True)``.
    ratio : float in (0, 1], optional
        Lowe's ratio test: keep a match when its distance < ``ratio`` x the query's
        second-smallest distance (``knnMatch(k=2)``'s ``m.distance < ratio * n.distance``,
        in double). With a single train row there is no second distance and the match is kept.
        Combined with ``cross_check``, both must pass.
    backend, stream
        See :mod:`warpvx.backend`.

    Returns
    -------
    pairs : int32 [M, 2]
        (query index, train index), by increasing query index.
    distances : int32 [M]
        Hamming distance of each pair.

    Raises
    ------
    DTypeError, ShapeError
        A descriptor array that is not uint8 [N, B], or B differing between the two.
    WarpvxTypeError, WarpvxValueError
        ``cross_check`` not a bool, ``ratio`` outside (0, 1].

    Notes
    -----
    The Warp path syncs once, to read M. Reference: ``cv2.BFMatcher(cv2.NORM_HAMMING,
    crossCheck).match`` / ``knnMatch(k=2)``.
    """
    be = resolve_backend(backend, like=desc1)
    desc1, desc2 = _descriptors(desc1, desc2)
    check_bool(cross_check, "cross_check")
    if ratio is not None:
        if not isinstance(ratio, numbers.Real) or isinstance(ratio, bool):
            raise WarpvxTypeError(f"ratio: expected a number or None, got {type(ratio).__name__}")
        ratio = check_float(ratio, "ratio", min_value=0.0, max_value=1.0, strict_min=True)
    return dispatch("match_hamming", be, desc1, desc2, bool(cross_check), ratio, stream=stream)


def knn_match_hamming(desc1, desc2, k: int = 2, *, out=None, backend=None, stream=None) -> tuple:
    """The ``k`` nearest train rows of each query row by Hamming distance (k = 1 or 2).

    Parameters
    ----------
    desc1, desc2 : uint8 [N1, B], uint8 [N2, B]
        Query and train descriptors.
    k : int, 1 or 2
        Neighbours per query; capped at N2 (as ``cv2.BFMatcher.knnMatch``).
    out : (array, array), optional
        Writable int32 [N1, min(k, N2)] (indices, distances) to write the result into, NumPy or
        device arrays; returned.
    backend, stream
        See :mod:`warpvx.backend`.

    Returns
    -------
    indices : int32 [N1, min(k, N2)]
        Train indices, nearest first; ties to the lowest index (cv2's order).
    distances : int32 [N1, min(k, N2)]

    Raises
    ------
    UnsupportedError
        ``k`` > 2.
    WarpvxTypeError, ShapeError, DTypeError, WarpvxValueError
        ``out`` not a pair of arrays, or one of another shape or dtype, or read-only.
    """
    be = resolve_backend(backend, like=desc1)
    desc1, desc2 = _descriptors(desc1, desc2)
    k = check_int(k, "k", min_value=1)
    if k > 2:
        raise UnsupportedError(f"k: only k = 1 or 2 is supported, got {k}")
    k = min(k, int(desc2.shape[0]))
    if out is not None:
        shape = (int(desc1.shape[0]), k)
        out = check_outs(out, [("indices", shape, (np.int32,)), ("distances", shape, (np.int32,))])
    return dispatch("knn_match_hamming", be, desc1, desc2, k, out=out, stream=stream)


__all__ = ["match_hamming", "knn_match_hamming"]
