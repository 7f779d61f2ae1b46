"""Warp colour conversion, bit-exact with ``cv2.cvtColor`` for the codes of
:mod:`warpvx.color` (integer arithmetic; the formulas are in that module's docstring).

Two sets of kernels, same arithmetic:

- *quad* kernels, used when the output width is a multiple of 4 and both images start on a
  4-byte boundary: one thread converts 4 consecutive pixels of a row, reading and writing the
  rows as 32-bit words (a BGR quad is 3 words, a BGRA quad 4, a gray quad 1). Wide accesses
  keep enough bytes in flight per thread to run near the memory bandwidth (one byte per thread
  runs at a fraction of it). Inside a quad kernel each pixel is a *pixel word*: its channels
  in the bytes of a uint32, channel 0 in the low byte (alpha 255 for 3-channel sources);
- per-pixel kernels (one thread per output pixel) for every other width.

Launches go through :func:`warpvx.kernels_warp._launch.launch_cached` with non-owning views,
so a repeated call replays a recorded launch and the cache keeps no image alive.
"""

from __future__ import annotations

import warp as wp

from .._color_codes import code_spec, output_shape
from ._launch import array_key, as_view, as_words, launch_cached
from ._sampling import ALPHA, byte_of, load_quad, pack_bytes, store_quad

# BT.601 luma weights in 15-bit fixed point (sum 32768), OpenCV's RGB2Gray<uchar>.
GRAY_B = wp.constant(3735)
GRAY_G = wp.constant(19235)
GRAY_R = wp.constant(9798)
# BT.601 limited-range YUV->RGB in 20-bit fixed point, OpenCV's YUV420sp2RGB.
YUV_CY = wp.constant(1220542)
YUV_CUB = wp.constant(2116026)
YUV_CUG = wp.constant(-409993)
YUV_CVG = wp.constant(-852492)
YUV_CVR = wp.constant(1673527)
YUV_HALF = wp.constant(1 << 19)
# The bytes of a pixel word (see _sampling) that stay in place in an R/B swap.
KEEP_G_A = wp.constant(wp.uint32(0xFF00FF00))

# Inference only: no adjoint kernels (halves JIT time).
wp.set_module_options({"enable_backward": False})


@wp.func
def clamp_u8(v: int) -> wp.uint8:
    return wp.uint8(wp.clamp(v, 0, 255))


@wp.kernel
def convert_color_to_gray(
    src: wp.array3d(dtype=wp.uint8),
    blue: int,
    red: int,
    dst: wp.array2d(dtype=wp.uint8),
):
    y, x = wp.tid()
    b = int(src[y, x, blue])
    g = int(src[y, x, 1])
    r = int(src[y, x, red])
    # The weights sum to 2^15, so the result is at most 255: no clamp needed.
    dst[y, x] = wp.uint8((b * GRAY_B + g * GRAY_G + r * GRAY_R + (1 << 14)) >> 15)


@wp.kernel
def reorder_channels(
    src: wp.array3d(dtype=wp.uint8),
    blue: int,
    red: int,
    dst: wp.array3d(dtype=wp.uint8),
):
    y, x = wp.tid()
    dst[y, x, 0] = src[y, x, blue]
    dst[y, x, 1] = src[y, x, 1]
    dst[y, x, 2] = src[y, x, red]
    if dst.shape[2] == 4:
        if src.shape[2] == 4:
            dst[y, x, 3] = src[y, x, 3]
        else:
            dst[y, x, 3] = wp.uint8(255)


@wp.kernel
def expand_gray(src: wp.array2d(dtype=wp.uint8), dst: wp.array3d(dtype=wp.uint8)):
    y, x = wp.tid()
    v = src[y, x]
    dst[y, x, 0] = v
    dst[y, x, 1] = v
    dst[y, x, 2] = v
    if dst.shape[2] == 4:
        dst[y, x, 3] = wp.uint8(255)


@wp.kernel
def convert_nv_to_color(
    src: wp.array2d(dtype=wp.uint8),
    u_offset: int,
    blue: int,
    red: int,
    dst: wp.array3d(dtype=wp.uint8),
):
    y, x = wp.tid()
    h = dst.shape[0]
    row = h + y // 2
    col = (x // 2) * 2
    u = int(src[row, col + u_offset]) - 128
    v = int(src[row, col + 1 - u_offset]) - 128
    luma = wp.max(int(src[y, x]) - 16, 0) * YUV_CY
    dst[y, x, red] = clamp_u8((luma + YUV_CVR * v + YUV_HALF) >> 20)
    dst[y, x, 1] = clamp_u8((luma + YUV_CVG * v + YUV_CUG * u + YUV_HALF) >> 20)
    dst[y, x, blue] = clamp_u8((luma + YUV_CUB * u + YUV_HALF) >> 20)
    if dst.shape[2] == 4:
        dst[y, x, 3] = wp.uint8(255)


@wp.kernel
def copy_luma(src: wp.array2d(dtype=wp.uint8), dst: wp.array2d(dtype=wp.uint8)):
    y, x = wp.tid()
    dst[y, x] = src[y, x]


# --- quad kernels: 4 pixels per thread, rows read and written as 32-bit words ---------------


@wp.func
def swap_rb(p: wp.uint32) -> wp.uint32:
    """Exchange channels 0 and 2 of a pixel word."""
    low = (p & wp.uint32(0xFF)) << wp.uint32(16)
    high = (p >> wp.uint32(16)) & wp.uint32(0xFF)
    return (p & KEEP_G_A) | low | high


@wp.func
def gray_of(p: wp.uint32, w0: int, w2: int) -> int:
    """Luma of a pixel word with weight ``w0`` on channel 0 and ``w2`` on channel 2."""
    return (byte_of(p, 0) * w0 + byte_of(p, 1) * GRAY_G + byte_of(p, 2) * w2 + (1 << 14)) >> 15


@wp.kernel
def convert_quads_to_gray(
    src: wp.array2d(dtype=wp.uint32),
    channels: int,
    w0: int,
    w2: int,
    dst: wp.array2d(dtype=wp.uint32),
):
    y, q = wp.tid()
    p = load_quad(src, channels, y, q)
    dst[y, q] = pack_bytes(gray_of(p[0], w0, w2), gray_of(p[1], w0, w2), gray_of(p[2], w0, w2),
                           gray_of(p[3], w0, w2))


@wp.kernel
def reorder_quads(
    src: wp.array2d(dtype=wp.uint32),
    src_channels: int,
    swap: int,
    dst_channels: int,
    dst: wp.array2d(dtype=wp.uint32),
):
    y, q = wp.tid()
    p = load_quad(src, src_channels, y, q)
    if swap != 0:
        p = wp.vec4ui(swap_rb(p[0]), swap_rb(p[1]), swap_rb(p[2]), swap_rb(p[3]))
    store_quad(dst, dst_channels, y, q, p)


@wp.func
def gray_pixel(g: int) -> wp.uint32:
    return wp.uint32(g * 0x010101) | ALPHA


@wp.kernel
def expand_gray_quads(src: wp.array2d(dtype=wp.uint32), dst_channels: int, dst: wp.array2d(dtype=wp.uint32)):
    y, q = wp.tid()
    g = src[y, q]
    p = wp.vec4ui(gray_pixel(byte_of(g, 0)), gray_pixel(byte_of(g, 1)), gray_pixel(byte_of(g, 2)),
                  gray_pixel(byte_of(g, 3)))
    store_quad(dst, dst_channels, y, q, p)


@wp.func
def chroma_terms(u: int, v: int) -> wp.vec3i:
    """The chroma parts (plus rounding) of R, G and B for one U, V pair (minus 128), shared
    by the 2x2 pixels under it."""
    return wp.vec3i(YUV_CVR * v + YUV_HALF, YUV_CVG * v + YUV_CUG * u + YUV_HALF, YUV_CUB * u + YUV_HALF)


@wp.func
def yuv_pixel(luma: int, rgb: wp.vec3i, swap: int) -> wp.uint32:
    """BGR(A) pixel word of one NV pixel (RGB(A) when ``swap``) from its luma and the
    :func:`chroma_terms` of its U, V pair."""
    yy = wp.max(luma - 16, 0) * YUV_CY
    r = wp.clamp((yy + rgb[0]) >> 20, 0, 255)
    g = wp.clamp((yy + rgb[1]) >> 20, 0, 255)
    b = wp.clamp((yy + rgb[2]) >> 20, 0, 255)
    if swap != 0:
        return pack_bytes(r, g, b, 255)
    return pack_bytes(b, g, r, 255)


@wp.kernel
def convert_nv_quads(
    plane: wp.array2d(dtype=wp.uint32),
    height: int,
    u_offset: int,
    swap: int,
    dst_channels: int,
    dst: wp.array2d(dtype=wp.uint32),
):
    """Pixels 4q..4q+3 of output rows 2r and 2r + 1 per thread: the 4 pixels of each row
    share 2 chroma pairs, read once as one word."""
    r, q = wp.tid()
    # The chroma word under this quad: (U, V) or (V, U) of pixel pairs 2q and 2q + 1.
    cw = plane[height + r, q]
    c0 = chroma_terms(byte_of(cw, u_offset) - 128, byte_of(cw, 1 - u_offset) - 128)
    c1 = chroma_terms(byte_of(cw, 2 + u_offset) - 128, byte_of(cw, 3 - u_offset) - 128)
    for i in range(2):
        y = 2 * r + i
        lw = plane[y, q]
        p = wp.vec4ui(
            yuv_pixel(byte_of(lw, 0), c0, swap),
            yuv_pixel(byte_of(lw, 1), c0, swap),
            yuv_pixel(byte_of(lw, 2), c1, swap),
            yuv_pixel(byte_of(lw, 3), c1, swap),
        )
        store_quad(dst, dst_channels, y, q, p)


@wp.kernel
def copy_words(src: wp.array2d(dtype=wp.uint32), dst: wp.array2d(dtype=wp.uint32)):
    y, q = wp.tid()
    dst[y, q] = src[y, q]


# --- dispatch -------------------------------------------------------------------------------

_QUAD_KERNELS = {"gray": convert_quads_to_gray, "reorder": reorder_quads, "expand": expand_gray_quads,
                 "nv": convert_nv_quads, "luma": copy_words}
_PIXEL_KERNELS = {"gray": convert_color_to_gray, "reorder": reorder_channels, "expand": expand_gray,
                  "nv": convert_nv_to_color, "luma": copy_luma}


def color_convert(src, code: int, *, out=None):
    """Convert ``src`` (a ``wp.array``, validated) with cv2 integer ``code``; returns ``out``
    when given, else a new array on ``src.device``."""
    spec = code_spec(code)
    shape = output_shape(code, src.shape)
    if out is None:
        out = wp.empty(shape, dtype=wp.uint8, device=src.device)
    h, w = shape[0], shape[1]
    kind = spec.kind
    quads = w % 4 == 0 and src.ptr % 4 == 0 and out.ptr % 4 == 0
    kernel = (_QUAD_KERNELS if quads else _PIXEL_KERNELS)[kind]
    # NV quads cover two rows (the rows that share a chroma row).
    dim = ((h // 2 if kind == "nv" else h), w // 4) if quads else (h, w)

    def args():
        # Output channel order is B,G,R unless swapped: then channel 0 reads/writes R.
        swap = 1 if spec.swap_rb else 0
        if quads:
            src_c = 1 if src.ndim == 2 else src.shape[2]
            dst_c = 1 if len(shape) == 2 else shape[2]
            w0, w2 = (GRAY_R, GRAY_B) if swap else (GRAY_B, GRAY_R)
            scalars = {"gray": [src_c, w0, w2], "reorder": [src_c, swap, dst_c], "expand": [dst_c],
                       "nv": [h, spec.uv_first, swap, dst_c], "luma": []}[kind]
            # luma: the first H rows of the plane.
            return [as_words(src, h if kind == "luma" else None), *scalars], [as_words(out)]
        blue, red = (2, 0) if swap else (0, 2)
        scalars = {"gray": [blue, red], "reorder": [blue, red], "expand": [],
                   "nv": [spec.uv_first, blue, red], "luma": []}[kind]
        return [as_view(src), *scalars], [as_view(out)]

    launch_cached(kernel, dim, args, None, src.device, (array_key(src), array_key(out), code))
    return out
