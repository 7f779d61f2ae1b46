"""Run a risky snippet (one that used to hang, crash or allocate gigabytes) in a subprocess
with a timeout, so a regression fails one test instead of the whole session."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def run_isolated(code: str, *, timeout: float = 120.0) -> str:
    """Run ``code`` (dedented) with this interpreter from the repository root; fail the test
    on a non-zero exit or a timeout. Returns its stdout."""
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    try:
        res = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], cwd=ROOT, env=env,
                             capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        raise AssertionError(f"timed out after {timeout} s:\n{code}") from None
    assert res.returncode == 0, f"exit {res.returncode}\n{res.stdout}\n{res.stderr[-3000:]}"
    return res.stdout
