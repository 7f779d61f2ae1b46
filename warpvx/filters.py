"""Linear filters: Gaussian blur (OpenCV's ``GaussianBlur``, bit-exact on uint8)."""

from __future__ import annotations

import numpy as np

from .backend import resolve_backend
from .check import check_float, check_image, check_int, check_out
from .errors import UnsupportedError, WarpvxTypeError
from .modes import FILTER_BORDERS, mode_code
from .registry import dispatch

MAX_KSIZE = 31


def gaussian_blur(src, ksize, sigma, border="reflect101", *, out=None, backend=None, stream=None):
    """Blur a uint8 image with a Gaussian kernel, bit-exact with ``cv2.GaussianBlur``.

    ``dst = (sum_ij kx[i] ky[j] src[y+j, x+i] + 2^15) >> 16`` with ``kx``, ``ky`` OpenCV's
    8-bit fixed-point Gaussian kernels (1/256 units, summing to 256).

    Parameters
    ----------
    src : array
        uint8 HxW, HxWx1 (treated as HxW) or HxWxC (C = 3, 4), C-contiguous.
    ksize : int or (int, int)
        Odd kernel size, or (width, height) of odd sizes, each in 1..31.
    sigma : float or (float, float)
        Standard deviation, or (sigma_x, sigma_y); each >= 0. 0 derives sigma from the size
        (``0.3 * ((ksize - 1) * 0.5 - 1) + 0.8``); a sigma_y of 0 means sigma_x (OpenCV's
        rules). A sigma below 0.01 gives the identity kernel at every size, as OpenCV (the
        tails are below 2^-9 of the centre) and is taken as 0.01, so that no arithmetic on
        it underflows (a sigma of 1e-300 squares to 0).
    border : {"reflect101", "replicate", "reflect", "constant"} or int
        Pixels beyond the image: ``gfedcb|abcdefgh|gfedcba`` (default, ``BORDER_DEFAULT``),
        ``aaaaaa|abcdefgh|hhhhhhh``, ``fedcba|abcdefgh|hgfedcb``, or zeros; cv2's
        ``BORDER_*`` integers are accepted too.
    out : array, optional
        uint8 writable output of ``src``'s shape; may be ``src`` itself (in place), but not
        a view overlapping ``src`` elsewhere (refused: rows would be read after written).
    backend, stream
        See :mod:`warpvx.backend`.

    Returns
    -------
    array
        uint8 image of ``src``'s shape and kind (NumPy or ``wp.array``).

    Raises
    ------
    DTypeError, ShapeError, WarpvxValueError, WarpvxTypeError, UnsupportedError
        Bad ``src``, ``ksize`` (even, < 1, > 31), ``sigma`` (negative, not finite),
        ``border`` or ``out``.

    References
    ----------
    OpenCV ``GaussianBlur`` (``smooth.dispatch.cpp``: ``getGaussianKernelBitExact``,
    ``getGaussianKernelFixedPoint_ED``, ``GaussianBlurFixedPoint``).
    """
    be = resolve_backend(backend, like=src)
    src = _as_hw(check_image(src, "src", dtypes=(np.uint8,), channels=(1, 3, 4)))
    kx, ky = _ksize(ksize)
    sx, sy = _sigma(sigma)
    if sy == 0:
        sy = sx
    code = mode_code(border, "border", FILTER_BORDERS)
    check_out(out, tuple(src.shape), inputs=(("src", src),), in_place=True)
    return dispatch("gaussian_blur", be, src, (kx, ky), (sx, sy), code, out=out, stream=stream)


def _ksize(ksize) -> tuple[int, int]:
    if isinstance(ksize, (tuple, list)):
        if len(ksize) != 2:
            raise WarpvxTypeError(f"ksize: expected an int or (width, height), got {ksize!r}")
        pair = (ksize[0], ksize[1])
        names = ("ksize[0] (width)", "ksize[1] (height)")
    else:
        pair = (ksize, ksize)
        names = ("ksize", "ksize")
    out = []
    for v, name in zip(pair, names):
        k = check_int(v, name, min_value=1, max_value=MAX_KSIZE)
        if k % 2 == 0:
            raise UnsupportedError(f"{name}: expected an odd size, got {k}")
        out.append(k)
    return out[0], out[1]


#: Positive sigmas below this give the identity kernel (tails below 2^-9) and are raised to it.
MIN_SIGMA = 0.01


def _sigma(sigma) -> tuple[float, float]:
    if isinstance(sigma, (tuple, list)):
        if len(sigma) != 2:
            raise WarpvxTypeError(f"sigma: expected a number or (sigma_x, sigma_y), got {sigma!r}")
        return (_one_sigma(sigma[0], "sigma[0]"), _one_sigma(sigma[1], "sigma[1]"))
    s = _one_sigma(sigma, "sigma")
    return s, s


def _one_sigma(v, name: str) -> float:
    s = check_float(v, name, min_value=0.0)
    return s if s == 0.0 else max(s, MIN_SIGMA)


def _as_hw(src):
    """An HxWx1 image as an HxW view."""
    if src.ndim == 3 and src.shape[2] == 1:
        return src.reshape((src.shape[0], src.shape[1]))
    return src
