"""Warp remap: ``dst[y, x] = src(map_x[y, x], map_y[y, x])``, one thread per output pixel.

Sampling (nearest/bilinear, borders, rounding) is the shared code of
:mod:`warpvx.kernels_warp._sampling`, which follows ``cv2.remap`` (OpenCV >= 4.11, float32).
"""

from __future__ import annotations

import warp as wp

from ._sampling import sample_color_into, sample_gray

# Inference only: no adjoint kernels (halves JIT time). No implicit FMA contraction: the
# sampling code fuses explicitly where OpenCV does, so CPU and CUDA builds agree bit for bit.
wp.set_module_options({"enable_backward": False, "fuse_fp": False})


@wp.kernel
def remap_gray(
    src: wp.array2d(dtype=wp.uint8),
    map_x: wp.array2d(dtype=wp.float32),
    map_y: wp.array2d(dtype=wp.float32),
    interpolation: int,
    border: int,
    bval: float,
    dst: wp.array2d(dtype=wp.uint8),
):
    y, x = wp.tid()
    dst[y, x] = sample_gray(src, map_x[y, x], map_y[y, x], interpolation, border, bval)


@wp.kernel
def remap_color(
    src: wp.array3d(dtype=wp.uint8),
    map_x: wp.array2d(dtype=wp.float32),
    map_y: wp.array2d(dtype=wp.float32),
    interpolation: int,
    border: int,
    bval: wp.vec4,
    dst: wp.array3d(dtype=wp.uint8),
):
    y, x = wp.tid()
    sample_color_into(src, map_x[y, x], map_y[y, x], interpolation, border, bval, dst, y, x)


def remap(src, map_x, map_y, interpolation, border, border_value, *, out=None):
    """Remap a uint8 image on Warp.

    Parameters
    ----------
    src : wp.array
        uint8 HxW or HxWxC (C = 3, 4) source image.
    map_x, map_y : wp.array
        float32 arrays of the output's height and width: source x and y of each output pixel.
    interpolation : int
        0 nearest, 1 linear (OpenCV's INTER_* values).
    border : int
        0 constant, 1 replicate, 4 reflect101 (OpenCV's BORDER_* values).
    border_value : tuple of 4 float
        Per-channel border value, already saturated to [0, 255] integers.
    out : wp.array, optional
        uint8 output of shape ``map_x.shape`` (+ ``(C,)``) on ``src.device``.

    Returns
    -------
    wp.array
        The remapped image (``out`` when given).
    """
    h, w = map_x.shape
    if out is None:
        shape = (h, w) if src.ndim == 2 else (h, w, src.shape[2])
        out = wp.empty(shape, dtype=wp.uint8, device=src.device)
    if src.ndim == 2:
        wp.launch(
            remap_gray,
            dim=(h, w),
            inputs=[src, map_x, map_y, int(interpolation), int(border), float(border_value[0])],
            outputs=[out],
            device=src.device,
        )
    else:
        wp.launch(
            remap_color,
            dim=(h, w),
            inputs=[src, map_x, map_y, int(interpolation), int(border), wp.vec4(*border_value)],
            outputs=[out],
            device=src.device,
        )
    return out
