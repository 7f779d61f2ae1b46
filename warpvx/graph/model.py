"""A cost model that predicts out of sample: host contention, copies and hand-offs, fitted
on running frames and played through a simulation of the executor.

Why: a node's time inside a running frame is not its time alone. CPU workers and the GPU
host thread share Python's GIL, the cores and the memory bandwidth, so a task runs slower
the more other host threads are busy beside it; copies and hand-offs between threads cost
time the isolated calibration never sees; and the makespan is a function of placement *and*
overlap. So the model is

    work(node, pe) = e_node,pe * (r_pe * alone(node, pe) + d_pe) + copies(node, pe)
    speed(t)       = 1 / (1 + s_node * (a_pe * cpus(t) + b_pe * gpus(t)))

where ``alone`` is the calibrated time (:mod:`warpvx.graph.calibration`; for a GPU node the
host side of the call, its enqueue: the GPU nodes of a frame are host-bound), ``copies``
the transfer model's time for the bytes the executor copies for the task (plus the extra
per copying task the training frames measured), ``cpus(t)`` the *other* CPU workers
running a task at ``t`` and ``gpus(t)`` the GPU host thread inside a call, each counted by
its node's GIL pressure, ``s_node`` the node's GIL sensitivity
(:func:`~warpvx.graph.calibration.measure_gil`: how much a pure-Python neighbour slows
the node, how much the node slows a pure-Python neighbour; 1 and 1 where not measured),
``r_pe`` the in-frame over alone ratio, ``d_pe``
a fixed in-frame cost per task (the executor's work inside the interval), ``a_pe``/``b_pe``
the slowdown per busy CPU worker / busy GPU host thread of each kind of processing element
(``"cpu"``, ``"gpu"`` for the GPU host thread), and ``e`` a per-node correction, 1 for a
node never seen on that ``pe``. The fit (:func:`fit_slowdown`) takes ``r, d, a, b`` from
all nodes at once (least absolute deviations of the logs), then ``e`` as each node's median
residual, so a node's own usual contention is not mistaken for its own slowness. On CUDA
the device runs a GPU node's kernels for its calibrated device time, not before the host
started enqueuing them and not ending before the host call ended. Waits between tasks (a
thread taking its next task, a hand-off between threads by kind of edge: CPU after GPU,
GPU after CPU, CPU after CPU; the start of a frame) are the medians measured in the
training frames.

A captured GPU segment (consecutive capturable GPU tasks between CPU hand-offs, replayed as
one CUDA graph: :func:`gpu_segments`) is one replay: ``segment_ratio`` times its calibrated
device time as its lanes run it (:func:`lane_span`: independent branches side by side, as
the all-GPU baseline's two cameras, every lane joined before a task that inserts conditional
graph nodes; a mixed placement's one-task segment has none beside it) plus a fixed cost
(:func:`fit_segments`). A segment whose capture failed runs eagerly
from then on (:func:`eager_nodes`; ``predict(..., eager=)``): its tasks are eager calls,
whose law is fitted on eager calls alone (the contention probe's GPU mix, its calls in
turn, as the in-frame ratio where the training frames replayed every GPU task).

:func:`simulate` runs a schedule's per-processor orders through this model, event by event
(every busy thread advances at its current speed), and returns the predicted timeline; its
makespan is the prediction. :func:`fit` learns the model from frames run with one plan;
:meth:`ContentionModel.predict` predicts any plan of the same graph and GPU role, including
other policies' placements (out of sample).
"""

from __future__ import annotations

import math
import statistics
from dataclasses import dataclass, field

import numpy as np

from ..check import check_choice
from ..errors import GraphError
from ..sched.schedule import Schedule, ScheduledTask
from .data import INPUT, Data, DelayRef, nbytes

#: Latency classes: what a task waited for last before it started.
LATENCIES = ("start", "cpu_same", "gpu_same", "cpu_from_cpu", "cpu_from_gpu", "gpu_from_cpu")


def pe_of(processor: str) -> str:
    """``"gpu"`` for the GPU processor, ``"cpu"`` for a CPU worker ``"cpu<i>"``."""
    return "gpu" if processor.startswith("gpu") else "cpu"


# --------------------------------------------------------------------------- structure


@dataclass(frozen=True)
class Reads:
    """One input of a node: the data's name, its producer (None: a graph input, on the host),
    its bytes, and whether it comes from an earlier frame (a delay)."""

    key: str
    producer: str | None
    nbytes: int
    delayed: bool

    @property
    def offset(self) -> int:
        """Frames back, as the executor's reads count them (1: a delay's)."""
        return int(self.delayed)


def graph_reads(graph) -> dict:
    """node -> tuple of :class:`Reads` of a verified graph (data sizes from its samples)."""
    out = {}
    for node in graph.nodes.values():
        reads = []
        for ref in node.inputs.values():
            delayed = isinstance(ref, DelayRef)
            data = ref.data if delayed else ref
            if not isinstance(data, Data):
                continue
            producer = None if data.kind == INPUT or data.producer is None else data.producer.name
            reads.append(Reads(data.name, producer, nbytes(data.sample), delayed))
        out[node.name] = tuple(reads)
    return out


def copied_bytes(reads: dict, placement: dict, order: list, capturable=()) -> dict:
    """node -> bytes the executor copies for it under ``placement`` (node -> processor).

    A value crosses once per side: the first reader on the other side of its producer (in
    ``order``, the tasks by predicted start) copies it; later readers there reuse the copy
    (a delayed read too: the earlier frame's value was copied when that frame read it).
    Graph inputs live on the host. A GPU segment of ``capturable`` tasks
    (:func:`gpu_segments`) fills fixed buffers of its own before each run
    (:mod:`warpvx.runtime.capture`): it copies every host value it reads, a delayed one
    apart, reused by no other segment, charged to its first task as the executor records it
    (an H100 HEFT frame at 1920x1080 uploads a CPU-made pyramid twice, this frame's and the
    delayed one: 5.5 MB).
    """
    gpu_order = [t for t in order if pe_of(placement[t]) == "gpu"]
    owner = {t: seg[0] for seg in gpu_segments(reads, frozenset(capturable), placement, gpu_order)
             if seg[0] in capturable for t in seg}
    done, out = set(), {}
    for node in order:
        side = pe_of(placement[node])
        unit = owner.get(node)
        for r in reads[node]:
            home = "cpu" if r.producer is None else pe_of(placement[r.producer])
            key = (r.key, r.delayed and unit is not None, side, unit)
            if home != side and key not in done:
                done.add(key)
                charged = unit or node
                out[charged] = out.get(charged, 0) + r.nbytes
    return out


# --------------------------------------------------------------------------- fitting

#: Grid of slowdowns per busy neighbour tried by :func:`fit_slowdown` (per kind of
#: neighbour: busy CPU workers, the busy GPU host thread).
SLOWDOWN_GRID = np.linspace(0.0, 2.0, 21)

#: Grid of fixed in-frame costs per task (ms: the executor's bookkeeping inside a task's
#: interval, what makes a 3 us node take 20 us) tried by :func:`fit_slowdown`.
OVERHEAD_GRID = np.linspace(0.0, 0.1, 11)

#: At most this share of a task's interval is taken for copies it made but did not time
#: apart (the transfer model can overestimate a copy; the node's own work stays positive).
UNTIMED_COPY_SHARE = 0.9

#: The fixed cost (ms) of a captured segment's replay where the training frames' segments
#: are all one size (the all-GPU baseline: one segment a frame), which cannot tell it from
#: the ratio: what the fit finds where sizes differ (100-200 us on the H100's heft and xeft
#: placements, s3-s5). Without it a baseline-trained model played heft's one-node segments
#: at a ratio of their device time (a 0.06 ms blur measured 0.27 ms, s4 1280x720).
SEGMENT_FIXED_PRIOR = 0.1

#: How much of the lanes' concurrency a captured segment's replay gets, tried by
#: :func:`fit_segments` where the training segments differ in size (1: its independent
#: branches side by side, as :func:`lane_span` spreads them; 0: one after the other).
#: Training frames of one segment size take 1: the all-GPU baseline replays both cameras
#: in one segment, and a ratio learnt on its summed device time (0.3-0.44 on the H100,
#: s6/s6b) played the one-task segments of mixed placements 2-3x too short.
LANES_GRID = np.linspace(0.0, 1.0, 5)
SEGMENT_LANES_PRIOR = 1.0

#: Weight of a contention probe (:func:`~warpvx.graph.calibration.measure_contention`)
#: measurement in the fit, in training samples.
PROBE_WEIGHT = 8


@dataclass
class Slowdown:
    """The fitted contention law of one kind of processing element.

    ``ratio``: in-frame over alone time with no busy neighbour, for a node not seen on this
    kind (the alone-time-weighted median of the seen nodes'); ``per_cpu``/``per_gpu``: extra
    slowdown per busy CPU worker / while the GPU host thread is busy; ``node``: node -> its
    own in-frame ratio over ``ratio`` (``e``); ``samples``: how many samples the fit used;
    ``rms_log``: the fit's rms residual of ``log(measured / predicted)``; ``overhead``: the
    fixed in-frame cost of a task (ms).
    """

    ratio: float = 1.0
    per_cpu: float = 0.0
    per_gpu: float = 0.0
    node: dict = field(default_factory=dict)
    samples: int = 0
    rms_log: float = 0.0
    overhead: float = 0.0

    def in_frame(self, node: str, alone: float) -> float:
        """``node``'s time (ms) in a frame with no busy neighbour, ``alone`` ms alone."""
        return (self.ratio * alone + self.overhead) * self.node.get(node, 1.0)

    def speed_divisor(self, cpus: float, gpus: float) -> float:
        """``1 + per_cpu * cpus + per_gpu * gpus``: how much slower than with none busy."""
        return 1.0 + self.per_cpu * cpus + self.per_gpu * gpus


def fit_slowdown(samples, probes=(), *, per_node: bool = True, prior_ratio: float = 1.0) -> Slowdown:
    """Fit ``measured = (ratio * alone + overhead) * (1 + a * cpus + b * gpus) * e_node``.

    Parameters
    ----------
    samples : iterable of (node, alone_ms, measured_ms, cpus, gpus)
        ``cpus``/``gpus``: the mean number of other CPU workers / GPU host threads busy
        during the measured interval. Samples with a non-positive time are skipped.
    probes : iterable of (alone_ms, loaded_ms, cpus, gpus)
        A call timed alone and with that many threads of each kind busy beside it
        (:func:`~warpvx.graph.calibration.measure_contention`): each adds
        :data:`PROBE_WEIGHT` times its ``|log(loaded / alone) - log(1 + a cpus + b gpus)|``
        to the cost, so ``a`` and ``b`` are known even when the frames kept the other
        threads idle; they do not enter ``ratio`` or ``overhead``.
    per_node : bool
        Also fit each node's correction ``e`` (the median of its samples' residuals,
        after the shared law), else ``e = 1``.
    prior_ratio : float
        ``ratio`` where there is no sample (:func:`_probe_slowdown`).

    Returns
    -------
    Slowdown
        The shared law first, over every node at once, so that ``a`` and ``b`` come from
        how nodes that ran beside busy threads differ from nodes that did not (a per-node
        factor fitted with them would absorb each node's usual contention, and a node
        moved to a busier or quieter place would be mispredicted): ``a``, ``b`` and
        ``overhead`` on :data:`SLOWDOWN_GRID`/:data:`OVERHEAD_GRID`, ``ratio`` the
        alone-time-weighted median for each; kept: the triple with the least absolute
        deviation of the logs, summed over all samples under the one law plus within each
        node (its samples about their mean: how one node's time moved with its neighbours)
        -- absolute deviations and medians, so a frame the machine hiccupped in does not
        move the fit. A kind of neighbour never busy in the samples (nor in a probe) cannot
        be identified and stays 0. Without samples, the probes' law
        (:func:`_probe_slowdown`).
    """
    rows = [r for r in samples if r[1] > 0 and r[2] > 0]
    probes = np.array([p for p in probes if p[0] > 0 and p[1] > 0], np.float64).reshape(-1, 4)
    p_log = np.log(probes[:, 1] / probes[:, 0])
    if not rows:
        return _probe_slowdown(probes, p_log, prior_ratio)
    alone = np.array([r[1] for r in rows])
    meas = np.array([r[2] for r in rows])
    cpus = np.array([r[3] for r in rows], np.float64)
    gpus = np.array([r[4] for r in rows], np.float64)
    names = sorted({r[0] for r in rows})
    idx = np.array([names.index(r[0]) for r in rows])
    groups = [np.flatnonzero(idx == i) for i in range(len(names))]
    counts = np.bincount(idx, minlength=len(names))
    best = None
    for a in SLOWDOWN_GRID if np.ptp(cpus) > 0 or probes[:, 2].any() else (0.0,):
        for b in SLOWDOWN_GRID if np.ptp(gpus) > 0 or probes[:, 3].any() else (0.0,):
            plain = meas / (1.0 + a * cpus + b * gpus)
            probe_cost = PROBE_WEIGHT * float(
                np.abs(p_log - np.log1p(a * probes[:, 2] + b * probes[:, 3])).sum())
            for d in OVERHEAD_GRID:
                ratio = _weighted_median((plain - d) / alone, alone)
                if ratio <= 0:
                    continue
                z = np.log(plain / (ratio * alone + d))
                within = z - (np.bincount(idx, z, len(names)) / counts)[idx]
                cost = float(np.abs(z).sum() + np.abs(within).sum()) + probe_cost
                if best is None or cost < best[0] - 1e-12:
                    best = (cost, a, b, d, ratio)
    if best is None:
        return Slowdown()
    _, a, b, d, ratio = best
    z = np.log(meas / ((ratio * alone + d) * (1.0 + a * cpus + b * gpus)))
    node = {}
    if per_node:
        meds = np.array([np.median(z[g]) for g in groups])
        node = {n: math.exp(float(m)) for n, m in zip(names, meds)}
        z = z - meds[idx]
    return Slowdown(float(ratio), float(a), float(b), node, len(rows),
                    math.sqrt(float(z @ z) / len(rows)), float(d))


def _probe_slowdown(probes, p_log, ratio: float = 1.0) -> Slowdown:
    """The law of a kind no training sample shows (an eager GPU call where the training
    frames replayed every GPU task): ``ratio`` given, no fixed cost, and ``a``, ``b`` from
    the probes alone (least absolute deviations on :data:`SLOWDOWN_GRID`), 0 without
    probes."""
    if not len(probes):
        return Slowdown(ratio)
    grid = [(float(np.abs(p_log - np.log1p(a * probes[:, 2] + b * probes[:, 3])).sum()), a, b)
            for a in SLOWDOWN_GRID for b in SLOWDOWN_GRID]
    _, a, b = min(grid, key=lambda c: c[0])
    return Slowdown(ratio, float(a), float(b))


def _weighted_median(values, weights) -> float:
    order = np.argsort(values)
    cum = np.cumsum(weights[order])
    return float(values[order][np.searchsorted(cum, 0.5 * cum[-1])])


def busy_overlap(interval, others, weights=None) -> float:
    """Mean number of ``others`` (``(start, end)`` intervals) active during ``interval``,
    each counted ``weights[i]`` times (default once)."""
    s, f = interval
    if f <= s:
        return 0.0
    weights = weights if weights is not None else [1.0] * len(others)
    total = sum(w * max(0.0, min(f, b) - max(s, a)) for (a, b), w in zip(others, weights))
    return total / (f - s)


def host_intervals(run) -> dict:
    """task -> ``(processor, start, end)`` of a FrameResult's host-side work: a CPU task's
    interval, a GPU task's call on the GPU host thread (its device interval without CUDA)."""
    out = {}
    for task, t in run.timeline.items():
        if pe_of(t.processor) == "gpu" and task in run.host:
            out[task] = (t.processor,) + tuple(run.host[task])
        else:
            out[task] = (t.processor, t.start, t.finish)
    return out


@dataclass
class ContentionModel:
    """What :func:`fit` learnt (times in ms); :meth:`predict` simulates a plan with it.

    Attributes
    ----------
    slowdown : dict
        ``"cpu"``/``"gpu"`` -> :class:`Slowdown` (``"gpu"``: the GPU host thread's calls).
    latency : dict
        :data:`LATENCIES` -> median wait (ms) between a task becoming ready and starting.
    alone : dict
        node -> ``{"cpu": ms, "gpu": ms (host side of the call), "device": ms}`` from the
        calibration (None where there is no implementation; ``device`` 0 without CUDA).
    reads : dict
        :func:`graph_reads` of the graph.
    transfer : TransferModel
    cuda : bool
        The GPU role is a CUDA device (host enqueue and device run apart).
    trained_on : str
        The policy whose frames the model learnt from, and how many.
    capturable : frozenset
        Nodes the executor runs in GPU segments (:func:`gpu_segments`): a segment is one
        unit, its values published to CPU readers when it ends.
    gil : dict
        :func:`~warpvx.graph.calibration.measure_gil`: node -> ``{pe: (sensitivity,
        pressure)}``; a busy neighbour counts its pressure, a victim its sensitivity
        (1 and 1 for a node not measured: every busy thread counts alike).
    copy_extra : dict
        ``"cpu"``/``"gpu"`` -> the median time (ms) a task's copies took in the training
        frames beyond the transfer model's (a frame's copies wait on a synchronisation and
        copy pageable arrays; calibration's do neither): a fixed cost per copying task,
        not a factor, so a scale learnt on 8 KB downloads is not applied to a frame.
    segment_ratio : float or None
        A captured GPU segment's measured interval (its copies taken out) over the sum of
        its tasks' calibrated device times (host times without CUDA), the median over the
        training frames' segments (:func:`fit_segments`): a replay runs its kernels back
        to back with no launch gaps, so it is shorter than the eager calls calibrated
        alone. None where the training frames ran no segment: each task played eagerly.
    segment_fixed : float
        The fixed cost (ms) of one segment's replay (:func:`fit_segments`), on its first task.
    segment_lanes : float
        How much of its lanes' concurrency a segment's replay gets (:func:`fit_segments`,
        :func:`segment_scale`): its calibrated time is that share of its
        :func:`lane_span` plus the rest of its summed device times.
    serial : frozenset
        Capturable nodes that insert conditional graph nodes (Harris's selection rounds,
        FAST's counted sort): a segment's lanes are all joined before each
        (:class:`~warpvx.runtime.lanes.Lanes`), which :func:`lane_span` plays (the
        executor finds them on a segment's first run: ``Executor.serial_tasks``).
    """

    slowdown: dict
    latency: dict
    alone: dict
    reads: dict
    transfer: object
    cuda: bool
    trained_on: str = ""
    copy_extra: dict = field(default_factory=dict)
    gil: dict = field(default_factory=dict)
    capturable: frozenset = frozenset()
    segment_ratio: float | None = None
    segment_fixed: float = 0.0
    segment_lanes: float = 1.0
    serial: frozenset = frozenset()

    def sensitivity(self, node: str, pe: str) -> float:
        """How much ``node`` on ``pe`` suffers from a busy GIL-holding neighbour (0-1)."""
        return _gil_share(self.gil, node, pe, 0)

    def pressure(self, node: str, pe: str) -> float:
        """How much ``node`` running on ``pe`` slows a neighbour down (0-1)."""
        return _gil_share(self.gil, node, pe, 1)

    def work(self, node: str, pe: str, copied: int = 0) -> float:
        """``node``'s time on ``pe`` in a frame with no busy neighbour, its copies of
        ``copied`` bytes included (ms)."""
        alone = self.alone[node][pe]
        if alone is None:
            raise GraphError(f"node {node!r}: no {pe.upper()} implementation to predict")
        return self.slowdown[pe].in_frame(node, alone) + self.copy_time(pe, copied)

    def segment_work(self, node: str, first: bool, scale: float = 1.0) -> float:
        """``node``'s share (ms) of a captured segment's replay: :attr:`segment_ratio` times
        its calibrated device time (host time without CUDA), plus :attr:`segment_fixed` on
        the segment's ``first`` task."""
        return self.segment_ratio * scale * _segment_base(self.alone, node, self.cuda) + \
            (self.segment_fixed if first else 0.0)

    def copy_time(self, pe: str, nbytes: int) -> float:
        """The copies a task on ``pe`` makes of ``nbytes`` (uploads on the GPU thread,
        downloads on a CPU worker): the transfer model plus ``copy_extra``."""
        if not nbytes:
            return 0.0
        return max(0.0, _copy_ms(self.transfer, pe, nbytes) + self.copy_extra.get(pe, 0.0))

    def predict(self, plan_or_schedule, processors=None, *, eager=()) -> Schedule:
        """The predicted timeline of one frame of a plan (or of a Schedule's orders):
        :func:`simulate` (``eager``: its capturable tasks run eagerly, :func:`eager_nodes`
        of frames the plan ran)."""
        sch = getattr(plan_or_schedule, "schedule", plan_or_schedule)
        return simulate(self, sch, eager)

    def makespan(self, plan_or_schedule, *, eager=()) -> float:
        """Predicted makespan (ms) of one frame (``eager``: see :meth:`predict`)."""
        return self.predict(plan_or_schedule, eager=eager).makespan

    def summary(self) -> dict:
        """JSON-friendly parameters."""
        return {
            "trained_on": self.trained_on,
            "slowdown": {k: {"ratio": s.ratio, "overhead_us": s.overhead * 1e3, "per_cpu": s.per_cpu,
                             "per_gpu": s.per_gpu, "samples": s.samples, "rms_log": s.rms_log}
                         for k, s in self.slowdown.items()},
            "latency_us": {k: v * 1e3 for k, v in self.latency.items()},
            "copy_extra_us": {k: v * 1e3 for k, v in self.copy_extra.items()},
            "segment_ratio": self.segment_ratio, "segment_fixed_us": self.segment_fixed * 1e3,
            "segment_lanes": self.segment_lanes,
        }


def _gil_share(gil, node, pe, which) -> float:
    got = (gil or {}).get(node, {}).get(pe)
    return 1.0 if got is None else float(got[which])


def alone_costs(calibration) -> dict:
    """node -> ``{"cpu", "gpu" (host side), "device"}`` ms from a Calibration."""
    cuda = bool(calibration.gpu) and calibration.gpu.startswith("cuda")
    out = {}
    for node, t in calibration.nodes.items():
        host = t.get("gpu_host") if cuda else t.get("gpu")
        out[node] = {"cpu": t.get("cpu"),
                     "gpu": host if host is not None else t.get("gpu"),
                     "device": (t.get("gpu") or 0.0) if cuda else 0.0}
    return out


def gpu_segments(reads: dict, capturable, placement: dict, gpu_order) -> list:
    """The GPU queue ``gpu_order`` cut as the executor cuts it
    (:func:`warpvx.runtime.capture.segments`): runs of consecutive ``capturable`` tasks, a
    new one where a task reads (at any frame offset) a value a CPU worker made; any other
    task a segment of its own. Lists of task names."""
    groups, current = [], []
    for task in gpu_order:
        if task not in capturable:
            if current:
                groups.append(current)
                current = []
            groups.append([task])
            continue
        if current and any(r.producer is not None and pe_of(placement[r.producer]) == "cpu"
                           for r in reads[task]):
            groups.append(current)
            current = []
        current.append(task)
    if current:
        groups.append(current)
    return groups


def eager_nodes(runs, reads, capturable, placement) -> frozenset:
    """Capturable GPU tasks that ran eagerly in most of ``runs`` (FrameResults of one plan).

    The executor runs a segment whose capture failed eagerly from then on, task by task
    (:mod:`warpvx.runtime.segment_runner`: a failure is not retried). A replayed segment's
    tasks share its one host interval, so theirs abut exactly, and its uploads are not
    timed apart; an eager task has a host interval of its own and times its uploads
    (large ones on CUDA). So a segment ran eagerly in a frame where its tasks' host
    intervals do not abut or a task timed a copy (a one-task segment without a timed
    upload cannot be told apart: taken as replayed). On the H100, mixed placements lost a
    segment to a failed capture in 4 of 8 runs of s6/s6b (a CPU worker's copy during the
    capture is the suspect) and ran it 2x slower than replayed.
    """
    capturable = frozenset(capturable)
    counts, n = {}, 0
    for run in runs:
        if not run.timeline:
            continue
        n += 1
        hosts = host_intervals(run)
        order = sorted((t for t, (p, _, _) in hosts.items() if pe_of(p) == "gpu"),
                       key=lambda t: hosts[t][1])
        for seg in gpu_segments(reads, capturable, placement, order):
            if seg[0] not in capturable:
                continue
            apart = any(hosts[a][2] != hosts[b][1] for a, b in zip(seg, seg[1:]))
            if apart or any(run.transfers.get(t, 0.0) > 0 for t in seg):
                for t in seg:
                    counts[t] = counts.get(t, 0) + 1
    return frozenset(t for t, c in counts.items() if 2 * c > n)


def _segment_base(alone, node, cuda) -> float:
    """The calibrated time a captured segment's replay scales: the device time on CUDA (the
    replay is device-bound), else the call."""
    return alone[node]["device"] if cuda else alone[node]["gpu"]


def lane_span(reads, seg, base, serial=()) -> float:
    """The span (ms) of a captured segment's tasks ``seg`` spread over
    :data:`~warpvx.runtime.lanes.MAX_LANES` streams as the executor spreads them
    (:func:`~warpvx.runtime.lanes.lanes`, its ``span``: list scheduling by this frame's
    dependencies inside the segment), each task taking ``base[task]`` ms: independent
    branches (two cameras, a detector beside the features) run side by side, so a segment of
    both cameras replays in well under its summed device time and a one-task segment in all
    of it; the ``serial`` tasks (:attr:`ContentionModel.serial`: they insert conditional
    graph nodes) each run with every lane joined before them."""
    from ..runtime.lanes import lanes

    inside = set(seg)
    tasks = [_LaneTask(t, reads[t], frozenset(r.key for u in inside for r in reads[u]
                                              if r.producer == t))
             for t in seg]
    return lanes(tasks, base, serial=frozenset(serial) & inside).span


@dataclass(frozen=True)
class _LaneTask:
    """A segment's task as :func:`~warpvx.runtime.lanes.lanes` takes it (its reads: the
    :class:`Reads`, whose ``offset`` it needs; its outputs: the keys read in the segment)."""

    name: str
    inputs: tuple
    outputs: frozenset


def segment_scale(reads, segments, alone, cuda, lanes: float = 1.0, serial=()) -> dict:
    """task -> its segment's calibrated span over the sum of its tasks'
    :func:`_segment_base` (1 where that sum is 0), for each of ``segments``: the span is
    ``lanes`` times the :func:`lane_span` (its ``serial`` tasks run with every lane joined)
    plus ``1 - lanes`` times the sum (``lanes``: how much of the lanes' concurrency the
    replays get)."""
    out = {}
    for seg in segments:
        base = {t: _segment_base(alone, t, cuda) or 0.0 for t in seg}
        total = sum(base.values())
        f = lanes * lane_span(reads, seg, base, serial) / total + 1.0 - lanes if total > 0 else 1.0
        out.update((t, f) for t in seg)
    return out


def segment_samples(runs, reads, capturable, placement, alone, transfer, cuda, slow=None,
                    serial=()) -> list:
    """``(calibrated ms, its lanes' span ms, replay ms)`` of each captured segment of each
    frame (:func:`lane_span`: the calibrated times as the lanes spread them, ``serial``
    tasks with every lane joined).

    A segment (:func:`gpu_segments`, capturable tasks only) of a frame is timed as one
    interval, shared by its tasks (:mod:`warpvx.runtime.capture`): its span, less the
    transfer model's time for the bytes uploaded into it and divided by ``slow``'s (the GPU
    :class:`Slowdown`) contention for the CPU workers busy beside it, against the sum of its
    tasks' :func:`_segment_base`. Segments with no calibrated time are skipped."""
    out = []
    for run in runs:
        hosts = host_intervals(run)
        order = sorted((t for t, v in run.timeline.items() if pe_of(v.processor) == "gpu"),
                       key=lambda t: run.timeline[t].start)
        cpu_busy = [(s, f) for p, s, f in hosts.values() if pe_of(p) == "cpu"]
        for seg in gpu_segments(reads, capturable, placement, order):
            if seg[0] not in capturable:
                continue
            times = {t: _segment_base(alone, t, cuda) or 0.0 for t in seg}
            base, span = sum(times.values()), lane_span(reads, seg, times, serial)
            s0 = min(run.timeline[t].start for t in seg)
            s1 = max(run.timeline[t].finish for t in seg)
            copies = _copy_ms(transfer, "gpu", sum(run.copied.get(t, 0) for t in seg))
            div = slow.speed_divisor(busy_overlap((s0, s1), cpu_busy), 0.0) if slow else 1.0
            if base > 0 and s1 - s0 > copies:
                out.append((base, span, (s1 - s0 - copies) / div))
    return out


def fit_segments(samples) -> tuple:
    """``(ratio, fixed ms per segment, lanes)`` of ``replay = ratio * (lanes * span + (1 -
    lanes) * calibrated) + fixed`` over :func:`segment_samples` (``span``: the lanes'
    :func:`lane_span`): least absolute deviations on :data:`OVERHEAD_GRID` x 10 (the fixed
    cost of a replay: input fills, launch, copy-out) and :data:`LANES_GRID` where the
    segments differ in size, else (one size cannot tell them apart)
    :data:`SEGMENT_FIXED_PRIOR`, at most half the shortest replay, lanes 1 and the median
    ratio of the rest; ``(None, 0, 1)`` without samples."""
    if not samples:
        return None, 0.0, 1.0
    total, span, meas = (np.array(v, np.float64) for v in zip(*samples))
    if np.ptp(total) <= 0.05 * total.max():
        c = min(SEGMENT_FIXED_PRIOR, 0.5 * float(meas.min()))
        w = SEGMENT_LANES_PRIOR
        return float(np.median((meas - c) / (w * span + (1.0 - w) * total))), c, w
    best = None
    for w in LANES_GRID:
        base = w * span + (1.0 - w) * total
        for c in np.asarray(OVERHEAD_GRID) * 10:
            if c >= meas.min():
                break
            r = _weighted_median((meas - c) / base, base)
            cost = float(np.abs(meas - r * base - c).sum())
            if best is None or cost < best[0] - 1e-12:
                best = (cost, r, float(c), float(w))
    return float(best[1]), best[2], best[3]


def _segment_of(reads, capturable, placement, gpu_order) -> dict:
    """task -> the tasks of its GPU segment (:func:`gpu_segments`)."""
    return {t: seg for seg in gpu_segments(reads, capturable, placement, gpu_order) for t in seg}


def _ready_parts(run, task, reads, placement, hosts, segment):
    """(latency class, time the task became ready) in a measured frame; ``segment``: GPU
    task -> its segment's tasks (a CPU reader waits for the whole segment)."""
    proc, start, _ = hosts[task]
    side = pe_of(proc)
    ready, cls = 0.0, "start"
    same = [t for t, (p, s, _) in hosts.items() if p == proc and s < start]
    if same:
        prev = max(same, key=lambda t: hosts[t][1])
        ready, cls = hosts[prev][2], f"{side}_same"
    for r in reads[task]:
        if r.delayed or r.producer is None or r.producer not in hosts:
            continue
        p_side = pe_of(placement[r.producer])
        if hosts[r.producer][0] == proc:
            continue  # ordered on this thread already
        # A CPU reader of GPU data waits for the device, to the end of the producer's
        # segment; a GPU reader for the host call.
        t = (max(run.timeline[u].finish for u in segment.get(r.producer, (r.producer,))
                 if u in run.timeline)
             if p_side == "gpu" and side == "cpu" else hosts[r.producer][2])
        if t > ready:
            ready, cls = t, f"{side}_from_{p_side}"
    return cls, ready


def fit(calibration, reads: dict, runs, placement: dict, *, policy: str = "",
        probe: dict | None = None, gil: dict | None = None, capturable=(),
        serial=()) -> ContentionModel:
    """Learn a :class:`ContentionModel` from frames run with one plan.

    Parameters
    ----------
    calibration : Calibration
        Of the graph and GPU role that ran (alone costs and the transfer model).
    reads : dict
        :func:`graph_reads` of the graph.
    runs : list of FrameResult
        The training frames (one at a time, not pipelined).
    placement : dict
        node -> processor of the plan that ran.
    probe : dict, optional
        :func:`~warpvx.graph.calibration.measure_contention`'s ``(victim, loader) ->
        (mix, alone, loaded, busy_cpus, busy_gpus)``: a mix timed alone and with other
        host threads busy (loader ``"heavy"``: the heavy CPU nodes beside each other),
        so the slowdown per busy thread of each kind is known even when
        the training placement keeps the other threads idle (see :func:`fit_slowdown`).
    gil : dict, optional
        :func:`~warpvx.graph.calibration.measure_gil`: each busy neighbour (in the frames
        and in the probe's mixes) counts its GIL pressure, each victim its sensitivity,
        so ``a`` and ``b`` are per unit of Python run beside, not per busy thread.
    capturable : iterable of str
        Nodes the executor runs in GPU segments (:func:`gpu_segments`).
    serial : iterable of str
        Capturable nodes a segment's lanes join before (:attr:`ContentionModel.serial`).
    """
    runs = [r for r in runs if r.timeline]
    if not runs:
        raise GraphError("fit: no measured frames to learn from")
    alone = alone_costs(calibration)
    cuda = bool(calibration.gpu) and calibration.gpu.startswith("cuda")
    samples = {"cpu": [], "gpu": []}
    copies = {"cpu": [], "gpu": []}
    waits = {k: [] for k in LATENCIES}
    capturable = frozenset(capturable)
    # What the training frames replayed: their eager segments' tasks were eager calls.
    replayed = capturable - eager_nodes(runs, reads, capturable, placement)
    shares = ContentionModel({}, {}, alone, reads, None, cuda, gil=dict(gil or {}))
    for run in runs:
        hosts = host_intervals(run)
        gpu_order = sorted((t for t, (p, _, _) in hosts.items() if pe_of(p) == "gpu"),
                           key=lambda t: hosts[t][1])
        segment = _segment_of(reads, replayed, placement, gpu_order)
        for task, (proc, s, f) in hosts.items():
            pe = pe_of(proc)
            copy_ms = run.transfers.get(task, 0.0)
            modelled = _copy_ms(calibration.transfer, pe, run.copied.get(task, 0))
            busy = []
            for kind in ("cpu", "gpu"):
                near = [(t, b0, b1) for t, (p, b0, b1) in hosts.items() if p != proc and pe_of(p) == kind]
                busy.append(shares.sensitivity(task, pe) * busy_overlap(
                    (s, f), [(b0, b1) for _, b0, b1 in near], [shares.pressure(t, kind) for t, _, _ in near]))
            if copy_ms > 0 and modelled > 0:
                copies[pe].append((copy_ms, modelled, *busy))
            elif modelled > 0:
                # Copies made but not timed apart (a captured segment's uploads, small ones
                # on CUDA) are inside the interval: take out what the simulation adds back,
                # else the node's correction counts them a second time.
                copy_ms = min(modelled, UNTIMED_COPY_SHARE * (f - s))
            # A replayed task's share is the segment model's (fit_segments), not a call's.
            if alone[task][pe] is not None and not (pe == "gpu" and task in replayed):
                samples[pe].append((task, alone[task][pe], f - s - copy_ms, *busy))
            cls, ready = _ready_parts(run, task, reads, placement, hosts, segment)
            waits[cls].append(max(0.0, s - ready))
    probes = {"cpu": [], "gpu": []}
    # Loader mix -> its nodes: a kind's mix, or the heavy CPU nodes' looping each other.
    mixes = {"heavy" if loader == "heavy" else victim: mix.split(",")
             for (victim, loader), (mix, *_rest) in (probe or {}).items()}
    for (pe, loader), (mix, alone_ms, loaded, cpus, gpus) in (probe or {}).items():
        # The victim mix's sensitivity times the loader mix's pressure (time-weighted).
        w = _mix_share(shares.sensitivity, alone, mix.split(","), pe) * \
            _mix_share(shares.pressure, alone, mixes.get(loader, ()),
                       "cpu" if loader == "heavy" else loader)
        probes[pe].append((alone_ms, loaded, cpus * w, gpus * w))
    slow = {pe: fit_slowdown(s, probes[pe], prior_ratio=_probe_ratio(probe, alone, pe))
            for pe, s in samples.items()}
    d = calibration.dispatch or {}
    fallback = {"start": d.get("start", 0.0), "cpu_same": d.get("cpu_gap", 0.0),
                "gpu_same": d.get("gpu_gap", 0.0), "cpu_from_cpu": d.get("cpu_gap", 0.0),
                "cpu_from_gpu": d.get("handoff", 0.0), "gpu_from_cpu": d.get("handoff", 0.0)}
    latency = {k: statistics.median(v) if v else fallback[k] for k, v in waits.items()}
    # Copies slow down with busy neighbours like the rest of the task (the simulation
    # applies the same speed to the whole task), so their extra is taken without that.
    copy_extra = {pe: statistics.median(t / slow[pe].speed_divisor(c, g) - m for t, m, c, g in v)
                  for pe, v in copies.items() if v}
    serial = frozenset(serial)
    ratio, fixed, lanes = fit_segments(segment_samples(runs, reads, replayed, placement, alone,
                                                       calibration.transfer, cuda, slow["gpu"],
                                                       serial))
    return ContentionModel(slow, latency, alone, reads, calibration.transfer, cuda,
                           f"{policy} ({len(runs)} frames)" if policy else f"{len(runs)} frames",
                           copy_extra, shares.gil, capturable, ratio, fixed, lanes, serial)


def _probe_ratio(probe, alone, pe) -> float:
    """The contention probe's ``pe`` mix timed alone (its calls in turn, as a frame makes
    them) over the sum of its nodes' calibrated times: the in-frame ratio of a kind of call
    the training frames never made (an eager GPU call beside an all-replayed baseline; the
    H100's in-frame eager calls ran 2x their calibrated host time, s6/s6b), measured near
    the training frames where the calibration may be older. 1 without a probe."""
    for (victim, _), (mix, alone_ms, *_rest) in (probe or {}).items():
        total = sum(alone[n][pe] or 0.0 for n in mix.split(",") if n in alone)
        if victim == pe and total > 0:
            return alone_ms / total
    return 1.0


def _mix_share(share, alone, names, pe) -> float:
    """A mix's share: its nodes' ``share(node, pe)`` weighted by their alone times (1 for
    an unknown mix)."""
    w = [(alone[n][pe] or 0.0, share(n, pe)) for n in names if n in alone]
    total = sum(t for t, _ in w)
    return sum(t * x for t, x in w) / total if total > 0 else 1.0


def _copy_ms(transfer, pe, n):
    if not n:
        return 0.0
    return transfer.upload(n) if pe == "gpu" else transfer.download(n)


# --------------------------------------------------------------------------- simulation


def simulate(model: ContentionModel, schedule: Schedule, eager=()) -> Schedule:
    """Play ``schedule``'s per-processor orders through ``model``: the predicted timeline.

    ``eager``: capturable tasks the executor runs eagerly all the same (its segment's
    capture failed: :func:`eager_nodes`), played as eager calls.

    Each processor takes its tasks in the executor's order (by scheduled start). A task
    starts when its processor is free and its inputs are ready, plus the measured latency of
    what it waited for last (:data:`LATENCIES`); it then does its work (alone cost plus
    copies, times ``ratio * e``) at speed ``1 / (1 + a * c(t))``, ``c(t)`` the other host
    threads busy at ``t``, re-evaluated whenever a task starts or ends. On CUDA a GPU task's
    device interval follows its host call: from ``max(device free, call start)`` for its
    device time, ending no earlier than the call. Returned times are ms from the frame's
    submission; a GPU task's interval is its device interval, as the executor measures it.
    """
    placement = {t: s.processor for t, s in schedule.tasks.items()}
    order = sorted(schedule.tasks, key=lambda t: (schedule.tasks[t].start, schedule.tasks[t].finish))
    queues = {p: [t for t in order if placement[t] == p] for p in schedule.processors}
    queues = {p: q for p, q in queues.items() if q}
    capturable = model.capturable - frozenset(eager)
    copied = copied_bytes(model.reads, placement, order, capturable)
    # A GPU segment is one unit: CPU readers see its values when its last task ends.
    segs = [seg for p, q in queues.items() if pe_of(p) == "gpu"
            for seg in gpu_segments(model.reads, capturable, placement, q)]
    last_of = {t: seg[-1] for seg in segs for t in seg}
    # Tasks replayed in a captured segment: host and device busy for the replay's share.
    replayed = {} if model.segment_ratio is None else \
        {t: t == seg[0] for seg in segs if seg[0] in capturable for t in seg}
    scale = segment_scale(model.reads, [seg for seg in segs if seg[0] in replayed],
                          model.alone, model.cuda, model.segment_lanes, model.serial)
    seg_end = 0.0
    lat = model.latency
    pos = {p: 0 for p in queues}
    free_at = {p: 0.0 for p in queues}
    started_any = {p: False for p in queues}
    running = {}  # proc -> [task, remaining work, host start]
    host_done, avail_gpu, avail_cpu = {}, {}, {}  # task -> ms
    device_free = 0.0
    out = {}
    now = 0.0

    def ready_time(proc, task):
        side = pe_of(proc)
        t = free_at[proc] + (lat[f"{side}_same"] if started_any[proc] else lat["start"])
        for r in model.reads[task]:
            if r.delayed or r.producer is None:
                continue
            if placement[r.producer] == proc:
                if r.producer not in host_done:
                    return None
                continue
            p_side = pe_of(placement[r.producer])
            done = (avail_cpu if side == "cpu" else avail_gpu).get(r.producer)
            if done is None:
                return None
            t = max(t, done + lat[f"{side}_from_{p_side}"])
        return t

    while len(out) < len(schedule.tasks):
        # Start every task whose time has come.
        starts = []
        for p, q in queues.items():
            if p in running or pos[p] >= len(q):
                continue
            t = ready_time(p, q[pos[p]])
            if t is not None:
                starts.append((t, p))
        for t, p in starts:
            if t <= now + 1e-12:
                task = queues[p][pos[p]]
                pe = pe_of(p)
                work = (model.segment_work(task, replayed[task], scale[task])
                        + _copy_ms(model.transfer, pe, copied.get(task, 0))
                        if task in replayed else model.work(task, pe, copied.get(task, 0)))
                running[p] = [task, work, now]
        if not running:
            if not starts:
                raise GraphError("simulate: the schedule's orders deadlock")
            now = min(t for t, _ in starts)
            continue
        # Advance to the next start or end at the current speeds.
        press = {p: model.pressure(r[0], pe_of(p)) for p, r in running.items()}
        speed = {}
        for p, r in running.items():
            me = pe_of(p)
            busy = {k: sum(w for q, w in press.items() if q != p and pe_of(q) == k) for k in ("cpu", "gpu")}
            sens = model.sensitivity(r[0], me)
            speed[p] = 1.0 / model.slowdown[me].speed_divisor(sens * busy["cpu"], sens * busy["gpu"])
        dt_end = min(r[1] / speed[p] for p, r in running.items())
        pending = [t for t, p in starts if p not in running and t > now]
        dt = min([dt_end] + [t - now for t in pending])
        for p, r in running.items():
            r[1] -= dt * speed[p]
        now += dt
        for p in [p for p, r in running.items() if r[1] <= 1e-12]:
            task, _, h0 = running.pop(p)
            pos[p] += 1
            free_at[p] = now
            started_any[p] = True
            host_done[task] = now
            if pe_of(p) == "gpu" and model.cuda:
                d0 = max(device_free, h0)
                d1 = max(d0 + (0.0 if task in replayed else model.alone[task]["device"]), now)
                device_free = d1
                out[task] = ScheduledTask(task, p, d0, d1)
            else:
                d1 = now
                out[task] = ScheduledTask(task, p, h0, now)
            avail_gpu[task] = now
            if pe_of(p) != "gpu":
                avail_cpu[task] = now
            else:
                seg_end = max(seg_end, d1)
                if last_of.get(task, task) == task:
                    for t in queues[p][:pos[p]]:
                        if t not in avail_cpu:
                            avail_cpu[t] = seg_end
                    seg_end = 0.0
    return Schedule(out, list(schedule.processors), policy=f"{schedule.policy} (simulated)",
                    info={"model": model.trained_on})


# --------------------------------------------------------------------------- choosing


def in_frame_dag(model: ContentionModel, pes: dict, n_cpus: int):
    """The task DAG with the model's in-frame costs (no busy neighbour) for a scheduler.

    ``pes``: node -> the processing elements it may run on (``{"cpu", "gpu"}``, narrowed by
    pins). A GPU node costs the longer of its host call (its share of a segment's replay
    where it is capturable) and its device time; an edge costs a hand-off plus the
    transfer model's time for its bytes.
    """
    from ..sched import cpu_gpu_dag

    tasks = {}
    for node, allowed in pes.items():
        times = []
        for pe in ("cpu", "gpu"):
            if pe not in allowed or model.alone[node][pe] is None:
                times.append(None)
                continue
            # A capturable GPU node is replayed in a segment (its share, the segment's
            # fixed cost apart), not called eagerly.
            replayed = pe == "gpu" and model.segment_ratio is not None and node in model.capturable
            t = model.segment_work(node, False) if replayed else model.work(node, pe)
            times.append(max(t, model.alone[node]["device"]) if pe == "gpu" else t)
        tasks[node] = tuple(times)
    handoff = 0.5 * (model.latency["cpu_from_gpu"] + model.latency["gpu_from_cpu"])
    edges = {}
    for node, reads in model.reads.items():
        for r in reads:
            if r.producer is not None and not r.delayed:
                edges[(r.producer, node)] = handoff + model.transfer.time(r.nbytes)
    return cpu_gpu_dag(tasks, edges, n_cpus)


def pipeline_period(predicted: Schedule) -> float:
    """The least time between two frames of a pipelined stream of ``predicted`` (a
    :func:`simulate` timeline), ms: its busiest processor's work per frame (a GPU's: its
    device intervals). A lower bound: the host threads' own work between a frame's tasks is
    not in it, so streams measure slower (``schedule(..., objective="throughput")`` ranks by
    it and a trial measures)."""
    busy: dict = {}
    for st in predicted.tasks.values():
        busy[st.processor] = busy.get(st.processor, 0.0) + (st.finish - st.start)
    return max(busy.values(), default=0.0)


def choose(model: ContentionModel, dags: dict, policies=("baseline", "heft", "xeft"), *,
           objective: str = "latency") -> list:
    """Every candidate schedule of ``policies`` on each of ``dags``, fastest predicted first.

    Parameters
    ----------
    dags : dict
        label -> task DAG (same tasks and processors).
    objective : {"latency", "throughput"}
        Fastest by predicted makespan (one frame), or by :func:`pipeline_period` (a stream).

    Returns
    -------
    list of (name, Schedule, task DAG, predicted Schedule)
        ``name``: ``"<policy>"`` or ``"<policy> (<label>)"``; a schedule with the same
        placement and per-processor order as a faster one is left out (it would run the
        same). Each Schedule's ``info["candidates"]`` maps every candidate's name to its
        predicted makespan (ms; with ``objective="throughput"``, its predicted period).
    """
    from .. import sched

    cost = _OBJECTIVES[check_choice(objective, "objective", tuple(_OBJECTIVES))]
    found, seen, out = {}, set(), []
    for label, dag in dags.items():
        for policy in policies:
            sch = sched.schedule(dag, policy)
            pred = simulate(model, sch)
            name = f"{policy} ({label})" if label else policy
            found[name] = cost(pred)
            order = tuple(sorted(sch.tasks, key=lambda v: (sch.tasks[v].processor, sch.tasks[v].start)))
            key = (tuple(sch.tasks[v].processor for v in order), order)
            if key not in seen:
                seen.add(key)
                out.append((name, sch, dag, pred))
    out.sort(key=lambda c: found[c[0]])
    for _, sch, _, _ in out:
        sch.info = {**sch.info, "candidates": found}
    return out


#: What :func:`choose` ranks candidates by, per objective.
_OBJECTIVES = {"latency": lambda pred: pred.makespan, "throughput": pipeline_period}


__all__ = [
    "choose",
    "pipeline_period",
    "in_frame_dag",
    "ContentionModel",
    "LATENCIES",
    "Reads",
    "Slowdown",
    "alone_costs",
    "busy_overlap",
    "copied_bytes",
    "eager_nodes",
    "fit",
    "fit_slowdown",
    "gpu_segments",
    "graph_reads",
    "host_intervals",
    "pe_of",
    "simulate",
]
