"""The package's structure stays as issue 31 left it: no import loops, no arrows from a lower layer up (envs/
to eval/, teacher/ to datasets/, ...), and no private name used across modules (LeRobot's only in
`datasets/lerobot_private.py`). Measured from the source by `scripts/import_graph.py` (no imports run)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _import_graph():
    spec = importlib.util.spec_from_file_location("import_graph", REPO / "scripts" / "import_graph.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_no_import_loops_no_upward_arrows_no_private_use_across_modules():
    graph = _import_graph()
    modules, edges, private = graph.scan(sorted((REPO / "lerobot_bavo").rglob("*.py")))
    assert graph.cycles(edges) == []
    assert graph.upward_arrows(edges) == []
    assert private == [], "\n".join(f"{m}:{line} {expr}" for m, line, expr in private)
