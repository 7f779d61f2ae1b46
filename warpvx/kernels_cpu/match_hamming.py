"""Brute-force Hamming matching on OpenCV (``cv2.batchDistance``, what cv2.BFMatcher runs).

The selection rules (shared with the Warp implementation, stated in
:func:`warpvx.matching.match_hamming`):

- best train per query: the smallest distance, the lowest train index on a tie;
- ``cross_check``: a query is kept when its best train row's best query is itself (mutual
  best, ties to the lowest index both ways), what ``cv2.BFMatcher(crossCheck=True)`` keeps;
- ``ratio``: kept when the pair's distance < ratio x the query's second-smallest distance
  (always kept when there is only one train row).
"""

from __future__ import annotations

import cv2
import numpy as np

from ..errors import UnsupportedError


def nearest(desc1: np.ndarray, desc2: np.ndarray, k: int) -> tuple:
    """(dist, idx) int32 [N1, k]: the k nearest rows of desc2 for each row of desc1."""
    return cv2.batchDistance(desc1, desc2, cv2.CV_32S, normType=cv2.NORM_HAMMING, K=k)


def knn_match_hamming(desc1: np.ndarray, desc2: np.ndarray, k: int, *, out=None) -> tuple:
    """(int32 [N1, k] train indices, int32 [N1, k] distances), nearest first, k <= N2;
    written into ``out`` = (indices, distances) when given."""
    nq = desc1.shape[0]
    if nq == 0 or k == 0:
        return out if out is not None else (np.zeros((nq, k), np.int32), np.zeros((nq, k), np.int32))
    dist, idx = nearest(desc1, desc2, k)
    if out is None:
        return np.ascontiguousarray(idx, np.int32), np.ascontiguousarray(dist, np.int32)
    np.copyto(out[0], idx)
    np.copyto(out[1], dist)
    return out


def match_hamming(desc1: np.ndarray, desc2: np.ndarray, cross_check: bool, ratio, *,
                  out=None) -> tuple:
    """Matches of desc1 (query) rows in desc2 (train): (int32 [M, 2] pairs, int32 [M] distances).

    Pairs are listed by increasing query index. ``out`` is refused: M depends on the data.
    """
    if out is not None:
        raise UnsupportedError("out: match_hamming returns a data-dependent number of pairs; "
                               "it takes no out=")
    nq, nt = desc1.shape[0], desc2.shape[0]
    if nq == 0 or nt == 0:
        return np.zeros((0, 2), np.int32), np.zeros(0, np.int32)
    k = 2 if ratio is not None and nt >= 2 else 1
    dist, idx = nearest(desc1, desc2, k)
    train, pair_dist = idx[:, 0].astype(np.int32), dist[:, 0].astype(np.int32)
    keep = train >= 0
    if cross_check:
        _, t_idx = nearest(desc2, desc1, 1)
        keep &= t_idx[train, 0] == np.arange(nq)
    if ratio is not None and k == 2:
        keep &= pair_dist.astype(np.float64) < float(ratio) * dist[:, 1].astype(np.float64)
    query = np.flatnonzero(keep).astype(np.int32)
    pairs = np.stack([query, train[keep]], axis=1).astype(np.int32)
    return np.ascontiguousarray(pairs), np.ascontiguousarray(pair_dist[keep], dtype=np.int32)


__all__ = ["match_hamming", "knn_match_hamming"]
