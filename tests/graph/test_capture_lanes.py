"""Lanes of a captured segment (warpvx.runtime.capture.lanes): its tasks spread over streams
by their data dependencies, so that its CUDA graph runs independent branches concurrently;
tasks inserting conditional graph nodes run with every lane joined (Warp pauses the capture).

The rule is checked on hand-built programs (every dependency ordered by a lane or an event,
independent branches on different lanes), the fork/wait/join protocol on streams that log
what is enqueued on them (Warp's CPU device has one stream, so the executor never switches
there), and the two-camera graph's captured runs with lanes against one lane and the eager
run on real frames (on cuda too where present: many replays, where a race would show).
"""

from __future__ import annotations

import itertools

import networkx as nx
import numpy as np
import pytest

from tests.graph.test_capture import _camera_frames, _capture_arg, _same, _two_cameras
from warpvx.errors import WarpvxTypeError, WarpvxValueError
from warpvx.runtime import ExecTask, InputRef, Program
from warpvx.runtime.capture import NotCapturable, SegmentGraph, segments
from warpvx.runtime.lanes import MAX_LANES, Lanes, lanes

pytestmark = pytest.mark.timeout(300)


def _task(name, inputs, out=None):
    refs = tuple(r if isinstance(r, InputRef) else InputRef(r) for r in inputs)
    return ExecTask(name, refs, (name,), gpu=lambda *v, out=None: out,
                    gpu_out=out or (lambda: None), capture=True)


def _dependencies(tasks):
    """(producer index, consumer index) of every same-frame read inside ``tasks``."""
    made = {k: i for i, t in enumerate(tasks) for k in t.outputs}
    return {(made[r.key], i) for i, t in enumerate(tasks) for r in t.inputs
            if r.offset == 0 and r.key in made and made[r.key] < i}


def _ordered_by(assigned):
    """What the lanes order, in enqueue order: each lane's tasks one after the other, each
    wait, a serial task after every task before it and before every task after it (the
    lanes joined before it and forked from it after)."""
    g = nx.DiGraph()
    g.add_nodes_from(range(len(assigned.of)))
    assert sorted(assigned.order) == list(range(len(assigned.of)))
    done, last, fork = [], {}, None
    for i in assigned.order:
        if i in assigned.serial:
            assert assigned.of[i] == 0 and not assigned.waits[i]
            g.add_edges_from((j, i) for j in done)
            last, fork = {}, i
        else:
            lane = assigned.of[i]
            if lane in last:
                g.add_edge(last[lane], i)
            elif fork is not None:
                g.add_edge(fork, i)
            last[lane] = i
            g.add_edges_from((p, i) for p in assigned.waits[i])
        done.append(i)
    return g


def _assert_respects(tasks, assigned):
    order = _ordered_by(assigned)
    for p, c in _dependencies(tasks):
        assert nx.has_path(order, p, c), (tasks[p].name, tasks[c].name, assigned)


# Two cameras: gray -> pyramid -> lk (reading the pyramid a frame back too), gray -> blur ->
# fast, and a detector on the left gray; in the executor's order (left, then right).
TWO_CAMERAS = [_task(f"{n}{c}", ins) for c in "LR" for n, ins in (
    ("gray", [f"frame{c}"]), ("pyramid", ["gray" + c]),
    ("lk", [InputRef("pyramid" + c, -1), "pyramid" + c]), ("blur", ["gray" + c]),
    ("fast", ["blur" + c]))] + [_task("detectorL", ["grayL"])]


SORTING = {"fastL", "fastR", "grayR"}  # tasks taken as inserting conditional nodes


@pytest.mark.parametrize("serial", [(), SORTING])
@pytest.mark.parametrize("max_lanes", [1, 2, 3, 4, 8])
def test_lanes_respect_every_dependency(max_lanes, serial):
    assigned = lanes(TWO_CAMERAS, None, max_lanes, serial)
    assert len(assigned.of) == len(TWO_CAMERAS)
    assert assigned.count == len(set(assigned.of)) <= max_lanes
    assert set(assigned.of) == set(range(assigned.count))
    _assert_respects(TWO_CAMERAS, assigned)


def test_lanes_put_independent_branches_on_different_lanes():
    assigned = lanes(TWO_CAMERAS, None, MAX_LANES)
    of = dict(zip((t.name for t in TWO_CAMERAS), assigned.of))
    assert of["grayL"] != of["grayR"]  # the cameras
    assert len({of["pyramidL"], of["blurL"], of["detectorL"]}) > 1  # one camera's branches
    assert of["lkL"] == of["pyramidL"]  # a chain stays on its lane: no event
    assert not assigned.waits[[t.name for t in TWO_CAMERAS].index("lkL")]


def test_lanes_serial_tasks_run_last_on_lane_zero():
    """Serial tasks (conditional graph nodes: Warp pauses the capture, so every lane is
    joined) and what reads them are enqueued after the rest, on lane 0 for the serial ones;
    the rest still spreads over lanes."""
    names = [t.name for t in TWO_CAMERAS]
    assigned = lanes(TWO_CAMERAS, None, 4, SORTING)
    assert {names[i] for i in assigned.serial} == SORTING
    order = [names[i] for i in assigned.order]
    after = {"grayR", "pyramidR", "lkR", "blurR", "fastR", "fastL"}  # grayR and its readers
    assert set(order[-len(after):]) == after
    assert all(assigned.of[names.index(n)] == 0 for n in SORTING)
    first = [assigned.of[names.index(n)] for n in order[:-len(after)]]
    assert len(set(first)) > 1
    _assert_respects(TWO_CAMERAS, assigned)


def test_lanes_one_lane_is_the_chain_and_a_chain_takes_one_lane():
    one = lanes(TWO_CAMERAS, None, 1)
    assert one.of == (0,) * len(TWO_CAMERAS) and not any(one.waits) and one.count == 1
    chain = [_task("a", ["x"]), _task("b", ["a"]), _task("c", ["b", "a"])]
    assert lanes(chain, None, 4) == Lanes((0, 0, 0), ((), (), ()), 1, (0, 1, 2))


def test_lanes_follow_the_durations():
    """Two branches after a fork: the long one keeps the lane, and the task that reads both
    goes where it can start first (after the long one), waiting for the short one."""
    tasks = [_task("a", ["x"]), _task("long", ["a"]), _task("short", ["a"]),
             _task("join", ["long", "short"])]
    assigned = lanes(tasks, {"a": 1, "long": 10, "short": 1, "join": 1}, 4)
    assert assigned.of == (0, 0, 1, 0)
    assert assigned.waits == ((), (), (0,), (2,))
    _assert_respects(tasks, assigned)


def test_lanes_wait_once_per_producer_lane():
    """A lane that waited for a task of another lane needs no wait for that lane's earlier
    tasks."""
    tasks = [_task("a", ["x"]), _task("b", ["a"]), _task("c", ["x"]),
             _task("d", ["c", "a"]), _task("e", ["b", "a"])]
    assigned = lanes(tasks, None, 2)
    _assert_respects(tasks, assigned)
    for lane in range(assigned.count):
        waited = [p for i, w in enumerate(assigned.waits) if assigned.of[i] == lane for p in w]
        assert len(waited) == len(set(waited)), assigned


def test_lanes_random_dags_respect_every_dependency():
    rng = np.random.default_rng(11)
    for trial in range(200):
        n = int(rng.integers(1, 14))
        tasks = []
        for i in range(n):
            reads = [f"t{j}" for j in range(i) if rng.random() < 0.25] or ["x"]
            if i and rng.random() < 0.3:
                reads.append(InputRef(f"t{int(rng.integers(0, i))}", -1))
            tasks.append(_task(f"t{i}", reads))
        durations = {t.name: float(rng.random()) for t in tasks}
        serial = {t.name for t in tasks if rng.random() < 0.15}
        for cap in (1, 2, 4):
            assigned = lanes(tasks, durations if trial % 2 else None, cap, serial)
            assert assigned.count <= cap
            _assert_respects(tasks, assigned)


BAD_MAX_LANES = [(0, WarpvxValueError), (-2, WarpvxValueError), (2.5, WarpvxTypeError),
                 (True, WarpvxTypeError)]


@pytest.mark.parametrize("bad, error", BAD_MAX_LANES)
def test_lanes_bad_max_lanes_raises_naming_it(bad, error):
    with pytest.raises(error, match="max_lanes"):
        lanes(TWO_CAMERAS, None, bad)


# --------------------------------------------------------------------------- the protocol


class _Stream:
    """A stream that logs what is enqueued on it (as one node each of a happens-before DAG)."""

    def __init__(self, name, log, device):
        self.name, self.log, self.device = name, log, device

    def record_event(self, event):
        self.log.append(("record", self, event))
        return event

    def wait_event(self, event):
        self.log.append(("wait", self, event))


class _Device:
    def __init__(self):
        self.stream = None

    def set_stream(self, stream, sync=True):
        assert not sync, "a lane must not wait for the whole current stream"
        self.stream = stream


def _happens_before(log):
    """The DAG of the logged operations: each stream in order, each wait after the operation
    its event was last recorded behind."""
    g, last, recorded = nx.DiGraph(), {}, {}
    for k, (kind, stream, what) in enumerate(log):
        g.add_node(k)
        if stream in last:
            g.add_edge(last[stream], k)
        last[stream] = k
        if kind == "record":
            recorded[what] = k
        elif kind == "wait":
            g.add_edge(recorded[what], k)
    return g


def _logged_segment(tasks, max_lanes, fail=None, conditional=()):
    """Run segment ``tasks`` uncaptured on logging streams, after the first run (one
    stream, finding the tasks that insert conditional nodes: those in ``conditional``
    call ``wp.capture_if``); ``fail``: a task that raises in the second run. Returns (the
    second run's log, the streams, the SegmentGraph, the error or None)."""
    import warp as wp

    log, device = [], _Device()
    streams = [_Stream(f"lane{k}", log, device) for k in range(max_lanes)]
    device.stream = streams[0]
    flag = wp.array([1], dtype=wp.int32, device="cpu")
    second = []

    def run(name):
        def gpu(*values, out=None):
            if name == fail and second:
                raise RuntimeError(f"{name} failed")
            if name in conditional:
                wp.capture_if(flag, on_true=lambda: None)
            log.append(("task", device.stream, name))
            return out
        return gpu

    made = [ExecTask(t.name, t.inputs, t.outputs, gpu=run(t.name),
                     gpu_out=lambda: wp.zeros(4, dtype=wp.float32, device="cpu"), capture=True)
            for t in tasks]
    program = Program({t.name: t for t in made}, ("frameL", "frameR", "x"),
                      {t.name: t.name for t in made})
    (seg,) = segments(program, [t.name for t in made])
    x = np.zeros(4, np.float32)
    sg = SegmentGraph(seg, [x] * len(seg.inputs), "cpu", None, max_lanes)
    events = {}
    sg._event = lambda kind, i, dev: events.setdefault((kind, i), object())
    sg._run_tasks(0, streams=streams)  # the first run: one stream
    assert {e[1] for e in log} == {streams[0]}
    assert {tasks[i].name for i in sg.lanes.serial} == set(conditional)
    del log[:]
    second.append(True)
    log.append(("copy in", streams[0], None))
    error = None
    try:
        sg._run_tasks(0, streams=streams)
    except RuntimeError as exc:
        error = exc
    log.append(("copy out", streams[0], None))
    assert device.stream is streams[0]  # the executor's stream is current again
    return log, streams, sg, error


@pytest.mark.parametrize("conditional", [(), SORTING])
@pytest.mark.parametrize("max_lanes", [1, 2, 4])
def test_lanes_fork_wait_and_join_order_every_dependency(max_lanes, conditional):
    """Each task runs on its lane's stream, after the copies in and its producers, and
    before the copies out (the join): what a capture turns into graph edges. A task found
    inserting a conditional node runs on the first stream with every lane joined."""
    log, streams, sg, error = _logged_segment(TWO_CAMERAS, max_lanes, conditional=conditional)
    assert error is None
    g = _happens_before(log)
    at = {what: k for k, (kind, _, what) in enumerate(log) if kind == "task"}
    for k, (kind, stream, what) in enumerate(log):
        if kind == "task":
            assert stream is streams[sg.lanes.of[[t.name for t in TWO_CAMERAS].index(what)]]
    names = [t.name for t in TWO_CAMERAS]
    for p, c in _dependencies(TWO_CAMERAS):
        assert nx.has_path(g, at[names[p]], at[names[c]]), (names[p], names[c])
    for k in at.values():
        assert nx.has_path(g, 0, k) and nx.has_path(g, k, len(log) - 1)
    used = {s for _, s, _ in log}
    assert used == set(streams[:sg.lanes.count])  # no lane beyond the assignment's
    for name in conditional:  # after everything enqueued before it, on the first stream
        k = at[name]
        assert log[k][1] is streams[0]
        assert all(nx.has_path(g, j, k) for j in range(k))


def test_lanes_join_even_when_a_task_fails():
    """A failing task still leaves every forked lane joined (a capture could not end
    otherwise) and the executor's stream current."""
    log, streams, sg, error = _logged_segment(TWO_CAMERAS, 4, fail="blurL")
    assert error is not None and "blurL" in str(error)
    g = _happens_before(log)
    forked = {s for _, s, _ in log} - {streams[0]}  # lanes forked before the failure
    assert forked
    for lane in forked:
        last = max(k for k, (_, s, _) in enumerate(log) if s is lane)
        assert nx.has_path(g, last, len(log) - 1), lane.name


# --------------------------------------------------------------------------- runs


def test_executor_bad_max_lanes_raises_naming_it(frames):
    g = _two_cameras(frames, "warp-cpu")
    try:
        ex = g.plan.executor()
        for bad, error in BAD_MAX_LANES:
            with pytest.raises(error, match="max_lanes"):
                ex.max_lanes = bad
        assert ex.max_lanes == MAX_LANES
    finally:
        g.close()


def _captured_graph(ex):
    """The executor's captured SegmentGraph (the two-camera graph has one)."""
    (sg,) = [sg for states in ex._captured.values() for by_shape in states if by_shape
             for sg in by_shape.values() if sg is not None and sg.captured]
    return sg


def test_two_cameras_with_lanes_equal_one_lane_and_eager(frames, warp_backend):
    """The 16-node graph on real frames, captured with lanes and with one lane: every output
    equal to the eager run's, frame after frame (many replays: a race between lanes would
    change outputs from run to run); the lanes split the cameras and respect the DAG."""
    n = 24 if warp_backend == "warp-cpu" else 120  # more replays where lanes run concurrently
    cams = list(itertools.islice(itertools.cycle(_camera_frames(frames)), n))
    runs = {}
    for max_lanes in (None, 1, MAX_LANES):  # None: eager
        g = _two_cameras(frames, warp_backend)
        g.plan.executor().max_lanes = max_lanes or 1
        try:
            capture = False if max_lanes is None else _capture_arg(warp_backend)
            runs[max_lanes] = [g.process(f, capture=capture) for f in cams]
            ex = g.plan.executor()
            if max_lanes is None:
                assert ex.captures == 0
                continue
            sg = _captured_graph(ex)
            assert all(b.graph is not None for b in sg.sets)
            assert ex.replays >= len(cams) - 6
            tasks = sg.segment.tasks
            _assert_respects(tasks, sg.lanes)
            assert sg.lanes.count == max_lanes
            of = {t.name: lane for t, lane in zip(tasks, sg.lanes.of)}
            assert max_lanes == 1 or of["grayL"] != of["grayR"]
            # Harris's selection loops in conditional nodes: found, and run with every lane
            # joined (FAST's sort too where its capacity passes SMALL, as at 720p).
            assert {"harrisL", "harrisR"} <= {tasks[i].name for i in sg.lanes.serial}
        finally:
            g.close()
    for lanes_run in (1, MAX_LANES):
        for i, (e, c) in enumerate(zip(runs[None], runs[lanes_run])):
            assert e.keys() == c.keys()
            for k in e:
                assert _same(e[k], c[k]), (lanes_run, i, k)


def refuse_lanes(monkeypatch) -> list:
    """Make every capture on several lanes fail (as Warp may refuse one); returns the list
    of the lane counts refused, filled as it happens."""
    real = SegmentGraph.capture
    refused = []

    def capture(self, device, streams):
        if self.lanes.count > 1:
            refused.append(self.lanes.count)
            raise NotCapturable("refused on lanes (test)")
        return real(self, device, streams)

    monkeypatch.setattr(SegmentGraph, "capture", capture)
    return refused


def test_capture_refused_on_lanes_falls_back_to_one_lane(frames, monkeypatch):
    """A capture on several lanes that fails (as Warp may refuse one) is made again on one
    lane instead of the segment turning eager; outputs equal the eager run's."""
    refused = refuse_lanes(monkeypatch)
    cams = _camera_frames(frames) * 3
    g = _two_cameras(frames, "warp-cpu")
    try:
        eager = [g.process(f, capture=False) for f in cams]
        g.reset()
        got = [g.process(f, capture=True) for f in cams]
        sg = _captured_graph(g.plan.executor())
        assert refused and sg.lanes.count == 1 and all(b.graph is not None for b in sg.sets)
        for i, (e, c) in enumerate(zip(eager, got)):
            for k in e:
                assert _same(e[k], c[k]), (i, k)
    finally:
        g.close()
