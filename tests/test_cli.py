"""The warpvx command line: help, subcommands, forwarding to the scheduling study."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import types
from pathlib import Path

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


@pytest.mark.parametrize("command", [["bench"], ["sched-study"]])
def test_help_shows_every_default(command, capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main([*command, "--help"])
    assert exc.value.code == 0
    text = capsys.readouterr().out
    options = text[text.index("options:"):]
    # one entry per option: from its flag at the start of a line to the next one
    entries = re.split(r"\n  (?=-)", options)[1:]
    assert len(entries) >= 8
    for entry in entries:
        if entry.startswith("-h, --help"):
            continue
        assert "default" in " ".join(entry.split()), entry


@pytest.mark.parametrize("argv, name", [
    (["sched-study", "--classes", "foo"], "--classes"),
    (["sched-study", "--classes", "tree,foo"], "--classes"),
    (["sched-study", "--n-dags", "0"], "--n-dags"),
    (["sched-study", "--n-dags", "many"], "--n-dags"),
    (["sched-study", "--sizes", "30-20"], "--sizes"),
    (["sched-study", "--sizes", "1-20"], "--sizes"),
    (["sched-study", "--cpus", "0-2"], "--cpus"),
    (["sched-study", "--comm", "a-b"], "--comm"),
    (["sched-study", "--workers", "0"], "--workers"),
    (["bench", "--backends", "gpu"], "--backends"),
])
def test_bad_arguments_are_one_line_and_exit_2(argv, name, capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert f"warpvx {argv[0]}: error: argument {name}" in err


def test_bad_classes_names_the_valid_ones(capsys):
    with pytest.raises(SystemExit):
        cli.main(["sched-study", "--classes", "foo"])
    assert "valid: tree, linear" in capsys.readouterr().err


def test_warpvx_error_in_a_command_is_one_line(monkeypatch, capsys):
    """A warpvx error a command raises (bad input found later than argparse can see it)."""
    from warpvx.errors import WarpvxValueError

    def fake_main(argv):
        raise WarpvxValueError("thing: expected a better thing")

    fake = types.ModuleType("warpvx.sched.study")
    fake.main = fake_main
    monkeypatch.setitem(sys.modules, "warpvx.sched.study", fake)
    assert cli.main(["sched-study"]) == 2
    assert capsys.readouterr().err == "warpvx sched-study: error: thing: expected a better thing\n"


def test_fresh_results_dir_is_new_each_time(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    a, b = cli.fresh_results_dir("bench"), cli.fresh_results_dir("bench")
    assert a != b and a.is_dir() and b.is_dir()
    assert a.parent == b.parent == Path("warpvx-results")
    assert re.fullmatch(r"bench-\d{8}-\d{6}(-\d+)?", a.name)


def _git(cwd, *args):
    return subprocess.run(["git", *args], cwd=cwd, capture_output=True, text=True, check=True).stdout


@pytest.mark.skipif(shutil.which("git") is None, reason="needs git")
def test_default_outputs_leave_committed_results_alone(tmp_path, monkeypatch):
    """Regression (issue 10, item 19): run from a repository root with committed results,
    ``warpvx sched-study`` and ``warpvx bench`` with their default outputs change no tracked
    file, create nothing git would track, and each run lands in a new folder."""
    recorded = {"benchmarks/results/sched_study/summary.md": "recorded study\n",
                "benchmarks/results/sched_study/per_dag.csv": "dag\n",
                "benchmarks/results/cpu/bench-1.json": "{}\n"}
    for rel, text in recorded.items():
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text(text)
    _git(tmp_path, "init", "-q")
    _git(tmp_path, "add", ".")
    _git(tmp_path, "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "recorded")
    monkeypatch.chdir(tmp_path)

    study = ["sched-study", "--n-dags", "4", "--sizes", "20-24", "--workers", "1", "--no-plots",
             "--quiet"]
    assert cli.main(study) == 0
    assert cli.main(study) == 0
    assert cli.main(["bench", "--quick", "--primitives", "color_convert", "--sizes", "32x24",
                     "--no-progress", "--no-plot"]) == 0

    assert _git(tmp_path, "status", "--porcelain", "--untracked-files=all") == ""
    for rel, text in recorded.items():
        assert (tmp_path / rel).read_text() == text
    assert sorted(p.relative_to(tmp_path).as_posix() for p in (tmp_path / "benchmarks").rglob("*")
                  if p.is_file()) == sorted(recorded)
    studies = sorted((tmp_path / "warpvx-results").glob("sched-study-*"))
    assert len(studies) == 2 and all((d / "summary.json").is_file() for d in studies)
    (bench_dir,) = (tmp_path / "warpvx-results").glob("bench-*")
    assert len(list(bench_dir.glob("bench-*.json"))) == 1


def test_results_folder_is_ignored_by_this_repository():
    """The repository's own .gitignore covers ./warpvx-results/ too (belt and braces)."""
    root = Path(__file__).resolve().parent.parent
    if shutil.which("git") is None or not (root / ".git").exists():
        pytest.skip("needs a git checkout")
    res = subprocess.run(["git", "check-ignore", "-q", "warpvx-results/bench-x/bench.json"],
                         cwd=root)
    assert res.returncode == 0
