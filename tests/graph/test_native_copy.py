"""The runtime's copies: Warp's native entry points against the public-API fallback (same bytes,
on Warp's CPU device and on CUDA where present), and the flatten protocol of tree_map."""

from __future__ import annotations

import numpy as np
import pytest

from warpvx.backend import cuda_available, init_warp
from warpvx.keypoints import Keypoints
from warpvx.runtime import Transfers, tree_map
from warpvx.runtime import native_copy as nc

DEVICES = ["cpu"] + (["cuda:0"] if cuda_available() else [])

#: Host arrays of every scalar kind the runtime moves, an empty one, odd sizes and a 3-D image.
ARRAYS = [
    np.random.default_rng(0).integers(0, 256, (37, 53, 3), dtype=np.uint8),
    np.random.default_rng(1).standard_normal((5, 2)).astype(np.float32),
    np.arange(-7, 6, dtype=np.int32),
    np.float64([1.5, -2.0, np.pi]),
    np.array([True, False, True]),
    np.zeros((0, 2), np.float32),
    np.random.default_rng(2).integers(0, 1 << 16, 1 << 17, dtype=np.uint16),  # past PINNED_MIN_BYTES
]


def _stream(wp, device):
    return wp.Stream(device) if device.startswith("cuda") else None


def test_this_warp_has_the_native_entry_points():
    # Otherwise the comparisons below compare the fallback with itself.
    init_warp()
    assert nc.native_entry_points() is not None


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("host", ARRAYS, ids=lambda a: f"{a.dtype}{list(a.shape)}")
def test_native_and_public_copies_give_the_same_bytes(device, host):
    wp = init_warp()
    stream = _stream(wp, device)
    dtype = wp.dtype_from_numpy(host.dtype)
    fast_dst = wp.empty(host.shape, dtype=dtype, device=device)
    slow_dst = wp.empty(host.shape, dtype=dtype, device=device)
    nc.to_device(fast_dst, host, stream, native=True)
    nc.to_device(slow_dst, host, stream, native=False)
    if stream is not None:
        wp.synchronize_stream(stream)
    # Both device buffers, read back through Warp's own public copy.
    np.testing.assert_array_equal(fast_dst.numpy(), host)
    np.testing.assert_array_equal(slow_dst.numpy(), host)

    fast = nc.to_host(fast_dst, stream, native=True)
    slow = nc.to_host(fast_dst, stream, native=False)
    for got in (fast, slow):
        assert got.dtype == host.dtype and got.shape == host.shape
        assert got.tobytes() == host.tobytes()
    # Fresh arrays: writing the device buffer afterwards does not change what was copied.
    fast_dst.zero_()
    if stream is not None:
        wp.synchronize_device(device)
    assert fast.tobytes() == host.tobytes() and slow.tobytes() == host.tobytes()


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("native", [True, False])
@pytest.mark.parametrize("into", ["warp", "numpy"])
def test_asynchronous_downloads_give_the_same_bytes(device, native, into):
    """Into a host wp.array or a NumPy array (a HostPool's lent buffer)."""
    wp = init_warp()
    host = np.random.default_rng(3).integers(-1000, 1000, (67, 5), dtype=np.int32)
    src = wp.array(host, dtype=wp.int32, device=device)
    dst = wp.empty(host.shape, dtype=wp.int32, device="cpu", pinned=device != "cpu")
    got = dst.numpy() if into == "numpy" else dst
    stream = _stream(wp, device)
    nc.to_host_async(got, src, stream, native=native)
    if stream is not None:
        wp.synchronize_event(stream.record_event())
    np.testing.assert_array_equal(dst.numpy(), host)


@pytest.mark.skipif(not cuda_available(), reason="CUDA staging and events")
def test_staged_download_and_native_elapsed_time():
    from warpvx.runtime.pinned import HostPool

    wp = init_warp()
    host = np.arange(1000, dtype=np.float32) * 0.25
    a = wp.array(host, dtype=wp.float32, device="cuda:0")
    pool = HostPool(1 << 20, pinned=True)
    io = Transfers("cuda:0", pool)
    start, end = (wp.Event("cuda:0", enable_timing=True) for _ in range(2))
    stream = wp.get_stream("cuda:0")
    stream.record_event(start)
    a.fill_(2.0)
    stream.record_event(end)
    staged = io.stage_download(a, end)  # waits for the fill on the device, not on the host
    staged_event = staged.event
    got = io.unstage(staged)
    np.testing.assert_array_equal(got, np.full_like(host, 2.0))
    assert pool.lent() == host.nbytes  # a view of the pinned buffer, lent while it lives
    assert list(io._events) == [staged_event] and staged.event is None  # read: event free
    del got
    assert pool.lent() == 0
    wp.synchronize_event(end)
    assert nc.elapsed_since(start)(end) == pytest.approx(wp.get_event_elapsed_time(start, end))
    # Another kind of value (a vector dtype) downloads the usual way.
    assert io.stage_download(wp.zeros(3, dtype=wp.vec2, device="cuda:0")) is None
    # A small one goes on the producer's stream after its kernels (no event between streams).
    small = wp.zeros(16, dtype=wp.int32, device="cuda:0")
    assert small.capacity < io.SAME_STREAM_MAX_BYTES
    with wp.ScopedStream(stream):
        small.fill_(7)
        staged = io.stage_download(small, after=stream)
    np.testing.assert_array_equal(io.unstage(staged), np.full(16, 7, np.int32))


@pytest.mark.parametrize("device", DEVICES)
def test_pinned_source_uploads_agree(device):
    wp = init_warp()
    host = np.arange(4096, dtype=np.float32) * 0.5
    pinned = wp.array(host, dtype=wp.float32, device="cpu", pinned=device != "cpu")
    stream = _stream(wp, device)
    out = []
    for native in (True, False):
        dst = wp.empty(host.shape, dtype=wp.float32, device=device)
        nc.to_device(dst, pinned, stream, native=native)
        if stream is not None:
            wp.synchronize_stream(stream)
        out.append(dst.numpy())
    np.testing.assert_array_equal(out[0], host)
    np.testing.assert_array_equal(out[1], host)


@pytest.mark.parametrize("device", DEVICES)
def test_vector_dtypes_take_the_public_path(device):
    wp = init_warp()
    host = np.arange(8, dtype=np.float32).reshape(4, 2)
    a = wp.array(host, dtype=wp.vec2, device=device)
    got = nc.to_host(a, _stream(wp, device))
    np.testing.assert_array_equal(got, host)


class Pair:
    """A user data type with the flatten protocol: two arrays and a label (aux)."""

    def __init__(self, a, b, label):
        self.a, self.b, self.label = a, b, label

    def __warpvx_flatten__(self):
        return (self.a, self.b), self.label

    @classmethod
    def __warpvx_unflatten__(cls, aux, arrays):
        return cls(*arrays, aux)


def test_tree_map_uses_the_flatten_protocol():
    p = Pair(np.arange(3), np.ones(2), "hello")
    out = tree_map(lambda x: x * 2, {"p": [p, (np.arange(2), 7)]})
    q = out["p"][0]
    assert isinstance(q, Pair) and q.label == "hello"
    np.testing.assert_array_equal(q.a, [0, 2, 4])
    np.testing.assert_array_equal(q.b, [2, 2])
    np.testing.assert_array_equal(out["p"][1][0], [0, 2])
    assert out["p"][1][1] == 7


@pytest.mark.parametrize("device", DEVICES)
def test_keypoints_and_user_types_round_trip_through_transfers(device):
    wp = init_warp()
    kp = Keypoints.from_arrays([1.5, 2.5], [3.0, 4.0], response=[0.25, 0.5], octave=[0, 2])
    pair = Pair(np.arange(5, dtype=np.int32), np.float32([0.5]), "lbl")
    io = Transfers(device)
    with wp.ScopedDevice(device):
        dev = io.upload([kp, pair])
        assert all(nc.is_warp_array(getattr(dev[0], f)) for f in ("x", "octave"))
        assert nc.is_warp_array(dev[1].a) and dev[1].label == "lbl"
        wp.synchronize_device(device)
        back = io.download(dev)
    assert isinstance(back[0], Keypoints)
    for f in ("x", "y", "response", "size", "angle", "octave"):
        np.testing.assert_array_equal(getattr(back[0], f), getattr(kp, f))
    assert isinstance(back[1], Pair) and back[1].label == "lbl"
    np.testing.assert_array_equal(back[1].a, pair.a)
    np.testing.assert_array_equal(back[1].b, pair.b)
