"""The package's structure stays as issue 31 left it: no import loops, no arrows from a lower layer up (envs/
to eval/, teacher/ to datasets/, ...), and no private name used across modules (LeRobot's only in
`datasets/lerobot_private.py`). Measured from the source by `scripts/import_graph.py` (no imports run)."""

from __future__ import annotations

from pathlib import Path

from _helpers import load_script

REPO = Path(__file__).resolve().parents[1]


def _import_graph():
    return load_script("scripts/import_graph.py")


def test_no_import_loops_no_upward_arrows_no_private_use_across_modules():
    graph = _import_graph()
    modules, edges, private = graph.scan(sorted((REPO / "lerobot_bavo").rglob("*.py")))
    assert graph.cycles(edges) == []
    assert graph.upward_arrows(edges) == []
    assert private == [], "\n".join(f"{m}:{line} {expr}" for m, line, expr in private)


def test_every_command_answers_help_without_importing_lerobot_or_pytorch():
    """`import lerobot_bavo` registers only the gym ids, and each CLI parses its arguments before importing
    LeRobot, so `--help` is quick (the timing itself is in docs/results/costs.md, not asserted here)."""
    import os
    import subprocess
    import sys

    code = (
        "import sys\n"
        "from lerobot_bavo.{module} import main\n"
        "try:\n"
        "    main(['--help'])\n"
        "except SystemExit:\n"
        "    pass\n"
        "sys.stderr.write(str(sorted(m for m in ('torch', 'lerobot') if m in sys.modules)))\n")
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    env.pop("BAVO_LIGHT_IMPORT", None)
    for module in ("eval.cli", "teleop.server", "demo", "datasets.collect", "viz.cli"):
        out = subprocess.run(
            [sys.executable, "-c", code.format(module=module)],
            capture_output=True,
            text=True,
            timeout=120,
            env=env,
            cwd=REPO,
        )
        assert out.returncode == 0 and out.stderr.endswith("[]"), (module, out.stderr[-2000:])
