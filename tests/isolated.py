"""Running Python in a fresh interpreter that imports this checkout's warpvx.

A clean process is what a test needs to see what gets imported or printed on stderr, to run a
README block as written, and (SPEC section 10's hostile-input suite) to run a case that once
crashed the process, hung or allocated gigabytes, so that a regression fails one test instead
of the whole run.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# Prepended to isolated snippets: ``outcome(fn)`` prints "ok" or the exception's class and message.
_PRELUDE = '''
def outcome(fn):
    try:
        fn()
    except Exception as e:
        print(f"{type(e).__name__}: {e}", flush=True)
    else:
        print("ok", flush=True)
'''


def run_python(code: str, cwd=ROOT, *, timeout: float = 120, env: dict | None = None):
    """Run ``code`` with ``python -c`` in ``cwd``; return the CompletedProcess (text output).

    ``PYTHONPATH`` starts with the repository root, so the checkout under test is imported
    whatever the working directory; ``env`` adds or overrides variables.
    """
    full_env = {**os.environ, **(env or {})}
    full_env["PYTHONPATH"] = os.pathsep.join(
        p for p in (str(ROOT), full_env.get("PYTHONPATH", "")) if p
    )
    return subprocess.run([sys.executable, "-c", code], cwd=cwd, env=full_env,
                          capture_output=True, text=True, timeout=timeout)


def run_isolated(code: str, *, timeout: float = 120.0) -> str:
    """Run ``code`` (dedented, after a prelude defining ``outcome(fn)``) from the repository
    root; fail the calling test on a non-zero exit (a segfault, an abort) or past ``timeout``
    seconds. Returns its stdout."""
    try:
        res = run_python(_PRELUDE + textwrap.dedent(code), timeout=timeout)
    except subprocess.TimeoutExpired:
        raise AssertionError(f"timed out after {timeout} s:\n{code}") from None
    assert res.returncode == 0, f"exit {res.returncode}\n{res.stdout}\n{res.stderr[-3000:]}"
    return res.stdout
