"""The rotated-BRIEF kernel at integer level centres, shared by the ORB stage nodes
(:mod:`warpvx.kernels_warp.orb_stages`) and :class:`warpvx.cv.ORB` (:mod:`warpvx.cv._orb_levels`);
a module of its own so either compiles only this kernel."""

from __future__ import annotations

import warp as wp

from .funcs import describe_byte

# Forward-only kernels: no adjoint code to generate and compile.
wp.set_module_options({"enable_backward": False})


@wp.kernel
def describe_points(img: wp.array2d(dtype=wp.uint8), x: wp.array(dtype=wp.int32),
                    y: wp.array(dtype=wp.int32), angle: wp.array(dtype=wp.float32),
                    pattern: wp.array2d(dtype=wp.int32), desc: wp.array2d(dtype=wp.uint8)):
    """desc[i, j] (uint8 [N, 32]): byte ``j`` of the descriptor of point ``i``, centred at
    integer pixel (x[i], y[i]) of the blurred level ``img`` (uint8 [H, W]), rotated by
    angle[i] (degrees); ``pattern`` int32 [256, 4], the BRIEF point pairs."""
    i, j = wp.tid()
    desc[i, j] = wp.uint8(describe_byte(img, y[i], x[i], angle[i], pattern, j))
