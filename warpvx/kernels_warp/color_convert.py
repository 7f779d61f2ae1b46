"""Warp colour conversion, one thread per output pixel (2-D launches).

Bit-exact with ``cv2.cvtColor`` for the codes of :mod:`warpvx.color` (integer arithmetic;
the formulas are in that module's docstring).
"""

from __future__ import annotations

import warp as wp

from ..color import code_spec, output_shape

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


def color_convert(src, code: int, *, out=None):
    """Convert ``src`` (a ``wp.array``, validated) with cv2 integer ``code``; returns ``out``
    when given, else a new array on ``src.device``."""
    spec = code_spec(code)
    shape = output_shape(code, tuple(src.shape))
    if out is None:
        out = wp.empty(shape, dtype=wp.uint8, device=src.device)
    dim = (shape[0], shape[1])
    # Output channel order is B,G,R unless swapped: then channel 0 reads/writes R.
    blue, red = (2, 0) if spec.swap_rb else (0, 2)
    if spec.kind == "gray":
        wp.launch(convert_color_to_gray, dim=dim, inputs=[src, blue, red], outputs=[out], device=src.device)
    elif spec.kind == "reorder":
        wp.launch(reorder_channels, dim=dim, inputs=[src, blue, red], outputs=[out], device=src.device)
    elif spec.kind == "expand":
        wp.launch(expand_gray, dim=dim, inputs=[src], outputs=[out], device=src.device)
    elif spec.kind == "nv":
        wp.launch(convert_nv_to_color, dim=dim, inputs=[src, spec.uv_first, blue, red], outputs=[out],
                  device=src.device)
    else:  # luma: the first H rows of the plane
        wp.launch(copy_luma, dim=dim, inputs=[src], outputs=[out], device=src.device)
    return out
