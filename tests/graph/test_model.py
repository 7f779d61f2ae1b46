"""The contention cost model: the fit recovers a known law, the executor simulation gives
hand-computed timelines, and on a real graph it predicts other placements out of sample."""

from __future__ import annotations

import functools
import gzip
import json
import math
import statistics
import time
import types
from pathlib import Path

import numpy as np
import pytest

import warpvx
from warpvx.graph.calibration import TransferModel
from warpvx.graph.model import (
    LATENCIES,
    ContentionModel,
    Reads,
    Slowdown,
    copied_bytes,
    fit_slowdown,
    simulate,
)
from warpvx.sched.schedule import Schedule, ScheduledTask

from tests.benchmark_scripts import bench_module

from .helpers import joined_pair

pytestmark = pytest.mark.timeout(120)

ROOT = Path(__file__).resolve().parents[2]


def test_fit_slowdown_recovers_a_known_law():
    # Two kinds of busy neighbour, a fixed cost per task and per-node corrections.
    rng = np.random.default_rng(3)
    ratio, per_cpu, per_gpu, overhead = 1.3, 0.45, 0.8, 0.02
    e = {"a": 0.97, "b": 1.0, "c": 1.03}
    samples = []
    for node, corr in e.items():
        alone = rng.uniform(0.5, 4.0)
        for _ in range(30):
            cpus, gpus = rng.uniform(0.0, 3.0), rng.uniform(0.0, 1.0)
            noise = math.exp(rng.normal(0, 0.01))
            t = (ratio * alone + overhead) * (1 + per_cpu * cpus + per_gpu * gpus) * corr * noise
            samples.append((node, alone, t, cpus, gpus))
    s = fit_slowdown(samples)
    assert s.per_cpu == pytest.approx(per_cpu, abs=0.06)
    assert s.per_gpu == pytest.approx(per_gpu, abs=0.1)
    for node, corr in e.items():
        alone = samples[list(e).index(node) * 30][1]
        assert s.in_frame(node, alone) == pytest.approx((ratio * alone + overhead) * corr, rel=0.1)
    assert s.rms_log < 0.05


def test_per_node_corrections_do_not_absorb_contention():
    # Each node always ran with its own number of busy workers (one sample level per
    # node): the slowdown is learnt across nodes, not hidden in each node's correction.
    law = [("n%d" % i, 1.0 + i, (1.0 + i) * 1.2 * (1 + 0.5 * (i % 3)), float(i % 3), 0.0)
           for i in range(9)]
    s = fit_slowdown(law)
    assert s.per_cpu == pytest.approx(0.5, abs=0.05)
    assert s.in_frame("n4", 5.0) == pytest.approx(6.0, rel=0.05)


def test_a_probe_identifies_what_the_frames_cannot():
    # The frames never had a busy neighbour; the probe (alone 2 ms, 3.2 ms with 2 busy CPU
    # workers) says a = 0.3; without it the slowdown stays 0.
    quiet = [("x", 1.0, 1.5, 0.0, 0.0)] * 5
    assert fit_slowdown(quiet).per_cpu == 0.0
    s = fit_slowdown(quiet, [(2.0, 3.2, 2, 0)])
    assert s.per_cpu == pytest.approx(0.3, abs=0.01)
    assert s.in_frame("x", 1.0) == pytest.approx(1.5, rel=0.01)
    assert fit_slowdown([]).ratio == 1.0


def _model(alone, reads, *, cpu=0.0, gpu=0.0, latency=0.0, cuda=False, transfer=None):
    return ContentionModel(
        {"cpu": Slowdown(per_cpu=cpu), "gpu": Slowdown(per_cpu=gpu)},
        dict.fromkeys(LATENCIES, latency), alone, reads, transfer or TransferModel(), cuda)


def _sched(places):
    return Schedule({t: ScheduledTask(t, p, i, i + 1) for i, (t, p) in enumerate(places)},
                    ["cpu0", "cpu1", "gpu"])


def test_simulate_two_busy_workers_share_at_the_fitted_rate():
    # a and b (1 ms alone each) run together on two workers at half speed (a = 1), then c.
    alone = {n: {"cpu": 1.0, "gpu": None, "device": 0.0} for n in "abc"}
    reads = {"a": (), "b": (), "c": (Reads("a.out", "a", 8, False), Reads("b.out", "b", 8, False))}
    pred = simulate(_model(alone, reads, cpu=1.0), _sched([("a", "cpu0"), ("b", "cpu1"), ("c", "cpu0")]))
    assert pred.tasks["a"].finish == pytest.approx(2.0)
    assert pred.tasks["b"].finish == pytest.approx(2.0)
    assert pred.tasks["c"].start == pytest.approx(2.0)
    assert pred.makespan == pytest.approx(3.0)
    # Without contention they overlap fully.
    assert simulate(_model(alone, reads), _sched([("a", "cpu0"), ("b", "cpu1"), ("c", "cpu0")])
                    ).makespan == pytest.approx(2.0)


def test_simulate_weighs_busy_neighbours_by_their_gil_shares():
    # Same as above, but b releases the GIL (pressure 0): a runs at full speed beside it;
    # b is still slowed by a (its sensitivity 1). A victim with sensitivity 0 is never slowed.
    alone = {n: {"cpu": 1.0, "gpu": None, "device": 0.0} for n in "abc"}
    reads = {"a": (), "b": (), "c": (Reads("a.out", "a", 8, False), Reads("b.out", "b", 8, False))}
    sch = _sched([("a", "cpu0"), ("b", "cpu1"), ("c", "cpu0")])
    model = _model(alone, reads, cpu=1.0)
    model.gil = {"b": {"cpu": (1.0, 0.0)}}
    pred = simulate(model, sch)
    assert pred.tasks["a"].finish == pytest.approx(1.0)
    # b: half speed while a runs (1 ms: 0.5 done), then full speed for the rest.
    assert pred.tasks["b"].finish == pytest.approx(1.5)
    model.gil = {"a": {"cpu": (0.0, 1.0)}, "b": {"cpu": (0.0, 1.0)}}
    assert simulate(model, sch).makespan == pytest.approx(2.0)


def test_simulate_a_gpu_segment_publishes_to_cpu_readers_when_it_ends():
    # g1, g2 (1 ms each) run in one captured GPU segment; x on a CPU worker reads g1 and
    # starts only when the segment ends (2 ms), as the executor runs it; without capture
    # each GPU task is its own unit and x starts after g1 (1 ms). A task reading a CPU
    # value starts a new segment (gpu_segments cuts where the executor cuts).
    from warpvx.graph.model import gpu_segments

    alone = {"g1": {"cpu": None, "gpu": 1.0, "device": 0.0},
             "g2": {"cpu": None, "gpu": 1.0, "device": 0.0},
             "x": {"cpu": 1.0, "gpu": None, "device": 0.0}}
    reads = {"g1": (), "g2": (Reads("g1.out", "g1", 8, False),), "x": (Reads("g1.out", "g1", 8, False),)}
    sch = _sched([("g1", "gpu"), ("g2", "gpu"), ("x", "cpu0")])
    model = _model(alone, reads)
    assert simulate(model, sch).tasks["x"].start == pytest.approx(1.0)
    model.capturable = frozenset({"g1", "g2"})
    pred = simulate(model, sch)
    assert pred.tasks["g2"].finish == pytest.approx(2.0)
    assert pred.tasks["x"].start == pytest.approx(2.0) and pred.makespan == pytest.approx(3.0)
    reads["g2"] = (Reads("x.out", "x", 8, False),)
    placement = {"g1": "gpu", "g2": "gpu", "x": "cpu0"}
    assert gpu_segments(reads, {"g1", "g2"}, placement, ["g1", "g2"]) == [["g1"], ["g2"]]
    assert gpu_segments(reads, {"g2"}, placement, ["g1", "g2"]) == [["g1"], ["g2"]]


def test_simulate_cuda_device_follows_the_host_call_and_copies_are_charged_once():
    # g (GPU, host 0.2 ms, device 3 ms) feeds two CPU readers; its output crosses once.
    alone = {"g": {"cpu": None, "gpu": 0.2, "device": 3.0},
             "x": {"cpu": 1.0, "gpu": None, "device": 0.0},
             "y": {"cpu": 1.0, "gpu": None, "device": 0.0}}
    reads = {"g": (Reads("in", None, 1000, False),),
             "x": (Reads("g.out", "g", 1000, False),), "y": (Reads("g.out", "g", 1000, False),)}
    tm = TransferModel(0.0, 1e-4, 0.0, 2e-4)  # upload 0.1 ms, download 0.2 ms per 1000 bytes
    sch = _sched([("g", "gpu"), ("x", "cpu0"), ("y", "cpu0")])
    order = ["g", "x", "y"]
    assert copied_bytes(reads, {t: s.processor for t, s in sch.tasks.items()}, order) == \
        {"g": 1000, "x": 1000}
    pred = simulate(_model(alone, reads, cuda=True, transfer=tm), sch)
    # Host call: 0.2 + 0.1 upload; the device runs 3 ms from the call's start.
    assert pred.tasks["g"].start == pytest.approx(0.0)
    assert pred.tasks["g"].finish == pytest.approx(3.0)
    assert pred.tasks["x"].start == pytest.approx(3.0)
    assert pred.tasks["x"].finish == pytest.approx(3.0 + 1.0 + 0.2)
    assert pred.makespan == pytest.approx(5.2)


def test_captured_segment_replay_is_learnt_from_its_intervals():
    # CUDA: g1 (device 1 ms), g2 (device 2 ms) replayed as one captured segment, then x on
    # a CPU worker. The frames time the replay as one interval, 0.5 ms per calibrated ms
    # plus 0.2 ms per replay (no launch gaps: shorter than the eager calls); the fit learns
    # it and the simulation plays the segment so. One segment size alone cannot tell the
    # fixed cost from the ratio: the prior fixed cost, the rest as the ratio; segments of
    # several sizes tell them apart.
    import types

    from warpvx.graph.model import SEGMENT_FIXED_PRIOR, fit, fit_segments, segment_samples
    from warpvx.runtime.timeline import FrameResult

    alone = {"g1": {"cpu": None, "gpu": 0.1, "device": 1.0},
             "g2": {"cpu": None, "gpu": 0.1, "device": 2.0},
             "x": {"cpu": 1.0, "gpu": None, "device": 0.0}}
    reads = {"g1": (), "g2": (Reads("g1.out", "g1", 8, False),), "x": (Reads("g2.out", "g2", 8, False),)}
    placement = {"g1": "gpu", "g2": "gpu", "x": "cpu0"}
    replay = 0.5 * 3.0 + 0.2
    frames = []
    for jitter in (0.0, 0.01, -0.01):
        span = replay + jitter
        timeline = {"g1": ScheduledTask("g1", "gpu", 0.0, span / 3),
                    "g2": ScheduledTask("g2", "gpu", span / 3, span),
                    "x": ScheduledTask("x", "cpu0", span, span + 1.0)}
        frames.append(FrameResult(0, {}, timeline, 0.0, host={"g1": (0.0, 0.05), "g2": (0.05, 0.1)}))
    cal = types.SimpleNamespace(nodes={n: {"cpu": t["cpu"], "gpu": t["device"] if t["gpu"] else None,
                                           "gpu_host": t["gpu"]} for n, t in alone.items()},
                                gpu="cuda:0", transfer=TransferModel(), dispatch={})
    model = fit(cal, reads, frames, placement, capturable={"g1", "g2"})
    assert model.segment_fixed == SEGMENT_FIXED_PRIOR
    assert model.segment_ratio == pytest.approx((replay - SEGMENT_FIXED_PRIOR) / 3.0, rel=0.01)
    pred = model.predict(_sched([("g1", "gpu"), ("g2", "gpu"), ("x", "cpu0")]))
    assert pred.tasks["g2"].finish == pytest.approx(replay, rel=0.02)
    # Eager (nothing capturable), the device times add up: 3 ms.
    eager = fit(cal, reads, frames, placement)
    assert eager.segment_ratio is None
    assert eager.predict(_sched([("g1", "gpu"), ("g2", "gpu"), ("x", "cpu0")])).tasks["g2"].finish \
        == pytest.approx(3.0, rel=0.02)
    # (summed calibrated ms, on its lanes: a chain, the same, replay ms)
    assert segment_samples(frames, reads, {"g1", "g2"}, placement, model.alone, TransferModel(),
                           True)[0] == pytest.approx((3.0, 3.0, replay))
    # Several sizes: ratio and fixed cost apart.
    sizes = [(b, b, 0.5 * b + 0.2) for b in (0.3, 0.6, 1.2, 3.0)]
    assert fit_segments(sizes)[:2] == pytest.approx((0.5, 0.2))
    assert fit_segments([]) == (None, 0.0, 1.0)
    # One size with replays shorter than twice the prior: at most half of the shortest.
    assert fit_segments([(0.1, 0.1, 0.08), (0.1, 0.1, 0.1)])[1] == pytest.approx(0.04)
    # Several sizes and shapes: how much of the lanes' concurrency the replays get.
    shapes = [(b, span, 0.5 * (0.5 * span + 0.5 * b) + 0.2)
              for b, span in ((0.4, 0.4), (1.0, 0.5), (2.0, 1.0), (3.0, 3.0), (4.0, 1.0))]
    assert fit_segments(shapes) == pytest.approx((0.5, 0.2, 0.5))


def _two_cameras():
    """Two independent GPU chains (cameras a and b: x1 -> x2, 1 ms of device time each,
    0.1 ms host call; x1 also has a 1 ms CPU implementation) and a CPU node joining them."""
    alone = {f"{c}{i}": {"cpu": 1.0 if i == 1 else None, "gpu": 0.1, "device": 1.0}
             for c in "ab" for i in (1, 2)}
    alone["j"] = {"cpu": 0.1, "gpu": None, "device": 0.0}
    reads = {"a1": (), "b1": (), "a2": (Reads("a1.out", "a1", 8, False),),
             "b2": (Reads("b1.out", "b1", 8, False),),
             "j": (Reads("a2.out", "a2", 8, False), Reads("b2.out", "b2", 8, False))}
    cal = types.SimpleNamespace(nodes={n: {"cpu": t["cpu"], "gpu": t["device"] if t["gpu"] else None,
                                           "gpu_host": t["gpu"]} for n, t in alone.items()},
                                gpu="cuda:0", transfer=TransferModel(), dispatch={})
    return alone, reads, cal


def _frame(gpu, cpu, host=None, transfers=None):
    """A FrameResult: ``gpu``/``cpu``: task -> (processor, start, finish) ms."""
    from warpvx.runtime.timeline import FrameResult

    timeline = {t: ScheduledTask(t, p, s, f) for t, (p, s, f) in {**gpu, **cpu}.items()}
    return FrameResult(0, {}, timeline, 0.0, dict(transfers or {}), {}, dict(host or {}))


def test_mixed_placement_segments_lose_the_baselines_lane_concurrency():
    # The all-GPU baseline replays both cameras in one captured segment, its two chains side
    # by side on lanes: 0.5 ms per calibrated ms of the lanes' span (2 ms) plus 0.1 ms a
    # replay, 1.1 ms, not 0.5 * 4 ms. A mixed placement (a1 on a CPU worker) replays a2
    # alone, a segment of one task with no branch beside it: 0.5 * 1 + 0.1 = 0.6 ms.
    # A ratio learnt on the summed device time (0.25) played it at 0.35 ms (the H100's
    # mixed placements at 1920x1080, s6/s6b: one-task segments 2-3x their prediction).
    from warpvx.graph.model import SEGMENT_FIXED_PRIOR, fit, lane_span

    alone, reads, cal = _two_cameras()
    assert lane_span(reads, ["a1", "b1", "a2", "b2"], {n: 1.0 for n in alone}) == 2.0
    gpu = ["a1", "b1", "a2", "b2"]
    placement = {**dict.fromkeys(gpu, "gpu"), "j": "cpu0"}
    replay = 0.5 * 2.0 + SEGMENT_FIXED_PRIOR
    frames = []
    for jitter in (0.0, 0.01, -0.01):
        span = replay + jitter
        edges = [span * i / 4 for i in range(5)]  # a replay's tasks share its interval
        frames.append(_frame({t: ("gpu", edges[i], edges[i + 1]) for i, t in enumerate(gpu)},
                             {"j": ("cpu0", span, span + 0.1)},
                             host={t: (0.01 * i, 0.01 * (i + 1)) for i, t in enumerate(gpu)}))
    model = fit(cal, reads, frames, placement, capturable=set(gpu))
    assert model.segment_ratio == pytest.approx(0.5, rel=0.02)
    mixed = model.predict(_sched([("a1", "cpu0"), ("b1", "gpu"), ("b2", "gpu"), ("a2", "gpu"),
                                  ("j", "cpu0")]))
    # b1 + b2 one segment (a chain: no concurrency), a2 its own after a1's hand-off.
    assert mixed.tasks["a2"].finish - mixed.tasks["a2"].start == pytest.approx(0.6, rel=0.02)
    assert mixed.tasks["b2"].finish - mixed.tasks["b1"].start == pytest.approx(0.5 * 2 + 0.1, rel=0.02)


def test_a_segment_whose_capture_failed_is_played_eagerly():
    # The executor runs a segment whose capture failed eagerly from then on (each task its
    # own host interval, its upload timed apart); eager_nodes finds it in frames where it
    # did, and predict(..., eager=) plays those tasks as eager calls: their calibrated host
    # time times the contention probe's GPU mix in-frame ratio (alone 0.4 ms for 0.2 ms of
    # calibrated calls: 2x), where a replay took 0.5 ms per calibrated device ms.
    from warpvx.graph.model import eager_nodes, fit

    alone, reads, cal = _two_cameras()
    gpu = ["a1", "b1", "a2", "b2"]
    placement = {**dict.fromkeys(gpu, "gpu"), "j": "cpu0"}
    replayed = _frame({t: ("gpu", 0.25 * i, 0.25 * (i + 1)) for i, t in enumerate(gpu)},
                      {"j": ("cpu0", 1.0, 1.1)},
                      host={t: (0.01 * i, 0.01 * (i + 1)) for i, t in enumerate(gpu)})
    assert eager_nodes([replayed] * 3, reads, set(gpu), placement) == frozenset()
    # a1 on the CPU: a2 (reads it) and b1 + b2 are segments; b1 + b2 ran eagerly.
    mixed = {"a1": "cpu0", "b1": "gpu", "b2": "gpu", "a2": "gpu", "j": "cpu0"}
    ran = _frame({"b1": ("gpu", 0.0, 1.0), "b2": ("gpu", 1.0, 2.0), "a2": ("gpu", 2.0, 2.5)},
                 {"a1": ("cpu0", 0.0, 1.0), "j": ("cpu0", 2.5, 2.6)},
                 host={"b1": (0.0, 0.2), "b2": (0.3, 0.5), "a2": (2.0, 2.05)}, transfers={"a2": 0.0})
    assert eager_nodes([ran, ran, replayed], reads, set(gpu), mixed) == {"b1", "b2"}
    # The gpu mix timed alone: 0.4 ms for its calls' 0.2 ms calibrated (host) time.
    probe = {("gpu", "cpu"): ("b1,b2", 0.4, 0.4, 1, 0)}
    model = fit(cal, reads, [replayed] * 3, placement, probe=probe, capturable=set(gpu))
    assert model.slowdown["gpu"].samples == 0  # replayed shares are the segment model's
    sch = _sched([("a1", "cpu0"), ("b1", "gpu"), ("b2", "gpu"), ("a2", "gpu"), ("j", "cpu0")])
    as_replayed = model.predict(sch)
    as_eager = model.predict(sch, eager={"b1", "b2"})
    # Eager: each call 2 x 0.1 ms on the host, its kernels 1 ms on the device after it.
    assert as_eager.tasks["b1"].finish - as_eager.tasks["b1"].start == pytest.approx(1.0, rel=0.02)
    assert as_eager.tasks["b2"].finish == pytest.approx(2.0, rel=0.02)
    assert as_replayed.tasks["b2"].finish < 1.5  # a replay of 2 ms of device time at 0.5


def test_simulate_refuses_an_order_that_deadlocks():
    alone = {n: {"cpu": 1.0, "gpu": None, "device": 0.0} for n in "ab"}
    reads = {"a": (Reads("b.out", "b", 8, False),), "b": ()}
    sch = Schedule({"a": ScheduledTask("a", "cpu0", 0, 1), "b": ScheduledTask("b", "cpu0", 1, 2)},
                   ["cpu0", "gpu"])
    with pytest.raises(warpvx.GraphError, match="deadlock"):
        simulate(_model(alone, reads), sch)


def _graph(size):
    w, h = size
    g = warpvx.Graph("model")
    frame = g.input("frame", shape=(h, w, 3), dtype=np.uint8)
    gray = g.color_convert(frame, code="BGR2GRAY", name="gray")
    blur = g.gaussian_blur(gray, ksize=(5, 5), sigma=1.2, name="blur")
    g.output("kps", g.fast_corners(blur, threshold=20, name="fast"))
    g.output("pyr", g.gaussian_pyramid(gray, levels=3, name="pyramid"))
    g.output("mean", g.user(lambda x: np.array([x.mean()]), [blur], "m", name="mean"))
    return g


def test_model_fits_one_placement_and_predicts_others_out_of_sample(frames):
    g = _graph((frames[0].shape[1], frames[0].shape[0]))
    g.verify({"frame": frames[0]})
    runs, plans = {}, {}
    for policy in ("baseline", "heft"):
        plans[policy] = plan = g.schedule(policy, n_cpus=1, gpu="warp-cpu")
        got = []
        for i in range(12):
            g.process({"frame": frames[i % len(frames)]})
            got.append(plan.last_run[-1])
        runs[policy] = got
    # The probes once per calibration, before the frames that train (measure_probes), and
    # fit_model reuses them (measured on first use otherwise).
    cal = g.measure_probes(plans["baseline"])
    probe = cal.contention[1]
    assert probe and all(v[2] > 0 for v in probe.values())
    model = g.fit_model(plans["baseline"], runs=runs["baseline"][:6])
    assert cal.contention[1] is probe  # not measured again
    assert set(model.slowdown) == {"cpu", "gpu"}
    errors = {}
    for policy, plan in plans.items():
        pred = model.predict(plan)
        assert set(pred.tasks) == set(g.nodes)
        assert math.isfinite(pred.makespan) and pred.makespan > 0
        measured = statistics.median(r.makespan for r in runs[policy][6:])
        errors[policy] = 100 * (pred.makespan - measured) / measured
    assert all(math.isfinite(e) for e in errors.values())
    # best with the model: the fastest predicted candidate, the baseline among them.
    best = g.schedule("best", n_cpus=1, gpu="warp-cpu", model=model)
    cands = best.schedule.info["candidates"]
    assert "baseline" in cands and len(cands) == 6
    assert best.predicted_makespan == pytest.approx(min(cands.values()))
    assert best.prediction is not None and best.predicted_makespan == best.prediction.makespan
    g.process({"frame": frames[0]})
    fig = best.gantt()
    assert "prediction error" in fig._suptitle.get_text()
    assert "time (ms)" in fig.axes[0].get_xlabel()
    g.close()


def _slow_on_cpu(x):
    time.sleep(0.03)
    return x


def _fast_on_gpu(x):
    return x


def _baseline_model(g, frame):
    """``g`` verified on ``frame`` and a model fitted on 3 frames of its baseline."""
    g.verify(frame)
    plan = g.schedule("baseline", n_cpus=1, gpu="warp-cpu")
    runs = []
    for _ in range(3):
        g.process(frame)
        runs.append(plan.last_run[-1])
    return g.fit_model(plan, runs=runs)


def _one_node_wrong_model(name, cpu_fn, gpu_fn):
    """A one-node graph (``cpu_fn`` on a CPU worker, ``gpu_fn`` on the GPU role), a frame,
    and a model fitted on its baseline then told the CPU placement is far faster."""
    g = warpvx.Graph(name)
    x = g.input("x", shape=(4,), dtype=np.float32)
    g.output("y", g.user(cpu_fn, [x], warp_fn=gpu_fn, name="work"))
    frame = {"x": np.arange(4, dtype=np.float32)}
    model = _baseline_model(g, frame)
    model.alone["work"] = {"cpu": 0.001, "gpu": 50.0, "device": 0.0}  # wrong on purpose
    return g, frame, model


def test_copied_bytes_delayed_values_apart_and_one_upload_per_captured_segment():
    # c (CPU) feeds g1 this frame's value and the delayed one: eagerly one upload (the
    # earlier frame's value was uploaded when that frame read it); a captured segment fills
    # its buffers with both. g2 reads a graph input (host) and g1's value: no cut, so with
    # capture it is in g1's segment, which uploads its inputs before it runs (charged to g1,
    # as the executor records it). g3 reads c's value again: eagerly the upload g1 made is
    # reused; a captured segment fills buffers of its own, so g3 (cut: it reads a CPU value)
    # uploads it again. The H100 runs' recorded uploads match this rule in 31 of 32 plans.
    reads = {"c": (),
             "g1": (Reads("c.out", "c", 100, False), Reads("c.out", "c", 100, True)),
             "g2": (Reads("in", None, 50, False), Reads("g1.out", "g1", 8, False)),
             "g3": (Reads("c.out", "c", 100, False),)}
    placement = {"c": "cpu0", "g1": "gpu", "g2": "gpu", "g3": "gpu"}
    order = ["c", "g1", "g2", "g3"]
    assert copied_bytes(reads, placement, order) == {"g1": 100, "g2": 50}
    assert copied_bytes(reads, placement, order, {"g1", "g2", "g3"}) == {"g1": 250, "g3": 100}


def test_best_trial_keeps_the_measured_winner_when_the_model_is_wrong():
    # One node, 30 ms on a CPU worker and fast on the GPU role; the model is told the
    # opposite, so it predicts the CPU placement fastest. The trial runs both candidates
    # and keeps the one that measured fastest: the GPU placement.
    g, frame, model = _one_node_wrong_model("trial", _slow_on_cpu, _fast_on_gpu)
    untried = g.schedule("best", n_cpus=1, gpu="warp-cpu", model=model)
    assert untried.placement["work"] == "cpu0"  # the model's (wrong) pick
    tried = g.schedule("best", n_cpus=1, gpu="warp-cpu", model=model, trial_inputs=[frame],
                       trial_frames=3, trial_margin=1e6)
    trial = tried.schedule.info["trial_ms"]
    assert len(trial) == 2
    assert tried.placement["work"] == "gpu"
    assert trial[tried.schedule.info["chosen"]] == min(trial.values())
    assert max(trial.values()) > 25.0  # the CPU candidate really ran its 30 ms sleep
    assert g.plan is tried
    np.testing.assert_array_equal(g.process(frame)["y"], frame["x"])
    with pytest.raises(warpvx.GraphError, match="trial_frames"):
        g.schedule("best", n_cpus=1, gpu="warp-cpu", model=model, trial_inputs=[frame],
                   trial_frames=0, trial_margin=1e6)
    with pytest.raises(warpvx.GraphError, match="trial_inputs"):
        g.schedule("heft", n_cpus=1, gpu="warp-cpu", trial_inputs=[frame])
    # Refused up front, even where no trial would have run (margins 0: one candidate).
    with pytest.raises(warpvx.GraphError, match="trial_frames"):
        g.schedule("best", n_cpus=1, gpu="warp-cpu", model=model, trial_inputs=[frame],
                   trial_frames=0, trial_margin=0.0, trial_runner_up=0.0)
    with pytest.raises(warpvx.GraphError, match="trial_inputs"):
        g.schedule("best", n_cpus=1, gpu="warp-cpu", model=model, trial_inputs=[])
    for bad in ("0.2", -0.1, float("nan")):
        with pytest.raises((warpvx.WarpvxTypeError, warpvx.WarpvxValueError), match="trial_margin"):
            g.schedule("best", n_cpus=1, gpu="warp-cpu", model=model, trial_margin=bad)
        with pytest.raises((warpvx.WarpvxTypeError, warpvx.WarpvxValueError), match="trial_runner_up"):
            g.schedule("best", n_cpus=1, gpu="warp-cpu", model=model, trial_runner_up=bad)
    g.close()


def test_best_trial_tries_the_runner_up_within_the_models_known_error():
    # The GPU placement is predicted slower than the CPU one by a gap wider than
    # trial_margin: alone, the margin leaves it untried and the model's wrong pick stands.
    # Within trial_runner_up (the model's known error) the runner-up is measured too, and
    # kept, as it measures faster (the H100's 1080p case: baseline predicted 23% slower
    # than HEFT, measured 17% faster).
    g, frame, model = _one_node_wrong_model("runner_up", _slow_on_cpu, _fast_on_gpu)
    preds = sorted(g.schedule("best", n_cpus=1, gpu="warp-cpu", model=model)
                   .schedule.info["candidates"].values())
    gap = preds[-1] / preds[0] - 1.0
    assert gap > 0
    kw = dict(n_cpus=1, gpu="warp-cpu", model=model, trial_inputs=[frame], trial_frames=2,
              trial_rounds=1, trial_margin=gap / 2)
    untried = g.schedule("best", trial_runner_up=0.0, **kw)
    assert untried.placement["work"] == "cpu0" and "trial_ms" not in untried.schedule.info
    tried = g.schedule("best", trial_runner_up=2 * gap, **kw)
    assert len(tried.schedule.info["trial_ms"]) == 2
    assert tried.placement["work"] == "gpu"
    g.close()


class _Drift:
    """A machine that slows down frame after frame: each call sleeps ``base`` ms plus
    ``step`` ms per call made so far (by either placement)."""

    calls = 0

    @classmethod
    def sleep(cls, base_ms, step_ms=1.0):
        time.sleep((base_ms + step_ms * cls.calls) / 1e3)
        cls.calls += 1


def _drift_cpu(x):
    _Drift.sleep(10.0)
    return x


def _drift_gpu(x):
    _Drift.sleep(6.0)
    return x


def test_best_trial_interleaves_candidates_so_a_drift_does_not_pick_the_loser():
    # The GPU placement is 4 ms faster, but the machine slows by 1 ms a frame and the
    # model predicts the CPU placement fastest, so the CPU one is tried first. Run one
    # after the other, the GPU candidate would measure ~6 ms of drift more and lose; in
    # interleaved rounds (A B B A) both see the same drift and the faster one wins.
    g, frame, model = _one_node_wrong_model("drift", _drift_cpu, _drift_gpu)
    _Drift.calls = 0
    tried = g.schedule("best", n_cpus=1, gpu="warp-cpu", model=model, trial_inputs=[frame],
                       trial_frames=3, trial_rounds=4, trial_margin=1e6)
    info = tried.schedule.info
    assert info["trial_frames"] == dict.fromkeys(info["trial_ms"], 12)
    assert _Drift.calls == 2 * 4 * (3 + 2)  # warm-up frames after each switch discarded
    assert tried.placement["work"] == "gpu"
    assert info["trial_ms"][info["chosen"]] == min(info["trial_ms"].values())
    # One round is the old trial (all of A, then all of B): the drift makes the slower
    # CPU placement measure faster.
    cpu_plan = g.schedule("heft", n_cpus=1, gpu=False)
    gpu_plan = g.schedule("baseline", n_cpus=1, gpu="warp-cpu")
    _Drift.calls = 0
    seq = g.measure_plans([cpu_plan, gpu_plan], frame, rounds=1, frames=5, warmup=1)
    assert cpu_plan.placement["work"] == "cpu0" and gpu_plan.placement["work"] == "gpu"
    assert statistics.median(r.makespan for r in seq[0]) < statistics.median(r.makespan for r in seq[1])
    cpu_plan.close()
    # A budget of 0 s runs the first round only.
    _Drift.calls = 0
    quick = g.schedule("best", n_cpus=1, gpu="warp-cpu", model=model, trial_inputs=[frame],
                       trial_frames=2, trial_rounds=5, trial_seconds=0.0, trial_margin=1e6)
    assert set(quick.schedule.info["trial_frames"].values()) == {2}
    for bad, kw in (("trial_rounds", {"trial_rounds": 0}), ("trial_seconds", {"trial_seconds": -1.0})):
        with pytest.raises((warpvx.WarpvxTypeError, warpvx.WarpvxValueError), match=bad):
            g.schedule("best", n_cpus=1, gpu="warp-cpu", model=model, trial_inputs=[frame], **kw)
    g.close()


def test_measure_plans_and_use_plan_switch_between_warm_plans(frames):
    g = _graph((frames[0].shape[1], frames[0].shape[0]))
    g.verify({"frame": frames[0]})
    plans = [g.schedule(p, n_cpus=1, gpu="warp-cpu") for p in ("baseline", "heft")]
    runs = g.measure_plans(plans, [{"frame": f} for f in frames], rounds=3, frames=2, warmup=1)
    assert [len(r) for r in runs] == [6, 6]
    for plan, got in zip(plans, runs):
        assert all(set(r.timeline) == set(g.nodes) for r in got)
        assert all({t.processor for t in r.timeline.values()} <= set(plan.placement.values())
                   for r in got)
    assert g.plan is plans[1]  # rounds alternate A B, B A, A B: the last plan run stays
    other = warpvx.Graph("other")
    with pytest.raises(warpvx.GraphError, match="plan"):
        other.use_plan(plans[0])
    with pytest.raises(warpvx.GraphError, match="inputs"):
        g.measure_plans(plans, [])
    for name, bad in (("rounds", 0), ("frames", 0), ("warmup", -1), ("rounds", 1.5), ("frames", "3")):
        with pytest.raises((warpvx.WarpvxTypeError, warpvx.WarpvxValueError), match=name):
            g.measure_plans(plans, {"frame": frames[0]}, **{name: bad})
    for plan in plans:
        plan.close()
    g.close()


def _spin(x):
    # Pure Python: holds the GIL, so two workers running it at once take turns.
    s = 0
    for i in range(150_000):
        s += i
    return x + 1


def test_cpu_interference_is_learnt_from_the_contention_probe(tmp_path, monkeypatch):
    # Trained on a placement that runs both spinning nodes on one worker (never side by
    # side), the frames cannot show that they slow each other down; the contention probe
    # (the CPU mix run beside a second worker looping it) does, and the model then
    # predicts the placement that runs them on two workers -- no faster, under the GIL.
    from warpvx.graph.model import fit, graph_reads

    monkeypatch.setenv("WARPVX_CACHE_DIR", str(tmp_path))
    g, frame = joined_pair("gil", _spin, ("spinA", "spinB"))
    g.verify(frame)
    plans = {p: g.schedule(p, n_cpus=2, gpu=False) for p in ("baseline", "heft")}
    assert len(set(plans["baseline"].placement.values())) == 1
    assert plans["heft"].placement["spinA"] != plans["heft"].placement["spinB"]
    # Interleaved, so that the other processes of a loaded machine fall on both alike.
    runs = dict(zip(plans, g.measure_plans(list(plans.values()), frame, rounds=4, frames=3)))
    model = g.fit_model(plans["baseline"], runs=runs["baseline"])
    _, alone, loaded, cpus, _ = plans["baseline"].calibration.contention[2][("cpu", "cpu")]
    assert cpus == 1 and loaded / alone > 1.4  # the GIL: about 2x
    assert model.slowdown["cpu"].per_cpu >= 0.5
    blind = fit(plans["baseline"].calibration, graph_reads(g), runs["baseline"],
                plans["baseline"].placement)
    assert blind.slowdown["cpu"].per_cpu == 0.0  # nothing in the frames to learn it from
    # Two workers over one: blind, the model expects them to nearly halve the time; with
    # the probe it expects the GIL to take most of that back. (What the frames measured is
    # not compared: on a loaded 2-core machine their ratio moves from 0.5 to 1.)
    probed, guessed = (m.makespan(plans["heft"]) / m.makespan(plans["baseline"]) for m in (model, blind))
    assert probed > guessed + 0.1
    g.close()


H100 = ROOT / "benchmarks" / "results" / "graph" / "h100-2026-11-24" / "graph_bench.json"


def _graph_bench():
    return bench_module("graph_bench")


@functools.lru_cache(maxsize=None)
def _report(run: str) -> dict:
    """A recorded graph_bench.json (``.gz``: compressed) under benchmarks/results/graph."""
    raw = (H100.parent.parent / run).read_bytes()
    return json.loads(gzip.decompress(raw) if run.endswith(".gz") else raw)


@functools.lru_cache(maxsize=None)
def _replay(run: str, gil: bool = False) -> list:
    """graph_bench's replay of ``run`` trained on baseline, fitted once for the tests that share it."""
    return _graph_bench().replay(_report(run), "baseline", gil=gil)


@pytest.mark.slow
def test_replayed_h100_measurements_are_predicted_within_20_percent():
    # The committed H100 run (recorded before per-frame data was kept): the model is refit
    # on the baseline placement's node medians and predicts the plans of heft, xeft and
    # best, which ran separately. Every policy within 20% of its measured makespan; the
    # model before the per-kind contention law missed xeft on the 16-node 1280x720 graph.
    rows = _replay("h100-2026-11-24/graph_bench.json")
    assert len(rows) == 16
    worst = max(rows, key=lambda r: abs(r["error_pct"]))
    assert abs(worst["error_pct"]) <= 20.0, worst
    # Plans that ran more than once (heft, xeft and best share one on three graphs) are
    # within 15% of the mean of their runs.
    assert max(abs(r["pooled_error_pct"]) for r in rows) <= 15.0


@pytest.mark.slow
def test_gil_weighted_model_transfers_to_mixed_placements_on_h100_s5():
    # The H100 run s5, refit offline on baseline's recorded training frames: unweighted,
    # every busy thread counts alike and the 16-node 1280x720 graph's heft and xeft
    # placements (CPU workers running OpenCV calls that release the GIL) are predicted
    # twice too slow; weighted by the recorded GIL shares (the bench's model on CUDA),
    # less wrong, and at least two more cells within 20% in all.
    rows = {gil: _replay("h100-2026-11-24-s5/graph_bench.json", gil) for gil in (False, True)}
    mixed = {gil: {r["policy"]: abs(r["error_pct"]) for r in got
                   if r["tag"] == "two-cameras_1280x720" and r["policy"] in ("heft", "xeft")}
             for gil, got in rows.items()}
    assert all(mixed[True][p] < mixed[False][p] for p in ("heft", "xeft")), mixed
    within = {gil: sum(abs(r["error_pct"]) <= 20.0 for r in got) for gil, got in rows.items()}
    assert within[True] >= within[False] + 2, within


@pytest.mark.slow
def test_mixed_placements_on_h100_runs_pay_lanes_and_failed_captures():
    # The H100 runs s5, s6, s6b, s7a and s9, refit offline on baseline's recorded training
    # frames (GIL-weighted, as the bench), predicting the 16-node graph's heft and xeft
    # placements against their own first frames (the training rounds: the machine's later
    # drift left out, 30% in s6b). The baseline replays both cameras in one segment, on
    # lanes joined before each Harris and FAST task (they insert conditional graph nodes);
    # mixed placements replay short chains with nothing beside them. Every placement whose
    # captures all held is within 20%; with the lanes spread freely past those joins (the
    # baseline's ratio learnt on a span half the true one) s5's and s9's were +28 to +43%
    # (benchmarks/results/graph/model-replay-s9.md). Failed captures (segments run eagerly
    # from then on) are read off the frames: s6b 1920x1080 lost blurR's in heft and xeft.
    errors, eager = {}, {}
    for run in ("h100-2026-11-24-s5/graph_bench.json", "h100-2026-11-24-s6/graph_bench.json.gz",
                "h100-2026-11-24-s6b/graph_bench.json.gz", "h100-2026-11-24-s7a/graph_bench.json.gz",
                "h100-2026-11-24-s9/graph_bench_720p.json.gz",
                "h100-2026-11-24-s9/graph_bench_1080p.json.gz"):
        first = {(e["tag"], p["policy"]): p["measured_in_ms"] for e in _report(run)["experiments"]
                 for p in e["policies"]}
        for r in _replay(run, True):
            if r["tag"].startswith("two-cameras_") and r["policy"] in ("heft", "xeft"):
                key = run.split("/")[0].rsplit("-", 1)[1], r["tag"], r["policy"]
                eager[key] = r["eager"]
                errors[key] = 100.0 * (r["pred_ms"] / first[r["tag"], r["policy"]] - 1.0)
    held = {k: e for k, e in errors.items() if not eager[k]}
    assert len(held) >= 12, sorted(held)
    assert all(abs(e) <= 20.0 for e in held.values()), held
    assert eager["s6b", "two-cameras_1920x1080", "heft"] == ["blurR", "detectorL", "fastL", "fastR"]
    assert eager["s5", "two-cameras_1280x720", "heft"] == []


def test_a_segments_lanes_join_before_its_serial_tasks():
    # Two cameras' chains (a1 -> a2, b1 -> b2, 1 ms each) on lanes: side by side, 2 ms. A
    # task inserting conditional graph nodes (a2) runs with every lane joined before it, and
    # what the others enqueue goes first: b2 beside a1's successor no longer overlaps it,
    # 3 ms -- the executor's Lanes (its span), which the model plays and fits on.
    from warpvx.graph.model import SEGMENT_FIXED_PRIOR, fit, lane_span

    alone, reads, cal = _two_cameras()
    seg, base = ["a1", "b1", "a2", "b2"], {n: 1.0 for n in alone}
    assert lane_span(reads, seg, base) == 2.0
    assert lane_span(reads, seg, base, serial={"a2"}) == 3.0
    assert lane_span(reads, ["a2"], base, serial={"a2"}) == 1.0
    # The all-GPU frames replay in 0.5 ms per calibrated ms of that span plus the fixed
    # cost; fitted without the join, the ratio comes out a third too high (0.5 * 3 / 2).
    placement = {**dict.fromkeys(seg, "gpu"), "j": "cpu0"}
    replay = 0.5 * 3.0 + SEGMENT_FIXED_PRIOR
    edges = [replay * i / 4 for i in range(5)]
    frame = _frame({t: ("gpu", edges[i], edges[i + 1]) for i, t in enumerate(seg)},
                   {"j": ("cpu0", replay, replay + 0.1)},
                   host={t: (0.01 * i, 0.01 * (i + 1)) for i, t in enumerate(seg)})
    joined = fit(cal, reads, [frame] * 3, placement, capturable=set(seg), serial={"a2"})
    free = fit(cal, reads, [frame] * 3, placement, capturable=set(seg))
    assert joined.serial == {"a2"}
    assert joined.segment_ratio == pytest.approx(0.5, rel=0.02)
    assert free.segment_ratio == pytest.approx(0.75, rel=0.02)
    # A mixed placement's one-task segment (a2 after a1's hand-off): 0.5 + 0.1 ms replayed.
    mixed = joined.predict(_sched([("a1", "cpu0"), ("b1", "gpu"), ("b2", "gpu"), ("a2", "gpu"),
                                   ("j", "cpu0")]))
    assert mixed.tasks["a2"].finish - mixed.tasks["a2"].start == pytest.approx(0.6, rel=0.02)


def test_fit_model_takes_the_serial_tasks_its_executor_found():
    # The executor finds a segment's serial tasks on its first run (Warp's conditional-node
    # calls noted; here on Warp's CPU device, capture forced): the bench's Harris nodes
    # (FAST's sort takes its one-pass branch at this size), which the fitted model joins
    # lanes before; graph_bench finds the same for results that did not record them.
    bench = _graph_bench()
    size = (320, 240)
    g = bench.build_graph(size, max_corners=200)
    try:
        frames = bench.make_frames(size, 3)
        g.verify(frames[:2])
        plan = g.schedule("baseline", n_cpus=1, gpu="warp-cpu")
        runs = []
        for f in frames:
            g.process(f, capture=True)
            runs.append(plan.last_run[-1])
        assert g.fit_model(plan, runs=runs).serial == {"harrisL", "harrisR"}
        # A closed plan (its executor gone; a later run starts a fresh one) keeps them.
        plan.close()
        assert plan.serial_tasks == {"harrisL", "harrisR"}
        assert g.fit_model(plan, runs=runs).serial == {"harrisL", "harrisR"}
    finally:
        g.close()
    assert bench.serial_nodes("two-cameras", size, 200) == {"harrisL", "harrisR"}


def test_cpu_slope_unseen_in_the_frames_is_the_probes():
    # Baseline-like training frames: one CPU node, never beside another busy worker (its
    # samples' busy count 0 throughout), some frames slower than others (noise). The slope
    # per busy CPU worker cannot be learnt from them: it is the contention probe's (a mix
    # 1.3x slower beside 3 busy workers: 0.1 per worker), not a value fitted to the noise,
    # and the probe alone gives the same law.
    from warpvx.graph.model import _probe_slowdown, fit_slowdown

    rng = np.random.default_rng(3)
    samples = [("homography", 0.5, 0.5 * 1.2 * f, 0.0, 0.0) for f in rng.uniform(0.9, 1.6, 40)]
    probe = [(1.0, 1.3, 3.0, 0.0)]
    law = fit_slowdown(samples, probe)
    assert law.per_cpu == pytest.approx(0.1)
    probes = np.array(probe)
    assert law.per_cpu == _probe_slowdown(probes, np.log(probes[:, 1] / probes[:, 0])).per_cpu
    # A few frames with a sliver of concurrency that happen to be the slow ones do not
    # move it to the grid's edge: the probe outweighs a regressor that barely varies.
    samples += [("homography", 0.5, 0.5 * 1.9, 0.02, 0.0)] * 5
    assert fit_slowdown(samples, probe).per_cpu == pytest.approx(0.1)
    # Without a probe, a kind never busy in the samples stays 0.
    assert fit_slowdown(samples[:40]).per_cpu == 0.0


# --------------------------------------------------------------------------- the bench's rounds


class _ScriptedGraph:
    """Stands in for a Graph in :func:`graph_bench.rounds`/``settle``: ``measure_plans`` of
    one round gives each plan ``frames`` runs of the makespan ``spans[call][plan]`` and
    records the order the plans ran in and the first input of the call."""

    def __init__(self, spans):
        self.spans, self.orders, self.first_inputs = spans, [], []

    def measure_plans(self, plans, inputs, *, rounds, frames, warmup):
        assert rounds == 1
        call = len(self.orders)
        self.orders.append(list(plans))
        self.first_inputs.append(inputs[0])
        return [[type("Run", (), {"makespan": self.spans[call % len(self.spans)][p],
                                  "timeline": {}, "host": {}})()] * frames for p in plans]


def test_bench_rounds_alternate_plans_and_go_on_through_the_inputs():
    bench = _graph_bench()
    g = _ScriptedGraph([{"a": 1.0, "b": 2.0, "c": 3.0}])
    log = []
    out = bench.rounds(g, ["a", "b", "c"], list(range(100)), 3, 4, start=5, log=log)
    assert g.orders == [["a", "b", "c"], ["c", "b", "a"], ["a", "b", "c"]]
    # Each round runs 3 plans x (4 + the switch warm-up) frames; the next starts after them.
    step = 3 * (4 + bench.SWITCH_WARMUP)
    assert g.first_inputs == [5, 5 + step, 5 + 2 * step]
    # Runs come back per plan in the order given, whatever order a round ran them in.
    assert [[r.makespan for r in runs] for runs in out] == [[1.0] * 12, [2.0] * 12, [3.0] * 12]
    assert [x["medians"] for x in log] == [[1.0, 2.0, 3.0]] * 3
    assert all(x["reference_ms"] > 0 and x["idle_cpu_pct"] >= 0 for x in log)
    assert all(0 <= x["steal_pct"] <= x["steal_pct"] + x["busy_pct"] <= 100.0 for x in log)


def test_bench_settle_stops_once_rounds_repeat_and_is_capped():
    bench = _graph_bench()
    # A machine slowing down after a load, then steady: 10 -> 8 -> 6.5 -> 6.4 ms per plan.
    spans = [{"a": v, "b": 2 * v} for v in (10.0, 8.0, 6.5, 6.4, 6.4, 6.4)]
    got = bench.settle(_ScriptedGraph(spans), ["a", "b"], list(range(50)), 3)
    assert got["rounds"] == 4 and got["settled"]
    assert got["change_pct"] == pytest.approx([20.0, 18.75, 100 * (1 - 6.4 / 6.5)])
    assert len(got["log"]) == 4 and all(x["reference_ms"] > 0 for x in got["log"])
    # Never steady (two speeds in turn): stops at the cap, and says so.
    flip = [{"a": 10.0, "b": 10.0}, {"a": 5.0, "b": 5.0}]
    got = bench.settle(_ScriptedGraph(flip), ["a", "b"], list(range(50)), 3)
    assert got["rounds"] == bench.SETTLE_ROUNDS and not got["settled"]
    assert len(got["change_pct"]) == bench.SETTLE_ROUNDS - 1


def test_bench_reports_drift_and_nearest_rounds(tmp_path):
    # A quick run: each scheduler policy's drift is its later frames' median over its
    # training rounds' (the first block of its makespans), the near error is the
    # out-of-sample prediction against the rounds right after training, and both are in
    # the table beside the settle phase and the CPU reference.
    bench = _graph_bench()
    report = bench.main(["--quick", "--frames", "8", "--fit-frames", "3", "--block", "3",
                         "--size", "96x72", "--graphs", "two-cameras", "--out", str(tmp_path),
                         "--overhead-nodes", "4", "--overhead-frames", "2", "--trial-frames", "0"])
    e = report["experiments"][0]
    assert 1 <= e["settle"]["rounds"] <= bench.SETTLE_ROUNDS
    assert len(e["round_log"]["training"]) == 1 and len(e["round_log"]["later"]) == 2
    for r in e["policies"]:
        spans = r["makespans"]
        if r["policy"] == "best":
            assert r["drift_pct"] is None
        else:
            want = 100 * (statistics.median(spans[3:]) / statistics.median(spans[:3]) - 1)
            assert r["drift_pct"] == pytest.approx(want)
        assert r["error_near_pct"] == pytest.approx(
            100 * (r["pred_out_ms"] - r["measured_near_ms"]) / r["measured_near_ms"])
    train = next(r for r in e["policies"] if r["policy"] == e["train"])
    assert e["drift_pct"] == train["drift_pct"]
    for r in e["policies"]:  # the training policy as the reference clock of the others
        if r["policy"] == e["train"]:
            assert r["error_dedrift_pct"] is None
        else:
            assert r["error_dedrift_pct"] == pytest.approx(
                100 * (r["pred_out_ms"] * (1 + e["drift_pct"] / 100) / r["measured_out_ms"] - 1))
    md = (tmp_path / "graph_bench.md").read_text()
    assert "Settle: " in md and "| drift | near: measured | error | drift out |" in md
    assert "CPU reference ms (median settle / training / later)" in md


def test_bench_idle_cpu_sees_a_spinning_thread():
    # The bench's check for a thread of ours burning CPU between rounds: near zero when
    # every other thread blocks, a good share of a core beside a thread that spins (on a
    # loaded 2-core machine the spinner gets a third of a core or less).
    bench = _graph_bench()
    import threading

    assert bench.idle_cpu_pct(0.2) < 10.0
    stop = threading.Event()
    spinner = threading.Thread(target=lambda: [None for _ in iter(stop.is_set, True)], daemon=True)
    spinner.start()
    try:
        assert bench.idle_cpu_pct(0.2) > 10.0
    finally:
        stop.set()
        spinner.join()


def test_bench_work_cores_counts_cpu_tasks_and_gpu_host_calls():
    # Two frames of 10 ms: a CPU task of 4 ms beside a GPU task whose host call took 1 ms
    # (its 10 ms on the device use no core), then 6 + 2 ms: (4 + 1 + 6 + 2) / 20 cores.
    bench = _graph_bench()
    frames = [bench.recorded_frame({"a": ["cpu0", 0.0, 4.0, 0.0, 0, None, None],
                                    "b": ["gpu", 0.0, 10.0, 0.0, 0, 0.0, 1.0]}),
              bench.recorded_frame({"a": ["cpu1", 1.0, 7.0, 0.0, 0, None, None],
                                    "b": ["gpu", 0.0, 10.0, 0.0, 0, 3.0, 5.0]})]
    assert [f.makespan for f in frames] == [10.0, 10.0]
    assert bench.work_cores(frames) == pytest.approx(13.0 / 20.0)


def _sleep_ms(ms):
    def fn(x):
        time.sleep(ms / 1e3)
        return x
    return fn


def test_best_for_throughput_keeps_the_placement_that_streams_fastest():
    """A -> B, B on the GPU role only. A on the GPU role finishes a frame first (15 + 15 ms
    against 20 + 15) but streams slower (the GPU role does 30 ms per frame, against 20 for
    the busier of a CPU worker and the GPU role). The latency trial keeps the first, the
    throughput trial the second, each measured."""
    g = warpvx.Graph("throughput")
    x = g.input("x", shape=(4,), dtype=np.float32)
    a = g.user(_sleep_ms(20), [x], warp_fn=_sleep_ms(15), name="A")
    g.output("y", g.user(None, [a], warp_fn=_sleep_ms(15), name="B"))
    frame = {"x": np.arange(4, dtype=np.float32)}
    model = _baseline_model(g, frame)
    # Told A is slower on the GPU role than it is, so that HEFT on the model's costs places
    # it on the CPU worker: the trials' second candidate.
    model.alone["A"] = {**model.alone["A"], "gpu": 40.0, "device": 0.0}
    kw = dict(n_cpus=1, gpu="warp-cpu", model=model, trial_inputs=[frame], trial_frames=6,
              trial_margin=1e6)
    latency = g.schedule("best", **kw)
    assert set(latency.schedule.info["trial_ms"]) == {"baseline", "heft (model costs)"}
    assert latency.placement["A"] == "gpu" and latency.schedule.info["objective"] == "latency"
    streamed = g.schedule("best", objective="throughput", trial_depth=3, **kw)
    fps = streamed.schedule.info["trial_fps"]
    assert streamed.placement["A"] == "cpu0"
    assert fps[streamed.schedule.info["chosen"]] == max(fps.values())
    assert max(fps.values()) > 1.2 * min(fps.values())  # ~50 against ~33 FPS
    assert streamed.schedule.info["trial_frames"] == {k: 6 * 4 for k in fps}
    np.testing.assert_array_equal(g.process(frame)["y"], frame["x"])
    with pytest.raises(warpvx.WarpvxValueError, match="objective"):
        g.schedule("best", objective="fps", **kw)
    for policy, model_kw in (("heft", {"model": model}), ("best", {})):
        with pytest.raises(warpvx.GraphError, match="objective"):  # not silently ignored
            g.schedule(policy, n_cpus=1, gpu="warp-cpu", objective="throughput", **model_kw)
    for bad in (0, True, 2.5):
        with pytest.raises((warpvx.WarpvxTypeError, warpvx.WarpvxValueError), match="trial_depth"):
            g.schedule("best", objective="throughput", trial_depth=bad, **kw)
    g.close()
