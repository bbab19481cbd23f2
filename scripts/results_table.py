"""Markdown table of `bavo-eval` runs beside the paper's numbers: SR with its 95 % Wilson interval, TPS, CVG.

Each `--run LABEL=results.json` is one bavo-eval output (any tasks and conditions; a label may be given
several files, e.g. Clean and Stage evaluated separately). The paper's rows (Appendix tables of SR and TPS,
mean over three training seeds) are printed for the tasks that appear.

    python scripts/results_table.py \\
        --run "A-FAR shipped=outputs/eval/shipped_afar_test/results.json" \\
        --run "A-FAR occluder dropout=outputs/eval/afar_od50_4000_test/results.json"
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from lerobot_bavo.metrics import wilson_interval

CONDITIONS = ("clean", "stage", "random")
# The paper's per-task SR and TPS (%), Appendix tables "Task-level success rate" / "task progress score",
# mean over three training seeds, 20 episodes per condition each: {task: {method: ((C, S, R) SR, (C, S, R)
# TPS)}}.
PAPER = {
    "cube_handoff": {
        "ACT": ((0.0, 6.7, 0.0), (33.0, 44.0, 24.0)),
        "ManiFlow": ((41.7, 68.3, 8.3), (70.3, 87.7, 45.3)),
        "A-FAR": ((43.3, 58.3, 13.3), (69.7, 84.0, 47.7)),
    },
}


def cells_of(paths: list[Path]) -> dict[str, dict]:
    """{"task/condition": cell} over bavo-eval results.json files (later files win on a repeated cell)."""
    cells: dict[str, dict] = {}
    for path in paths:
        cells.update(json.loads(Path(path).read_text())["cells"])
    return cells


def sr_text(cell: dict) -> str:
    n = int(cell["n_episodes"])
    wins = round(cell["sr"] * n / 100)
    low, high = wilson_interval(wins, n)
    return f"{cell['sr']:.1f} [{low:.0f}-{high:.0f}] ({wins}/{n})"


def table(runs: dict[str, list[Path]]) -> str:
    all_cells = {label: cells_of(paths) for label, paths in runs.items()}
    tasks = sorted({key.split("/")[0] for cells in all_cells.values() for key in cells})
    head = "| task | method | " + " | ".join(f"{c} SR [95 % CI]" for c in CONDITIONS) + " | " + \
        " | ".join(f"{c} TPS" for c in CONDITIONS) + " | random CVG (pp) |"
    lines = [head, "|" + "---|" * (3 + 2 * len(CONDITIONS))]
    for task in tasks:
        for label, cells in all_cells.items():
            row = [cells.get(f"{task}/{c}") for c in CONDITIONS]
            srs = [sr_text(cell) if cell else "-" for cell in row]
            tps = [f"{cell['tps']:.1f}" if cell else "-" for cell in row]
            cvg = row[2]["cvg"] if row[2] and row[2].get("cvg") is not None else None
            lines.append(
                f"| {task} | {label} | "
                + " | ".join(srs + tps)
                + f" | {'-' if cvg is None else f'{cvg:.1f}'} |"
            )
        for method, (sr, tps) in PAPER.get(task, {}).items():
            lines.append(f"| {task} | paper: {method} | " + " | ".join(f"{v:.1f}" for v in sr) + " | " +
                         " | ".join(f"{v:.1f}" for v in tps) + " | |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument(
        "--run",
        action="append",
        required=True,
        metavar="LABEL=results.json",
        help="a bavo-eval results.json and the row label it gets (repeat the label for more files)",
    )
    args = p.parse_args(argv)
    runs: dict[str, list[Path]] = {}
    for item in args.run:
        label, sep, path = item.partition("=")
        if not sep or not label or not path:
            p.error(f"--run must be LABEL=path/to/results.json, got {item!r}")
        if not Path(path).is_file():
            p.error(f"no results file at {path}")
        runs.setdefault(label, []).append(Path(path))
    print(table(runs))


if __name__ == "__main__":
    main()
