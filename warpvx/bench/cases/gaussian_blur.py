"""Benchmark cases of :func:`warpvx.gaussian_blur`."""

from __future__ import annotations

import numpy as np

from ...filters import gaussian_blur
from ..inputs import gray_of
from . import BenchCase, place


def cases(image_bgr: np.ndarray) -> list[BenchCase]:
    """5x5 sigma 1 (gray, BGR) and ORB's 7x7 sigma 2 (gray) blurs of ``image_bgr``'s size."""
    gray = gray_of(image_bgr)
    h, w = gray.shape
    return [BenchCase(
        primitive="gaussian_blur",
        label=label,
        size=(w, h),
        prepare=_prepare(img, k, s),
        opencv=_opencv(img, k, s),
        peers={"cvcuda": _cvcuda(img, k, s), "kornia": _kornia(img, k, s)},
        bytes_moved=2 * img.nbytes,
    ) for label, img, k, s in (
        ("5x5 s1 gray", gray, 5, 1.0),
        ("7x7 s2 gray (ORB)", gray, 7, 2.0),
        ("5x5 s1 BGR", np.ascontiguousarray(image_bgr), 5, 1.0),
    )]


def _prepare(img, k, s):
    def prepare(backend):
        src = place(img, backend)
        out = place(np.empty_like(img), backend)
        return lambda: gaussian_blur(src, k, s, out=out, backend=backend)
    return prepare


def _opencv(img, k, s):
    def prepare():
        import cv2

        dst = np.empty_like(img)
        return lambda: cv2.GaussianBlur(img, (k, k), s, dst=dst, borderType=cv2.BORDER_REFLECT_101)
    return prepare


def _cvcuda(img, k, s):
    def prepare():
        import cvcuda
        import torch

        t = torch.from_numpy(img.reshape(1, img.shape[0], img.shape[1], -1)).cuda()
        src = cvcuda.as_tensor(t, "NHWC")
        dst = cvcuda.as_tensor(torch.empty_like(t), "NHWC")
        return lambda: cvcuda.gaussian_into(dst, src, (k, k), (s, s), cvcuda.Border.REFLECT101)
    return prepare


def _kornia(img, k, s):
    def prepare():
        import kornia
        import torch

        t = torch.from_numpy(img.reshape(img.shape[0], img.shape[1], -1)).cuda()
        x = t.permute(2, 0, 1)[None].float()
        return lambda: kornia.filters.gaussian_blur2d(x, (k, k), (s, s), border_type="reflect")
    return prepare
