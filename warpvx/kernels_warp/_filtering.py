"""Shared separable filtering for Warp kernels: Gaussian blur and pyrDown in one kernel.

Both are a separable integer filter over a uint8 image followed by one rounding shift, which
is how OpenCV computes them for 8-bit images, so the results are bit-exact:

- ``cv2.GaussianBlur`` (8-bit path, ``GaussianBlurFixedPoint``): each 1-D kernel is quantised to
  8 fractional bits (``ufixedpoint16``, sums to exactly 256, error diffusion from the tails to
  the centre); rows then columns are summed exactly and the result is
  ``(sum + 2^15) >> 16``;
- ``cv2.pyrDown``: the kernel [1 4 6 4 1] in both directions on every second pixel,
  ``(sum + 2^7) >> 8``.

Images are filtered as 2-D ``rows x (width * channels)`` uint8 arrays (a colour image is viewed
that way), so one kernel serves gray and interleaved colour images; taps step over
``channels`` elements. Borders use OpenCV's integer codes (``BORDER_CONSTANT`` reads 0,
``BORDER_REPLICATE``, ``BORDER_REFLECT``, ``BORDER_REFLECT_101``), resolved by
:func:`filter_index` before every read, so no input can read out of bounds.
"""

from __future__ import annotations

import functools
import math
import threading
from collections import OrderedDict

import numpy as np
import warp as wp

from ._sampling import BORDER_CONSTANT, BORDER_REFLECT_101, BORDER_REPLICATE, border_index

# Forward-only kernels: no adjoint code to generate and compile.
wp.set_module_options({"enable_backward": False})

BORDER_REFLECT = wp.constant(2)

#: Largest kernel radius the taps struct holds (ksize up to 2 * 15 + 1 = 31); filter_row's
#: unrolled loop is written for it.
MAX_RADIUS = 15
taps16i = wp.types.vector(length=MAX_RADIUS + 1, dtype=wp.int32)

BORDER_CODES = {
    "constant": 0, "replicate": 1, "reflect": 2, "reflect101": 4, "reflect_101": 4,
    0: 0, 1: 1, 2: 2, 4: 4,
}


@wp.struct
class FilterTaps:
    """A symmetric separable integer filter: ``kx[|i|]`` for i in [-rx, rx], same for y.

    ``stride`` is the source step per output pixel (1: filter, 2: pyrDown); the output is
    ``(sum + 2^(shift-1)) >> shift`` saturated to uint8.
    """

    kx: taps16i
    ky: taps16i
    rx: int
    ry: int
    stride: int
    shift: int
    border: int


@wp.func
def filter_index(p: int, n: int, border: int) -> int:
    """Index ``p`` on an axis of length ``n`` under ``border``; -1 reads 0 (constant)."""
    if p >= 0 and p < n:
        return p
    if border == BORDER_REFLECT:
        # fedcba|abcdefgh|hgfedcb: period 2n, the edge pixel repeated.
        period = 2 * n
        q = p % period
        if q < 0:
            q = q + period
        if q >= n:
            q = period - 1 - q
        return q
    return border_index(p, n, border)


@wp.func
def read_tap(src: wp.array2d(dtype=wp.uint8), yy: int, p: int, width: int, channels: int, c: int,
             border: int) -> int:
    """Channel ``c`` of pixel ``p`` of row ``yy`` under the border rule (0 outside for constant)."""
    xx = filter_index(p, width, border)
    if xx < 0:
        return 0
    return int(src[yy, xx * channels + c])


@wp.func
def filter_row(src: wp.array2d(dtype=wp.uint8), yy: int, cx: int, width: int, channels: int, c: int,
               taps: FilterTaps) -> int:
    """Horizontal integer sum of row ``yy`` around column ``cx``, symmetric taps paired."""
    s = taps.kx[0] * read_tap(src, yy, cx, width, channels, c, taps.border)
    # A constant trip count (MAX_RADIUS) so Warp unrolls it and every kx[k] is a register,
    # not a dynamically indexed local array; the uniform k <= rx test skips unused taps.
    for k in range(1, 16):
        if k <= taps.rx:
            s += taps.kx[k] * (read_tap(src, yy, cx - k, width, channels, c, taps.border)
                               + read_tap(src, yy, cx + k, width, channels, c, taps.border))
    return s


@wp.func
def filter_at(src: wp.array2d(dtype=wp.uint8), channels: int, cy: int, cx: int, c: int, taps: FilterTaps) -> int:
    """Exact integer filter sum of channel ``c`` centred on source pixel (cx, cy)."""
    height = src.shape[0]
    width = src.shape[1] // channels
    acc = int(0)
    for j in range(-taps.ry, taps.ry + 1):
        yy = filter_index(cy + j, height, taps.border)
        if yy >= 0:
            acc += taps.ky[wp.abs(j)] * filter_row(src, yy, cx, width, channels, c, taps)
    return acc


@wp.kernel
def filter_separable(
    src: wp.array2d(dtype=wp.uint8),
    channels: int,
    taps: FilterTaps,
    edge_x: int,
    dst: wp.array2d(dtype=wp.uint8),
):
    y, x = wp.tid()
    half = 1 << (taps.shift - 1)
    cx = x * taps.stride
    if x > edge_x:
        # OpenCV's pyrDown steps its right-border table by one source pixel per output
        # pixel (not two); only a dstsize of w/2 + 1 reaches here.
        cx = edge_x * taps.stride + (x - edge_x)
    for c in range(channels):
        s = filter_at(src, channels, y * taps.stride, cx, c, taps)
        dst[y, x * channels + c] = wp.uint8(wp.min((s + half) >> taps.shift, 255))


# --- host side ------------------------------------------------------------------------------


def gaussian_kernel_q8(ksize: int, sigma: float) -> np.ndarray:
    """OpenCV's 8-bit Gaussian kernel: int64 [ksize] in units of 1/256, summing to 256.

    Follows ``getGaussianKernelBitExact`` (fixed small kernels for sigma <= 0 and ksize <= 9,
    else ``exp(-x^2 / (2 sigma^2))`` normalised, sigma <= 0 meaning
    ``0.3 * ((ksize - 1) * 0.5 - 1) + 0.8``) and ``getGaussianKernelFixedPoint_ED`` (tails
    rounded half to even with error diffusion towards the centre, which takes the remainder).
    """
    n = int(ksize)
    fixed = {
        1: [1.0], 3: [0.25, 0.5, 0.25], 5: [0.0625, 0.25, 0.375, 0.25, 0.0625],
        7: [0.03125, 0.109375, 0.21875, 0.28125, 0.21875, 0.109375, 0.03125],
        9: [v / 256 for v in (4, 13, 30, 51, 60, 51, 30, 13, 4)],
    }
    if sigma <= 0 and n in fixed:
        k = fixed[n]
    else:
        s = sigma if sigma > 0 else n * 0.15 + 0.35
        scale2 = -0.125 / (s * s)
        n2 = (n - 1) // 2
        tails = [math.exp((x * x) * scale2) for x in range(1 - n, 0, 2)][:n2]
        mul = 1.0 / (2.0 * sum(tails) + 1.0)
        k = [t * mul for t in tails] + [mul] + [t * mul for t in reversed(tails)]
    res = np.zeros(n, np.int64)
    err = 0.0
    for i in range(n // 2):
        adj = k[i] * 256.0 + err
        v = int(np.rint(adj))
        err = adj - v
        res[i] = res[n - 1 - i] = v
    res[n // 2] = 256 - 2 * int(res[: n // 2].sum())
    return res


def _half(kernel: np.ndarray):
    """Centre-first half of a symmetric kernel, padded into a ``taps16i``."""
    r = len(kernel) // 2
    vals = [int(kernel[r + i]) for i in range(r + 1)] + [0] * (MAX_RADIUS - r)
    return taps16i(*vals), r


@functools.lru_cache(maxsize=64)
def blur_taps(kx: int, ky: int, sigma_x: float, sigma_y: float, border: int) -> tuple[FilterTaps, tuple]:
    """``(taps, key)`` of ``cv2.GaussianBlur(src, (kx, ky), sigma_x, sigmaY=sigma_y,
    borderType=border)`` (sigma_y already resolved: <= 0 means sigma_x, as OpenCV); ``key``
    identifies the taps for :func:`launch_cached`."""
    t = FilterTaps()
    t.kx, t.rx = _half(gaussian_kernel_q8(kx, sigma_x))
    t.ky, t.ry = _half(gaussian_kernel_q8(ky, sigma_y))
    t.stride = 1
    t.shift = 16
    t.border = int(border)
    return t, ("blur", kx, ky, sigma_x, sigma_y, int(border))


@functools.lru_cache(maxsize=1)
def pyr_down_taps() -> tuple[FilterTaps, tuple]:
    """``(taps, key)`` of ``cv2.pyrDown``: [1 4 6 4 1] both ways, stride 2, REFLECT_101,
    shift 8."""
    t = FilterTaps()
    t.kx, t.rx = _half(np.array([1, 4, 6, 4, 1]))
    t.ky, t.ry = _half(np.array([1, 4, 6, 4, 1]))
    t.stride = 2
    t.shift = 8
    t.border = int(BORDER_REFLECT_101)
    return t, ("pyrdown",)


def as_rows(a):
    """``(view, channels)``: an HxW array itself, an HxWxC array as an H x (W*C) view."""
    if a.ndim == 2:
        return a, 1
    h, w, c = a.shape
    return a.reshape((h, w * c)), c


def pyr_down_edge(src_width: int, dst_width: int) -> int:
    """``width0`` of OpenCV's ``pyrDown_``: the first output column taken from its right-border
    table, ``min((w - 3) / 2 + 1, dw)`` with C's truncating division."""
    return min(int((src_width - 3) / 2) + 1, dst_width)


NO_EDGE = 1 << 30


def launch_filter(src, taps, out, edge_x: int = NO_EDGE, *, cache: bool = False):
    """Run :data:`filter_separable` from ``src`` into ``out`` (same channels; out's size sets
    the launch). ``taps`` is a ``(FilterTaps, key)`` pair from :func:`blur_taps` or
    :func:`pyr_down_taps`. ``out`` must not alias ``src``. Output columns after ``edge_x``
    follow OpenCV's pyrDown right-border stepping (see :func:`pyr_down_edge`). ``cache``:
    replay a recorded launch (caller-owned, reused buffers; see :func:`launch_cached`)."""
    struct, key = taps
    src2d, channels = as_rows(src)
    dst2d, _ = as_rows(out)
    args = ([src2d, channels, struct, int(edge_x)], [dst2d])
    dim = (out.shape[0], out.shape[1])
    if cache:
        launch_cached(filter_separable, dim, *args, src.device,
                      (array_key(src2d), array_key(dst2d), channels, key, int(edge_x)))
    else:
        wp.launch(filter_separable, dim=dim, inputs=args[0], outputs=args[1], device=src.device)
    return out


# --- recorded launches ----------------------------------------------------------------------

_LAUNCHES: OrderedDict = OrderedDict()
_LAUNCHES_MAX = 32
_launches_lock = threading.Lock()


def array_key(a) -> tuple:
    """What a kernel sees of an array: pointer, shape, strides."""
    return (a.ptr, a.shape, a.strides)


def launch_cached(kernel, dim, inputs, outputs, device, key):
    """``wp.launch`` through a small cache of recorded launches (``record_cmd=True``).

    ``key`` must determine every parameter value (array pointers, shapes and strides, scalars,
    struct contents): replaying the recorded ``wp.Launch`` skips Warp's per-call argument
    packing (tens of microseconds of Python per launch) and still runs on the device's current
    stream, so it is captured into CUDA graphs like any launch. Meant for buffers reused
    frame after frame (``out=``); the cache keeps the arrays of its last
    ``_LAUNCHES_MAX`` entries alive.
    """
    full_key = (kernel.key, str(device), key)
    cmd = _LAUNCHES.get(full_key)
    if cmd is None:
        cmd = wp.launch(kernel, dim=dim, inputs=inputs, outputs=outputs, device=device, record_cmd=True)
        with _launches_lock:
            _LAUNCHES[full_key] = cmd
            while len(_LAUNCHES) > _LAUNCHES_MAX:
                _LAUNCHES.popitem(last=False)
    cmd.launch()


__all__ = [
    "BORDER_CODES",
    "BORDER_CONSTANT",
    "BORDER_REFLECT",
    "BORDER_REFLECT_101",
    "BORDER_REPLICATE",
    "FilterTaps",
    "MAX_RADIUS",
    "as_rows",
    "blur_taps",
    "filter_index",
    "filter_separable",
    "gaussian_kernel_q8",
    "array_key",
    "launch_cached",
    "launch_filter",
    "pyr_down_edge",
    "pyr_down_taps",
]
