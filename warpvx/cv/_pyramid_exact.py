"""OpenCV's ORB pyramid: each level ``cv2.resize(previous, size, INTER_LINEAR_EXACT)``.

OpenCV's ORB resizes with INTER_LINEAR_EXACT (``resize_bitExact`` with ``interpolationLinear``
on uint8), not the INTER_LINEAR of :func:`warpvx.scale_pyramid`; the two differ by 1 on many
pixels, which moves FAST corners. NumPy images use cv2 itself; device arrays a Warp kernel
with OpenCV's fixed-point arithmetic, bit-exact:

- source coordinate ``f = (d + 0.5) * scale - 0.5`` in double (``scale = src / dst``),
  ``i = floor(f)``; weight ``c = cvRound((f - i) * 256)`` (8 fractional bits, half to even);
  a coordinate left of 0 or at/after the last pixel is pinned there with ``c = 0``;
- ``H = p0 (256 - c) + p1 c`` along x (exact), then
  ``(H0 (256 - cy) + H1 cy + 2^15) >> 16`` along y.
"""

from __future__ import annotations

import functools

import cv2
import numpy as np

from ..backend import init_warp

_ONE = 256  # 1.0 in OpenCV's ufixedpoint16 (8 fractional bits)


def exact_taps(src_len: int, dst_len: int) -> np.ndarray:
    """int32 [dst_len, 3]: ``(i0, i1, c)`` per output index, OpenCV's interpolationLinear."""
    scale = 1.0 / (dst_len / src_len)
    f = scale * (np.arange(dst_len) + 0.5) - 0.5
    i = np.floor(f)
    c = np.rint((f - i) * _ONE).astype(np.int64)
    i = i.astype(np.int64)
    outside = (i < 0) | (i >= src_len - 1)
    i = np.clip(i, 0, src_len - 1)
    c[outside] = 0
    return np.stack([i, np.minimum(i + 1, src_len - 1), c], 1).astype(np.int32)


@functools.cache
def _kernel():
    wp = init_warp()

    @wp.kernel(enable_backward=False, module="unique")
    def resize_linear_exact(src: wp.array2d(dtype=wp.uint8), x_taps: wp.array(dtype=wp.vec3i),
                            y_taps: wp.array(dtype=wp.vec3i), dst: wp.array2d(dtype=wp.uint8)):
        y, x = wp.tid()
        tx = x_taps[x]
        ty = y_taps[y]
        h0 = int(src[ty[0], tx[0]]) * (256 - tx[2]) + int(src[ty[0], tx[1]]) * tx[2]
        h1 = int(src[ty[1], tx[0]]) * (256 - tx[2]) + int(src[ty[1], tx[1]]) * tx[2]
        dst[y, x] = wp.uint8((h0 * (256 - ty[2]) + h1 * ty[2] + 32768) >> 16)

    return resize_linear_exact


@functools.lru_cache(maxsize=128)
def _tables(device: str, src_size: tuple, dst_size: tuple):
    wp = init_warp()
    (sw, sh), (dw, dh) = src_size, dst_size
    return (wp.array(exact_taps(sw, dw), dtype=wp.vec3i, device=device),
            wp.array(exact_taps(sh, dh), dtype=wp.vec3i, device=device))


def resize_exact(src, size):
    """``cv2.resize(src, size, interpolation=INTER_LINEAR_EXACT)`` of a gray uint8 HxW image
    (NumPy: cv2 itself; ``wp.array``: the kernel, on its device). ``size`` is (w, h)."""
    if isinstance(src, np.ndarray):
        return cv2.resize(src, size, interpolation=cv2.INTER_LINEAR_EXACT)
    wp = init_warp()
    w, h = size
    dst = wp.empty((h, w), dtype=wp.uint8, device=src.device)
    x_taps, y_taps = _tables(str(src.device), (src.shape[1], src.shape[0]), (w, h))
    wp.launch(_kernel(), dim=(h, w), inputs=[src, x_taps, y_taps], outputs=[dst],
              device=src.device)
    return dst


def exact_pyramid(src, sizes) -> list:
    """Levels of ``sizes`` ((w, h) each, ``sizes[0]`` the image's): level 0 is ``src``, level l
    :func:`resize_exact` of level l - 1, as OpenCV's ORB builds them."""
    levels = [src]
    for size in sizes[1:]:
        levels.append(resize_exact(levels[-1], size))
    return levels


__all__ = ["exact_pyramid", "exact_taps", "resize_exact"]
