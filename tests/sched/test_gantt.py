"""Gantt charts: PNG output, bars, exclusive hatching and XO shading."""

import pytest

pytest.importorskip("matplotlib")

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from warpvx.sched import heft, plot_gantt, save_gantt, xeft  # noqa: E402
from warpvx.sched.gantt import _xo_intervals  # noqa: E402

from .dags import fig51_dag  # noqa: E402


def test_save_gantt_writes_png(tmp_path):
    dag = fig51_dag()
    path = save_gantt(xeft(dag), tmp_path / "xeft.png", dag=dag, title="XEFT")
    data = open(path, "rb").read()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 5000


def test_plot_gantt_bars_and_hatching():
    dag = fig51_dag()
    fig, ax = plt.subplots()
    try:
        out = plot_gantt(heft(dag), ax=ax, dag=dag)
        assert out is ax
        bars = [p for p in ax.patches if p.get_width() > 0 and p.get_height() == pytest.approx(0.6)]
        assert len(bars) == 8
        hatched = sorted(round(b.get_x()) for b in bars if b.get_hatch())
        assert hatched == [0, 6, 10, 17]  # the exclusive tasks 0, 1, 4, 7 start at 0, 6, 10, 17
        assert [t.get_text() for t in ax.get_yticklabels()] == ["cpu0", "gpu"]
    finally:
        plt.close(fig)


def test_xo_intervals_of_fig51():
    # HEFT: GPU-only 1 (6-16) beside CPU-only 4 (10-17): XO during 10-16.
    # XEFT: 1 (8-18) beside 4 (5-12) then 7 (12-17): XO during 8-17.
    dag = fig51_dag()
    excl = {v: (0 if v in (0, 4, 7) else 1 if v == 1 else -1) for v in dag}
    assert _xo_intervals(heft(dag), excl) == [(10, 16)]
    assert _xo_intervals(xeft(dag), excl) == [(8, 17)]


def test_plot_without_dag():
    fig, ax = plt.subplots()
    try:
        plot_gantt(heft(fig51_dag()), ax=ax)
        assert ax.get_title() == "heft: makespan 22"
    finally:
        plt.close(fig)
