"""Benchmark cases of :func:`warpvx.harris_response`."""

from __future__ import annotations

import numpy as np

from ...features import harris_response
from ..inputs import gray_of
from . import BenchCase, place


def cases(image_bgr: np.ndarray) -> list[BenchCase]:
    """Harris response, block 2, Sobel 3; OpenCV's cornerHarris (and Kornia) beside it."""
    gray = gray_of(image_bgr)
    h, w = gray.shape

    def prepare(backend_name):
        src = place(gray, backend_name)
        out = place(np.empty((h, w), np.float32), backend_name)
        return lambda: harris_response(src, 2, 3, 0.04, out=out, backend=backend_name)

    def opencv():
        import cv2

        dst = np.empty((h, w), np.float32)
        return lambda: cv2.cornerHarris(gray, 2, 3, 0.04, dst=dst)

    def kornia_peer():
        import kornia  # noqa: F401 - ImportError skips the peer
        import torch

        if not torch.cuda.is_available():
            raise ImportError("kornia peer needs CUDA")
        t = torch.from_numpy(gray).cuda().float().div_(255.0)[None, None]
        return lambda: kornia.feature.harris_response(t, k=0.04, grads_mode="sobel")

    return [BenchCase("harris_response", "block 2, ksize 3", (w, h), prepare, opencv,
                      peers={"kornia": kornia_peer}, bytes_moved=h * w * 5)]
