"""The graph's cost model: calibration, the task DAG the schedulers read, scheduling into a
:class:`~warpvx.graph.plan.Plan`, and learning costs back from running frames.

:class:`CostModel` is a part of :class:`~warpvx.graph.Graph` (a mixin: it uses the graph's
nodes, verification and run lock); see :mod:`warpvx.graph.calibration` for the measurements.
"""

from __future__ import annotations

import os
import warnings
import weakref

from ..check import check_choice, check_float, check_int
from ..errors import GraphError
from .data import INPUT, Data, nbytes


def default_n_cpus() -> int:
    """CPU workers by default: the cores minus one for the GPU host thread, 1 to 4."""
    return max(1, min(4, (os.cpu_count() or 2) - 1))


#: ``schedule("best", model=..., trial_inputs=...)`` tries every candidate predicted
#: within this fraction of the fastest: the contention model's out-of-sample error (about
#: 20%, ``benchmarks/graph_bench.py``) is larger than most gaps between candidates.
TRIAL_MARGIN = 0.2

#: ``schedule("best", ..., trial_inputs=...)`` also tries the runner-up (the second-fastest
#: distinct candidate) when it is predicted within this fraction of the fastest: the
#: model's worst out-of-sample errors on mixed placements replayed from the H100 runs were
#: 27-43% (benchmarks/results/graph/model-replay-2026-11-24-s4.md), and at 1920x1080 the
#: all-GPU baseline, predicted 23% slower than HEFT, measured 17% faster and went untried.
TRIAL_RUNNER_UP_MARGIN = 0.5

#: Frames run and discarded each time a trial or :meth:`CostModel.measure_plans` switches
#: to a plan: its threads wake, and captured segments record on a signature's second frame.
SWITCH_WARMUP = 2

#: Rounds of a trial by default: each candidate runs once per round, the order reversed
#: every other round (ABBA), so a drift of the machine over the trial (measured on the H100:
#: the same placement 30-40% apart minutes later) falls on every candidate alike.
TRIAL_ROUNDS = 4

#: Frames in flight in a throughput trial (``schedule(..., objective="throughput")``).
TRIAL_DEPTH = 3


class NoCudaWarning(UserWarning):
    """The GPU role fell back to Warp's CPU device (no CUDA): "gpu" nodes run on the CPU."""


_warned_no_cuda = False


def warn_no_cuda(graph_name: str, on_gpu: list):
    """Warn once per process that nodes ``on_gpu`` placed on the GPU role run on Warp's CPU
    device because this machine has no CUDA (the user asked for no GPU role explicitly)."""
    global _warned_no_cuda
    if _warned_no_cuda:
        return
    _warned_no_cuda = True
    warnings.warn(f"graph {graph_name!r}: no CUDA device, so the GPU role runs on Warp's CPU "
                  f"device: node(s) {sorted(on_gpu)} placed on 'gpu' run on the CPU (charts "
                  f"label it 'gpu (warp-cpu)'). Pass gpu='warp-cpu' to choose this (no warning) "
                  f"or gpu=False for CPU workers only.", NoCudaWarning, stacklevel=3)


def gpu_backend(gpu):
    """``"cuda"``, ``"cuda:N"``, ``"warp-cpu"``, None (CUDA if present, else warp-cpu) or
    False (no GPU role) -> :class:`~warpvx.backend.Backend` or None."""
    from ..backend import cuda_available, resolve_backend

    if gpu is False:
        return None
    if gpu is None:
        gpu = "cuda" if cuda_available() else "warp-cpu"
    be = resolve_backend(gpu)
    if be.kind != "warp":
        raise GraphError(f"gpu: expected 'cuda', 'cuda:N', 'warp-cpu', None or False, got {gpu!r}")
    return be


class CostModel:
    """Calibrate, model, schedule and learn: the cost half of :class:`~warpvx.graph.Graph`."""

    def calibrate(self, inputs: dict | None = None, *, gpu=None, recalibrate: bool = False,
                  warmup: int = 2, repeats: int = 5):
        """Measure node and transfer costs on this machine (cached; see
        :mod:`warpvx.graph.calibration`). ``inputs`` re-verifies on real data first."""
        from .calibration import calibrate as _calibrate

        be = gpu_backend(gpu)
        with self._run_lock:
            if inputs is not None or not self.verified:
                self.verify(inputs)
            cal = _calibrate(self, be, recalibrate=recalibrate, warmup=warmup, repeats=repeats)
            self._calibrations[cal.gpu] = cal
        return cal

    def to_task_dag(self, n_cpus: int | None = None, *, gpu=None, calibration=None,
                    costs: str = "calibrated"):
        """The scheduler's task DAG of one frame (times in ms).

        Node costs come from calibration (run now if needed), narrowed by pins, plus the
        executor's dispatch cost per task on that kind of processor; each edge's ``comm`` is
        the transfer model's time for the bytes of its data plus the executor's hand-off
        between a CPU worker and the GPU thread (the scheduler charges ``comm`` only between
        them). A GPU node reading a graph input also pays that input's upload (frames arrive
        in host memory).

        ``costs="history"`` uses what running frames measured (:meth:`learn`) where known:
        those intervals already hold the executor's work inside a task, so only its cost
        between tasks is added. The executor makes a task's copies on the task's own
        processor (the GPU thread uploads, a CPU worker downloads), so history costs charge
        copies to the consumer, not to the edge: a node's measured copies where it ran, or,
        elsewhere, the transfer model's time for the inputs whose producers ran on the
        other side, scaled by what copies took in running frames
        (``calibration.transfer_scale``); an edge keeps only the hand-off.
        """
        from ..sched import cpu_gpu_dag

        if costs not in ("calibrated", "history"):
            raise GraphError(f"costs: expected 'calibrated' or 'history', got {costs!r}")
        n_cpus = default_n_cpus() if n_cpus is None else n_cpus
        be = gpu_backend(gpu)
        cal = calibration or self._calibrations.get(be.name if be else None)
        if cal is None or not self.verified:
            cal = self.calibrate(gpu=be.name if be else False)
        d = cal.dispatch or {}
        history = costs == "history"
        scale = cal.transfer_scale if history else 1.0
        tasks, edges = {}, {}
        for node in self.nodes.values():
            pes = node.processing_elements
            known = cal.history.get(node.name, {}) if history else {}

            def copies(pe):
                """Copies ``node`` makes on ``pe`` (graph inputs on the GPU; in history mode
                also inputs whose producers last ran on the other side)."""
                ms = 0.0
                for ref in node.inputs.values():
                    if not isinstance(ref, Data):
                        continue
                    if ref.kind == INPUT:
                        if pe == "gpu":
                            ms += scale * cal.transfer.upload(nbytes(ref.sample))
                    elif history and ref.producer is not None:
                        where = cal.placement.get(ref.producer.name)
                        if where is not None and where != pe:
                            n = nbytes(ref.sample)
                            ms += scale * (cal.transfer.upload(n) if pe == "gpu" else cal.transfer.download(n))
                return ms

            def cost(pe):
                if pe not in pes or (pe == "gpu" and be is None):
                    return None
                if pe in known:
                    return known[pe] + known.get(f"{pe}_copies", 0.0) + d.get(f"{pe}_gap", 0.0)
                return cal.nodes[node.name][pe] + d.get(f"{pe}_node", 0.0) + copies(pe)

            cpu_t, gpu_t = cost("cpu"), cost("gpu")
            if cpu_t is None and gpu_t is None:
                raise GraphError(f"node {node.name!r} ({node.kind}), port 'target': no processing "
                                 f"element of this plan can run it (pinned to {node.target!r}, "
                                 f"gpu={be.name if be else None})")
            tasks[node.name] = (cpu_t, gpu_t)
            for ref in node.inputs.values():
                if isinstance(ref, Data) and ref.producer is not None:
                    key = (ref.producer.name, node.name)
                    if key not in edges:
                        edges[key] = d.get("handoff", 0.0)
                    if not history:
                        edges[key] += cal.transfer.time(nbytes(ref.sample))
        return cpu_gpu_dag(tasks, edges, n_cpus)

    def schedule(self, policy="best", *, n_cpus: int | None = None, gpu=None,
                 recalibrate: bool = False, costs: str = "calibrated", model=None,
                 trial_inputs=None, trial_frames: int = 5, trial_margin: float = TRIAL_MARGIN,
                 trial_runner_up: float = TRIAL_RUNNER_UP_MARGIN,
                 trial_rounds: int = TRIAL_ROUNDS, trial_seconds: float | None = None,
                 objective: str = "latency", trial_depth: int = TRIAL_DEPTH):
        """Calibrate (cached), schedule with ``policy`` and make the result the current plan.

        Parameters
        ----------
        policy : str or callable
            ``"baseline"``, ``"heft"``, ``"xeft"``, ``"best"`` or ``policy(dag) -> Schedule``.
        n_cpus : int, optional
            CPU workers (default :func:`default_n_cpus`).
        gpu : str, None or False
            The GPU role: ``"cuda"``/``"cuda:N"``, ``"warp-cpu"`` (Warp's CPU device, for
            tests), None (CUDA if present, else warp-cpu: then, once per process, a
            :class:`NoCudaWarning` if nodes are placed on it) or False (CPU workers only).
        costs : str
            ``"calibrated"`` (nodes timed alone) or ``"history"`` (what running frames
            measured, after :meth:`learn`; calibrated costs where none was measured).
        model : ContentionModel, optional
            A fitted model (:meth:`fit_model`): the plan's prediction becomes its simulation
            of the schedule (``plan.prediction``), and ``"best"`` keeps, of the baseline,
            HEFT and XEFT schedules of the task DAG and of the model's in-frame costs
            (:func:`~warpvx.graph.model.choose`), the one the model predicts fastest, so a
            mixed placement that loses to the all-GPU one in reality loses in the prediction
            too; with ``trial_inputs``, the measured fastest of those it cannot tell apart.
        trial_inputs : dict or list of dict, optional
            With ``policy="best"`` and a ``model``: frames to try the candidates on. Every
            distinct candidate predicted within ``trial_margin`` (a fraction) of the fastest
            prediction -- closer than the model can tell apart -- is measured by
            :meth:`measure_plans`: ``trial_rounds`` interleaved rounds (ABBA), each running
            every candidate for :data:`SWITCH_WARMUP` discarded frames and ``trial_frames``
            measured ones through :meth:`process` (frames cycle through ``trial_inputs``);
            the one with the least median measured makespan over all its rounds is kept:
            the measured winner, not the predicted one. ``plan.schedule.info["trial_ms"]``
            gives each tried candidate's median (ms), ``info["trial_frames"]`` how many
            frames each measured. These are real frames: outputs are published and delays
            advance. With one candidate in the margin nothing runs.
        trial_runner_up : float
            The second-fastest distinct candidate is tried too when predicted within this
            fraction of the fastest (default :data:`TRIAL_RUNNER_UP_MARGIN`, the model's
            worst out-of-sample error seen; 0: only ``trial_margin``), so a winner the model
            misranks by less than its known error is measured, not assumed.
        trial_rounds : int
            Rounds of the trial (>= 1).
        trial_seconds : float, optional
            Time budget of the trial (s): no round starts after it is spent (the first
            always runs).
        objective : {"latency", "throughput"}
            What ``"best"`` with a ``model`` optimises: one frame's makespan (``process``, the default), or
            the frame rate of a pipelined ``stream`` (a placement that finishes one frame
            first may stream slower: its CPU workers' and GPU thread's work per frame, not
            its critical path, bounds a stream). With ``"throughput"`` candidates are ranked
            by the model's :func:`~warpvx.graph.model.pipeline_period` (a lower bound) and a
            trial streams each for ``trial_frames`` frames (``trial_depth`` in flight) per
            round, after :data:`SWITCH_WARMUP` discarded ones, keeping the highest median
            frame rate (``info["trial_fps"]``).
        trial_depth : int
            Frames in flight in a throughput trial (>= 1).

        Returns
        -------
        Plan
        """
        from .. import sched
        from .plan import Plan

        n_cpus = default_n_cpus() if n_cpus is None else n_cpus
        if trial_inputs is not None:  # checked before anything is calibrated
            if model is None or policy != "best":
                raise GraphError("trial_inputs: a trial needs policy='best' and a model= "
                                 "(g.fit_model()) to choose its candidates")
            trial_inputs = [trial_inputs] if isinstance(trial_inputs, dict) else list(trial_inputs)
            if not trial_inputs:
                raise GraphError("trial_inputs: expected a dict of inputs or a non-empty list of them")
            if isinstance(trial_frames, bool) or not isinstance(trial_frames, int) or trial_frames < 1:
                raise GraphError(f"trial_frames: expected an int >= 1, got {trial_frames!r}")
        trial_margin = check_float(trial_margin, "trial_margin", min_value=0.0)
        trial_runner_up = check_float(trial_runner_up, "trial_runner_up", min_value=0.0)
        trial_rounds = check_int(trial_rounds, "trial_rounds", min_value=1)
        if trial_seconds is not None:
            trial_seconds = check_float(trial_seconds, "trial_seconds", min_value=0.0)
        objective = check_choice(objective, "objective", ("latency", "throughput"))
        trial_depth = check_int(trial_depth, "trial_depth", min_value=1)
        if objective != "latency" and (model is None or policy != "best"):
            raise GraphError("objective: a throughput objective needs policy='best' and a "
                             "model= (g.fit_model()) to rank its candidates by")
        be = gpu_backend(gpu)
        with self._run_lock:
            if not self.verified:
                self.verify()
            cal = self._calibrations.get(be.name if be else None)
            if cal is None or recalibrate:
                cal = self.calibrate(gpu=be.name if be else False, recalibrate=recalibrate)
            dag = self.to_task_dag(n_cpus, gpu=be.name if be else False, calibration=cal,
                                   costs=costs)
            name = policy if isinstance(policy, str) else getattr(policy, "__name__", "custom")

            def make_plan(sch, dag, prediction):
                sched.validate_schedule(dag, sch)
                if model is not None and prediction is None:
                    prediction = model.predict(sch)
                plan = Plan(weakref.ref(self), sch, dag, sched.metrics(dag, sch), name, n_cpus,
                            be.name if be else None, cal, costs=costs, prediction=prediction)
                self.use_plan(plan, close_previous=True)
                return plan

            if model is not None and policy == "best":
                from .model import choose

                cands = choose(model, self._candidate_dags(dag, model, n_cpus),
                               objective=objective)
                predicted = cands[0][1].info["candidates"]  # name -> ms (objective's)
                fastest = predicted[cands[0][0]]
                top = [c for i, c in enumerate(cands)
                       if predicted[c[0]] <= fastest * (1 + (max(trial_margin, trial_runner_up)
                                                             if i == 1 else trial_margin))]
                chosen, trial, plan = cands[0], None, None
                if trial_inputs is not None and len(top) > 1:
                    chosen, trial, plan = self._trial(
                        top, trial_inputs, make_plan, frames=trial_frames, rounds=trial_rounds,
                        seconds=trial_seconds,
                        depth=trial_depth if objective == "throughput" else None)
                label, sch, dag, prediction = chosen
                sch.info = {**sch.info, "chosen": label, "objective": objective}
                if trial is not None:
                    what = "trial_fps" if objective == "throughput" else "trial_ms"
                    sch.info[what] = {k: v[0] for k, v in trial.items()}
                    sch.info["trial_frames"] = {k: v[1] for k, v in trial.items()}
                sch.policy = "best"
                plan = plan or make_plan(sch, dag, prediction)
            else:
                plan = make_plan(sched.schedule(dag, policy), dag, None)
        if gpu is None and be is not None and be.device == "cpu":
            on_gpu = [n for n, p in plan.placement.items() if p == "gpu"]
            if on_gpu:
                warn_no_cuda(self.name, on_gpu)
        return plan

    def _trial(self, candidates, inputs, make_plan, *, frames, rounds, seconds,
               depth=None) -> tuple:
        """Measure each candidate (``(name, Schedule, dag, prediction)``) with
        :meth:`measure_plans` (or, with ``depth``, :meth:`measure_streams`); (the fastest by
        median measured makespan, or highest median frame rate, name -> (that median in ms,
        or FPS, frames measured), its plan, now the current one)."""
        import statistics

        plans = [make_plan(sch, dag, prediction) for _, sch, dag, prediction in candidates]
        try:
            if depth is None:
                runs = self.measure_plans(plans, inputs, rounds=rounds, frames=frames,
                                          seconds=seconds)
                measured = {c[0]: (statistics.median(r.makespan for r in got), len(got))
                            for c, got in zip(candidates, runs)}
            else:
                runs = self.measure_streams(plans, inputs, rounds=rounds, frames=frames,
                                            depth=depth, seconds=seconds)
                measured = {c[0]: (statistics.median(got), frames * len(got))
                            for c, got in zip(candidates, runs)}
        except BaseException:
            for plan in plans:
                plan.close()
            raise
        sign = 1 if depth is None else -1  # least ms, or most frames per second
        i = min(range(len(candidates)), key=lambda k: sign * measured[candidates[k][0]][0])
        for k, plan in enumerate(plans):  # idle executors' threads: only the kept one stays
            if k != i:
                plan.close()
        self.use_plan(plans[i])
        return candidates[i], measured, plans[i]

    def use_plan(self, plan, *, close_previous: bool = False):
        """Make ``plan`` (one of this graph's, e.g. from an earlier :meth:`schedule`) the
        current plan, which :meth:`process` and :meth:`stream` run. The previous plan's
        executor keeps its threads (switching back is cheap) unless ``close_previous``;
        a plan left idle is closed with :meth:`~warpvx.graph.plan.Plan.close`."""
        if getattr(plan, "graph", None) is not self:
            raise GraphError(f"plan: expected a Plan of graph {self.name!r}, got {plan!r}")
        with self._run_lock:
            if close_previous and self._plan is not None and self._plan is not plan:
                self._plan.close()
            self._plan = plan
            self._plan_box[0] = plan

    def measure_plans(self, plans, inputs, *, rounds: int = TRIAL_ROUNDS, frames: int = 5,
                      warmup: int = SWITCH_WARMUP, seconds: float | None = None) -> list:
        """Run ``plans`` (this graph's) in interleaved rounds, one frame at a time, so that a
        drift of the machine falls on each alike: per plan, the FrameResults of its
        measured frames.

        Each round makes each plan current (:meth:`use_plan`; executors stay warm) and runs
        ``warmup`` frames, discarded (the first frames after a switch wake its threads and
        record captures), then ``frames`` measured ones; every other round takes the plans
        in reverse order (A B B A: a linear drift cancels, and no plan always runs first).
        No round starts once ``seconds`` (a budget, s) have passed; the first always runs.
        Inputs cycle through ``inputs`` (a dict or a list of dicts); frames are real:
        outputs are published and delays advance. The last plan run stays current.
        """
        out = [[] for _ in plans]
        for i, feed in self._rounds(plans, inputs, rounds, frames, warmup, seconds):
            for j, frame in enumerate(feed):
                self.process(frame)
                if j >= warmup:
                    out[i].append(plans[i].last_run[-1])
        return out

    def measure_streams(self, plans, inputs, *, rounds: int = TRIAL_ROUNDS, frames: int = 20,
                        depth: int = TRIAL_DEPTH, warmup: int = SWITCH_WARMUP,
                        seconds: float | None = None) -> list:
        """Stream ``plans`` (this graph's) in interleaved rounds, as :meth:`measure_plans`
        runs them one frame at a time: per plan, the frame rate (frames per second of wall
        time) of each round's ``frames`` frames streamed ``depth`` in flight, after
        ``warmup`` discarded ones."""
        import time

        depth = check_int(depth, "depth", min_value=1)
        out = [[] for _ in plans]
        for i, feed in self._rounds(plans, inputs, rounds, frames, warmup, seconds):
            stream = self.stream(feed, depth=depth)
            for _ in range(warmup):
                next(stream)
            start = time.perf_counter()
            done = sum(1 for _ in stream)
            out[i].append(done / max(time.perf_counter() - start, 1e-9))
        return out

    def _rounds(self, plans, inputs, rounds, frames, warmup, seconds):
        """:meth:`measure_plans`' rounds: ``(i, the inputs of plan i's warmup + frames
        frames)`` with plan i made current, in A B B A order, until ``rounds`` or
        ``seconds``; inputs cycle through ``inputs``."""
        import time

        inputs = [inputs] if isinstance(inputs, dict) else list(inputs)
        if not inputs:
            raise GraphError("inputs: expected a dict of inputs or a non-empty list of them")
        rounds = check_int(rounds, "rounds", min_value=1)
        n = check_int(frames, "frames", min_value=1) + check_int(warmup, "warmup", min_value=0)
        t0, k = time.perf_counter(), 0
        for r in range(rounds):
            if r and seconds is not None and time.perf_counter() - t0 > seconds:
                break
            for i in range(len(plans)) if r % 2 == 0 else range(len(plans) - 1, -1, -1):
                self.use_plan(plans[i])
                yield i, [inputs[(k + j) % len(inputs)] for j in range(n)]
                k += n

    def _candidate_dags(self, dag, model, n_cpus) -> dict:
        """name -> task DAG: the schedule's own and one with the model's in-frame costs."""
        from .model import in_frame_dag

        pes = {n: node.processing_elements for n, node in self.nodes.items()}
        return {"": dag, "model costs": in_frame_dag(model, pes, n_cpus)}

    def measure_probes(self, plan=None, *, gil: bool = False):
        """Measure what :meth:`fit_model` needs beside the frames, once per calibration (kept
        there): the contention probe for ``plan``'s CPU workers
        (:func:`~warpvx.graph.calibration.measure_contention`) and, with ``gil``, each
        node's GIL shares (:func:`~warpvx.graph.calibration.measure_gil`). They load every
        core for seconds: a benchmark runs them before its timed frames (default plan: the
        current one). Returns the plan's calibration."""
        from .calibration import measure_contention, measure_gil

        plan = plan or self._plan
        if plan is None:
            raise GraphError("measure_probes: no plan yet; call g.schedule() first")
        cal = plan.calibration
        be = gpu_backend(plan.gpu or False)
        with self._run_lock:
            if plan.n_cpus not in cal.contention:
                cal.contention[plan.n_cpus] = measure_contention(self, cal, be, plan.n_cpus)
            if gil and cal.gil is None:
                cal.gil = measure_gil(self, cal, be)
        return cal

    def fit_model(self, plan=None, *, runs=None, gil: bool = False):
        """A :class:`~warpvx.graph.model.ContentionModel` learnt from frames run with ``plan``
        (default: the current plan and its ``last_run``): host contention, copies and
        hand-offs, to predict this plan's later frames and other plans' (out of sample).
        The probes are measured on first use (:meth:`measure_probes`: the contention probe;
        with ``gil``, each node's GIL shares, and busy neighbours count by them: not yet the
        default, as on a loaded 2-core machine the shares are noise; see
        ``benchmarks/graph_bench.py``, which reports both). The segments' serial tasks (their
        lanes joined before each) are the plan's executors' (:attr:`Plan.serial_tasks`; none
        before a capture)."""
        from .model import fit, graph_reads

        plan = plan or self._plan
        runs = list(plan.last_run) if runs is None and plan is not None else runs
        if plan is None or not runs:
            raise GraphError("fit_model: nothing measured yet; run g.process() first")
        cal = self.measure_probes(plan, gil=gil)
        return fit(cal, graph_reads(self), runs, plan.placement, policy=plan.policy,
                   probe=cal.contention[plan.n_cpus], gil=cal.gil if gil else None,
                   capturable=self.capturable_nodes(plan.gpu),
                   serial=plan.serial_tasks)

    def capturable_nodes(self, gpu) -> frozenset:
        """Nodes the executor may run in captured GPU segments with GPU role ``gpu`` (a
        backend name): capturable with a preallocated output."""
        from .run import program

        return frozenset(t.name for t in program(self, gpu).tasks.values() if t.capture)

    def learn(self, plan=None, *, runs=None, skip: int = 1) -> dict:
        """Fold measured frames into the plan's calibration history (and the cache), for
        ``schedule(..., costs="history")``.

        ``runs``: the :class:`~warpvx.runtime.FrameResult` of frames run with ``plan``
        (default: the plan's ``last_run``; :meth:`process` keeps only its latest frame there,
        so collect them to learn from many). Each node's cost on the processing element it
        ran on becomes the median of its measured intervals without their transfers, over
        the frames after the first ``skip``. Returns node -> ``{pe: ms}`` learnt.
        """
        from .calibration import learn as _learn

        plan = plan or self._plan
        runs = list(plan.last_run) if runs is None and plan is not None else runs
        if plan is None or not runs:
            raise GraphError("learn: nothing measured yet; run g.process() or g.stream() first")
        return _learn(plan.calibration, runs, plan.placement, skip=skip)

    @property
    def plan(self):
        """The current :class:`Plan` (None until :meth:`schedule` or the first run)."""
        return self._plan


__all__ = ["CostModel", "NoCudaWarning", "SWITCH_WARMUP", "TRIAL_DEPTH", "TRIAL_MARGIN", "TRIAL_ROUNDS", "TRIAL_RUNNER_UP_MARGIN", "default_n_cpus", "gpu_backend", "warn_no_cuda"]
