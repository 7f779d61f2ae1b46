"""What the two pyramid primitives' benchmark cases share: buffers per level, the bytes a
pyramid moves, and the OpenCV / CV-CUDA / Kornia level-by-level loops."""

from __future__ import annotations

import numpy as np

from . import place


def level_shape(img, size):
    """Array shape of ``img`` at ``size`` = (width, height), channels kept."""
    return (size[1], size[0]) + tuple(img.shape[2:])


def pyramid_bytes(img, sizes) -> int:
    """Bytes read plus written building levels 1.. of ``sizes`` from ``img``'s level 0."""
    per_pixel = img.nbytes // (img.shape[0] * img.shape[1])
    areas = [w * h for w, h in sizes]
    return per_pixel * sum(areas[i - 1] + areas[i] for i in range(1, len(areas)))


def prepare_pyramid(fn, img, sizes, args):
    """``prepare(backend)`` for ``fn(src, *args, out=levels)`` (levels preallocated)."""
    def prepare(backend):
        src = place(img, backend)
        out = [src] + [place(np.empty(level_shape(img, s), np.uint8), backend) for s in sizes[1:]]
        return lambda: fn(src, *args, out=out, backend=backend)
    return prepare


def opencv_pyramid(img, sizes, kind):
    """OpenCV's loop: ``cv2.pyrDown`` (``kind="pyrdown"``) or ``cv2.resize`` INTER_LINEAR."""
    def prepare():
        import cv2

        bufs = [np.empty(level_shape(img, s), np.uint8) for s in sizes[1:]]

        def run():
            prev = img
            for s, dst in zip(sizes[1:], bufs):
                if kind == "pyrdown":
                    prev = cv2.pyrDown(prev, dst=dst, dstsize=s)
                else:
                    prev = cv2.resize(prev, s, dst=dst, interpolation=cv2.INTER_LINEAR)
            return prev
        return run
    return prepare


def cvcuda_resize_pyramid(img, sizes):
    """CV-CUDA's loop of ``resize_into`` (linear) into preallocated levels."""
    def prepare():
        import cvcuda
        import torch

        t = torch.from_numpy(img.reshape(1, img.shape[0], img.shape[1], -1)).cuda()
        levels = [cvcuda.as_tensor(t, "NHWC")]
        for w, h in sizes[1:]:
            levels.append(cvcuda.as_tensor(torch.empty((1, h, w, t.shape[3]), dtype=torch.uint8,
                                                       device="cuda"), "NHWC"))

        def run():
            for i in range(1, len(levels)):
                cvcuda.resize_into(levels[i], levels[i - 1], cvcuda.Interp.LINEAR)
        return run
    return prepare


def kornia_pyramid(img, sizes, kind):
    """Kornia's loop: ``pyrdown`` (``kind="pyrdown"``) or bilinear ``resize``, float32."""
    def prepare():
        import kornia
        import torch

        t = torch.from_numpy(img.reshape(img.shape[0], img.shape[1], -1)).cuda()
        x = t.permute(2, 0, 1)[None].float()

        def run():
            prev = x
            for w, h in sizes[1:]:
                if kind == "pyrdown":
                    prev = kornia.geometry.transform.pyrdown(prev, border_type="reflect")
                else:
                    prev = kornia.geometry.transform.resize(prev, (h, w), interpolation="bilinear",
                                                            antialias=False)
            return prev
        return run
    return prepare
