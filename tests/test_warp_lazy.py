"""Warp is imported only when a Warp backend is used, and is quiet on CPU-only machines
(issue 10, item 24).

Each case runs in a fresh interpreter: whether ``warp`` was imported, and what Warp's native
library wrote to stderr, are properties of the whole process.
"""

from __future__ import annotations

import pytest

from warpvx.backend import cuda_driver_present

from .isolated import run_python

NO_DRIVER = "Could not find or load the NVIDIA CUDA driver"

needs_no_driver = pytest.mark.skipif(
    cuda_driver_present(),
    reason="the NVIDIA CUDA driver is present here; the no-driver behaviour needs a CPU-only machine",
)

CALL = """
import sys, numpy as np, cv2, warpvx
from tests.images import bgr
img = bgr("astronaut")
gray = warpvx.color_convert(img, "BGR2GRAY"{backend})
assert np.array_equal(gray, cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))
print("warp imported:", "warp" in sys.modules)
"""


def _call(tmp_path, backend_arg: str, env=None):
    res = run_python(CALL.format(backend=backend_arg), tmp_path, env=env)
    assert res.returncode == 0, res.stderr
    return res


def test_cpu_backend_does_not_import_warp(tmp_path):
    res = _call(tmp_path, ', backend="cpu"')
    assert "warp imported: False" in res.stdout
    assert res.stderr == ""


@needs_no_driver
def test_default_backend_without_driver_does_not_import_warp(tmp_path):
    res = _call(tmp_path, "")
    assert "warp imported: False" in res.stdout
    assert res.stderr == ""


@needs_no_driver
def test_warp_cpu_prints_no_driver_warning(tmp_path):
    res = _call(tmp_path, ', backend="warp-cpu"')
    assert "warp imported: True" in res.stdout
    assert NO_DRIVER not in res.stderr
    assert res.stderr == ""


@needs_no_driver
def test_verbose_keeps_warps_own_output(tmp_path):
    # The control for the test above: without the filter, Warp does print the line.
    res = _call(tmp_path, ', backend="warp-cpu"', env={"WARPVX_VERBOSE": "1"})
    assert NO_DRIVER in res.stderr


def test_driver_probe_agrees_with_warp(tmp_path):
    # No driver by the probe must mean no driver and no device for Warp; Warp having a driver
    # must mean the probe found it (a driver without a GPU leaves Warp's version unset).
    code = (
        "from warpvx.backend import cuda_driver_present, init_warp\n"
        "probe = cuda_driver_present()\n"
        "wp = init_warp()\n"
        "print(probe, wp.get_cuda_driver_version() is not None, wp.get_cuda_device_count())\n"
    )
    res = run_python(code, tmp_path)
    assert res.returncode == 0, res.stderr
    probe, warp_has_driver, devices = res.stdout.split()
    assert probe == "True" or (warp_has_driver == "False" and devices == "0")
    assert warp_has_driver == "False" or probe == "True"


def test_stderr_filter_drops_only_the_given_line(tmp_path):
    # Native writes to fd 2 and Python's sys.stderr both pass, in order; only the line goes.
    code = (
        "import os, sys\n"
        "from warpvx.backend import _stderr_without\n"
        "with _stderr_without(b'drop me'):\n"
        "    os.write(2, b'first\\nplease drop me now\\n')\n"
        "    sys.stderr.write('from python\\n')\n"
        "    os.write(2, b'last')\n"
        "sys.stderr.write(' after')\n"
    )
    res = run_python(code, tmp_path)
    assert res.returncode == 0, res.stderr
    assert res.stderr == "first\nfrom python\nlast after"
