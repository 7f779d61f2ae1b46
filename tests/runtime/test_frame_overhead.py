"""What the executor does per value and per frame, kept small: a slot is its own ready flag,
a frame makes no capture signature without a capturable segment, the plan keeps results
without their outputs (not copies), a stream reads no old frame's CUDA events per frame, and
the benchmark's call counters count Warp's native calls and leave Warp as it was."""

from __future__ import annotations

import gc
import threading
import time
from collections import deque

import numpy as np
import pytest

from warpvx.graph.diagnostics import _chain
from warpvx.graph.plan import KEEP_FRAMES
from warpvx.runtime import HOST, Flag, Slot
from warpvx.runtime import timeline as tl

from tests.benchmark_scripts import load_bench


def test_slot_is_its_own_flag_and_wakes_every_waiter():
    s = Slot()
    assert isinstance(s, Flag)
    assert not s.ready and not s.is_set() and s.wait(0.001) is False
    woke = []
    threads = [threading.Thread(target=lambda: woke.append((s.wait(5.0), s.value)))
               for _ in range(3)]
    for t in threads:
        t.start()
    time.sleep(0.01)
    value = np.arange(3)
    s.set(value, HOST)
    for t in threads:
        t.join(5)
    assert [w for w, _ in woke] == [True] * 3 and all(v is value for _, v in woke)
    assert s.ready and s.is_set() and s.where == HOST
    held = Slot.holding(7)
    assert held.ready and held.value == 7 and held.where == HOST


@pytest.mark.parametrize("chain, capturable", [("gpu", False), ("blur", True)])
def test_a_frame_makes_a_capture_signature_only_where_a_segment_may_be_captured(chain, capturable):
    if chain == "blur":
        import warpvx

        g = warpvx.Graph("blur")
        v = g.input("x", shape=(16, 16), dtype=np.uint8)
        g.output("y", g.gaussian_blur(g.gaussian_blur(v, ksize=(3, 3), sigma=0.8, target="gpu"),
                                      ksize=(3, 3), sigma=0.8, target="gpu"))
        x = (np.arange(256).reshape(16, 16) * 37 % 251).astype(np.uint8)
        g.verify({"x": x})
        g.schedule("baseline", n_cpus=1, gpu="warp-cpu")
    else:
        g = _chain(3, chain)
        x = np.arange(4, dtype=np.float32)
        g.schedule("heft", n_cpus=1, gpu="warp-cpu")
    ex = g.plan.executor()
    try:
        frame = ex.submit(0, {"x": (x, HOST)}, capture=True)
        assert frame.capture is capturable
        assert (frame.signature is not None) is capturable
        want = g.process({"x": x}, capture=False)["y"]
        got = ex.wait(frame).outputs["y"]
        np.testing.assert_array_equal(got, want)
    finally:
        g.close()


def test_the_plan_keeps_each_result_without_its_outputs_and_the_caller_gets_them():
    g = _chain(4, "mixed")
    g.schedule("heft", n_cpus=1, gpu="warp-cpu")
    x = np.arange(4, dtype=np.float32)
    try:
        out = g.process({"x": x})
        np.testing.assert_array_equal(out["y"], x)
        kept = g.plan.last_run[-1]
        assert kept.outputs == {} and set(kept.timeline) == {f"n{i}" for i in range(4)}
        streamed = list(g.stream(({"x": x + i} for i in range(3)), depth=2))
        for i, o in enumerate(streamed):
            np.testing.assert_array_equal(o["y"], x + i)
        assert [r.outputs for r in list(g.plan.last_run)[-3:]] == [{}, {}, {}]
        np.testing.assert_array_equal(g.outputs["y"].read(), x + 2)  # published
    finally:
        g.close()


class _Clock:
    """A stand-in CUDA event: its device time in ms."""

    def __init__(self, ms):
        self.ms = ms


def test_a_stream_keeping_the_plans_window_reads_no_old_events_per_frame(monkeypatch):
    """A stream's plan keeps KEEP_FRAMES results (Plan.last_run); results leaving that window
    are garbage. No frame may read an older frame's events on its way out (a native call per
    event, on the critical path): the pool's unread bound lies above the window plus frames
    in flight."""
    reads = []
    monkeypatch.setattr(tl, "elapsed_since",
                        lambda start: lambda end: reads.append(end) or end.ms - start.ms)
    pool = tl.EventPool("cuda:0")
    last_run = deque(maxlen=KEEP_FRAMES)
    anchor = (100.0, _Clock(0.0))
    for i in range(KEEP_FRAMES * 3):
        f = tl.Frame(i, {}, 1)
        a, b = _Clock(1.0 + i), _Clock(2.0 + i)
        f.trace, f.t0, f.events = {"g": ("gpu", a, b, None)}, 100.0, [a, b]
        res = tl.frame_result(f, {}, anchor, pool.put)
        pool.lend(res)
        last_run.append(res)
        del res
    gc.collect()
    assert reads == []  # every result that left the window went back unread
    assert len(pool) == 2 * (KEEP_FRAMES * 2)
    assert last_run[0].timeline["g"].finish == pytest.approx(2.0 + KEEP_FRAMES * 2)
    assert len(reads) == 2  # read when asked


def test_native_counter_counts_warps_native_calls_and_restores_them():
    from warpvx.backend import init_warp
    from warpvx.runtime import native_copy

    counts = load_bench("native_counts")
    wp = init_warp()
    a = wp.array(np.arange(6, dtype=np.float32), device="cpu")
    with counts.NativeCounter() as c:
        got = native_copy.to_host(a)
        got2 = native_copy.to_host(a)
    np.testing.assert_array_equal(got, np.arange(6, dtype=np.float32))
    np.testing.assert_array_equal(got2, got)
    assert c.counts["wp_memcpy_h2h"] == 2
    native_copy.to_host(a)  # restored: no longer counted
    assert c.counts["wp_memcpy_h2h"] == 2
    import ctypes

    assert isinstance(native_copy.native_entry_points().h2h, ctypes._CFuncPtr)  # Warp's own again


def test_calls_split_into_per_node_and_per_frame():
    counts = load_bench("native_counts")
    # chains of 4 and 8 nodes: 3 Python calls and 1 event per node, 20 calls and 2 syncs per frame
    short = {"python": 20 + 4 * 3, "native": {"event": 4.0, "sync": 2.0}}
    long_ = {"python": 20 + 8 * 3, "native": {"event": 8.0, "sync": 2.0}}
    split = counts.per_node_and_frame(short, long_, 4, 8)
    assert split["python"] == (3, 20)
    assert split["native"] == (1, 2)
    assert split["by_name"] == {"event": (1, 0), "sync": (0, 2)}


def test_address_is_numpys_data_pointer_for_every_kind_of_array():
    from warpvx.runtime.native_copy import address

    a = np.arange(12, dtype=np.float32)
    ro = a.copy()
    ro.flags.writeable = False
    empty = np.empty(0, np.uint8)
    strided = a.reshape(3, 4)[:, ::2]  # (callers pass contiguous arrays; still the right pointer)
    for x in (a, a[3:], ro, empty, strided):
        assert address(x) == x.ctypes.data


def test_is_warp_array_tells_warp_arrays_from_the_rest():
    from warpvx.backend import init_warp
    from warpvx.runtime.native_copy import is_warp_array

    wp = init_warp()
    w = wp.zeros(3, dtype=wp.float32, device="cpu")
    assert is_warp_array(w) and is_warp_array(w)  # found, then remembered
    for other in (np.zeros(3), [1, 2], None, 3.0, wp.float32):
        assert not is_warp_array(other)


def test_event_pool_makes_reserved_events_ahead_and_gets_them_without_making_any(monkeypatch):
    made = []

    class _Warp:
        @staticmethod
        def Event(device, enable_timing=False):  # noqa: N802 - Warp's name
            made.append((device, enable_timing))
            return _Clock(len(made))

    monkeypatch.setattr(tl, "warp", lambda: _Warp)
    pool = tl.EventPool("cuda:0")
    pool.reserve(5)
    assert len(made) == 5 and made[0] == ("cuda:0", True) and len(pool) == 5
    pool.reserve(3)  # enough already
    assert len(made) == 5
    got = [pool.get() for _ in range(5)]
    assert len(made) == 5 and len({id(e) for e in got}) == 5 and len(pool) == 0
    pool.get()  # the pool empty: made on the spot, as before
    assert len(made) == 6
    pool.put(got)
    pool.reserve(4)
    assert len(made) == 6 and len(pool) == 5
