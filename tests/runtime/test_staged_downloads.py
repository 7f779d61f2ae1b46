"""Staged downloads (Transfers.stage_download into a HostPool): the pool lends buffers as NumPy
arrays and recycles one only once every array on it is garbage, within its cap; a graph
streamed with staged downloads gives the unstaged run's outputs bit for bit, also to a
caller that keeps them across many frames. A delay's value a CPU task of the next frame
reads (the two-camera graph's ``prev_pts[-1]``) is staged too and kept in its ring's slot
until read or dropped: the reader downloads nothing itself.

Without CUDA the staged path runs on Warp's CPU device through ``Executor.STAGE_ON_HOST``
(plain host buffers, synchronous copies): the same code, minus the DMA.
"""

from __future__ import annotations

import collections
import gc

import cv2
import numpy as np
import pytest

from tests.benchmark_scripts import load_bench
from tests.images import bgr
from tests.isolated import run_isolated
from warpvx.backend import init_warp
from warpvx.runtime import DEVICE, Executor, Ring, Slot, Transfers
from warpvx.runtime.pinned import HostPool, size_class
from warpvx.runtime.transfers import ROW_HINTS

SIZE = (128, 96)


def _cams(n):
    """``n`` two-camera frames of a real photo panning (the right camera mirrored)."""
    src = cv2.resize(bgr("astronaut"), (SIZE[0] + 32, SIZE[1] + 32), interpolation=cv2.INTER_AREA)
    out = []
    for i in range(n):
        M = np.float32([[1, 0, -16 + 1.5 * (i % 12)], [0, 1, -16 + 0.75 * (i % 12)]])
        f = cv2.warpAffine(src, M, SIZE, borderMode=cv2.BORDER_REFLECT)
        out.append({"frameL": f, "frameR": np.ascontiguousarray(f[:, ::-1])})
    return out


def _same(a, b):
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return type(a) is type(b) and len(a) == len(b) and all(map(_same, a, b))
    flat = getattr(a, "__warpvx_flatten__", None)
    if flat is not None:
        (xa, _), (xb, _) = flat(), b.__warpvx_flatten__()
        return type(a) is type(b) and all(_same(u, v) for u, v in zip(xa, xb))
    if not isinstance(a, np.ndarray):
        return type(a) is type(b) and a == b
    return isinstance(b, np.ndarray) and a.shape == b.shape and a.dtype == b.dtype and \
        np.array_equal(a, b)


#: The executors' host pool size (tests set it to 0 for unstaged runs on CUDA).
POOL_BYTES = Executor.HOST_POOL_BYTES


def _graph(cams, gpu):
    g = load_bench("graph_bench").build_graph(SIZE, max_corners=100)
    g.verify(cams[:2])
    g.schedule("baseline", n_cpus=2, gpu=gpu)
    return g


def _stream(cams, gpu, *, staged, capture, monkeypatch, depth=3):
    """Outputs (host) of the two-camera graph streamed over ``cams``, and the executor's host
    pool (None without one). Unstaged: no pool on warp-cpu, an empty one on CUDA."""
    monkeypatch.setattr(Executor, "STAGE_ON_HOST", staged)
    monkeypatch.setattr(Executor, "HOST_POOL_BYTES", POOL_BYTES if staged else 0)
    g = _graph(cams, gpu)
    try:
        outs = list(g.stream(cams, depth=depth, capture=capture))
        return outs, g.plan.executor()._host_pool
    finally:
        g.close()


def test_pool_recycles_a_buffer_only_once_every_array_on_it_is_garbage():
    pool = HostPool(1 << 20, pinned=False)
    a = pool.take((4, 3), np.dtype(np.float32))
    assert a.shape == (4, 3) and a.dtype == np.float32 and pool.lent() == 48
    a[:] = 7
    view = a[1:, :2]
    del a
    gc.collect()
    b = pool.take((4, 3), np.dtype(np.float32))  # the first buffer is still held by `view`
    b[:] = -1
    assert np.all(view == 7) and pool.allocated == 96
    del view
    gc.collect()
    assert pool.lent() == 48
    c = pool.take((12,), np.dtype(np.float32))  # same bytes: the freed buffer again
    assert pool.allocated == 96 and pool.lent() == 96 and not np.shares_memory(b, c)


def test_pool_reuses_a_buffer_for_counted_rows_of_another_count():
    """Downloads of a few KB whose size changes every frame (a detector's counted rows) share
    buffers of a size class: one allocation, not one per count."""
    pool = HostPool(1 << 20, pinned=False)
    a = pool.take((700, 2), np.dtype(np.float32))  # 5600 bytes
    assert a.shape == (700, 2) and pool.allocated == size_class(5600) >= 5600
    a[:] = 3
    del a
    gc.collect()
    b = pool.take((690, 2), np.dtype(np.float32))  # 5520 bytes: the same class
    assert b.shape == (690, 2) and pool.allocated == size_class(5600) == size_class(5520)
    c = pool.take((690, 2), np.dtype(np.float32))  # b is lent: a new buffer
    assert pool.allocated == 2 * size_class(5520) and not np.shares_memory(b, c)
    assert size_class(48) == 48 and size_class(4096) == 4096  # small ones exact
    for n in (4097, 5000, 65537, 3686400):
        assert n <= size_class(n) <= 1.125 * n


def test_pool_stays_within_its_cap_and_frees_on_close():
    pool = HostPool(100, pinned=False)
    held = [pool.take((10,), np.dtype(np.float64)) for _ in range(2)]
    assert held[0] is not None and held[1] is None and pool.allocated == 80
    pool.close()
    assert pool.allocated == 80  # lent: freed once garbage, never under the caller
    held[0][:] = 1.0
    del held
    gc.collect()
    assert pool.allocated == 0 and pool.take((1,), np.dtype(np.uint8)) is None


def test_a_slot_reads_its_staged_download_as_views_of_the_pool():
    """Slot.host takes a staged download instead of downloading again: a Counted with a
    block cut to its count on the host, views of the pool's buffers (no copy), read once."""
    from warpvx._counted import Block

    wp = init_warp()
    rows = np.arange(10, dtype=np.float32).reshape(5, 2)
    (c,) = Block.layout([rows], 5, "cpu")
    c.rows.assign(rows)
    c.count.assign(np.int32([3]))
    pool = HostPool(1 << 20, pinned=False)
    io = Transfers("cpu", pool)
    slot = Slot.holding(c, DEVICE)
    slot.staged = io.stage_download(c)
    assert slot.ready_event() is None  # done on return on Warp's CPU device
    c.rows.assign(np.zeros_like(rows))  # after the copy: not what is read
    got = slot.host(io, waited=None)
    np.testing.assert_array_equal(got, rows[:3])
    assert slot.staged is None and slot.host(io) is got and io.moved == c.block.array.shape[0]
    assert pool.lent() == c.block.array.shape[0]
    assert io.stage_download(wp.zeros(3, dtype=wp.vec2, device="cpu")) is None  # a vector dtype
    assert Transfers("cpu").stage_download(c) is None  # no pool


def test_a_large_counted_block_stages_its_count_and_copies_only_its_counted_rows():
    """A Counted whose block is past ONE_COPY_MAX_BYTES (FAST's keypoints) stages its count
    and copies the rows it counts when read (not the whole capacity), the same value as the
    synchronous download."""
    from warpvx._counted import ONE_COPY_MAX_BYTES, Block

    wp = init_warp()
    cap = ONE_COPY_MAX_BYTES // 8 + 100
    rows = np.random.default_rng(4).standard_normal((cap, 2)).astype(np.float32)
    (c,) = Block.layout([rows], cap, "cpu")
    c.rows.assign(rows)
    c.count.assign(np.int32([7]))
    assert c.block.array.shape[0] > ONE_COPY_MAX_BYTES
    ROW_HINTS._last.clear()  # no count of this layout read yet
    pool = HostPool(1 << 22, pinned=False)
    io = Transfers("cpu", pool)
    staged = io.stage_download(c)
    assert staged.nbytes == 4 and pool.lent() == 4  # the count only
    got = io.unstage(staged)
    np.testing.assert_array_equal(got, rows[:7])
    np.testing.assert_array_equal(got, Transfers("cpu").download(c))
    # the count's buffer went back once read (the value holds its rows only)
    assert pool.lent() == got.nbytes and io.moved == 4 + got.nbytes


def test_a_large_counted_block_stages_the_rows_its_last_count_suggests(monkeypatch):
    """Once a count of a large Counted's layout was read, its next staged download copies
    that many rows (plus a margin) with the count: a reader whose count fits gets them
    without a second copy; a count past them copies its rows when read, as before. Values
    always equal the synchronous download's."""
    from warpvx._counted import ONE_COPY_MAX_BYTES, Block

    cap = ONE_COPY_MAX_BYTES // 8 + 300
    rows = np.random.default_rng(5).standard_normal((cap, 2)).astype(np.float32)
    (c,) = Block.layout([rows], cap, "cpu")
    c.rows.assign(rows)
    ROW_HINTS._last.clear()
    pool = HostPool(1 << 22, pinned=False)
    io = Transfers("cpu", pool)
    copies = []
    real_copy = Transfers._counted_rows_copy

    def copy(self, block, n, count):
        copies.append(n)
        return real_copy(self, block, n, count)

    monkeypatch.setattr(Transfers, "_counted_rows_copy", copy)
    ahead = 40 + 40 // 4 + ROW_HINTS.MARGIN  # rows staged after a count of 40
    for count, staged_rows, copied in [(40, 0, [40]), (45, ahead, []), (ahead, 45 + 45 // 4 + 64, []),
                                       (cap, ahead + ahead // 4 + 64, [cap]), (3, cap, [])]:
        copies.clear()
        c.count.assign(np.int32([count]))
        staged = io.stage_download(c)
        assert staged.nbytes == 4 + 8 * staged_rows
        got = io.unstage(staged)
        np.testing.assert_array_equal(got, rows[:count])
        np.testing.assert_array_equal(got, Transfers("cpu").download(c))
        assert copies == copied
    # a value read from a prefix keeps its buffer; once garbage, every buffer went back
    del got, staged
    gc.collect()
    assert pool.lent() == 0


@pytest.mark.parametrize("depth", [1, 3])
@pytest.mark.parametrize("capture", [False, True], ids=["eager", "captured"])
def test_staged_stream_gives_the_unstaged_outputs(capture, depth, warp_backend, monkeypatch):
    cams = _cams(16)
    ref, unstaged = _stream(cams, warp_backend, staged=False, capture=capture,
                            monkeypatch=monkeypatch, depth=depth)
    got, pool = _stream(cams, warp_backend, staged=True, capture=capture,
                        monkeypatch=monkeypatch, depth=depth)
    assert unstaged is None or unstaged.allocated == 0
    assert pool.allocated > 0  # the staged path ran
    assert len(got) == len(ref) == 16
    for a, b in zip(got, ref):
        assert _same(a, b)


def _lease(a):
    """The pool lease (or other owner) under NumPy array ``a`` and its views."""
    while isinstance(a, np.ndarray):
        a = a.base
    return a


def test_a_units_staged_downloads_take_one_pool_lease_a_frame(monkeypatch):
    """The captured segment's outputs that CPU tasks and the caller read (9 values a frame:
    keypoints, the detector's score map, the homographies' points) are staged as one batch:
    once the first frame sized it, one pool lease a frame with every buffer carved from it,
    not one lease per buffer (11); buffers past BATCH_LEASE_MAX_BYTES get their own, so a
    caller keeping a frame's keypoints does not hold its score map's buffer. Outputs: the
    unstaged run's, bit for bit."""
    cams = _cams(20)
    ref, _ = _stream(cams, "warp-cpu", staged=False, capture=True, monkeypatch=monkeypatch)
    monkeypatch.setattr(Executor, "STAGE_ON_HOST", True)
    monkeypatch.setattr(Executor, "HOST_POOL_BYTES", POOL_BYTES)
    counts = collections.Counter()
    take, batch = HostPool.take, Transfers.stage_downloads

    def counted_take(self, shape, dtype):
        counts["takes"] += 1
        return take(self, shape, dtype)

    def counted_batch(self, values, *args, **kwargs):
        counts["batches"] += 1
        counts["values"] += len(values)
        return batch(self, values, *args, **kwargs)

    monkeypatch.setattr(HostPool, "take", counted_take)
    monkeypatch.setattr(Transfers, "stage_downloads", counted_batch)
    for limit, takes in ((Transfers.BATCH_LEASE_MAX_BYTES, 1), (4096, 2)):
        monkeypatch.setattr(Transfers, "BATCH_LEASE_MAX_BYTES", limit)
        g = _graph(cams, "warp-cpu")
        try:
            got = []
            for i, outputs in enumerate(g.stream(cams, depth=3, capture=True)):
                if i == 3:
                    counts.clear()
                got.append(outputs)
        finally:
            g.close()
        frames = len(cams) - 4
        assert counts["batches"] == frames and counts["values"] == 9 * frames
        # The score map (128x96 float32, 48 KB) is the one buffer past 4096 bytes.
        assert counts["takes"] == takes * frames
        last = got[-1]
        kps = [_lease(a) for a in last["keypointsL"].__warpvx_flatten__()[0]]
        assert len({id(x) for x in kps}) == 1
        assert (_lease(last["scoreL"]) is kps[0]) == (limit > 48 << 10)
        for a, b in zip(got, ref):
            assert _same(a, b)


def test_a_batchs_shared_event_is_recycled_once_every_download_is_closed():
    """Downloads staged as one batch share one event: it goes back to the free events only
    when the last of them is closed (read or dropped), once."""
    from warpvx.runtime.transfers import _Sharers, _Staged

    free = collections.deque()
    event = object()
    sharers = _Sharers(3)
    batch = [_Staged(None, {}, {}, event, 0, free, sharers) for _ in range(3)]
    batch[1].close()
    batch[1].close()  # closed twice: counted once
    batch[0].close()
    assert not free
    batch[2].close()
    assert list(free) == [event]


def test_outputs_kept_across_many_frames_keep_their_values(warp_backend, monkeypatch):
    """A caller keeping the first 10 frames' outputs while 50 more run sees their values
    (a pool buffer is never lent again while an array on it lives), and a small pool stays
    within its cap (past it, downloads are the usual fresh arrays)."""
    cams = _cams(60)
    ref, _ = _stream(cams, warp_backend, staged=False, capture=True, monkeypatch=monkeypatch)
    ref = ref[:10]
    cap = 64 << 10
    monkeypatch.setattr(Executor, "STAGE_ON_HOST", True)
    monkeypatch.setattr(Executor, "HOST_POOL_BYTES", cap)
    g = _graph(cams, warp_backend)
    try:
        kept, most = [], 0
        for i, outputs in enumerate(g.stream(cams, depth=3, capture=True)):
            if i < 10:
                kept.append(outputs)
            most = max(most, g.plan.executor()._host_pool.allocated)
        assert 0 < most <= cap
    finally:
        g.close()
    for a, b in zip(kept, ref):
        assert _same(a, b)


def test_outputs_are_staged_only_for_a_caller_wanting_host_data(monkeypatch):
    """Device inputs give device outputs (Graph.process): their downloads are not staged,
    those of the GPU -> CPU edges still are."""
    wp = init_warp()
    staged = []
    stage = Transfers.stage_downloads  # (every staged download goes through it)
    monkeypatch.setattr(Transfers, "stage_downloads",
                        lambda self, vs, e=None, **kw: staged.extend(vs) or stage(self, vs, e, **kw))
    monkeypatch.setattr(Executor, "STAGE_ON_HOST", True)
    cams = _cams(3)
    g = _graph(cams, "warp-cpu")
    try:
        staged.clear()  # (verify's)
        g.process(cams[0])
        on_host = len(staged)
        staged.clear()
        device = {k: wp.array(v, dtype=wp.uint8, device="cpu") for k, v in cams[1].items()}
        out = g.process(device)
    finally:
        g.close()
    assert 0 < len(staged) < on_host
    assert any(not isinstance(v, np.ndarray) for v in out.values())  # device outputs


def test_a_ring_releases_the_staged_downloads_of_the_slots_it_drops():
    """A delay's slot keeps its staged download for a later frame's reader (who takes it:
    views of the pool, no second copy); a slot the ring drops (aged out, replaced by a
    write, reset), a cancelled frame's or every slot when the executor closes lets its
    download go, waited for, and its buffers return to the pool. The values stay readable."""
    wp = init_warp()
    pool = HostPool(1 << 20, pinned=False)
    io = Transfers("cpu", pool)
    ring = Ring(1, np.zeros(3, np.float32))
    slots = {}

    def produce(f):
        slot = slots[f] = Slot.holding(wp.array(np.full(3, f, np.float32), device="cpu"), DEVICE)
        slot.staged = io.stage_download(slot.value)
        ring.reserve(f, slot)

    for f in range(4):
        produce(f)
    assert pool.lent() == 4 * 12 and all(s.staged is not None for s in slots.values())
    got = ring.get(1).host(io)  # frame 2's reader of delay[-1] takes frame 1's download
    assert slots[1].staged is None and got.base is not None and io.moved == 12
    np.testing.assert_array_equal(got, [1, 1, 1])
    ring.age(2)  # keeps frames 1 and 2: frame 0's download is dropped, unread
    assert slots[0].staged is None and slots[2].staged is not None
    assert pool.lent() == 3 * 12  # (frame 1's value holds its buffer)
    ring.put(3, np.full(3, 9, np.float32))  # a user's write replaces frame 3's slot
    assert slots[3].staged is None and pool.lent() == 2 * 12
    ring.discard_pending(2)  # frame 2 cancelled after its producer ran: its value stays
    assert slots[2].staged is None and ring.get(2) is slots[2] and pool.lent() == 12
    np.testing.assert_array_equal(ring.get(2).host(io), [2, 2, 2])  # downloaded, not staged
    produce(4)
    ring.release_staged()  # the executor closes
    assert slots[4].staged is None and ring.get(4) is slots[4] and pool.lent() == 12
    produce(5)
    ring.reset()
    assert slots[5].staged is None and pool.lent() == 12 and ring.get(5).value[0] == 0
    del got, slots
    gc.collect()
    assert pool.lent() == 0


def _count_downloads(monkeypatch) -> collections.Counter:
    """Synchronous downloads (``Transfers._download_array``: a reader copying after the
    producer, not a staged download) counted from now."""
    counts = collections.Counter()
    download = Transfers._download_array

    def counted(self, a, event):
        counts["synchronous"] += 1
        return download(self, a, event)

    monkeypatch.setattr(Transfers, "_download_array", counted)
    return counts


@pytest.mark.parametrize("depth", [1, 3])
def test_the_next_frames_reader_of_a_delayed_gpu_value_gets_a_staged_download(
        depth, warp_backend, monkeypatch):
    """The two-camera graph's homographies (CPU) read the previous frame's Harris corners
    (``prev_pts[-1]``, made on the GPU): staged as they are produced, kept in the delay's
    ring across the frame's wait, so after the first frame (its delayed value is another
    executor's, verification's) no frame downloads anything synchronously; the pool's lent
    bytes repeat with the input (frames cycle with period 12): nothing piles up."""
    monkeypatch.setattr(Executor, "STAGE_ON_HOST", True)
    # FAST's rows staged ahead follow the last count read, which with frames in flight is
    # read after or before the next frame stages (thread timing): the lent bytes would
    # wobble by a size class. Without the hint they are a function of the frame.
    monkeypatch.setattr(ROW_HINTS, "rows", lambda block: 0)
    cams = _cams(36)
    g = _graph(cams, warp_backend)
    counts = _count_downloads(monkeypatch)
    per_frame, lent = [], []
    try:
        for out in g.stream(cams, depth=depth, capture=True):
            del out
            per_frame.append(counts["synchronous"])
            counts.clear()
            lent.append(g.plan.executor()._host_pool.lent())
    finally:
        g.close()
    # (Two a frame without staging. Exactly none: the staged copy is queued before the
    # corners are published, so no reader woken by them can find it missing.)
    assert len(per_frame) == 36 and sum(per_frame[1:]) == 0, per_frame
    # Frame k lends about what frame k - 12 did (the input's period), past warm-up: nothing
    # piles up. (Not to the byte on CUDA: which frames' outputs the caller still holds when
    # a frame's staging takes its buffers depends on thread timing.)
    assert max(lent[-12:]) <= 1.1 * max(lent[4:16]), lent


def test_lent_bytes_return_to_the_same_value_after_each_reset(warp_backend, monkeypatch):
    """Streams of the same frames, each followed by ``Graph.reset`` (the delays drop their
    slots and the staged downloads in them): the pool lends the same bytes after each (the
    graph's published outputs), and the staged delayed reads went on after a reset."""
    monkeypatch.setattr(Executor, "STAGE_ON_HOST", True)
    monkeypatch.setattr(ROW_HINTS, "rows", lambda block: 0)  # (as above)
    cams = _cams(10)
    g = _graph(cams, warp_backend)
    counts = _count_downloads(monkeypatch)
    lent = []
    try:
        for _ in range(3):
            for out in g.stream(cams, depth=3, capture=True):
                del out
            g.reset()
            gc.collect()
            lent.append(g.plan.executor()._host_pool.lent())
    finally:
        g.close()
    assert lent[0] > 0 and max(lent) <= 1.1 * min(lent), lent  # (as above: about the same)
    # None at all: a reset's first frame reads the delays' initial values (host data), each
    # later frame the staged download of its predecessor's corners.
    assert counts["synchronous"] == 0, counts  # (as above; 54 without staging)


RESET_AND_FAIL = """
from tests.benchmark_scripts import load_bench
from tests.runtime.test_staged_downloads import SIZE, _cams, _same
from warpvx.errors import NodeExecutionError
from warpvx.runtime import Executor

cams = _cams(20)
POOL = Executor.HOST_POOL_BYTES

def run(staged):  # unstaged: no pool on warp-cpu, an empty one on CUDA
    Executor.STAGE_ON_HOST = staged
    Executor.HOST_POOL_BYTES = POOL if staged else 0
    bench = load_bench("graph_bench")
    homography, calls, armed = bench.homography, [], []

    def failing(*args):  # both cameras' homographies: two calls a frame
        calls.append(1)
        if armed and len(calls) == 13:
            raise ValueError("boom in homography")
        return homography(*args)

    bench.homography = failing
    g = bench.build_graph(SIZE, max_corners=100)
    g.verify(cams[:2])
    g.schedule("baseline", n_cpus=2, gpu=GPU)
    before, failing, after = [], [], []  # outputs: before the failure, up to it, after it
    try:
        for i, out in enumerate(g.stream(cams[:10], depth=3, capture=CAPTURE)):
            before.append(out)
            if i == 4:
                break  # the generator closes: frames in flight are dropped
        g.reset()
        before += list(g.stream(cams[10:], depth=3, capture=CAPTURE))
        calls.clear()
        armed.append(True)
        try:
            for out in g.stream(cams, depth=3, capture=CAPTURE):
                failing.append(out)
        except NodeExecutionError as e:
            assert isinstance(e.__cause__, ValueError), e
            print("raised", staged, flush=True)
        armed.clear()
        more = list(g.stream(cams[:6], depth=3, capture=CAPTURE))  # goes on, no reset
        print("after failure", staged, len(more), flush=True)
        g.reset()
        after += list(g.stream(cams[:8], depth=3, capture=CAPTURE))
        return before, failing, after, g.plan.executor()._host_pool
    finally:
        g.close()

ref = run(False)
got = run(True)
# (Which frame fails depends on the two CPU workers' interleaving: compare a common prefix.)
n = min(len(ref[1]), len(got[1]))
print("frames", len(got[0]), len(got[2]), n >= 3)
print("same", all(len(a) == len(b) for a, b in [(ref[0], got[0]), (ref[2], got[2])]) and
      all(_same(a, b) for r, o in zip(ref[:3], got[:3]) for a, b in zip(o, r)))
print("pool", got[3] is not None and got[3].allocated > 0 and
      (ref[3] is None or ref[3].allocated == 0))
"""


@pytest.mark.parametrize("capture", [False, True], ids=["eager", "captured"])
def test_reset_and_a_failing_node_mid_stream_with_staged_delays(capture, warp_backend):
    """Staged delayed downloads across a stream closed early and a reset, a node failing
    mid-stream (frames cancelled with staged downloads in their delays' slots), a stream
    going on after the failure, and a reset again: no hang (a subprocess with a time-out),
    the same outputs as without staging (where they do not depend on which cancelled frames'
    producers ran: up to the failure, and after the last reset)."""
    code = RESET_AND_FAIL.replace("GPU", repr(warp_backend)).replace(
        "CAPTURE", repr(True if capture else False))
    out = run_isolated(code, timeout=300).split("\n")
    assert "raised False" in out and "raised True" in out, out
    assert "after failure False 6" in out and "after failure True 6" in out, out
    assert "frames 15 8 True" in out and "same True" in out and "pool True" in out, out
