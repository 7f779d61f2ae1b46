"""Border and interpolation modes: the one vocabulary of names, OpenCV flags and kernel codes.

A public function takes a mode by name (``"reflect101"``) or by cv2's integer
(``cv2.BORDER_REFLECT_101``) and resolves it with :func:`mode_code` against the table of the
modes it supports. The resolved integer *is* cv2's flag, and both backends take it as is: the
CPU kernels hand it to OpenCV, the Warp kernels compare against the same values
(``kernels_warp._sampling``/``_filtering`` declare them as ``wp.constant``). This module
imports neither Warp nor OpenCV nor a public module, so kernel modules may import it.

Borders (``|abcdefgh|`` is a row; what a tap beyond each end reads)::

    constant    iiiiii|abcdefgh|iiiiiii   a constant (0, or the border value)
    replicate   aaaaaa|abcdefgh|hhhhhhh
    reflect     fedcba|abcdefgh|hgfedcb
    reflect101  gfedcb|abcdefgh|gfedcba   (OpenCV's BORDER_DEFAULT)
"""

from __future__ import annotations

import numbers

from .check import check_choice
from .errors import UnsupportedError

# cv2's values (cv2.BORDER_*, cv2.INTER_*), which the kernels use as their codes too.
BORDER_CONSTANT = 0
BORDER_REPLICATE = 1
BORDER_REFLECT = 2
BORDER_REFLECT_101 = 4
INTER_NEAREST = 0
INTER_LINEAR = 1

#: Every border name -> cv2's flag.
BORDER_NAMES = {
    "constant": BORDER_CONSTANT, "replicate": BORDER_REPLICATE, "reflect": BORDER_REFLECT,
    "reflect101": BORDER_REFLECT_101, "reflect_101": BORDER_REFLECT_101,
}
#: Every interpolation name -> cv2's flag.
INTERPOLATION_NAMES = {"nearest": INTER_NEAREST, "linear": INTER_LINEAR}


def accepted(names, vocabulary) -> dict:
    """The spellings of the modes ``names`` (from ``vocabulary``): each name and each cv2
    integer, mapped to the cv2 integer."""
    table = {n: vocabulary[n] for n in names}
    table.update({code: code for code in table.values()})
    return table


#: Borders of the separable filters (:func:`warpvx.gaussian_blur`).
FILTER_BORDERS = accepted(("constant", "replicate", "reflect", "reflect101", "reflect_101"),
                          BORDER_NAMES)
#: Borders of the samplers (:func:`warpvx.remap`, :func:`warpvx.warp_perspective`).
SAMPLER_BORDERS = accepted(("constant", "replicate", "reflect101", "reflect_101"), BORDER_NAMES)
#: Interpolations of the samplers.
SAMPLER_INTERPOLATIONS = accepted(("nearest", "linear"), INTERPOLATION_NAMES)


def mode_code(value, name: str, table: dict) -> int:
    """cv2's integer of a mode given by name (any case) or cv2 integer, from ``table`` (one
    of the tables above); ``name`` is the argument named by the error.

    Raises
    ------
    UnsupportedError
        ``value`` is not a mode of ``table``.
    """
    t = type(value)
    if t is str or t is int:  # the common spellings, looked up directly
        mode = table.get(value.lower() if t is str else value)
        if mode is not None:
            return mode
    if isinstance(value, bool) or not isinstance(value, (str, numbers.Integral)):
        names = ", ".join(repr(k) for k in table if isinstance(k, str))
        raise UnsupportedError(f"{name}: expected one of {names} or its cv2 integer, got {value!r}")
    return check_choice(value.lower() if isinstance(value, str) else int(value), name, table)


__all__ = [
    "BORDER_CONSTANT",
    "BORDER_NAMES",
    "BORDER_REFLECT",
    "BORDER_REFLECT_101",
    "BORDER_REPLICATE",
    "FILTER_BORDERS",
    "INTERPOLATION_NAMES",
    "INTER_LINEAR",
    "INTER_NEAREST",
    "SAMPLER_BORDERS",
    "SAMPLER_INTERPOLATIONS",
    "accepted",
    "mode_code",
]
