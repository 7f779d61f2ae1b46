"""The border / interpolation vocabulary (warpvx.modes): names map to OpenCV's flags, which
both backends take as their codes; bad modes raise an error naming the argument."""

from __future__ import annotations

import subprocess
import sys

import cv2
import numpy as np
import pytest

from warpvx import modes
from warpvx.errors import UnsupportedError

CV_BORDERS = {"constant": cv2.BORDER_CONSTANT, "replicate": cv2.BORDER_REPLICATE,
              "reflect": cv2.BORDER_REFLECT, "reflect101": cv2.BORDER_REFLECT_101,
              "reflect_101": cv2.BORDER_REFLECT_101}
CV_INTERPOLATIONS = {"nearest": cv2.INTER_NEAREST, "linear": cv2.INTER_LINEAR}


def test_names_are_opencv_flags():
    assert modes.BORDER_NAMES == CV_BORDERS
    assert modes.INTERPOLATION_NAMES == CV_INTERPOLATIONS


@pytest.mark.parametrize("table, names", [
    (modes.FILTER_BORDERS, ("constant", "replicate", "reflect", "reflect101", "reflect_101")),
    (modes.SAMPLER_BORDERS, ("constant", "replicate", "reflect101", "reflect_101")),
])
def test_border_spellings(table, names):
    for n in names:
        flag = CV_BORDERS[n]
        assert modes.mode_code(n, "border", table) == flag
        assert modes.mode_code(n.upper(), "border", table) == flag
        assert modes.mode_code(flag, "border", table) == flag
        assert modes.mode_code(np.int64(flag), "border", table) == flag


def test_interpolation_spellings():
    for n, flag in CV_INTERPOLATIONS.items():
        assert modes.mode_code(n, "interpolation", modes.SAMPLER_INTERPOLATIONS) == flag
        assert modes.mode_code(flag, "interpolation", modes.SAMPLER_INTERPOLATIONS) == flag


@pytest.mark.parametrize("bad", ["reflect", cv2.BORDER_REFLECT, "wrap", 3, True, 1.0, None])
def test_unsupported_sampler_border_names_the_argument(bad):
    with pytest.raises(UnsupportedError, match=r"^border: expected one of 'constant'"):
        modes.mode_code(bad, "border", modes.SAMPLER_BORDERS)


def test_warp_kernel_codes_are_opencv_flags():
    pytest.importorskip("warp")
    from warpvx.kernels_warp import _filtering, _sampling

    assert int(_sampling.BORDER_CONSTANT) == cv2.BORDER_CONSTANT
    assert int(_sampling.BORDER_REPLICATE) == cv2.BORDER_REPLICATE
    assert int(_sampling.BORDER_REFLECT_101) == cv2.BORDER_REFLECT_101
    assert int(_filtering.BORDER_REFLECT) == cv2.BORDER_REFLECT
    assert int(_sampling.INTER_NEAREST) == cv2.INTER_NEAREST
    assert int(_sampling.INTER_LINEAR) == cv2.INTER_LINEAR


def test_importable_without_warp_or_opencv():
    code = "import sys, warpvx.modes; assert 'warp' not in sys.modules and 'cv2' not in sys.modules"
    subprocess.run([sys.executable, "-c", code], check=True)
