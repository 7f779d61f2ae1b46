"""Benchmark cases of :func:`warpvx.gaussian_pyramid`."""

from __future__ import annotations

import numpy as np

from ...pyramid import gaussian_pyramid, gaussian_pyramid_sizes
from ..inputs import gray_of
from . import BenchCase
from ._pyramids import kornia_pyramid, opencv_pyramid, prepare_pyramid, pyramid_bytes


def cases(image_bgr: np.ndarray) -> list[BenchCase]:
    """A 4-level gray pyramid (LK's) and one BGR pyrDown at ``image_bgr``'s size."""
    out = []
    for label, img, levels in (("4 levels gray (LK)", gray_of(image_bgr), 4),
                               ("pyrDown BGR", np.ascontiguousarray(image_bgr), 2)):
        h, w = img.shape[:2]
        sizes = gaussian_pyramid_sizes(w, h, levels)
        out.append(BenchCase(
            primitive="gaussian_pyramid",
            label=label,
            size=(w, h),
            prepare=prepare_pyramid(gaussian_pyramid, img, sizes, (levels,)),
            opencv=opencv_pyramid(img, sizes, "pyrdown"),
            peers={"kornia": kornia_pyramid(img, sizes, "pyrdown")},
            bytes_moved=pyramid_bytes(img, sizes),
        ))
    return out
