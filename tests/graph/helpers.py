"""Helpers shared by the graph tests."""

from __future__ import annotations

import cv2
import numpy as np


def homography(prev_pts, next_pts, status):
    """The RANSAC homography of the points tracked (``status == 1``), the identity when fewer
    than 8 were tracked or OpenCV finds none: the user node of the parity graphs."""
    ok = status.reshape(-1) == 1
    if ok.sum() < 8:
        return np.eye(3)
    H, _ = cv2.findHomography(prev_pts[ok], next_pts[ok], cv2.RANSAC, 3.0)
    return np.eye(3) if H is None else H


def joined_pair(name: str, fn, names=("a", "b")):
    """A graph of two ``fn`` user nodes (``names``) on one float32 [4] input ``x``, joined by
    an ``np.add`` node ``join`` into output ``y`` (two CPU nodes a schedule may run side by
    side), and an input frame for it."""
    import warpvx

    g = warpvx.Graph(name)
    x = g.input("x", shape=(4,), dtype=np.float32)
    a = g.user(fn, [x], name=names[0])
    b = g.user(fn, [x], name=names[1])
    g.output("y", g.user(np.add, [a, b], name="join"))
    return g, {"x": np.zeros(4, np.float32)}
