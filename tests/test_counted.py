"""Counted results (warpvx._counted): fixed rows and a device count behave as their value
wherever they reach the host."""

from __future__ import annotations

import numpy as np
import pytest

import warpvx
from warpvx._counted import ONE_COPY_MAX_BYTES, Block, Counted
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


def _block_values(device, capacity, n):
    """A node's three Counted outputs laid out in one Block (points, Keypoints, status), with
    rows written through the views and the shared count set to ``n``; and the host rows."""
    wp = init_warp()
    kps = warpvx.Keypoints(*(np.zeros(1, np.float32) for _ in range(5)), np.zeros(1, np.int32))
    samples = [np.zeros((1, 2), np.float32), kps, np.zeros(1, np.uint8)]
    pts, kp, status = Block.layout(samples, capacity, device)
    rng = np.random.default_rng(7)
    rows = {"pts": rng.random((capacity, 2), np.float32),
            "status": rng.integers(0, 2, capacity).astype(np.uint8)}
    rows.update({f: rng.random(capacity, np.float32) for f in ("x", "y", "response", "size",
                                                                  "angle")})
    rows["octave"] = rng.integers(0, 4, capacity).astype(np.int32)
    wp.copy(pts.rows, wp.array(rows["pts"], device=device))
    wp.copy(status.rows, wp.array(rows["status"], device=device))
    for f in ("x", "y", "response", "size", "angle", "octave"):
        wp.copy(getattr(kp.rows, f), wp.array(rows[f], device=device))
    wp.copy(pts.count, wp.array([n], dtype=wp.int32, device=device))
    return (pts, kp, status), rows


@pytest.mark.parametrize("capacity,n", [(40, 17), (40, 0), (40, 99), (5000, 1234)])
def test_block_values_download_as_their_rows(warp_backend, capacity, n):
    """A node's Counted outputs in one Block share the count and each downloads as its own
    counted rows: one copy of the block when it is small, count then rows when large."""
    device = _device(warp_backend)
    (pts, kp, status), rows = _block_values(device, capacity, n)
    assert pts.block.array.ptr == kp.block.array.ptr == status.block.array.ptr
    assert pts.count.ptr == kp.count.ptr == status.count.ptr
    m = min(n, capacity)
    io = Transfers(device)
    got = io.download((pts, kp, status))
    np.testing.assert_array_equal(got[0], rows["pts"][:m])
    np.testing.assert_array_equal(got[2], rows["status"][:m])
    assert isinstance(got[1], warpvx.Keypoints) and got[1].is_host
    for f in ("x", "y", "response", "size", "angle", "octave"):
        np.testing.assert_array_equal(getattr(got[1], f), rows[f][:m])
    small = pts.block.array.shape[0] <= ONE_COPY_MAX_BYTES
    # Small: each value one copy of the whole block; large: each its count, then its rows.
    expected = 3 * pts.block.array.shape[0] if small else 3 * 4 + m * (8 + 24 + 1)
    assert io.moved == expected


def test_block_view_of_a_copy_reads_the_copy(warp_backend):
    """A Block's Counted as views of another allocation (a copy-out buffer) reads that
    allocation, not the original."""
    wp = init_warp()
    device = _device(warp_backend)
    (pts, _, _), rows = _block_values(device, 40, 9)
    copy = wp.empty_like(pts.block.array)
    wp.copy(copy, pts.block.array)
    moved = pts.block.view(copy)
    pts.rows.zero_()
    assert moved.block.array is copy and moved.rows.ptr != pts.rows.ptr
    np.testing.assert_array_equal(moved.to("host"), rows["pts"][:9])
    np.testing.assert_array_equal(Transfers(device).download(moved), rows["pts"][:9])
