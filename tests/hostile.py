"""Running a risky call in a fresh interpreter, so a crash or a hang fails one test, not the run.

SPEC section 10 keeps a hostile-input suite: each case that once crashed the process or hung
runs through :func:`run_isolated` with a timeout.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

# Prepended to each snippet: ``outcome(fn)`` prints "ok" or the exception's class and message.
_PRELUDE = '''
def outcome(fn):
    try:
        fn()
    except Exception as e:
        print(f"{type(e).__name__}: {e}", flush=True)
    else:
        print("ok", flush=True)
'''


def run_isolated(code: str, *, timeout: float = 60) -> list[str]:
    """Run ``code`` with ``python -c`` from the repository root; its stdout lines.

    Fails the calling test (AssertionError, or ``subprocess.TimeoutExpired`` past ``timeout``
    seconds) when the interpreter dies (a segfault, an abort) or exits non-zero.
    """
    proc = subprocess.run([sys.executable, "-c", _PRELUDE + textwrap.dedent(code)],
                          capture_output=True, text=True, timeout=timeout, cwd=ROOT)
    assert proc.returncode == 0, f"exit status {proc.returncode}:\n{proc.stderr[-3000:]}"
    return proc.stdout.splitlines()
