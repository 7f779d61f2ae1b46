"""A Plan: a graph's schedule with its task DAG and metrics, the executor that runs it, and the
measured timelines of its last run, drawn as Gantt charts beside the prediction."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

from ..errors import GraphError
from ..sched.schedule import Schedule, ScheduledTask

#: Frames of the last run whose measured timelines a plan keeps.
KEEP_FRAMES = 64


@dataclass
class Plan:
    """What :meth:`Graph.schedule` returns and :meth:`Graph.process`/``stream`` run.

    Attributes
    ----------
    graph : Graph
        (held weakly: a plan does not keep its graph alive)
    schedule : Schedule
        Predicted placement and times (ms) of one frame.
    dag : networkx.DiGraph
        The task DAG the policy scheduled (:meth:`Graph.to_task_dag`).
    metrics : dict
        :func:`warpvx.sched.metrics` of the schedule.
    policy : str
    n_cpus : int
    gpu : str or None
        The GPU role's backend name (``"cuda:0"``, ``"warp-cpu"``) or None.
    calibration : Calibration
    costs : str
        ``"calibrated"`` or ``"history"``: which node costs the schedule used.
    prediction : Schedule or None
        The fitted contention model's simulation of one frame
        (:func:`warpvx.graph.model.simulate`), when the plan was made with a model; it is
        then the prediction (:attr:`predicted_makespan`, the Gantt chart's top row).
    frame_schedule : Schedule or None
        With K frames in flight (``Graph.schedule(..., frames=K)``, K > 1): the schedule of
        the task DAG unrolled over K frames (tasks ``(node, f)``; ``info`` holds its ``dag``,
        each frame's ``latency`` and the steady-state ``period``), which the executor runs,
        frame *i* as frame ``i mod K`` of it.
    last_run : collections.deque of FrameResult
        Measured timelines (ms from each frame's submission) of the last ``process`` or
        ``stream`` call, newest last, at most :data:`KEEP_FRAMES` (without their outputs,
        which went to the caller).
    """

    graph_ref: object
    schedule: Schedule
    dag: object
    metrics: dict
    policy: str
    n_cpus: int
    gpu: str | None
    calibration: object
    last_run: deque = field(default_factory=lambda: deque(maxlen=KEEP_FRAMES))
    _executor: object = None
    _serial: frozenset = frozenset()  # serial_tasks of executors closed so far
    costs: str = "calibrated"
    prediction: Schedule | None = None
    frame_schedule: Schedule | None = None

    @property
    def graph(self):
        return self.graph_ref()

    @property
    def predicted(self) -> Schedule:
        """The predicted timeline of one frame: the model's simulation, else the schedule."""
        return self.prediction if self.prediction is not None else self.schedule

    @property
    def predicted_makespan(self) -> float:
        """Predicted time of one frame (ms)."""
        return self.predicted.makespan

    def processor_label(self, processor: str) -> str:
        """How charts and summaries name ``processor``: the GPU role on Warp's CPU device is
        ``"gpu (warp-cpu)"``, as it is no GPU."""
        if processor == "gpu" and self.gpu == "warp-cpu":
            return "gpu (warp-cpu)"
        return processor

    def _label_rows(self, ax):
        ax.set_yticklabels([self.processor_label(t.get_text()) for t in ax.get_yticklabels()])

    @property
    def placement(self) -> dict:
        """node -> processor."""
        return {t: s.processor for t, s in self.schedule.tasks.items()}

    def executor(self):
        """The plan's :class:`~warpvx.runtime.Executor` (created on first use)."""
        if self._executor is None:
            from ..runtime import Executor
            from .run import gpu_device, program

            graph = self.graph
            self._executor = Executor(self.frame_schedule or self.schedule, program(graph, self.gpu),
                                      gpu_device=gpu_device(self.gpu), name=graph.name)
        return self._executor

    def abort(self):
        """Cancel the frames in flight, if the executor has started (the plan stays usable)."""
        if self._executor is not None:
            self._executor.abort()

    @property
    def serial_tasks(self) -> frozenset:
        """The GPU tasks whose captured segments join their lanes before them (see
        :attr:`~warpvx.runtime.segment_runner.SegmentRunner.serial_tasks`), as the plan's
        executors found them, this one and the closed ones (a run after a close starts a fresh
        executor, which knows none before its captures)."""
        ex = self._executor
        return self._serial | (ex.serial_tasks if ex is not None else frozenset())

    def close(self):
        """Stop the executor's threads (a later run starts a fresh executor)."""
        if self._executor is not None:
            self._serial = self.serial_tasks
            self._executor.close()
            self._executor = None

    # ------------------------------------------------------------------ measurements

    def measured_makespans(self) -> list:
        """Measured makespan (ms) of each frame of the last run."""
        return [r.makespan for r in self.last_run]

    def measured(self, frames: int = 1) -> Schedule:
        """The last run's measured timeline as a Schedule (ms).

        ``frames=1``: the newest frame, with the graph's node names. ``frames=k``: the newest
        ``k`` frames on one time axis starting at the first of their tasks, tasks named
        ``"<node>#<frame>"`` — pipelined runs show frames overlapping.
        """
        if not self.last_run:
            raise GraphError("plan: nothing measured yet; run g.process() or g.stream() first")
        runs = list(self.last_run)[-max(1, frames):]
        if len(runs) == 1:
            r = runs[0]
            return Schedule(dict(r.timeline), list(self.schedule.processors),
                            policy=f"{self.policy} (measured)")
        # One time axis, from the first task shown (frames queue before they start).
        base = min(r.t0 + t.start / 1e3 for r in runs for t in r.timeline.values())
        tasks = {}
        for r in runs:
            shift = (r.t0 - base) * 1e3
            for name, t in r.timeline.items():
                key = f"{name}#{r.index}"
                tasks[key] = ScheduledTask(key, t.processor, t.start + shift, t.finish + shift)
        return Schedule(tasks, list(self.schedule.processors),
                        policy=f"{self.policy} (measured, {len(runs)} frames)")

    def gantt(self, path=None, *, frames: int = 1, title: str | None = None):
        """Predicted (top) and measured (bottom) Gantt charts in one figure, time in ms.

        The title gives the prediction's error against the measured makespan (the median
        of the last run's frames); bars too narrow for their name are numbered and listed
        under each row's axis; the GPU row reads ``gpu (warp-cpu)`` when the GPU role is
        Warp's CPU device.

        Parameters
        ----------
        path : str or Path, optional
            Write the figure there (PNG, SVG, ... by suffix).
        frames : int
            Measured frames to draw (see :meth:`measured`).

        Returns
        -------
        matplotlib.figure.Figure
        """
        import statistics

        import matplotlib

        if path is not None:
            matplotlib.use("Agg", force=False)
        import matplotlib.pyplot as plt

        from ..sched.gantt import plot_gantt

        fig, (ax0, ax1) = plt.subplots(2, 1, figsize=(12, 7.5), constrained_layout=True)
        name = title or self.graph.name
        predicted = self.predicted
        source = "contention model" if self.prediction is not None else f"{self.costs} costs"
        chosen = self.schedule.info.get("chosen")
        what = f"{self.policy}" + (f" -> {chosen}" if chosen and chosen != self.policy else "")
        error = ""
        meas = self.measured_makespans()
        if meas:
            m = statistics.median(meas)
            error = (f"; measured {m:.3f} ms (median of {len(meas)}), prediction error "
                     f"{100 * (predicted.makespan - m) / m:+.1f}%")
        fig.suptitle(f"{name}: {what}, predicted {predicted.makespan:.3f} ms{error}", fontsize=10)
        plot_gantt(predicted, ax=ax0, dag=self.dag, unit="ms",
                   title=f"predicted ({source}), makespan {predicted.makespan:.3f} ms")
        if self.last_run:
            measured = self.measured(frames)
            if frames > 1:
                shown = min(frames, len(self.last_run))
                title_m = (f"measured, {shown} pipelined frames; "
                           f"{shown / measured.makespan * 1e3:.1f} frames/s over this window")
            else:
                title_m = f"measured (newest frame), makespan {self.last_run[-1].makespan:.3f} ms"
            plot_gantt(measured, ax=ax1, dag=self._frames_dag(measured), title=title_m, unit="ms")
            if frames == 1:  # one frame each: one time scale for both
                hi = max(predicted.makespan, measured.makespan) * 1.02
                ax0.set_xlim(0, hi)
                ax1.set_xlim(0, hi)
            self._label_rows(ax1)
        else:
            ax1.set_axis_off()
            ax1.set_title("measured: not run yet")
        self._label_rows(ax0)
        if path is not None:
            fig.savefig(path, dpi=110)
            plt.close(fig)
        return fig

    def _frames_dag(self, measured: Schedule):
        """The task DAG relabelled for a multi-frame measured schedule (for bar colours)."""
        import networkx as nx

        names = set(measured.tasks)
        if names <= set(self.dag.nodes):
            return self.dag
        frames = sorted({t.rsplit("#", 1)[1] for t in names})
        parts = [nx.relabel_nodes(self.dag, {v: f"{v}#{f}" for v in self.dag.nodes}) for f in frames]
        dag = nx.compose_all(parts)
        dag.graph.update(self.dag.graph)
        return dag.subgraph(names).copy() if names <= set(dag.nodes) else None

    def summary(self) -> dict:
        """Predicted and measured makespans (ms), placement and metrics, JSON-friendly;
        ``processors`` labels each processor as charts do (:meth:`processor_label`)."""
        import statistics

        meas = self.measured_makespans()
        return {
            "policy": self.policy,
            "chosen": self.schedule.info.get("chosen", self.policy),
            "n_cpus": self.n_cpus,
            "gpu": self.gpu,
            "processors": [self.processor_label(p) for p in self.schedule.processors],
            "predicted_makespan_ms": self.predicted_makespan,
            "measured_makespan_ms": statistics.median(meas) if meas else None,
            "placement": self.placement,
            "metrics": {k: v for k, v in self.metrics.items() if k != "idle_per_processor"},
        }

    def __repr__(self):
        return (f"Plan({self.graph.name!r}, policy={self.policy!r}, n_cpus={self.n_cpus}, "
                f"gpu={self.gpu!r}, makespan={self.predicted_makespan:.3f} ms)")


__all__ = ["Plan", "KEEP_FRAMES"]
