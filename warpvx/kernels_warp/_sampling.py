"""Shared image sampling for Warp kernels: border handling, nearest/bilinear taps, and
*pixel words* (a pixel's channels packed in a uint32, for kernels that move 4 pixels at a time
as 32-bit words).

Used by ``remap`` and ``warp_perspective`` (and any later kernel that samples a uint8 image at
real coordinates; :func:`make_samplers` gives the samplers for a channel count), and the
pixel words by ``color_convert``. The arithmetic follows OpenCV >= 4.11
(``warp_common.scalar.hpp``), which samples in float32 rather than with the older 1/32-px
fixed-point tables:

- pixel centres at integer coordinates;
- nearest: ``ix = cvRound(sx)`` (round half to even);
- linear: ``ix = floor(sx)``, ``ax = sx - ix``; ``v0 = fma(ax, p01 - p00, p00)``,
  ``v1 = fma(ax, p11 - p10, p10)``, ``v = fma(ay, v1 - v0, v0)`` in float32, stored as
  ``saturate(cvRound(v))``;
- border ``constant``: every tap outside the image reads the border value;
  ``replicate``: clamp; ``reflect101``: ``gfedcb|abcdefgh|gfedcba`` (replicate on a
  1-pixel axis, as OpenCV).

A non-finite coordinate (NaN, inf; also W == 0 in a perspective warp) has no source pixel:
the output takes the border value under every border mode (OpenCV gives the same under
``constant``, and 0 for linear sampling under the others). Finite coordinates beyond +-1e9
are clamped there (still far outside). Every tap is resolved into the image before it is
read: no input can read out of bounds.
"""

from __future__ import annotations

import warp as wp

from .. import modes

# OpenCV's integer values (warpvx.modes), so cv2 constants pass straight through.
INTER_NEAREST = wp.constant(modes.INTER_NEAREST)
INTER_LINEAR = wp.constant(modes.INTER_LINEAR)
BORDER_CONSTANT = wp.constant(modes.BORDER_CONSTANT)
BORDER_REPLICATE = wp.constant(modes.BORDER_REPLICATE)
BORDER_REFLECT_101 = wp.constant(modes.BORDER_REFLECT_101)

# Coordinates are clamped to +-1e9 before the int conversion (an out-of-range float->int
# conversion differs between CPU and GPU).
COORD_LIMIT = wp.constant(1.0e9)


@wp.func
def split_coord(v: float) -> tuple[int, float]:
    """``(floor(v), v - floor(v))`` of a finite ``v``."""
    c = wp.clamp(v, -COORD_LIMIT, COORD_LIMIT)
    f = wp.floor(c)
    return int(f), c - f


@wp.func
def round_coord(v: float) -> int:
    """``cvRound(v)`` (half to even) of a finite ``v``."""
    return int(wp.rint(wp.clamp(v, -COORD_LIMIT, COORD_LIMIT)))


@wp.func
def is_finite_point(sx: float, sy: float) -> bool:
    """Whether both are finite (x * 0 is 0 for finite x, NaN otherwise; no branch)."""
    return wp.isfinite(sx * 0.0 + sy * 0.0)


@wp.func
def border_index(p: int, n: int, border: int) -> int:
    """Index ``p`` on an axis of length ``n`` after the border rule; -1 means "use the
    border value" (constant border only). The result is always in [-1, n)."""
    if p >= 0 and p < n:
        return p
    if border == BORDER_CONSTANT:
        return -1
    if border == BORDER_REPLICATE or n == 1:
        return wp.clamp(p, 0, n - 1)
    # reflect101: period 2(n-1), mirrored about 0 and n-1 without repeating the edge.
    period = 2 * (n - 1)
    q = p % period
    if q < 0:
        q = q + period
    if q >= n:
        q = period - q
    return q


@wp.func
def read_reflect101(img: wp.array2d(dtype=wp.uint8), y: int, x: int) -> int:
    """``img[y, x]`` with BORDER_REFLECT_101 outside the image: never reads out of bounds."""
    yy = border_index(y, img.shape[0], BORDER_REFLECT_101)
    xx = border_index(x, img.shape[1], BORDER_REFLECT_101)
    return int(img[yy, xx])


@wp.func
def nearest_tap(sx: float, sy: float, width: int, height: int, border: int) -> wp.vec2i:
    """Resolved ``(x, y)`` of the nearest source pixel (-1 entries: border value)."""
    x = border_index(round_coord(sx), width, border)
    y = border_index(round_coord(sy), height, border)
    return wp.vec2i(x, y)


@wp.func_native("return fmaf(a, b, c);")
def fma32(a: float, b: float, c: float) -> float:
    """``a*b + c`` rounded once to float32 (C's ``fmaf``), as the ``v_fma`` of OpenCV's
    vector paths, on CPU and CUDA alike (no double-precision work on the GPU)."""
    ...


# Raw loads, for what Warp's typed array reads cannot do: on CUDA, go through the read-only
# data cache (``__ldg``, ``ld.global.nc``; a typed read is a plain global load), for the
# gather reads of sampling (4 taps x C channels per output pixel) and remap's map reads; and
# read a 1-, 3- or 4-channel image at one flat byte offset per tap shared by its channels
# (:class:`SourceImage`). They check no bounds: each call site says why its offset lies
# inside the array.
_LOAD = """
#if defined(__CUDA_ARCH__)
return __ldg(reinterpret_cast<const {t}*>(ptr) + offset);
#else
return reinterpret_cast<const {t}*>(ptr)[offset];
#endif
"""


@wp.func_native(_LOAD.format(t="unsigned char"))
def load_byte(ptr: wp.uint64, offset: int) -> int:
    """Byte ``offset`` from address ``ptr``."""
    ...


@wp.func_native(_LOAD.format(t="float"))
def load_float(ptr: wp.uint64, offset: int) -> float:
    """float32 number ``offset`` from address ``ptr``."""
    ...


@wp.func
def lerp2(p00: float, p01: float, p10: float, p11: float, ax: float, ay: float) -> float:
    """Bilinear blend in OpenCV's order of operations (each step one fused multiply-add)."""
    v0 = fma32(ax, p01 - p00, p00)
    v1 = fma32(ax, p11 - p10, p10)
    return fma32(ay, v1 - v0, v0)


@wp.func
def saturate_int(v: float) -> int:
    """``saturate_cast<uchar>(v)`` as an int: round half to even, clamp to [0, 255]."""
    return wp.clamp(int(wp.rint(v)), 0, 255)


# --- pixel words ----------------------------------------------------------------------------
# A pixel word holds one pixel's channels in the bytes of a uint32, channel 0 in the low byte.
# Kernels that handle 4 pixels per thread read and write image rows as 32-bit words through
# these (a quad of 3-channel pixels is 3 words, of 4-channel pixels 4 words, of gray pixels 1).

ALPHA = wp.constant(wp.uint32(0xFF000000))
LOW24 = wp.constant(wp.uint32(0x00FFFFFF))


@wp.func
def byte_of(w: wp.uint32, k: int) -> int:
    """Byte ``k`` (0 = lowest) of ``w``."""
    return int((w >> wp.uint32(8 * k)) & wp.uint32(0xFF))


@wp.func
def pack_bytes(b0: int, b1: int, b2: int, b3: int) -> wp.uint32:
    """A word of four bytes given as ints in [0, 255], ``b0`` lowest."""
    return (wp.uint32(b0) | (wp.uint32(b1) << wp.uint32(8)) | (wp.uint32(b2) << wp.uint32(16))
            | (wp.uint32(b3) << wp.uint32(24)))


@wp.func
def load_quad(src: wp.array2d(dtype=wp.uint32), channels: int, y: int, q: int) -> wp.vec4ui:
    """Pixel words of pixels 4q..4q+3 of row ``y`` of a 3- or 4-channel image viewed as words
    (alpha 255 for 3 channels)."""
    if channels == 4:
        return wp.vec4ui(src[y, 4 * q], src[y, 4 * q + 1], src[y, 4 * q + 2], src[y, 4 * q + 3])
    a = src[y, 3 * q]
    b = src[y, 3 * q + 1]
    c = src[y, 3 * q + 2]
    return wp.vec4ui(
        (a & LOW24) | ALPHA,
        (a >> wp.uint32(24)) | ((b & wp.uint32(0xFFFF)) << wp.uint32(8)) | ALPHA,
        (b >> wp.uint32(16)) | ((c & wp.uint32(0xFF)) << wp.uint32(16)) | ALPHA,
        (c >> wp.uint32(8)) | ALPHA,
    )


@wp.func
def store_quad(dst: wp.array2d(dtype=wp.uint32), channels: int, y: int, q: int, p: wp.vec4ui):
    """Write 4 pixel words to a 1-, 3- or 4-channel image viewed as words: 1 word of gray
    pixels (channel 0 of each), 3 words of 3-channel pixels or 4 words of 4-channel ones."""
    if channels == 4:
        dst[y, 4 * q] = p[0]
        dst[y, 4 * q + 1] = p[1]
        dst[y, 4 * q + 2] = p[2]
        dst[y, 4 * q + 3] = p[3]
    elif channels == 3:
        dst[y, 3 * q] = (p[0] & LOW24) | (p[1] << wp.uint32(24))
        dst[y, 3 * q + 1] = ((p[1] >> wp.uint32(8)) & wp.uint32(0xFFFF)) | (p[2] << wp.uint32(16))
        dst[y, 3 * q + 2] = ((p[2] >> wp.uint32(16)) & wp.uint32(0xFF)) | (p[3] << wp.uint32(8))
    else:
        dst[y, q] = pack_bytes(byte_of(p[0], 0), byte_of(p[1], 0), byte_of(p[2], 0), byte_of(p[3], 0))


@wp.func
def store_pixel(dst: wp.array2d(dtype=wp.uint8), channels: int, y: int, x: int, p: wp.uint32):
    """Write the ``channels`` low bytes of pixel word ``p`` to pixel (y, x) of an image
    viewed as rows of ``width * channels`` bytes."""
    o = x * channels
    dst[y, o] = wp.uint8(byte_of(p, 0))
    if channels > 1:
        dst[y, o + 1] = wp.uint8(byte_of(p, 1))
        dst[y, o + 2] = wp.uint8(byte_of(p, 2))
        if channels == 4:
            dst[y, o + 3] = wp.uint8(byte_of(p, 3))


# --- sampling -------------------------------------------------------------------------------


@wp.struct
class SourceImage:
    """A C-contiguous uint8 image (HxW or HxWxC) of ``width`` x ``height`` pixels at address
    ``ptr``: channel ``c`` of pixel (x, y) is byte ``(y * width + x) * C + c``. The samplers
    compute the offset of a tap once for all its channels and read with :func:`load_byte`;
    :func:`source_image` makes one that matches its array."""

    ptr: wp.uint64
    width: int
    height: int


@wp.struct
class Sampling:
    """How a sampler reads: ``interpolation`` (INTER_*), ``border`` (BORDER_*) and
    ``border_value``, the value of a border pixel per channel (saturated to [0, 255])."""

    interpolation: int
    border: int
    border_value: wp.vec4


def source_image(src) -> SourceImage:
    """The :class:`SourceImage` of a C-contiguous uint8 ``wp.array`` image (its address:
    keeps nothing alive)."""
    img = SourceImage()
    img.ptr = src.ptr
    img.height = src.shape[0]
    img.width = src.shape[1]
    return img


def sampling(interpolation: int, border: int, border_value) -> Sampling:
    """The :class:`Sampling` of OpenCV's ``interpolation`` and ``border`` codes and a
    4-channel ``border_value``."""
    how = Sampling()
    how.interpolation = int(interpolation)
    how.border = int(border)
    how.border_value = wp.vec4(*border_value)
    return how


@wp.func
def border_pixel(bval: wp.vec4) -> wp.uint32:
    """The pixel word of the border value."""
    return pack_bytes(saturate_int(bval[0]), saturate_int(bval[1]), saturate_int(bval[2]),
                      saturate_int(bval[3]))


def make_samplers(channels: int):
    """``(sample_nearest, sample_linear)`` for :class:`SourceImage` s of ``channels`` channels
    (1, 3 or 4), each ``f(img, sx, sy, how: Sampling) -> pixel word`` (a gray image: byte 0;
    bytes past ``channels`` are 0).

    The channel count is a compile-time constant of the returned functions (one pair per
    count, made once at import), so their channel loops unroll. Bilinear sampling takes a
    straight path when the 2x2 neighbourhood lies inside the image (no border rule, no border
    value); elsewhere each tap is resolved by :func:`border_index` and border taps read pixel
    (0, 0), in bounds, whose value the border value then replaces. A non-finite coordinate is
    sampled at (0, 0) and replaced by the border value likewise. Within each path the reads are
    unconditional, so the compiler can issue a pixel's reads together.
    """

    @wp.func
    def offset(img: SourceImage, x: int, y: int) -> int:
        """Byte offset of resolved tap (x, y), each in [-1, size) (:func:`border_index`): a
        border tap (-1) reads pixel 0, whose value the border value replaces, so the offset
        of every tap is that of a pixel inside the image."""
        return (wp.max(y, 0) * img.width + wp.max(x, 0)) * wp.static(channels)

    @wp.func
    def blend(img: SourceImage, o00: int, o01: int, o10: int, o11: int, in00: bool, in01: bool,
              in10: bool, in11: bool, ax: float, ay: float, bval: wp.vec4) -> wp.vec4i:
        """Each channel of the bilinear blend of the taps at offsets ``o00..o11`` (a tap not
        ``in`` the image takes the border value). Each offset is that of a pixel inside the
        image and ``k`` < C, so every byte read lies inside it."""
        c = wp.vec4i(0, 0, 0, 0)
        for k in range(wp.static(channels)):
            b = bval[k]
            p00 = wp.where(in00, float(load_byte(img.ptr, o00 + k)), b)
            p01 = wp.where(in01, float(load_byte(img.ptr, o01 + k)), b)
            p10 = wp.where(in10, float(load_byte(img.ptr, o10 + k)), b)
            p11 = wp.where(in11, float(load_byte(img.ptr, o11 + k)), b)
            c[k] = saturate_int(lerp2(p00, p01, p10, p11, ax, ay))
        return c

    @wp.func
    def sample_nearest(img: SourceImage, sx: float, sy: float, how: Sampling) -> wp.uint32:
        finite = is_finite_point(sx, sy)
        t = nearest_tap(wp.where(finite, sx, 0.0), wp.where(finite, sy, 0.0), img.width,
                        img.height, how.border)
        o = offset(img, t[0], t[1])  # a pixel inside the image: its C bytes are in bounds
        c = wp.vec4i(0, 0, 0, 0)
        for k in range(wp.static(channels)):
            c[k] = load_byte(img.ptr, o + k)
        inside = finite and t[0] >= 0 and t[1] >= 0
        return wp.where(inside, pack_bytes(c[0], c[1], c[2], c[3]), border_pixel(how.border_value))

    @wp.func
    def sample_linear(img: SourceImage, sx: float, sy: float, how: Sampling) -> wp.uint32:
        finite = is_finite_point(sx, sy)
        ix, ax = split_coord(wp.where(finite, sx, 0.0))
        iy, ay = split_coord(wp.where(finite, sy, 0.0))
        bval = how.border_value
        # Unsigned compares: a negative index is out too. Inside: 0 <= ix < W - 1 and
        # 0 <= iy < H - 1, so all four taps are pixels of the image.
        if wp.uint32(ix) < wp.uint32(img.width - 1) and wp.uint32(iy) < wp.uint32(img.height - 1):
            o = (iy * img.width + ix) * wp.static(channels)
            below = img.width * wp.static(channels)
            c = blend(img, o, o + wp.static(channels), o + below, o + below + wp.static(channels),
                      True, True, True, True, ax, ay, bval)
        else:
            x0 = border_index(ix, img.width, how.border)
            x1 = border_index(ix + 1, img.width, how.border)
            y0 = border_index(iy, img.height, how.border)
            y1 = border_index(iy + 1, img.height, how.border)
            c = blend(img, offset(img, x0, y0), offset(img, x1, y0), offset(img, x0, y1), offset(img, x1, y1),
                      x0 >= 0 and y0 >= 0, x1 >= 0 and y0 >= 0, x0 >= 0 and y1 >= 0, x1 >= 0 and y1 >= 0,
                      ax, ay, bval)
        return wp.where(finite, pack_bytes(c[0], c[1], c[2], c[3]), border_pixel(bval))

    return sample_nearest, sample_linear


#: ``{channels: (sample_nearest, sample_linear)}`` for 1, 3 and 4 channels.
SAMPLERS = {c: make_samplers(c) for c in (1, 3, 4)}
