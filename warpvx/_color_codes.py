"""Colour-conversion codes: what each of cv2's integer codes does (neutral module).

Shared by :mod:`warpvx.color` (validation) and the kernels (``kernels_warp.color_convert``),
which must not import the public module.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class ColorCode:
    """What a conversion code does.

    Attributes
    ----------
    kind : str
        ``"gray"`` (colour to gray), ``"reorder"`` (channel copy/swap/alpha),
        ``"expand"`` (gray to colour), ``"nv"`` (NV12/NV21 to colour), ``"luma"`` (NV to gray).
    src_channels : tuple of int
        Accepted input channel counts (1 for gray and NV planes).
    dst_channels : int
        Output channels (1 means an HxW output).
    swap_rb : bool
        Whether R and B change places (or, for ``"gray"``, whether the input is RGB order).
    uv_first : int
        For ``"nv"``: 0 when U precedes V (NV12), 1 when V precedes U (NV21).
    """

    kind: str
    src_channels: tuple
    dst_channels: int
    swap_rb: bool = False
    uv_first: int = 0


# cv2's integer codes (shared by aliases such as BGR2RGB/RGB2BGR, which do the same thing).
_SPECS = {
    0: ColorCode("reorder", (3, 4), 4),  # BGR2BGRA, RGB2RGBA
    1: ColorCode("reorder", (3, 4), 3),  # BGRA2BGR, RGBA2RGB
    2: ColorCode("reorder", (3, 4), 4, swap_rb=True),  # BGR2RGBA, RGB2BGRA
    3: ColorCode("reorder", (3, 4), 3, swap_rb=True),  # RGBA2BGR, BGRA2RGB
    4: ColorCode("reorder", (3, 4), 3, swap_rb=True),  # BGR2RGB, RGB2BGR
    5: ColorCode("reorder", (3, 4), 4, swap_rb=True),  # BGRA2RGBA, RGBA2BGRA
    6: ColorCode("gray", (3, 4), 1),  # BGR2GRAY
    7: ColorCode("gray", (3, 4), 1, swap_rb=True),  # RGB2GRAY
    8: ColorCode("expand", (1,), 3),  # GRAY2BGR, GRAY2RGB
    9: ColorCode("expand", (1,), 4),  # GRAY2BGRA, GRAY2RGBA
    10: ColorCode("gray", (3, 4), 1),  # BGRA2GRAY
    11: ColorCode("gray", (3, 4), 1, swap_rb=True),  # RGBA2GRAY
    90: ColorCode("nv", (1,), 3, swap_rb=True, uv_first=0),  # YUV2RGB_NV12
    91: ColorCode("nv", (1,), 3, swap_rb=False, uv_first=0),  # YUV2BGR_NV12
    92: ColorCode("nv", (1,), 3, swap_rb=True, uv_first=1),  # YUV2RGB_NV21
    93: ColorCode("nv", (1,), 3, swap_rb=False, uv_first=1),  # YUV2BGR_NV21
    94: ColorCode("nv", (1,), 4, swap_rb=True, uv_first=0),  # YUV2RGBA_NV12
    95: ColorCode("nv", (1,), 4, swap_rb=False, uv_first=0),  # YUV2BGRA_NV12
    96: ColorCode("nv", (1,), 4, swap_rb=True, uv_first=1),  # YUV2RGBA_NV21
    97: ColorCode("nv", (1,), 4, swap_rb=False, uv_first=1),  # YUV2BGRA_NV21
    106: ColorCode("luma", (1,), 1),  # YUV2GRAY_NV12 / NV21 / 420sp
}


def code_spec(code: int) -> ColorCode:
    """The :class:`ColorCode` of a resolved integer code."""
    return _SPECS[code]


def output_shape(code: int, src_shape: tuple) -> tuple:
    """Output shape of ``code`` on an input of ``src_shape`` (HxW for NV planes is the luma size)."""
    spec = _SPECS[code]
    h, w = src_shape[0], src_shape[1]
    if spec.kind in ("nv", "luma"):
        h = h * 2 // 3
    return (h, w) if spec.dst_channels == 1 else (h, w, spec.dst_channels)
