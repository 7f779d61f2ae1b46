"""Benchmark cases of :func:`warpvx.scale_pyramid`."""

from __future__ import annotations

import numpy as np

from ...pyramid import scale_pyramid, scale_pyramid_sizes
from ..inputs import gray_of
from . import BenchCase
from ._pyramids import (cvcuda_resize_pyramid, kornia_pyramid, opencv_pyramid, prepare_pyramid,
                        pyramid_bytes)


def cases(image_bgr: np.ndarray) -> list[BenchCase]:
    """ORB-SLAM2's 8-level, 1.2 gray pyramid at ``image_bgr``'s size."""
    gray = gray_of(image_bgr)
    h, w = gray.shape
    sizes = scale_pyramid_sizes(w, h, 8, 1.2)
    return [BenchCase(
        primitive="scale_pyramid",
        label="8 levels x1.2 gray (ORB)",
        size=(w, h),
        prepare=prepare_pyramid(scale_pyramid, gray, sizes, (8, 1.2)),
        opencv=opencv_pyramid(gray, sizes, "resize"),
        peers={"cvcuda": cvcuda_resize_pyramid(gray, sizes),
               "kornia": kornia_pyramid(gray, sizes, "resize")},
        bytes_moved=pyramid_bytes(gray, sizes),
    )]
