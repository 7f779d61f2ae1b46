"""Counted results (warpvx._counted): fixed rows and a device count behave as their value
wherever they reach the host."""

from __future__ import annotations

import numpy as np
import pytest

import warpvx
from warpvx._counted import Counted
from warpvx.backend import init_warp, resolve_backend
from warpvx.runtime import Transfers, tree_map


def _device(warp_backend):
    return resolve_backend(warp_backend).device


def _counted_points(device, n, capacity=8):
    wp = init_warp()
    rows = np.arange(capacity * 2, dtype=np.float32).reshape(capacity, 2)
    return Counted(wp.array(rows, device=device), wp.array([n], dtype=wp.int32, device=device)), rows


@pytest.mark.parametrize("n,expected", [(3, 3), (0, 0), (8, 8), (50, 8), (-2, 0)])
def test_value_is_the_counted_rows_count_clamped(warp_backend, n, expected):
    """On the host a Counted is rows[:count], the count clamped to [0, rows]: by .to("host")
    and through the flatten protocol (what the runtime's copies use)."""
    c, rows = _counted_points(_device(warp_backend), n)
    np.testing.assert_array_equal(c.to("host"), rows[:expected])
    host = tree_map(lambda a: a.numpy() if hasattr(a, "numpy") else a, (c, "other"))
    assert isinstance(host[0], np.ndarray) and host[1] == "other"
    np.testing.assert_array_equal(host[0], rows[:expected])
    on_device = tree_map(lambda a: a, c)
    assert isinstance(on_device, Counted) and on_device.capacity == 8


def test_keypoints_rows_are_cut_before_they_are_validated(warp_backend):
    """Rows past the count may hold anything (NaN here): the host value is only the counted
    keypoints, which Keypoints validates."""
    wp = init_warp()
    device = _device(warp_backend)
    x = np.array([1, 2, np.nan, np.nan], np.float32)
    fields = {f: wp.array(x if f in ("x", "y") else np.zeros(4, np.float32), device=device)
              for f in ("x", "y", "response", "size", "angle")}
    fields["octave"] = wp.zeros(4, dtype=wp.int32, device=device)
    c = Counted(warpvx.Keypoints(**fields), wp.array([2], dtype=wp.int32, device=device))
    for kps in (c.to("host"), Transfers(device).download(c)):
        assert isinstance(kps, warpvx.Keypoints) and kps.is_host
        np.testing.assert_array_equal(kps.x, [1, 2])


def test_download_copies_only_the_counted_rows(warp_backend):
    """Transfers.download reads the count first and moves only the rows it counts."""
    device = _device(warp_backend)
    c, rows = _counted_points(device, 3, capacity=1000)
    io = Transfers(device)
    got = io.download({"pts": c, "n": 1})
    np.testing.assert_array_equal(got["pts"], rows[:3])
    assert got["n"] == 1
    assert io.moved == 3 * 2 * 4 + 4  # three float32 (x, y) rows and the count
