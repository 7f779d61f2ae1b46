"""What the captured path lists once instead of per frame (a buffer set's copy-out plan, a
segment's input buffers' leaves, a large Counted's staged row prefixes in one buffer) follows
what it was made for: another shape of a segment's inputs, a reset, a failed frame. Outputs
of a captured, staged, pipelined stream equal the eager unstaged run's bit for bit on real
frames.

Without CUDA the staged path runs on Warp's CPU device through ``Executor.STAGE_ON_HOST`` and
the captured one with ``capture=True`` (Warp 1.19 captures there too).
"""

from __future__ import annotations

import gc

import numpy as np
import pytest

from tests.graph.test_capture import _capture_arg, _flow_graph
from tests.runtime.test_staged_downloads import _cams, _graph, _same
from warpvx.backend import init_warp
from warpvx.errors import NodeExecutionError
from warpvx.runtime import Executor, Transfers
from warpvx.runtime.pinned import HostPool
from warpvx.runtime.transfers import ROW_HINTS


class _Boom(Exception):
    pass


def _fail_on(g, n):
    """Make ``g``'s homographyL (a CPU node, once per frame in frame order) raise on its
    ``n``-th call from now (0-based); returns the undo."""
    task = g.plan.executor().program.tasks["homographyL"]
    real, calls = task.cpu, []

    def cpu(*args):
        calls.append(1)
        if len(calls) - 1 == n:
            raise _Boom("a failed frame")
        return real(*args)

    task.cpu = cpu

    def undo():
        task.cpu = real

    return undo


def _plans_follow_outputs(ex) -> int:
    """Buffer sets with a copy-out plan; each plan is of its set's current outputs."""
    n = 0
    for states in ex._captured.values():
        for by_shape in states:
            for sg in (by_shape or {}).values():
                for b in sg.sets if sg is not None else ():
                    if b.plan is not None:
                        assert b.plan[0] is b.outputs
                        n += 1
    return n


def test_captured_staged_stream_through_a_reset_and_a_failed_frame_equals_eager(
        warp_backend, monkeypatch):
    """Three streams with a reset between them, the second cut by a failing CPU node: the
    frames before the failure, and every frame of the other streams, equal the eager run's
    (after a reset the corners are the delay's initial plain array: another shape of the
    segment's inputs, another graph and plan; the failure leaves plans and buffers of frames
    never waited for)."""
    cams = _cams(30)
    parts = (cams[:10], cams[10:20], cams[20:])
    fail = 2  # the second stream's third frame
    monkeypatch.setattr(Executor, "STAGE_ON_HOST", False)
    ref_graph = _graph(cams, warp_backend)
    try:
        ref = []
        for part in parts:
            ref_graph.reset()
            ref.append([ref_graph.process(c, capture=False) for c in part])
    finally:
        ref_graph.close()
    monkeypatch.setattr(Executor, "STAGE_ON_HOST", True)
    cap = _capture_arg(warp_backend)
    g = _graph(cams, warp_backend)
    try:
        ex = g.plan.executor()
        got = []
        for k, part in enumerate(parts):
            g.reset()
            out = []
            if k == 1:
                undo = _fail_on(g, fail)
                with pytest.raises(NodeExecutionError) as err:
                    for o in g.stream(part, depth=3, capture=cap):
                        out.append(o)
                undo()
                assert isinstance(err.value.__cause__, _Boom)
                assert len(out) == fail
            else:
                out = list(g.stream(part, depth=3, capture=cap))
                assert len(out) == len(part)
            got.append(out)
        assert ex.replays > 0 and ex._host_pool.allocated > 0  # captured and staged
        assert _plans_follow_outputs(ex) > 0
    finally:
        g.close()
    for k, (r, o) in enumerate(zip(ref, got)):
        for i, (a, b) in enumerate(zip(r, o)):
            assert _same(a, b), (k, i)


def test_captured_staged_flow_with_points_of_other_counts_equals_eager(warp_backend, monkeypatch):
    """LK's points (a graph input) change count: another count is another shape of the
    segment's inputs (another SegmentGraph, run eagerly as its out= does not fit), then
    verification's count replays again; pipelined, staged, each output equals the eager run's
    and each buffer set's copy-out plan is of its current outputs."""
    frames = [c["frameL"] for c in _cams(4)]
    rng = np.random.default_rng(11)
    h, w = frames[0].shape[:2]

    def points(n):
        return (rng.random((n, 2)) * [w - 20, h - 20] + 10).astype(np.float32)

    counts = [24, 24, 24, 24, 31, 24, 24, 17, 17, 24, 24, 24, 24, 31, 24, 24]
    feed = [{"frame": f, "pts": points(n)} for f, n in zip(frames * 6, counts)]
    monkeypatch.setattr(Executor, "STAGE_ON_HOST", True)
    g = _flow_graph(frames, warp_backend, points(24))
    try:
        eager = [g.process(x, capture=False) for x in feed]
        g.reset()
        ex = g.plan.executor()
        got = list(g.stream(feed, depth=3, capture=_capture_arg(warp_backend)))
        assert ex.replays > 0
        assert _plans_follow_outputs(ex) > 0
        for i, (e, c) in enumerate(zip(eager, got)):
            for k in e:
                assert _same(e[k], c[k]), (i, k)
    finally:
        g.close()


def test_a_large_counted_blocks_staged_prefix_is_one_pool_buffer_for_all_its_arrays():
    """Keypoints rows (five float32 arrays and an int32 one) past ONE_COPY_MAX_BYTES: once a
    count was read, the staged prefix of every rows array is one pool lease (plus the
    count's), read as views, equal to the synchronous download; the buffer goes back once
    the value is garbage. A count past the prefix copies its rows when read, as before."""
    from warpvx import Keypoints
    from warpvx._counted import ONE_COPY_MAX_BYTES, Block

    init_warp()
    cap = ONE_COPY_MAX_BYTES // 16 + 50
    rng = np.random.default_rng(7)
    host = Keypoints(x=rng.random(cap, dtype=np.float32) * 100,
                     y=rng.random(cap, dtype=np.float32) * 100,
                     response=rng.random(cap, dtype=np.float32),
                     size=np.full(cap, 7.0, np.float32),
                     angle=rng.random(cap, dtype=np.float32) * 360,
                     octave=rng.integers(0, 4, cap).astype(np.int32))
    (c,) = Block.layout([host], cap, "cpu")
    for name in ("x", "y", "response", "size", "angle", "octave"):
        getattr(c.rows, name).assign(getattr(host, name))
    assert c.block.array.shape[0] > ONE_COPY_MAX_BYTES
    ROW_HINTS._last.clear()
    pool = HostPool(1 << 22, pinned=False)
    io = Transfers("cpu", pool)
    leases = []
    take = pool.take
    pool.take = lambda shape, dtype: leases.append(shape) or take(shape, dtype)
    for count, prefix_leases in [(30, 0), (33, 1), (200, 1)]:
        leases.clear()
        c.count.assign(np.int32([count]))
        staged = io.stage_download(c)
        assert len(leases) == 1 + prefix_leases  # the count's, and one for every prefix
        got = io.unstage(staged)
        want = Transfers("cpu").download(c)
        assert len(got) == count and _same(got, want)
        for name in ("x", "y", "response", "size", "angle", "octave"):
            np.testing.assert_array_equal(getattr(got, name), getattr(host, name)[:count])
    del got, staged
    gc.collect()
    assert pool.lent() == 0


@pytest.mark.parametrize("shape,dtype", [((7, 9), np.float32), ((5,), np.int32), ((0, 3), np.uint8)])
def test_copier_copies_its_source_into_each_destination(warp_backend, shape, dtype):
    """copier(src), made once per fixed buffer of a copy-out plan, copies src's bytes into
    each buffer it is given (a later write of src is copied too: it reads src per call),
    as copy_device does; an empty source copies nothing."""
    from warpvx.backend import resolve_backend
    from warpvx.runtime.native_copy import copier, copy_device

    wp = init_warp()
    device = resolve_backend(warp_backend).device
    rng = np.random.default_rng(9)
    host = (rng.random(shape) * 100).astype(dtype)
    src = wp.array(host, device=device)
    copy = copier(src)
    a, b, ref = wp.zeros_like(src), wp.zeros_like(src), wp.zeros_like(src)
    copy(a, None)
    np.testing.assert_array_equal(a.numpy(), host)
    host2 = (rng.random(shape) * 100).astype(dtype)
    src.assign(host2)
    copy(b, None)
    copy_device(ref, src)
    np.testing.assert_array_equal(b.numpy(), host2)
    np.testing.assert_array_equal(b.numpy(), ref.numpy())
    np.testing.assert_array_equal(a.numpy(), host)  # the first copy is its own
