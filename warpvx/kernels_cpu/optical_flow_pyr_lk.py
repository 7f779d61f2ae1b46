"""Pyramidal Lucas-Kanade sparse optical flow on the CPU: OpenCV's ``calcOpticalFlowPyrLK``."""

from __future__ import annotations

import cv2
import numpy as np


def optical_flow_pyr_lk(
    prev,
    next,  # noqa: A002 - OpenCV's name
    prev_pts: np.ndarray,
    next_pts,
    win_size,
    max_level: int,
    max_iters: int,
    eps: float,
    min_eig_threshold: float,
    *,
    out=None,
):
    """Track ``prev_pts`` from ``prev`` to ``next`` with ``cv2.calcOpticalFlowPyrLK``.

    ``prev``/``next``: gray uint8 HxW images or lists of pyramid levels (level 0 first).
    OpenCV's Python binding takes no pyramids, so for a list only level 0 is handed over and
    OpenCV rebuilds the levels with pyrDown (the same levels when the list was built by
    :func:`warpvx.build_optical_flow_pyramid`). ``max_level`` is already limited as OpenCV
    limits it. ``prev_pts``/``next_pts`` float32 [N, 2] (``next_pts`` the initial flow or
    None). Returns (next_pts float32 [N, 2], status uint8 [N], err float32 [N]); ``err`` is 0
    where ``status`` is 0 (OpenCV leaves it unset there). ``out``: the same triple to fill.
    """
    prev0 = prev[0] if isinstance(prev, (list, tuple)) else prev
    next0 = next[0] if isinstance(next, (list, tuple)) else next
    n = prev_pts.shape[0]
    if out is None:
        out = (
            np.empty((n, 2), np.float32),
            np.empty(n, np.uint8),
            np.empty(n, np.float32),
        )
    res, status, err = out
    if n == 0:
        return res, status, err

    flags = 0
    guess = None
    if next_pts is not None:
        flags = cv2.OPTFLOW_USE_INITIAL_FLOW
        guess = np.array(next_pts, dtype=np.float32).reshape(n, 1, 2)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, int(max_iters), float(eps))
    tracked, st, er = cv2.calcOpticalFlowPyrLK(
        prev0,
        next0,
        np.ascontiguousarray(prev_pts, dtype=np.float32).reshape(n, 1, 2),
        guess,
        winSize=(int(win_size[0]), int(win_size[1])),
        maxLevel=int(max_level),
        criteria=criteria,
        flags=flags,
        minEigThreshold=float(min_eig_threshold),
    )
    res[...] = tracked.reshape(n, 2)
    status[...] = st.reshape(n)
    err[...] = np.where(status != 0, er.reshape(n), np.float32(0))
    return res, status, err
