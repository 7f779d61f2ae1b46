"""OpenCV's ORB pyramid work: levels resized INTER_LINEAR_EXACT, blurred, described.

OpenCV's ORB resizes with INTER_LINEAR_EXACT (``resize_bitExact`` with ``interpolationLinear``
on uint8), not the INTER_LINEAR of :func:`warpvx.scale_pyramid`, and blurs each level in
floating point (``GaussianBlur`` of an ROI of its bordered pyramid buffer takes the separable
float path, not the bit-exact fixed-point one :func:`warpvx.gaussian_blur` reproduces).
NumPy levels use cv2 itself (bit-exact); device arrays the kernels of
:mod:`warpvx.cv._orb_kernels`: the resize with OpenCV's fixed-point arithmetic, bit-exact,

- source coordinate ``f = (d + 0.5) * scale - 0.5`` in double (``scale = src / dst``),
  ``i = floor(f)``; weight ``c = cvRound((f - i) * 256)`` (8 fractional bits, half to even);
  a coordinate left of 0 or at/after the last pixel is pinned there with ``c = 0``;
- ``H = p0 (256 - c) + p1 c`` along x (exact), then
  ``(H0 (256 - cy) + H1 cy + 2^15) >> 16`` along y;

the blur in float32 in OpenCV's order (equal to cv2's but for a sum within float rounding of
a half, which OpenCV's SIMD may round the other way).
"""

from __future__ import annotations

import functools

import cv2
import numpy as np

from .._orb_spec import DESCRIPTOR_BYTES, PATTERN_RADIUS, pattern
from ..backend import init_warp
from ..kernels_cpu.orb import compute_descriptors, padded_centres

_ONE = 256  # 1.0 in OpenCV's ufixedpoint16 (8 fractional bits)
#: Margin around a blurred level: rotated pattern points land within PATTERN_RADIUS px of a
#: centre, and centres lie in the level.
MARGIN = PATTERN_RADIUS


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
def _gaussian7() -> np.ndarray:
    """float32 [7]: ``cv2.getGaussianKernel(7, 2, CV_32F)``, ORB's blur kernel."""
    return cv2.getGaussianKernel(7, 2, ktype=cv2.CV_32F).ravel()


@functools.lru_cache(maxsize=128)
def _on_device(device: str, what: str, *key):
    """Constant tables on a device, built once: resize taps, the blur kernel, the pattern."""
    wp = init_warp()
    if what == "taps":
        (sw, sh), (dw, dh) = key
        return (wp.array(exact_taps(sw, dw), dtype=wp.vec3i, device=device),
                wp.array(exact_taps(sh, dh), dtype=wp.vec3i, device=device))
    if what == "gaussian7":
        return wp.array(_gaussian7(), dtype=wp.float32, device=device)
    return wp.array(np.ascontiguousarray(pattern()), dtype=wp.int32, device=device)


def _launch(kernel, dim, inputs, out):
    wp = init_warp()
    wp.launch(kernel, dim=dim, inputs=inputs, outputs=[out], device=out.device)
    return out


def resize_exact(src, size):
    """``cv2.resize(src, size, interpolation=INTER_LINEAR_EXACT)`` of a gray uint8 HxW image
    (NumPy: cv2 itself; ``wp.array``: the kernel, on its device). ``size`` is (w, h)."""
    if isinstance(src, np.ndarray):
        return cv2.resize(src, size, interpolation=cv2.INTER_LINEAR_EXACT)
    from ._orb_kernels import resize_linear_exact

    w, h = size
    x_taps, y_taps = _on_device(str(src.device), "taps", (src.shape[1], src.shape[0]), (w, h))
    out = init_warp().empty((h, w), dtype=init_warp().uint8, device=src.device)
    return _launch(resize_linear_exact, (h, w), [src, x_taps, y_taps], out)


def exact_pyramid(src, sizes) -> list:
    """Levels of ``sizes`` ((w, h) each, ``sizes[0]`` the image's): level 0 is ``src``, level l
    :func:`resize_exact` of level l - 1, as OpenCV's ORB builds them."""
    levels = [src]
    for size in sizes[1:]:
        levels.append(resize_exact(levels[-1], size))
    return levels


def blur_level(level):
    """ORB's 7x7, sigma 2 Gaussian of a uint8 HxW level (BORDER_REFLECT_101, OpenCV's float
    separable filter: NumPy ``cv2.sepFilter2D``, ``wp.array`` the kernel) inside a margin of
    :data:`MARGIN` px holding the *unblurred* level reflected, as OpenCV's bordered pyramid
    does where a descriptor near the edge reads past the level."""
    k = _gaussian7()
    h, w = int(level.shape[0]), int(level.shape[1])
    if isinstance(level, np.ndarray):
        out = _reflected(level, MARGIN)
        out[MARGIN:MARGIN + h, MARGIN:MARGIN + w] = cv2.sepFilter2D(
            level, -1, k, k, borderType=cv2.BORDER_REFLECT_101)
        return out
    from ._orb_kernels import blur_columns7, blur_rows7

    wp = init_warp()
    k = _on_device(str(level.device), "gaussian7")
    rows = _launch(blur_rows7, (h, w), [level, k],
                   wp.empty((h, w), dtype=wp.float32, device=level.device))
    out = wp.empty((h + 2 * MARGIN, w + 2 * MARGIN), dtype=wp.uint8, device=level.device)
    return _launch(blur_columns7, out.shape, [level, rows, k, MARGIN], out)


def _reflected(img: np.ndarray, r: int) -> np.ndarray:
    """``img`` with ``r`` px of BORDER_REFLECT_101 (repeated reflection past a small image,
    as the Warp kernel's ``read_reflect101``)."""
    return padded_centres(img, np.zeros(0), np.zeros(0), r)[0].copy()


def describe(blurred, cx: np.ndarray, cy: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """uint8 [N, 32] rotated BRIEF (``WTA_K`` 2, the 31x31 pattern) at integer level centres
    (``cx``, ``cy`` int32) of a :func:`blur_level` result, angles in degrees; host result."""
    cx = np.ascontiguousarray(cx + MARGIN, np.int32)
    cy = np.ascontiguousarray(cy + MARGIN, np.int32)
    if isinstance(blurred, np.ndarray):
        return compute_descriptors(blurred, cx, cy, angle)
    from ..kernels_warp.orb.brief import describe_points

    wp = init_warp()
    device = blurred.device
    n = int(cx.shape[0])
    out = wp.empty((n, DESCRIPTOR_BYTES), dtype=wp.uint8, device=device)
    if n:
        args = [wp.array(a, dtype=t, device=device)
                for a, t in ((cx, wp.int32), (cy, wp.int32), (angle, wp.float32))]
        _launch(describe_points, (n, DESCRIPTOR_BYTES),
                [blurred, *args, _on_device(str(device), "pattern")], out)
    return out.numpy()


__all__ = ["MARGIN", "blur_level", "describe", "exact_pyramid", "exact_taps", "resize_exact"]
