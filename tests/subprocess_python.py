"""Run Python code in a fresh interpreter that imports this checkout's warpvx.

Used where a test needs a clean process: what gets imported, what a native library prints on
stderr, whether a README block runs as written.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


def run_python(code: str, cwd, *, timeout: float = 120, env: dict | None = None):
    """Run ``code`` with ``python -c`` in ``cwd``; return the CompletedProcess (text output).

    ``PYTHONPATH`` starts with the repository root, so the checkout under test is imported
    whatever the working directory; ``env`` adds or overrides variables.
    """
    full_env = {**os.environ, **(env or {})}
    full_env["PYTHONPATH"] = os.pathsep.join(
        p for p in (str(REPO), full_env.get("PYTHONPATH", "")) if p
    )
    return subprocess.run(
        [sys.executable, "-c", code], cwd=cwd, env=full_env, capture_output=True, text=True,
        timeout=timeout,
    )
