"""Corner responses on Warp from the structure tensor: Harris and the minimum eigenvalue.

OpenCV's ``cornerEigenValsVecs`` (``modules/imgproc/src/corner.cpp``). For the usual Sobel
aperture 3 and blocks up to :data:`FUSED_MAX_BLOCK`, one kernel (``compute_response_sobel3``)
recomputes the few gradients each output pixel needs straight from the image (read through
the L1 cache; no intermediate image, no border logic away from the edges). Other apertures
use two kernels:

1. ``compute_gradient_products``: Sobel derivatives ``dx``, ``dy`` of aperture ``ksize``
   (1, 3, 5, 7) with BORDER_REFLECT_101, scaled by ``1 / (2^(ksize-1) * block_size * 255)``
   (OpenCV's scale for 8-bit input; ``2^0`` for ksize 1), stored as (dx*dx, dx*dy, dy*dy).
2. ``compute_corner_response``: unnormalised box sums of the products over ``block_size``
   x ``block_size`` (anchor at ``block_size // 2``, BORDER_REFLECT_101) giving the tensor
   (a, b, c), then Harris ``a*c - b*b - k*(a+c)^2`` or the minimum eigenvalue
   ``(a+c)/2 - sqrt(((a-c)/2)^2 + b^2)`` (``cv2.cornerMinEigenVal``).
"""

from __future__ import annotations

import warp as wp

from ._sampling import BORDER_REFLECT_101, border_index
from ._launch import Recorded, workspace

# Forward-only kernels: no adjoint code to generate and compile.
wp.set_module_options({"enable_backward": False})

vec7 = wp.types.vector(length=7, dtype=wp.int32)

# Sobel taps centred on index 3 (OpenCV's getSobelKernels, derivative order 1 and 0).
SMOOTH_1 = wp.constant(vec7(0, 0, 0, 1, 0, 0, 0))
SMOOTH_3 = wp.constant(vec7(0, 0, 1, 2, 1, 0, 0))
SMOOTH_5 = wp.constant(vec7(0, 1, 4, 6, 4, 1, 0))
SMOOTH_7 = wp.constant(vec7(1, 6, 15, 20, 15, 6, 1))
DERIV_3 = wp.constant(vec7(0, 0, -1, 0, 1, 0, 0))  # also ksize 1
DERIV_5 = wp.constant(vec7(0, -1, -2, 0, 2, 1, 0))
DERIV_7 = wp.constant(vec7(-1, -4, -5, 0, 5, 4, 1))

SCORE_HARRIS = wp.constant(0)
SCORE_MIN_EIGEN = wp.constant(1)
SCORES = {"harris": 0, "min_eigen": 1}


@wp.struct
class ResponseParams:
    """What turns gradients into a response: the ``block_size`` x ``block_size`` box of the
    structure tensor, the derivatives' ``scale`` (:func:`derivative_scale`), Harris ``k``, and
    ``score`` (:data:`SCORE_HARRIS` or :data:`SCORE_MIN_EIGEN`)."""

    block_size: int
    scale: float
    k: float
    score: int


@wp.func
def reflect101(p: int, n: int) -> int:
    """OpenCV's BORDER_REFLECT_101 index (gfedcb|abcdefgh|gfedcba), always in [0, n)."""
    return border_index(p, n, BORDER_REFLECT_101)


@wp.func
def smooth_tap(ksize: int, i: int) -> int:
    """Smoothing tap at offset i (-3..3) of the Sobel aperture ``ksize``."""
    if ksize == 7:
        return SMOOTH_7[i + 3]
    if ksize == 5:
        return SMOOTH_5[i + 3]
    if ksize == 3:
        return SMOOTH_3[i + 3]
    return SMOOTH_1[i + 3]


@wp.func
def deriv_tap(ksize: int, i: int) -> int:
    """First-derivative tap at offset i (-3..3) of the Sobel aperture ``ksize``."""
    if ksize == 7:
        return DERIV_7[i + 3]
    if ksize == 5:
        return DERIV_5[i + 3]
    return DERIV_3[i + 3]


@wp.func
def sobel_gradient(img: wp.array2d(dtype=wp.uint8), y: int, x: int, ksize: int) -> wp.vec2i:
    """Integer Sobel (dx, dy) at (y, x) with REFLECT_101 (correlation, as cv2.Sobel)."""
    h = img.shape[0]
    w = img.shape[1]
    r = wp.max(ksize // 2, 1)
    gx = int(0)
    gy = int(0)
    for i in range(-r, r + 1):
        row = reflect101(y + i, h)
        sy = smooth_tap(ksize, i)
        dy = deriv_tap(ksize, i)
        for j in range(-r, r + 1):
            v = int(img[row, reflect101(x + j, w)])
            gx += sy * deriv_tap(ksize, j) * v
            gy += dy * smooth_tap(ksize, j) * v
    return wp.vec2i(gx, gy)


@wp.func
def corner_score(cov: wp.vec3, params: ResponseParams) -> float:
    """Harris ``a*c - b*b - k*(a+c)^2`` or the minimum eigenvalue of the tensor (a, b, c)."""
    a = cov[0]
    b = cov[1]
    c = cov[2]
    if params.score == SCORE_MIN_EIGEN:
        ha = a * 0.5
        hc = c * 0.5
        return (ha + hc) - wp.sqrt((ha - hc) * (ha - hc) + b * b)
    return a * c - b * b - params.k * (a + c) * (a + c)


@wp.kernel
def compute_gradient_products(
    img: wp.array2d(dtype=wp.uint8),
    ksize: int,
    scale: float,
    products: wp.array2d(dtype=wp.vec3),
):
    y, x = wp.tid()
    g = sobel_gradient(img, y, x, ksize)
    dx = float(g[0]) * scale
    dy = float(g[1]) * scale
    products[y, x] = wp.vec3(dx * dx, dx * dy, dy * dy)


@wp.kernel
def compute_corner_response(
    products: wp.array2d(dtype=wp.vec3),
    params: ResponseParams,
    response: wp.array2d(dtype=wp.float32),
):
    y, x = wp.tid()
    h = products.shape[0]
    w = products.shape[1]
    block_size = params.block_size
    lo = -(block_size // 2)
    cov = wp.vec3()
    for i in range(lo, lo + block_size):
        row = reflect101(y + i, h)
        for j in range(lo, lo + block_size):
            cov += products[row, reflect101(x + j, w)]
    response[y, x] = corner_score(cov, params)


@wp.func
def reflect_near(p: int, n: int) -> int:
    """REFLECT_101 of an index at most one step outside [0, n) (also for n = 1)."""
    q = p
    if q < 0:
        q = -q
    if q >= n:
        q = 2 * n - 2 - q
    return wp.clamp(q, 0, n - 1)


@wp.func
def sobel3_gradient(img: wp.array2d(dtype=wp.uint8), y: int, x: int, interior: bool) -> wp.vec2i:
    """Integer 3x3 Sobel (dx, dy) at (y, x), which lies in the image; its neighbours are read
    directly when ``interior`` (all inside), else reflected (BORDER_REFLECT_101)."""
    ym = y - 1
    yp = y + 1
    xm = x - 1
    xp = x + 1
    if not interior:
        h = img.shape[0]
        w = img.shape[1]
        ym = reflect_near(ym, h)
        yp = reflect_near(yp, h)
        xm = reflect_near(xm, w)
        xp = reflect_near(xp, w)
    a = int(img[ym, xm])
    b = int(img[ym, x])
    c = int(img[ym, xp])
    d = int(img[y, xm])
    f = int(img[y, xp])
    g = int(img[yp, xm])
    hh = int(img[yp, x])
    i = int(img[yp, xp])
    gx = (c - a) + 2 * (f - d) + (i - g)
    gy = (g - a) + 2 * (hh - b) + (i - c)
    return wp.vec2i(gx, gy)


mat55i = wp.types.matrix(shape=(5, 5), dtype=wp.int32)


@wp.func
def cov_from_patch5(img: wp.array2d(dtype=wp.uint8), top: int, left: int, block_size: int,
                    scale: float) -> wp.vec3:
    """Structure tensor of a block of at most 3x3 (Sobel 3) whose 5x5 pixel neighbourhood,
    rows ``top`` .. ``top + 4``, lies inside the image: 25 reads into registers, the
    gradients from them, summed in the order of the general path."""
    p = mat55i()
    for i in range(5):
        for j in range(5):
            p[i, j] = int(img[top + i, left + j])
    cov = wp.vec3()
    for i in range(3):
        if i < block_size:
            for j in range(3):
                if j < block_size:
                    gx = (p[i, j + 2] - p[i, j]) + 2 * (p[i + 1, j + 2] - p[i + 1, j]) + (
                        p[i + 2, j + 2] - p[i + 2, j])
                    gy = (p[i + 2, j] - p[i, j]) + 2 * (p[i + 2, j + 1] - p[i, j + 1]) + (
                        p[i + 2, j + 2] - p[i, j + 2])
                    dx = float(gx) * scale
                    dy = float(gy) * scale
                    cov += wp.vec3(dx * dx, dx * dy, dy * dy)
    return cov


@wp.kernel
def compute_response_sobel3(
    img: wp.array2d(dtype=wp.uint8),
    params: ResponseParams,
    response: wp.array2d(dtype=wp.float32),
):
    """Sobel 3 gradients, their products summed over the block, and the score, per pixel.

    Window positions outside the image reflect (the box filter's BORDER_REFLECT_101 on the
    product image), then each gradient reflects its own neighbours (the Sobel's border).
    """
    y, x = wp.tid()
    h = img.shape[0]
    w = img.shape[1]
    block_size = params.block_size
    scale = params.scale
    lo = -(block_size // 2)
    y0 = y + lo
    x0 = x + lo
    if block_size <= 3 and y0 >= 1 and x0 >= 1 and y0 + 4 < h and x0 + 4 < w:
        response[y, x] = corner_score(cov_from_patch5(img, y0 - 1, x0 - 1, block_size, scale),
                                      params)
        return
    interior = y0 >= 1 and x0 >= 1 and y0 + block_size < h and x0 + block_size < w
    cov = wp.vec3()
    for i in range(block_size):
        yy = y0 + i
        if not interior:
            yy = reflect101(yy, h)
        for j in range(block_size):
            xx = x0 + j
            if not interior:
                xx = reflect101(xx, w)
            g = sobel3_gradient(img, yy, xx, interior)
            dx = float(g[0]) * scale
            dy = float(g[1]) * scale
            cov += wp.vec3(dx * dx, dx * dy, dy * dy)
    response[y, x] = corner_score(cov, params)


FUSED_MAX_BLOCK = 5
"""Largest block the one-kernel Sobel-3 path takes (it recomputes block^2 gradients per pixel)."""


def derivative_scale(ksize: int, block_size: int) -> float:
    """OpenCV's scale of the Sobel derivatives for 8-bit input in cornerEigenValsVecs."""
    return 1.0 / (float(1 << (ksize - 1)) * block_size * 255.0)


def response_params(block_size: int, ksize: int, k: float, score: str) -> ResponseParams:
    """The :class:`ResponseParams` of a call (``score``: a key of :data:`SCORES`)."""
    params = ResponseParams()
    params.block_size = int(block_size)
    params.scale = derivative_scale(ksize, block_size)
    params.k = float(k)
    params.score = SCORES[score]
    return params


def corner_response(src, block_size: int, ksize: int, k: float, score: str, response) -> None:
    """Launch the kernels on ``src.device``, writing the float32 map into ``response``."""
    device = src.device
    h, w = src.shape
    if ksize == 3 and block_size <= FUSED_MAX_BLOCK:
        # A recorded launch per (size, parameters); only the two arrays change between calls.
        cmd = workspace(
            "harris_response", (h, w, int(block_size), float(k), score), device,
            lambda: Recorded(compute_response_sobel3, (h, w), device, img=src,
                             params=response_params(block_size, 3, k, score), response=response))
        cmd.launch(img=src, response=response)
        return
    params = response_params(block_size, ksize, k, score)
    products = wp.empty((h, w), dtype=wp.vec3, device=device)
    wp.launch(compute_gradient_products, dim=(h, w), inputs=[src, int(ksize), params.scale],
              outputs=[products], device=device)
    wp.launch(compute_corner_response, dim=(h, w), inputs=[products, params],
              outputs=[response], device=device)


def harris_response(src, block_size: int, ksize: int, k: float, *, score: str = "harris",
                    out=None):
    """Harris (or minimum-eigenvalue) response of a gray uint8 ``wp.array2d`` as float32 HxW."""
    if out is None:
        out = wp.empty(src.shape, dtype=wp.float32, device=src.device)
    corner_response(src, block_size, ksize, k, score, out)
    return out
