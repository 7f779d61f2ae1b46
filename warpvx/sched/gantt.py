"""Gantt charts of schedules, in the style of thesis Fig. 5.2 (matplotlib, optional extra)."""

from __future__ import annotations

import os

import networkx as nx

from ..errors import WarpvxTypeError
from .dag import prepare
from .schedule import Schedule

# Fill per processor kind; exclusive tasks are hatched on top of it.
_KIND_COLORS = ("#8fb8de", "#9fd39a", "#f2c57c", "#d9a3d6", "#c9c9c9")
_XO_COLOR = "#f4a6a6"


def _pyplot():
    try:
        import matplotlib.pyplot as plt  # falls back to Agg where there is no display
    except ImportError as exc:  # the "plot" extra
        raise ImportError(
            "Gantt charts need matplotlib: pip install 'warpvx[plot]' (or pip install matplotlib)"
        ) from exc
    return plt


def _xo_intervals(schedule: Schedule, excl: dict) -> list:
    """Maximal time intervals where tasks exclusive to two different kinds run together."""
    events = []
    for v, t in schedule.tasks.items():
        k = excl.get(v, -1)
        if k >= 0 and t.finish > t.start:
            events.append((t.start, 1, k))
            events.append((t.finish, -1, k))
    events.sort(key=lambda e: (e[0], e[1]))
    counts = {}
    out = []
    opened = None
    for i, (time, d, k) in enumerate(events):
        counts[k] = counts.get(k, 0) + d
        if i + 1 < len(events) and events[i + 1][0] == time:
            continue  # apply every event at this instant before judging
        active = sum(1 for c in counts.values() if c > 0) >= 2
        if active and opened is None:
            opened = time
        elif not active and opened is not None:
            if time > opened:
                out.append((opened, time))
            opened = None
    return out


def plot_gantt(schedule: Schedule, ax=None, dag: nx.DiGraph | None = None, title=None,
               unit: str | None = None):
    """Draw ``schedule`` as a Gantt chart on a matplotlib Axes.

    One row per processor (in ``schedule.processors`` order, top to bottom), one labelled bar
    per task from its start to its finish. With ``dag``: bars are coloured by the kind of the
    processor, tasks exclusive to one kind are hatched, and the intervals where tasks
    exclusive to different kinds overlap (the exclusive overlap XO, thesis eq. 3) are shaded
    in red behind the bars, as in thesis Fig. 5.2(c).

    Parameters
    ----------
    schedule : Schedule
    ax : matplotlib.axes.Axes, optional
        Drawn on a new figure when None.
    dag : networkx.DiGraph, optional
        The task DAG, for exclusive tasks and XO shading.
    title : str, optional
        Default: the policy name and the makespan.
    unit : str, optional
        Time unit for the axis label (``"ms"``). Bars too narrow for their name carry a
        number instead, and the axis label lists the numbers with the names.

    Returns
    -------
    matplotlib.axes.Axes

    Raises
    ------
    ImportError
        matplotlib is not installed (the ``plot`` extra).
    """
    if not isinstance(schedule, Schedule):
        raise WarpvxTypeError(f"schedule: expected a Schedule, got {type(schedule).__name__}")
    plt = _pyplot()
    from matplotlib.patches import Patch

    if ax is None:
        _, ax = plt.subplots(figsize=_figsize(schedule))
    procs = list(schedule.processors)
    row = {p: i for i, p in enumerate(procs)}
    excl, proc_kind, kinds = {}, {}, []
    if dag is not None:
        problem = prepare(dag)
        excl = {v: problem.excl[i] for i, v in enumerate(problem.names)}
        proc_kind = {p: problem.kind[k] for k, p in enumerate(problem.procs)}
        kinds = problem.kinds
    span = schedule.makespan
    narrow = []
    for s, f in _xo_intervals(schedule, excl):
        ax.axvspan(s, f, color=_XO_COLOR, alpha=0.35, lw=0, zorder=0)
    for v, t in schedule.tasks.items():
        y = row.get(t.processor)
        if y is None:
            continue
        color = _KIND_COLORS[proc_kind.get(t.processor, 0) % len(_KIND_COLORS)]
        hatched = excl.get(v, -1) >= 0
        ax.barh(
            y, t.finish - t.start, left=t.start, height=0.6, color=color, edgecolor="black",
            linewidth=0.6, hatch="///" if hatched else None, zorder=2,
        )
        if span > 0 and _fits(ax, str(v), t.finish - t.start, span):
            ax.text(
                (t.start + t.finish) / 2, y, str(v), ha="center", va="center", fontsize=7,
                zorder=3, clip_on=True,
                bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.8},
            )
        else:
            narrow.append((t, y))
    numbered = sorted(narrow, key=lambda ty: (ty[1], ty[0].start))
    _number_slivers(ax, numbered, span)
    ax.set_yticks(range(len(procs)))
    ax.set_yticklabels(procs)
    ax.set_ylim(len(procs) - 0.5, -0.85)  # room above the top row for sliver numbers
    ax.set_xlim(0, span * 1.02 if span > 0 else 1)
    label = f"time ({unit})" if unit else "time"
    if numbered:
        import textwrap

        key = ", ".join(f"{i} {t.task}" for i, (t, _) in enumerate(numbered, 1))
        label += "\n" + "\n".join(textwrap.wrap(key, 160))
    ax.set_xlabel(label, fontsize=8 if numbered else None)
    ax.grid(axis="x", alpha=0.3, zorder=1)
    ax.set_title(title if title is not None else f"{schedule.policy or 'schedule'}: makespan {span:.4g}")
    if dag is not None:
        handles = [
            Patch(facecolor=_KIND_COLORS[i % len(_KIND_COLORS)], edgecolor="black", label=name)
            for i, name in enumerate(kinds)
        ]
        handles.append(Patch(facecolor="white", edgecolor="black", hatch="///", label="exclusive task"))
        handles.append(Patch(facecolor=_XO_COLOR, alpha=0.35, label="exclusive overlap"))
        ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7,
                  frameon=False)
    return ax


def _number_slivers(ax, numbered, span: float, fontsize: float = 6):
    """Number the bars too narrow for their name (``numbered``: (task, row) in order, 1 up)
    above their row. Slivers closer together than a number is wide share one label
    ("3-9"); labels near each other go on different levels (4 at most) so none overlap."""
    clusters = []  # [row, first number, last number, first x, last x]
    for i, (t, y) in enumerate(numbered, 1):
        x = (t.start + t.finish) / 2
        c = clusters[-1] if clusters else None
        if c and c[0] == y and x - c[3] < _text_width(ax, f"{c[1]}-{i}", span, fontsize):
            c[2], c[4] = i, x
        else:
            clusters.append([y, i, i, x, x])
    placed = []  # (row, level, x, half width)
    for y, a, b, x0, x1 in clusters:
        text = str(a) if a == b else f"{a}-{b}"
        half = _text_width(ax, text, span, fontsize) / 2
        x = min(max((x0 + x1) / 2, half), span * 1.02 - half)  # inside the axis
        busy = {lv for row, lv, px, ph in placed if row == y and abs(px - x) < half + ph}
        level = next((lv for lv in range(4) if lv not in busy), a % 4)
        placed.append((y, level, x, half))
        ax.text(x, y - 0.31 - 0.13 * level, text, ha="center", va="bottom", fontsize=fontsize,
                zorder=3, clip_on=True)


def _fits(ax, text: str, width: float, span: float, fontsize: float = 7) -> bool:
    """Whether ``text`` fits inside a bar ``width`` long on an axis about ``span`` wide."""
    return width > _text_width(ax, text, span, fontsize)


def _text_width(ax, text: str, span: float, fontsize: float) -> float:
    """About how long ``text`` is, with a little margin, in time units of an axis about
    ``span`` wide."""
    px = (0.62 * fontsize * len(text) + 6) * ax.figure.dpi / 72
    return px * span * 1.02 / ax.bbox.width


def _figsize(schedule):
    return (11, 1.4 + 0.45 * len(schedule.processors))


def save_gantt(schedule: Schedule, path, dag: nx.DiGraph | None = None, title=None) -> str:
    """Draw :func:`plot_gantt` on a new figure, write it to ``path`` (format from the suffix,
    e.g. PNG), close it and return the path."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=_figsize(schedule))
    try:
        plot_gantt(schedule, ax=ax, dag=dag, title=title)
        fig.tight_layout()
        path = os.fspath(path)
        fig.savefig(path, dpi=120)
    finally:
        plt.close(fig)
    return path
