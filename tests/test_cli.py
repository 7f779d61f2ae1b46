"""The warpvx command line: help, subcommands, forwarding to the scheduling study."""

from __future__ import annotations

import subprocess
import sys
import types

import pytest

from warpvx import cli


def test_module_help_runs():
    res = subprocess.run([sys.executable, "-m", "warpvx", "--help"], capture_output=True, text=True,
                         timeout=120)
    assert res.returncode == 0
    assert "bench" in res.stdout and "sched-study" in res.stdout


def test_bench_help(capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(["bench", "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    for option in ("--sizes", "--primitives", "--backends", "--repeat", "--quick", "--graph", "--out",
                   "--no-plot"):
        assert option in out


def test_no_command_prints_help(capsys):
    assert cli.main([]) == 0
    assert "bench" in capsys.readouterr().out


def test_unknown_command_fails():
    with pytest.raises(SystemExit) as exc:
        cli.main(["frobnicate"])
    assert exc.value.code == 2


def test_sched_study_forwards_its_arguments(monkeypatch):
    seen = {}

    def fake_main(argv):
        seen["argv"] = argv
        return 0

    fake = types.ModuleType("warpvx.sched.study")
    fake.main = fake_main
    monkeypatch.setitem(sys.modules, "warpvx.sched.study", fake)
    assert cli.main(["sched-study", "--dags", "10", "--help"]) == 0
    assert seen["argv"] == ["--dags", "10", "--help"]
