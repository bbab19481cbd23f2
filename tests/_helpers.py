"""Small helpers shared by the task tests (imported as `from _helpers import ...`)."""

from __future__ import annotations


def milestone_flags(**true: bool) -> dict[str, bool]:
    """The expected `evaluate()` dict: m1..m5 all False except those given as True."""
    return {f"m{i}": bool(true.get(f"m{i}", False)) for i in range(1, 6)}
