"""The synthetic study runs end to end on a few small DAGs."""

import csv
import json

import pytest

from warpvx.sched import study


def test_run_study_small(tmp_path):
    pytest.importorskip("matplotlib")
    res = study.run_study(12, sizes=(20, 40), n_cpus_range=(2, 3), seed=5, out_dir=tmp_path,
                          workers=1, progress=False)
    rows = list(csv.DictReader(open(tmp_path / "per_dag.csv")))
    assert len(rows) == 12
    assert {r["cls"] for r in rows} == {"tree", "linear"}
    for r in rows:
        assert float(r["best"]) <= float(r["heft"]) + 1e-9
        assert 20 <= int(r["n_nodes"]) <= 40
    summary = json.load(open(tmp_path / "summary.json"))
    x = summary["summary"]["all"]["xeft_vs_heft"]
    assert x["wins"] + x["ties"] + x["losses"] == pytest.approx(1.0)
    assert "XEFT vs HEFT" in (tmp_path / "summary.md").read_text()
    for name in ("fig_tree.png", "fig_linear.png", "gain_vs_heft_metrics.png", "ratio_hist.png",
                 "heft_vs_baseline_hist.png"):
        assert (tmp_path / name).stat().st_size > 1000
    assert res["summary"]["all"]["n_dags"] == 12


def test_study_reproducible():
    a = study.run_study(6, sizes=(20, 30), seed=2, out_dir=None, workers=1, progress=False)
    b = study.run_study(6, sizes=(20, 30), seed=2, out_dir=None, workers=1, progress=False)
    assert [r["xeft"] for r in a["records"]] == [r["xeft"] for r in b["records"]]


def test_main_cli(tmp_path, capsys):
    assert study.main(["--n-dags", "4", "--sizes", "20-25", "--out", str(tmp_path), "--workers", "1",
                       "--no-plots", "--quiet"]) == 0
    assert "XEFT vs HEFT" in capsys.readouterr().out
    assert (tmp_path / "per_dag.csv").exists()
