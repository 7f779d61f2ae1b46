"""Tiny implementations registered by tests/test_core.py to exercise dispatch alone."""

import numpy as np
import warp as wp


def invert_cpu(src, *, out=None):
    if out is None:
        out = np.empty_like(src)
    np.subtract(255, src, out=out)
    return out


@wp.kernel
def invert(a: wp.array2d(dtype=wp.uint8), b: wp.array2d(dtype=wp.uint8)):
    y, x = wp.tid()
    b[y, x] = wp.uint8(255) - a[y, x]


def invert_warp(src, *, out=None):
    if out is None:
        out = wp.empty(src.shape, dtype=wp.uint8, device=src.device)
    wp.launch(invert, dim=src.shape, inputs=[src], outputs=[out], device=src.device)
    return out
