"""Benchmark cases of :func:`warpvx.optical_flow_pyr_lk`."""

from __future__ import annotations

import numpy as np

from ...backend import resolve_backend
from ...flow import build_optical_flow_pyramid, optical_flow_pyr_lk
from ..inputs import gray_of
from . import BenchCase, place


def cases(image_bgr: np.ndarray) -> list[BenchCase]:
    """1000 Shi-Tomasi corners tracked between the gray photo and a slightly rotated and
    shifted copy (0.4 degrees, (1.7, -1.2) px), 21x21 window, ``max_level=3``.

    Two rows: both frames as images (each call builds both pyramids, as OpenCV does), and a
    video loop's step (the previous frame's pyramid is kept, the new frame's is built in
    the call). OpenCV's ``calcOpticalFlowPyrLK`` on the same data beside both.
    """
    import cv2

    gray = gray_of(image_bgr)
    h, w = gray.shape
    m = cv2.getRotationMatrix2D((w / 2.0, h / 2.0), 0.4, 1.0)
    m[:, 2] += (1.7, -1.2)
    moved = cv2.warpAffine(gray, m, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT_101)
    pts = cv2.goodFeaturesToTrack(gray, 1000, 0.01, 5).reshape(-1, 2).astype(np.float32)
    win, max_level = (21, 21), 3
    label = f"{len(pts)} pts, 21x21, max_level 3"

    def on_device(backend_name):
        """The backend, both frames, the points and ``out`` buffers (next_pts, status, err)."""
        be = resolve_backend(backend_name)
        n = len(pts)
        out = tuple(place(np.empty(shape, dtype), be)
                    for shape, dtype in (((n, 2), np.float32), (n, np.uint8), (n, np.float32)))
        return be, place(gray, be), place(moved, be), place(pts, be), out

    def prepare_images(backend_name):
        be, a, b, p, out = on_device(backend_name)
        return lambda: optical_flow_pyr_lk(a, b, p, None, win, max_level, out=out, backend=be)

    def prepare_video(backend_name):
        be, a, b, p, out = on_device(backend_name)
        prev_pyr = build_optical_flow_pyramid(a, win, max_level, backend=be)

        def step():
            next_pyr = build_optical_flow_pyramid(b, win, max_level, backend=be)
            return optical_flow_pyr_lk(prev_pyr, next_pyr, p, None, win, max_level, out=out, backend=be)

        return step

    def opencv():
        p = pts.reshape(-1, 1, 2)
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.01)
        return lambda: cv2.calcOpticalFlowPyrLK(
            gray, moved, p, None, winSize=win, maxLevel=max_level, criteria=criteria
        )

    return [
        BenchCase("optical_flow_pyr_lk", label, (w, h), prepare_images, opencv=opencv),
        BenchCase(
            "optical_flow_pyr_lk", label + ", video loop (one new pyramid)", (w, h), prepare_video, opencv=opencv
        ),
    ]
