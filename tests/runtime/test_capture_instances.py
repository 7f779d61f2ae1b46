"""Captured segments' buffer sets per frame in flight (``Executor.instances``): frames go round
a ring of sets, each with its own input buffers and graph (on CUDA, its own streams, so frames
overlap on the device); a segment's delayed values are read from the previous frame's set.
On real frames (a photo panning, two cameras) every output equals the eager run's, bit for
bit, pipelined and one frame at a time, after a reset and with eager frames in between.
Without CUDA (Warp's CPU device, capture asked for) the same sets and graphs are made and
replayed, minus the streams. Caller frames in pinned memory (:func:`pinned_array`) give the
same outputs as pageable ones.
"""

from __future__ import annotations

import sys

import numpy as np
import pytest

from tests.benchmark_scripts import load_bench
from tests.graph.test_capture import _capture_arg
from tests.runtime.test_staged_downloads import SIZE, _cams, _same
from warpvx.errors import WarpvxError
from warpvx.runtime import is_pinned, pinned_array, pinned_copy

pytestmark = pytest.mark.timeout(300)


def _graph(gpu, instances):
    g = load_bench("graph_bench").build_graph(SIZE, max_corners=100)
    g.verify(_cams(2))
    g.schedule("baseline", n_cpus=2, gpu=gpu)
    g.plan.executor().instances = instances
    return g


def _segment_graphs(ex):
    """The captured segment's SegmentGraphs made so far (one per shapes of its inputs)."""
    (i,) = [i for i, s in enumerate(ex._segments) if s.captured]
    return [sg for states in ex._captured.values() for sg in states[i].values() if sg is not None]


@pytest.mark.parametrize("instances, depth", [(3, 3), (4, 2), (2, 6)])
def test_frames_round_the_sets_equal_eager(warp_backend, instances, depth):
    """Pipelined: every set is captured and replayed, each with input buffers of its own, and
    every output equals the eager run's; after a reset every frame but the first (the delays'
    initial values) replays again."""
    cams = _cams(16)
    g = _graph(warp_backend, instances)
    cap = _capture_arg(warp_backend)
    try:
        ex = g.plan.executor()
        eager = list(g.stream(cams, depth=depth, capture=False))
        g.reset()
        got = list(g.stream(cams, depth=depth, capture=cap))
        (sg,) = [sg for sg in _segment_graphs(ex) if sg.captured]
        assert len(sg.sets) == instances
        assert all(b.graph is not None for b in sg.sets)
        ptrs = [b.inputs[ref].ptr for b in sg.sets for ref in sg.segment.inputs
                if ref.key in ("frameL", "frameR")]
        assert len(set(ptrs)) == 2 * instances  # no set copies its frames into another's
        assert ex.replays > 0
        for i, (e, c) in enumerate(zip(eager, got)):
            assert _same(e, c), i
        replays = ex.replays
        g.reset()
        again = list(g.stream(cams, depth=depth, capture=cap))
        assert ex.replays - replays == len(cams) - 1
        for i, (e, c) in enumerate(zip(eager, again)):
            assert _same(e, c), i
    finally:
        g.close()


def test_eager_frames_between_replays_with_sets(warp_backend):
    """Frames run eagerly between replays leave their own values in the delays: the next
    replay copies them in rather than reading the previous set (an older frame's)."""
    cams = _cams(14)
    g = _graph(warp_backend, 3)
    cap = _capture_arg(warp_backend)
    try:
        eager = [g.process(f, capture=False) for f in cams]
        g.reset()
        got = [g.process(f, capture=False if i in (9, 11, 12) else cap)
               for i, f in enumerate(cams)]
        assert g.plan.executor().replays > 0
        for i, (e, c) in enumerate(zip(eager, got)):
            assert _same(e, c), i
    finally:
        g.close()


@pytest.mark.parametrize("bad", [0, -1, 1.5, "3"])
def test_instances_must_be_a_positive_int(bad):
    g = _graph("warp-cpu", 1)
    try:
        with pytest.raises(WarpvxError, match="instances"):
            g.plan.executor().instances = bad
    finally:
        g.close()


def test_instances_default_and_reset_captures(warp_backend):
    """segment_runner.INSTANCES sets on CUDA (1: no overlap measured on the H100), 1 elsewhere;
    setting it drops the graphs made so far."""
    g = _graph(warp_backend, None)
    try:
        ex = g.plan.executor()
        from warpvx.runtime import segment_runner
        assert ex.instances == (segment_runner.INSTANCES if warp_backend == "cuda" else 1) == 1
        g.process(_cams(1)[0], capture=_capture_arg(warp_backend))
        assert ex._captured
        ex.instances = 2
        assert ex.instances == 2 and not ex._captured
    finally:
        g.close()


def test_pinned_array_holds_a_frame():
    a = pinned_array((4, 6, 3), np.uint8)
    assert a.shape == (4, 6, 3) and a.dtype == np.uint8 and a.flags.c_contiguous
    assert not a.any()
    a[:] = 7
    assert int(a.sum()) == 7 * a.size
    b = pinned_array(5, np.float32)
    assert b.shape == (5,) and b.dtype == np.float32
    assert not is_pinned(np.zeros((4, 6, 3), np.uint8))
    assert not is_pinned(a[:, ::2])  # not contiguous: staged as a pageable array
    import warp as wp

    assert is_pinned(a) == is_pinned(a[1:]) == wp.is_cuda_available()


@pytest.mark.parametrize("bad", [(-1, 3), (2.5,), ("a",)])
def test_pinned_array_bad_shape(bad):
    with pytest.raises(WarpvxError, match="shape"):
        pinned_array(bad)


@pytest.mark.parametrize("bad", ["no-such-type", object, "O"])
def test_pinned_array_bad_dtype(bad):
    with pytest.raises(WarpvxError, match="dtype"):
        pinned_array((2, 2), bad)


def test_pinned_frames_give_the_pageable_outputs(warp_backend):
    """A stream of frames in pinned memory (copied to the device straight from there on
    CUDA) gives the outputs of the same frames in pageable memory."""
    cams = _cams(12)
    pinned = [{k: pinned_copy(v) for k, v in c.items()} for c in cams]
    assert all(np.array_equal(p[k], c[k]) for p, c in zip(pinned, cams) for k in c)
    g = _graph(warp_backend, 3)
    cap = _capture_arg(warp_backend)
    try:
        want = list(g.stream(cams, depth=3, capture=cap))
        g.reset()
        got = list(g.stream(pinned, depth=3, capture=cap))
        for i, (e, c) in enumerate(zip(want, got)):
            assert _same(e, c), i
    finally:
        g.close()


def test_linked_must_be_a_bool():
    g = _graph("warp-cpu", 1)
    try:
        with pytest.raises(WarpvxError, match="linked"):
            g.plan.executor().linked = 1
    finally:
        g.close()


@pytest.mark.parametrize("linked, rewrites, waits", [
    (False, False, ["previous"]),
    (False, True, ["previous"]),
    (True, False, ["last reader"]),
    (True, True, ["last reader", "previous"]),
])
def test_a_run_waits_for_the_runs_touching_its_set(monkeypatch, linked, rewrites, waits):
    """Which earlier runs, on other streams, a run of set s waits for (three sets): unlinked,
    the previous run (set s-1: the delayed values; it waited for the one before); linked, the
    run of set s+1 (two frames back: the last to read set s, as its delayed values), plus the
    previous run where this run rewrites the previous set's delayed values (an eager frame
    left its own)."""
    from warpvx.runtime import capture

    g = _graph("warp-cpu", 3)
    try:
        ex = g.plan.executor()
        list(g.stream(_cams(6), depth=3, capture=True))
        (sg,) = [sg for sg in _segment_graphs(ex) if sg.captured]
        names = {}
        for i, b in enumerate(sg.sets):
            b.done = object()
            names[id(b.done)] = i
        sg.links = [{} for _ in sg.sets] if linked else None
        got = []
        monkeypatch.setattr(capture, "wait_event", lambda stream, ev: got.append(names[id(ev)]))
        s = sg.next
        label = {(s - 1) % 3: "previous", (s + 1) % 3: "last reader"}
        sg.wait_previous(None, rewrites)
        assert [label[i] for i in got] == waits
    finally:
        g.close()


def test_a_graph_reading_its_own_delays_is_found_without_the_shapes(warp_backend, monkeypatch):
    """Frames whose segment inputs are the graph inputs and the delayed values the segment's
    last run published find that graph without walking the inputs' shapes (per frame on the
    GPU thread); a delayed value from elsewhere (after a reset: the initial one) is walked
    again, and every output stays the eager run's."""
    from warpvx.runtime import segment_runner

    cams = _cams(12)
    g = _graph(warp_backend, 3)
    cap = _capture_arg(warp_backend)
    try:
        eager = list(g.stream(cams, depth=3, capture=False))
        walks = []  # the walks of an input's leaves for its shapes (the key)
        walk = segment_runner._leaves

        def counted(v):
            if sys._getframe(2).f_code.co_name == "_inputs_key":  # (through its genexpr)
                walks.append(1)
            return walk(v)

        monkeypatch.setattr(segment_runner, "_leaves", counted)
        for _ in range(2):
            g.reset()
            before = len(walks)
            got = list(g.stream(cams, depth=3, capture=cap))
            for i, (e, c) in enumerate(zip(eager, got)):
                assert _same(e, c), i
        ex = g.plan.executor()
        (sg,) = [sg for sg in _segment_graphs(ex) if sg.captured]
        assert sg.self_keyed and ex._recent
        n_inputs = len(sg.segment.inputs)
        # The second pass: the shapes walked for the first frames only (the initial values,
        # then the first frame reading the graph's own), not once per frame.
        assert 0 < len(walks) - before <= 3 * n_inputs
    finally:
        g.close()


def test_capture_refused_on_lanes_with_sets(monkeypatch):
    """A capture refused on several lanes falls back to one lane with sets of their own too:
    each set first runs once on one lane (its scratch, per stream on CUDA), then is captured;
    every set ends captured and every output equals the eager run's."""
    from tests.graph.test_capture_lanes import refuse_lanes

    refused = refuse_lanes(monkeypatch)
    cams = _cams(16)
    g = _graph("warp-cpu", 3)
    try:
        eager = [g.process(f, capture=False) for f in cams]
        g.reset()
        got = [g.process(f, capture=True) for f in cams]
        (sg,) = [sg for sg in _segment_graphs(g.plan.executor()) if sg.captured]
        assert refused and sg.lanes.count == 1 and all(b.graph is not None for b in sg.sets)
        for i, (e, c) in enumerate(zip(eager, got)):
            assert _same(e, c), i
    finally:
        g.close()
