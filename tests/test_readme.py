"""Every README code block runs as written on a CPU-only machine (issue 10, item 18).

Each ```python block runs alone in a fresh interpreter, in a temporary working directory (so
what it writes, a Gantt chart say, stays out of the repository) with the calibration cache
there too. Bash blocks are install commands and are not run; their extras and ``warpvx``
subcommands are checked against the package.
"""

from __future__ import annotations

import re

import pytest

from warpvx import cli

from .isolated import ROOT as REPO, run_python

README = REPO / "README.md"
FENCE = re.compile(r"^(?P<indent> {0,3})(?P<fence>`{3,}|~{3,})\s*(?P<lang>[\w+-]*)")


def code_blocks(text: str) -> list[tuple[str, int, str]]:
    """Fenced code blocks of a Markdown text as (language, first line number, code)."""
    blocks, lines, i = [], text.splitlines(), 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        i += 1
        if not m:
            continue
        fence, indent, start, body = m["fence"], len(m["indent"]), i + 1, []
        while i < len(lines) and not re.match(rf" {{0,3}}{fence[0]}{{{len(fence)},}}\s*$", lines[i]):
            line = lines[i]
            body.append(line[min(indent, len(line) - len(line.lstrip(" "))):])
            i += 1
        i += 1  # the closing fence
        blocks.append((m["lang"].lower(), start, "\n".join(body) + "\n"))
    return blocks


BLOCKS = code_blocks(README.read_text(encoding="utf-8"))
PYTHON = [(line, code) for lang, line, code in BLOCKS if lang in ("python", "py")]
BASH = [code for lang, _, code in BLOCKS if lang in ("bash", "sh", "shell", "console")]


def test_code_block_parser():
    text = "x\n```python\na = 1\n```\n  ~~~~ bash\n  pip install x\n  ~~~~\n```\nplain\n```\n"
    assert code_blocks(text) == [("python", 3, "a = 1\n"), ("bash", 6, "pip install x\n"),
                                 ("", 9, "plain\n")]


def test_readme_has_a_python_tour():
    assert PYTHON, "README.md has no ```python block"


@pytest.mark.slow
@pytest.mark.parametrize("line, code", PYTHON, ids=[f"README.md:{line}" for line, _ in PYTHON])
def test_python_block_runs_as_written(line, code, tmp_path):
    res = run_python(code, tmp_path, timeout=300,
                     env={"WARPVX_CACHE_DIR": str(tmp_path), "MPLBACKEND": "Agg"})
    assert res.returncode == 0, f"README.md block at line {line} failed:\n{code}\n{res.stderr}"


def _extras() -> set:
    text = (REPO / "pyproject.toml").read_text(encoding="utf-8")
    section = re.search(r"^\[project\.optional-dependencies\]\n(.*?)(?=^\[|\Z)", text, re.S | re.M)
    return set(re.findall(r"^(\w[\w-]*)\s*=", section[1], re.M)) if section else set()


def test_bash_blocks_are_the_set_up_commands(capsys):
    # Two set-up commands, each an editable install (extras that exist) then one command.
    assert len(BASH) == 2, BASH
    extras = _extras()
    for code in BASH:
        assert re.match(r'python -m pip install -e "\.(\[[\w,-]+\])?" && \S', code), code
        for group in re.findall(r'install -e "\.\[([\w,-]+)\]"', code):
            assert set(group.split(",")) <= extras, (code, extras)
        for sub in re.findall(r"&& warpvx ([\w-]+)", code):
            with pytest.raises(SystemExit) as exc:  # an unknown subcommand exits with 2
                cli.main([sub, "--help"])
            assert exc.value.code == 0, code
    capsys.readouterr()
