"""Shared separable filtering for Warp kernels: Gaussian blur and pyrDown.

Both are a separable integer filter over a uint8 image followed by one rounding shift, which
is how OpenCV computes them for 8-bit images, so the results are bit-exact:

- ``cv2.GaussianBlur`` (8-bit path, ``GaussianBlurFixedPoint``): each 1-D kernel is quantised to
  8 fractional bits (``ufixedpoint16``, sums to exactly 256, error diffusion from the tails to
  the centre); rows then columns are summed exactly and the result is
  ``(sum + 2^15) >> 16``;
- ``cv2.pyrDown``: the kernel [1 4 6 4 1] in both directions on every second pixel,
  ``(sum + 2^7) >> 8``.

The filter runs in two passes: horizontal sums of the source rows (exact integers: at most
255 * 256, so they fit uint16), then the vertical sum of those with the rounding shift. Two
ways, the same integers:

- fused (kernel radius <= :data:`FUSED_MAX_RADIUS`, every pyrDown): one launch, no
  intermediate in memory. A thread owns a small block of outputs (:data:`ROWS_PER_THREAD`
  rows by :data:`PIXELS_PER_THREAD` pixels, all channels); for each source row under the
  block it reads the pixels the block's taps span once, forms the exact horizontal sums and
  adds each, weighted, into every output row it feeds, all in registers. The kernel is
  specialised on its shape (:func:`fused_filter_kernel`), so loops unroll and tap indices are
  constants;
- two launches (larger radii): :data:`filter_rows` writes the horizontal sums into a uint16
  scratch image, :data:`filter_columns` finishes. The scratch comes from
  :func:`scratch_image`, one per shape, device, stream and thread, allocated once.

Images are addressed as 2-D ``rows x (width * channels)`` uint8 arrays (a colour image is
viewed that way); neighbouring threads read neighbouring bytes (coalesced). Borders use
OpenCV's integer codes (:mod:`warpvx.modes`: ``BORDER_CONSTANT`` reads 0,
``BORDER_REPLICATE``, ``BORDER_REFLECT``, ``BORDER_REFLECT_101``), resolved by :func:`filter_index` only where a
footprint leaves the image (once per thread and tap column, once per row): no input can read
out of bounds.

Calls with caller-owned buffers (``out=``, reused frame after frame) replay recorded launches
(:func:`warpvx.kernels_warp._launch.run_recorded`), which skips Warp's per-call argument
packing.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
import warp as wp

from .. import modes
from ._launch import array_key, run_direct, run_recorded, workspace
from ._sampling import BORDER_CONSTANT, BORDER_REFLECT_101, BORDER_REPLICATE, border_index

# Forward-only kernels: no adjoint code to generate and compile.
wp.set_module_options({"enable_backward": False})

BORDER_REFLECT = wp.constant(modes.BORDER_REFLECT)

#: Largest kernel radius (ksize up to 2 * 15 + 1 = 31); the two-pass kernels' unrolled tap
#: loops are written for it.
MAX_RADIUS = 15
taps16i = wp.types.vector(length=MAX_RADIUS + 1, dtype=wp.int32)

#: Largest radius (either axis) filtered by the fused one-launch kernel. On an H200 it beats
#: the two launches through the scratch image 4x at radius 3 and 2x at radius 7 (1920x1080);
#: past 7 its unrolled code and registers grow with the square of the radius.
FUSED_MAX_RADIUS = 7

#: Output rows and pixels per thread of the fused kernel, by (stride, channels): more rows
#: reuse each horizontal sum more often, more pixels share more of their source pixels (a
#: thread reads each once); fewer of either give more threads and fewer registers.
ROWS_PER_THREAD = {(1, 1): 8, (1, 3): 8, (1, 4): 8, (2, 1): 8, (2, 3): 8, (2, 4): 8}
PIXELS_PER_THREAD = {(1, 1): 4, (1, 3): 2, (1, 4): 2, (2, 1): 1, (2, 3): 1, (2, 4): 1}

#: Threads a launch should keep (enough warps per SM to hide memory latency): smaller images
#: get smaller blocks per thread (:func:`fit_block`).
MIN_THREADS = 32768

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
def read_row_sum(rows: wp.array2d(dtype=wp.uint16), p: int, xc: int, border: int) -> int:
    """Horizontal sum of row ``p`` (resolved under the border rule, 0 outside for constant)."""
    yy = filter_index(p, rows.shape[0], border)
    if yy < 0:
        return 0
    return int(rows[yy, xc])


@wp.func
def round_shift(s: int, shift: int) -> wp.uint8:
    """``(s + 2^(shift-1)) >> shift`` saturated to uint8 (``s`` >= 0)."""
    return wp.uint8(wp.min((s + ((1 << shift) >> 1)) >> shift, 255))


# --- fused kernel: one launch, horizontal sums kept in registers ----------------------------


@functools.cache
def fused_filter_kernel(stride: int, rx: int, ry: int, rows: int, pixels: int, channels: int, zeros: bool):
    """The fused separable filter, specialised on its shape.

    Launched over ``(ceil(dst_rows / rows), ceil(dst_width / pixels))``: thread (by, bx) writes
    every channel of output pixels ``bx*pixels ... + pixels - 1`` on output rows
    ``by*rows ... + rows - 1``. Per source row it covers (``(rows - 1) * stride + 2 ry + 1`` of
    them) it reads the ``(pixels - 1) * stride + 2 rx + 1`` source pixels its outputs' taps
    span once, forms each output column's exact horizontal sum and adds it, weighted, into
    every output row it feeds. All loops are unrolled and all tap indices constant, so the
    sums live in registers; every source index is resolved before the loads, which are
    unconditional (the compiler can issue many at once). ``zeros``: the border is
    ``BORDER_CONSTANT`` (pixels outside read 0). ``pixels > 1`` requires that no output column
    is stepped by pyrDown's right-border rule (``edge_x``). Compiled on first use, in a module
    of its own.
    """
    span = (pixels - 1) * stride + 2 * rx + 1
    window = (rows - 1) * stride + 2 * ry + 1
    spanvec = wp.types.vector(length=span, dtype=wp.int32)
    rowvec = wp.types.vector(length=window, dtype=wp.int32)
    valvec = wp.types.vector(length=span * channels, dtype=wp.int32)
    accvec = wp.types.vector(length=rows * pixels * channels, dtype=wp.int32)

    @wp.kernel(enable_backward=False, module="unique")
    def filter_separable_fused(
        src: wp.array2d(dtype=wp.uint8),
        kx: taps16i,
        ky: taps16i,
        border: int,
        shift: int,
        edge_x: int,
        dst: wp.array2d(dtype=wp.uint8),
    ):
        by, bx = wp.tid()
        width = src.shape[1] // wp.static(channels)
        height = src.shape[0]
        x0 = bx * wp.static(pixels)
        cx = x0 * wp.static(stride)
        if x0 > edge_x:
            # OpenCV's pyrDown steps its right-border table by one source pixel per output
            # pixel (not two); only a dstsize of w/2 + 1 reaches here (one pixel per thread).
            cx = edge_x * wp.static(stride) + (x0 - edge_x)
        # Where each spanned source pixel starts in its row and each covered source row is,
        # resolved once per thread; under the constant border one outside reads 0 ("keep" 0).
        left = cx - wp.static(rx)
        inside_x = left >= 0 and left + wp.static(span) <= width
        base = spanvec()
        keep_x = spanvec()
        for l in range(wp.static(span)):
            p = left + l
            kept = int(1)
            if not inside_x:
                p = filter_index(p, width, border)
                if p < 0:
                    p = 0
                    kept = 0
            base[l] = p * wp.static(channels)
            keep_x[l] = kept
        y0 = by * wp.static(rows)
        top = y0 * wp.static(stride) - wp.static(ry)
        inside_y = top >= 0 and top + wp.static(window) <= height
        row = rowvec()
        keep_y = rowvec()
        for t in range(wp.static(window)):
            yy = top + t
            kept = int(1)
            if not inside_y:
                yy = filter_index(yy, height, border)
                if yy < 0:
                    yy = 0
                    kept = 0
            row[t] = yy
            keep_y[t] = kept
        acc = accvec()
        for t in range(wp.static(window)):
            vals = valvec()
            for l in range(wp.static(span)):
                for c in range(wp.static(channels)):
                    v = int(src[row[t], base[l] + c])
                    if wp.static(zeros):
                        v = v * keep_x[l]
                    vals[wp.static(l * channels + c)] = v
            for q in range(wp.static(pixels)):
                for c in range(wp.static(channels)):
                    # Exact horizontal sum of output column (q, c) on source row t ...
                    h = int(0)
                    for k in range(wp.static(2 * rx + 1)):
                        h += kx[wp.static(abs(k - rx))] * vals[wp.static((q * stride + k) * channels + c)]
                    if wp.static(zeros):
                        h = h * keep_y[t]
                    # ... weighted into every output row whose window holds row t.
                    for i in range(wp.static(rows)):
                        if wp.static(0 <= t - i * stride <= 2 * ry):
                            a = wp.static((i * pixels + q) * channels + c)
                            acc[a] += ky[wp.static(abs(t - i * stride - ry))] * h
        for i in range(wp.static(rows)):
            y = y0 + i
            if y < dst.shape[0]:
                for q in range(wp.static(pixels)):
                    x = x0 + q
                    if x * wp.static(channels) < dst.shape[1]:
                        for c in range(wp.static(channels)):
                            a = wp.static((i * pixels + q) * channels + c)
                            dst[y, x * wp.static(channels) + c] = round_shift(acc[a], shift)

    return filter_separable_fused


# --- two-pass kernels: any radius, through a uint16 scratch image ---------------------------


@wp.kernel
def filter_rows(
    src: wp.array2d(dtype=wp.uint8),
    channels: int,
    kx: taps16i,
    rx: int,
    border: int,
    sums: wp.array2d(dtype=wp.uint16),
):
    """Exact horizontal sums (<= 255 * 256) of every source pixel, stride 1."""
    y, xc = wp.tid()
    x = xc // channels
    c = xc - x * channels
    width = src.shape[1] // channels
    s = kx[0] * int(src[y, xc])
    # Constant trip counts: Warp unrolls them, every kx[k] is a register; the uniform
    # k <= rx test skips unused taps.
    if x >= rx and x + rx < width:
        for k in range(1, 16):
            if k <= rx:
                s += kx[k] * (int(src[y, xc - k * channels]) + int(src[y, xc + k * channels]))
    else:
        for k in range(1, 16):
            if k <= rx:
                s += kx[k] * (read_tap(src, y, x - k, width, channels, c, border)
                              + read_tap(src, y, x + k, width, channels, c, border))
    sums[y, xc] = wp.uint16(s)


@wp.kernel
def filter_columns(
    sums: wp.array2d(dtype=wp.uint16),
    ky: taps16i,
    ry: int,
    border: int,
    shift: int,
    dst: wp.array2d(dtype=wp.uint8),
):
    """Vertical sums of :data:`filter_rows`' output and the rounding shift, stride 1."""
    y, xc = wp.tid()
    height = sums.shape[0]
    s = ky[0] * int(sums[y, xc])
    if y >= ry and y + ry < height:
        for k in range(1, 16):
            if k <= ry:
                s += ky[k] * (int(sums[y - k, xc]) + int(sums[y + k, xc]))
    else:
        for k in range(1, 16):
            if k <= ry:
                s += ky[k] * (read_row_sum(sums, y - k, xc, border) + read_row_sum(sums, y + k, xc, border))
    dst[y, xc] = round_shift(s, shift)


# --- host side: taps ------------------------------------------------------------------------


@dataclass(frozen=True)
class FilterTaps:
    """A symmetric separable integer filter: ``kx[|i|]`` for i in [-rx, rx], same for y.

    ``stride`` is the source step per output pixel (1: filter, 2: pyrDown); the output is
    ``(sum + 2^(shift-1)) >> shift`` saturated to uint8. ``key`` identifies the taps.
    """

    kx: object  # taps16i
    ky: object  # taps16i
    rx: int
    ry: int
    stride: int
    shift: int
    border: int
    key: tuple


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
def blur_taps(kx: int, ky: int, sigma_x: float, sigma_y: float, border: int) -> FilterTaps:
    """The taps of ``cv2.GaussianBlur(src, (kx, ky), sigma_x, sigmaY=sigma_y,
    borderType=border)`` (sigma_y already resolved: <= 0 means sigma_x, as OpenCV)."""
    hx, rx = _half(gaussian_kernel_q8(kx, sigma_x))
    hy, ry = _half(gaussian_kernel_q8(ky, sigma_y))
    return FilterTaps(hx, hy, rx, ry, 1, 16, int(border), ("blur", kx, ky, sigma_x, sigma_y, int(border)))


@functools.lru_cache(maxsize=1)
def pyr_down_taps() -> FilterTaps:
    """The taps of ``cv2.pyrDown``: [1 4 6 4 1] both ways, stride 2, REFLECT_101, shift 8."""
    h, r = _half(np.array([1, 4, 6, 4, 1]))
    return FilterTaps(h, h, r, r, 2, 8, int(BORDER_REFLECT_101), ("pyrdown",))


def pyr_down_edge(src_width: int, dst_width: int) -> int:
    """``width0`` of OpenCV's ``pyrDown_``: the first output column taken from its right-border
    table, ``min((w - 3) / 2 + 1, dw)`` with C's truncating division."""
    return min(int((src_width - 3) / 2) + 1, dst_width)


NO_EDGE = 1 << 30


def as_rows(a):
    """``(view, channels)``: an HxW array itself, an HxWxC array as an H x (W*C) view."""
    if a.ndim == 2:
        return a, 1
    h, w, c = a.shape
    return a.reshape((h, w * c)), c


def scratch_image(device, shape: tuple):
    """The uint16 scratch image of the two-pass filter: one per shape, device, stream and thread
    (a :func:`warpvx.kernels_warp._launch.workspace`), so calls sharing it run one after the
    other on one stream; allocated on first use, then reused."""
    return workspace("filter_rows", (tuple(shape),), device,
                     lambda: wp.empty(shape, dtype=wp.uint16, device=device))


def stream_key(device):
    """The current stream of ``device`` as a hashable handle (None on the CPU)."""
    return None if device.is_cpu else device.stream.cuda_stream


# --- host side: the filter ------------------------------------------------------------------


def uses_fused(taps: FilterTaps) -> bool:
    """Whether ``taps`` run in the fused one-launch kernel (else the two-pass kernels)."""
    return taps.stride != 1 or max(taps.rx, taps.ry) <= FUSED_MAX_RADIUS


def fit_block(rows: int, pixels: int, out_rows: int, out_cols: int, device) -> tuple[int, int]:
    """``(rows, pixels)`` per thread, on a GPU halved (rows first, down to 2, then pixels)
    while the launch over an ``out_rows x out_cols`` output would have fewer than
    :data:`MIN_THREADS` threads (the CPU runs threads in turn: it keeps the largest blocks)."""
    if device.is_cpu:
        return rows, pixels

    def threads(r, p):
        return ((out_rows + r - 1) // r) * ((out_cols + p - 1) // p)

    while rows > 2 and threads(rows, pixels) < MIN_THREADS:
        rows //= 2
    while pixels > 1 and threads(rows, pixels) < MIN_THREADS:
        pixels //= 2
    return rows, pixels


def filter_launches(src, taps: FilterTaps, out, edge_x: int = NO_EDGE) -> list:
    """The launches filtering ``src`` into ``out``: ``[(kernel, dim, inputs, outputs)]``."""
    src2d, channels = as_rows(src)
    dst2d, _ = as_rows(out)
    if uses_fused(taps):
        shape = (taps.stride, channels)
        rows, pixels = fit_block(ROWS_PER_THREAD.get(shape, 8), PIXELS_PER_THREAD.get(shape, 1),
                                 out.shape[0], out.shape[1], src.device)
        if edge_x < out.shape[1] - 1:
            pixels = 1  # a pixel stepped by pyrDown's right-border rule needs a thread of its own
        # One radius for both axes (the shorter axis' taps are zero-padded): fewer kernels to
        # compile, the same sums.
        radius = max(taps.rx, taps.ry)
        kernel = fused_filter_kernel(taps.stride, radius, radius, rows, pixels, channels,
                                     bool(taps.border == BORDER_CONSTANT))
        dim = ((out.shape[0] + rows - 1) // rows, (out.shape[1] + pixels - 1) // pixels)
        return [(kernel, dim, [src2d, taps.kx, taps.ky, taps.border, taps.shift, int(edge_x)], [dst2d])]
    # Only blurs (stride 1) have radii past FUSED_MAX_RADIUS.
    sums = scratch_image(src.device, src2d.shape)
    return [
        (filter_rows, src2d.shape, [src2d, channels, taps.kx, taps.rx, taps.border], [sums]),
        (filter_columns, dst2d.shape, [sums, taps.ky, taps.ry, taps.border, taps.shift], [dst2d]),
    ]


def launch_filter(src, taps: FilterTaps, out, edge_x: int = NO_EDGE, *, cache: bool = False):
    """Filter ``src`` into ``out`` (same channels; out's size sets the launch; ``out`` must
    not alias ``src``). ``taps`` from :func:`blur_taps` or :func:`pyr_down_taps`. Output
    columns after ``edge_x`` follow OpenCV's pyrDown right-border stepping (see
    :func:`pyr_down_edge`). ``cache``: replay recorded launches (caller-owned, reused buffers;
    see :func:`run_recorded`)."""
    device = src.device
    if cache:
        key = ("filter", taps.key, array_key(src), array_key(out), int(edge_x))
        if not uses_fused(taps):
            key += (stream_key(device),)  # the scratch image is per stream
        run_recorded(key, lambda: filter_launches(src, taps, out, edge_x), device)
    else:
        run_direct(filter_launches(src, taps, out, edge_x), device)
    return out


__all__ = [
    "BORDER_CONSTANT",
    "BORDER_REFLECT",
    "BORDER_REFLECT_101",
    "BORDER_REPLICATE",
    "FUSED_MAX_RADIUS",
    "FilterTaps",
    "MAX_RADIUS",
    "MIN_THREADS",
    "NO_EDGE",
    "PIXELS_PER_THREAD",
    "ROWS_PER_THREAD",
    "as_rows",
    "blur_taps",
    "filter_columns",
    "filter_index",
    "filter_launches",
    "fit_block",
    "filter_rows",
    "fused_filter_kernel",
    "gaussian_kernel_q8",
    "launch_filter",
    "pyr_down_edge",
    "pyr_down_taps",
    "scratch_image",
    "stream_key",
    "uses_fused",
]
