"""How the applications place their graphs: one rule for both."""

from __future__ import annotations


def schedule(graph, backend="cpu"):
    """Place ``graph`` with the scheduler (policy ``best``): CPU workers only for ``"cpu"``,
    CPU workers plus the Warp device otherwise. Returns the plan."""
    return graph.schedule("best", gpu=False if backend == "cpu" else backend)


__all__ = ["schedule"]
