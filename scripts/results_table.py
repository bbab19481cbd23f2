"""BAVO-Bench's results table in the paper's format, from `bavo-eval` results, beside the paper's numbers.

    bavo-eval --grid configs/grid_table.yaml --output-dir outputs/eval/grid_table --workers 2
    python scripts/results_table.py --grid outputs/eval/grid_table/results.json --output docs/results/table.md

Sections (as in the paper): the macro table (SR and TPS per condition, mean over the tasks a method has, mean
± std over training seeds: Table 1), CVG / Joint per task under Random-time (Table 2), and per-task SR and
TPS (the appendix tables). Every SR of ours carries its 95 % Wilson interval over all of that cell's episodes
(pooled over training seeds). The paper's rows are printed under ours; its numbers are means over three
training seeds with 20 episodes per condition each.

`--run LABEL=results.json` adds a single `bavo-eval` run as a method with one training seed (repeat the label
for more files of the same method, e.g. conditions evaluated separately); a run's `episodes.jsonl[.gz]` works
too (the committed logs in docs/results/grid_table, for a run whose checkpoint is not shipped).
`--name METHOD=LABEL` shows a grid's method under a readable label (grid method names are folder names:
`afar`, `afar-stage+random`); the order of the rows is the grid's, then the `--run` labels'.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from lerobot_bavo.eval.grid import fmt_mean_std, mean_over_tasks, mean_std
from lerobot_bavo.metrics import wilson_interval

CONDITIONS = ("clean", "stage", "random")
TASKS = ("cube_handoff", "drawer_stowing", "slide_retrieval", "block_stacking", "dustpan_sweeping")
SHORT = {"cube_handoff": "Cube", "drawer_stowing": "Drawer", "slide_retrieval": "Slide",
         "block_stacking": "Stack", "dustpan_sweeping": "Sweep"}

# The paper (bavo_afar_paper.tex). Table 1, macro over five tasks: {method: ((C, S, R) SR, (C, S, R) TPS)} as
# (mean, std over three training seeds; None for pi0.5's single run).
PAPER_MACRO = {
    "ACT": (((10.3, 1.2), (24.7, 2.3), (15.7, 3.2)), ((46.2, 6.8), (58.1, 1.7), (46.6, 0.4))),
    "pi0.5": (((13.0, None), (42.0, None), (4.0, None)), ((55.2, None), (73.4, None), (40.8, None))),
    "ManiFlow": (((45.7, 1.5), (60.7, 3.1), (15.0, 3.5)), ((70.5, 6.4), (81.5, 3.2), (50.5, 2.7))),
    "A-FAR": (((51.3, 4.2), (63.7, 2.1), (18.7, 1.2)), ((73.9, 5.4), (83.9, 0.9), (51.9, 1.4))),
}
# Appendix tables "Task-level success rate" / "task progress score": {task: {method: (SR (C, S, R), TPS
# (C, S, R))}}, each a (mean, std) pair.
PAPER_TASKS = {
    "cube_handoff": {
        "ACT": (((0.0, 0.0), (6.7, 7.6), (0.0, 0.0)), ((33.0, 2.6), (44.0, 3.6), (24.0, 6.2))),
        "pi0.5": (((5.0, None), (30.0, None), (0.0, None)), ((45.0, None), (68.0, None), (31.0, None))),
        "ManiFlow": (((41.7, 2.9), (68.3, 5.8), (8.3, 7.6)), ((70.3, 5.0), (87.7, 2.3), (45.3, 5.7))),
        "A-FAR": (((43.3, 14.4), (58.3, 2.9), (13.3, 2.9)), ((69.7, 13.2), (84.0, 1.7), (47.7, 6.0))),
    },
    "drawer_stowing": {
        "ACT": (((50.0, 5.0), (56.7, 2.9), (45.0, 8.7)), ((78.7, 3.1), (80.7, 2.1), (77.3, 4.7))),
        "pi0.5": (((25.0, None), (75.0, None), (0.0, None)), ((70.0, None), (90.0, None), (51.0, None))),
        "ManiFlow": (((90.0, 13.2), (83.3, 5.8), (38.3, 14.4)), ((96.0, 5.3), (93.3, 2.3), (65.3, 5.5))),
        "A-FAR": (((86.7, 18.9), (81.7, 5.8), (40.0, 18.0)), ((94.7, 7.6), (92.7, 1.2), (66.0, 9.6))),
    },
    "slide_retrieval": {
        "ACT": (((0.0, 0.0), (31.7, 15.3), (30.0, 8.7)), ((48.0, 19.0), (65.7, 9.5), (62.7, 3.8))),
        "pi0.5": (((0.0, None), (55.0, None), (10.0, None)), ((40.0, None), (74.0, None), (53.0, None))),
        "ManiFlow": (((33.3, 12.6), (58.3, 2.9), (13.3, 2.9)), ((63.7, 7.0), (74.3, 2.5), (58.0, 3.5))),
        "A-FAR": (((41.7, 17.6), (65.0, 8.7), (16.7, 2.9)), ((67.7, 7.6), (77.3, 7.0), (59.7, 4.2))),
    },
    "block_stacking": {
        "ACT": (((0.0, 0.0), (0.0, 0.0), (0.0, 0.0)), ((24.3, 3.5), (28.7, 2.9), (22.3, 2.1))),
        "pi0.5": (((10.0, None), (15.0, None), (0.0, None)), ((69.0, None), (69.0, None), (22.0, None))),
        "ManiFlow": (((8.3, 7.6), (13.3, 2.9), (0.0, 0.0)), ((44.7, 20.3), (62.7, 6.7), (30.3, 3.2))),
        "A-FAR": (((13.3, 11.5), (23.3, 10.4), (1.7, 2.9)), ((53.7, 20.6), (69.7, 4.0), (28.7, 2.1))),
    },
    "dustpan_sweeping": {
        "ACT": (((1.7, 2.9), (28.3, 16.1), (3.3, 5.8)), ((47.0, 17.3), (71.3, 8.6), (46.7, 2.5))),
        "pi0.5": (((25.0, None), (35.0, None), (10.0, None)), ((52.0, None), (66.0, None), (47.0, None))),
        "ManiFlow": (((55.0, 15.0), (80.0, 8.7), (15.0, 5.0)), ((77.7, 3.1), (89.7, 5.0), (53.7, 6.5))),
        "A-FAR": (((71.7, 7.6), (90.0, 5.0), (21.7, 7.6)), ((84.0, 5.3), (96.0, 2.0), (57.3, 5.1))),
    },
}
# Table 2 (Random-time): {task: {method: (CVG pp, Joint)}}, means over training seeds.
PAPER_CVG = {
    "cube_handoff": {"ACT": (16.49, 0.00), "pi0.5": (32.81, 0.00), "ManiFlow": (26.25, 2.18),
                     "A-FAR": (25.88, 3.44)},
    "drawer_stowing": {"ACT": (19.71, 8.87), "pi0.5": (35.65, 0.00), "ManiFlow": (30.47, 11.67),
                       "A-FAR": (32.27, 12.91)},
    "slide_retrieval": {"ACT": (17.64, 5.29), "pi0.5": (28.72, 2.87), "ManiFlow": (22.50, 2.99),
                        "A-FAR": (24.08, 4.02)},
    "block_stacking": {"ACT": (20.36, 0.00), "pi0.5": (32.94, 0.00), "ManiFlow": (28.66, 0.00),
                       "A-FAR": (28.93, 0.49)},
    "dustpan_sweeping": {"ACT": (21.49, 0.71), "pi0.5": (41.99, 4.20), "ManiFlow": (34.97, 5.25),
                         "A-FAR": (37.04, 8.04)},
}


# ------------------------------------------------------------------ ours, per method, cell and seed
def methods_of_grid(results: dict) -> dict[str, dict[str, dict[str, dict]]]:
    """A `bavo-eval --grid` results.json -> {method: {"task/condition": {training-seed label: cell}}}."""
    return {name: {key: dict(cell["seeds"]) for key, cell in m["cells"].items()}
            for name, m in results["methods"].items()}


def cells_of_log(path: Path) -> dict[str, dict]:
    """A run's cells from its per-episode log (`episodes.jsonl`, or the `.jsonl.gz` that
    `scripts/grid_runs.py` commits), computed as bavo-eval computes them (`summarize_cell`)."""
    from lerobot_bavo.eval.run import read_episode_records, summarize_cell

    by_cell: dict[str, list[dict]] = {}
    for record in read_episode_records(path):
        by_cell.setdefault(f"{record['task']}/{record['condition']}", []).append(record)
    return {key: summarize_cell(records) for key, records in by_cell.items()}


def methods_of_runs(runs: dict[str, list[Path]]) -> dict[str, dict[str, dict[str, dict]]]:
    """`--run LABEL=results.json` (or a run's `episodes.jsonl[.gz]`) files -> the same shape, one training
    seed ("0") per method."""
    out: dict[str, dict[str, dict[str, dict]]] = {}
    for label, paths in runs.items():
        cells = out.setdefault(label, {})
        for path in paths:
            path = Path(path)
            run_cells = (cells_of_log(path) if path.name.endswith((".jsonl", ".jsonl.gz"))
                         else json.loads(path.read_text())["cells"])
            for key, cell in run_cells.items():
                cells[key] = {"0": cell}
    return out


# ------------------------------------------------------------------ pure summaries
def pooled_sr_interval(per_seed: dict[str, dict]) -> tuple[int, int, float, float]:
    """(successes, episodes, low, high): the 95 % Wilson interval of SR over every episode of a cell, pooled
    over training seeds (SR is a percentage of n_episodes, so successes = SR x n / 100 exactly)."""
    wins = sum(round(c["sr"] * c["n_episodes"] / 100) for c in per_seed.values())
    n = sum(int(c["n_episodes"]) for c in per_seed.values())
    low, high = wilson_interval(wins, n)
    return wins, n, low, high


def macro(cells: dict[str, dict[str, dict]], tasks: list[str], condition: str, metric: str):
    """Mean over `tasks` per training seed (the grid's own `mean_over_tasks`), then (mean, std) over the seeds
    every one of those tasks has."""
    labels = set.intersection(*(set(cells[f"{t}/{condition}"]) for t in tasks))
    per_seed = [mean_over_tasks([cells[f"{t}/{condition}"][label] for t in tasks])[metric]
                for label in sorted(labels)]
    return mean_std(per_seed)


def tasks_of(cells: dict[str, dict], condition: str | None = None) -> list[str]:
    """The tasks a method has every condition of (or the given condition), in the paper's order."""
    conds = (condition,) if condition else CONDITIONS
    return [t for t in TASKS if all(f"{t}/{c}" in cells for c in conds)]


def tasks_with_every_seed(cells: dict[str, dict], tasks: list[str]) -> list[str]:
    """The tasks among `tasks` that hold, in every condition, every training seed the method has anywhere: a
    method trained on more seeds for some tasks than others gets a macro over these too, so that a one-seed
    cell on a new task does not reduce the several-seed macro of the tasks before it to one seed."""
    seeds = set().union(*(set(cells[f"{t}/{c}"]) for t in tasks for c in CONDITIONS))
    return [t for t in tasks if all(set(cells[f"{t}/{c}"]) >= seeds for c in CONDITIONS)]


def cell_stat(per_seed: dict[str, dict], metric: str):
    return mean_std([c[metric] for c in per_seed.values()])


def paper_text(pair) -> str:
    mean, std = pair
    return f"{mean:.1f}" if std is None else f"{mean:.1f} ± {std:.1f}"


# ------------------------------------------------------------------ tables
def macro_table(methods: dict) -> list[str]:
    lines = ["| method | tasks | seeds | " + " | ".join(f"{c} SR | {c} TPS" for c in CONDITIONS) + " |",
             "|" + "---|" * (3 + 2 * len(CONDITIONS))]
    for name, cells in methods.items():
        tasks = tasks_of(cells)
        if not tasks:
            continue
        rows = [(name, tasks)]
        seeded = tasks_with_every_seed(cells, tasks)
        if 2 <= len(seeded) < len(tasks):
            rows.append((f"{name}, the tasks with every seed", seeded))
        for label, row_tasks in rows:
            n_seeds = len(set.intersection(*(set(cells[f"{t}/{c}"]) for t in row_tasks for c in CONDITIONS)))
            vals = [fmt_mean_std(*macro(cells, row_tasks, cond, metric))
                    for cond in CONDITIONS for metric in ("sr", "tps")]
            lines.append(f"| {label} | {len(row_tasks)} of 5 | {n_seeds} | " + " | ".join(vals) + " |")
    for name, (sr, tps) in PAPER_MACRO.items():
        vals = [paper_text(x) for pair in zip(sr, tps) for x in pair]
        lines.append(f"| paper: {name} | 5 of 5 | {1 if name == 'pi0.5' else 3} | " + " | ".join(vals) + " |")
    return lines


def per_task_table(methods: dict, metric: str) -> list[str]:
    with_ci = metric == "sr"
    lines = ["| task | method | seeds | " + " | ".join(CONDITIONS) + " |",
             "|" + "---|" * (3 + len(CONDITIONS))]
    for task in TASKS:
        for name, cells in methods.items():
            row = [cells.get(f"{task}/{c}") for c in CONDITIONS]
            if not any(row):
                continue
            texts = []
            for per_seed in row:
                if not per_seed:
                    texts.append("-")
                    continue
                text = fmt_mean_std(*cell_stat(per_seed, metric))
                if with_ci:
                    wins, n, low, high = pooled_sr_interval(per_seed)
                    text += f" [{low:.0f}-{high:.0f}] ({wins}/{n})"
                texts.append(text)
            n_seeds = max(len(p) for p in row if p)
            lines.append(f"| {task} | {name} | {n_seeds} | " + " | ".join(texts) + " |")
        for name, (sr, tps) in PAPER_TASKS[task].items():
            values = sr if metric == "sr" else tps
            lines.append(f"| {task} | paper: {name} | {1 if name == 'pi0.5' else 3} | "
                         + " | ".join(paper_text(v) for v in values) + " |")
    return lines


def cvg_table(methods: dict) -> list[str]:
    names = [n for n, cells in methods.items() if any(f"{t}/random" in cells for t in TASKS)]
    paper = list(PAPER_MACRO)
    lines = ["| task | " + " | ".join(names) + " | " + " | ".join(f"paper: {n}" for n in paper) + " |",
             "|" + "---|" * (1 + len(names) + len(paper))]
    for task in TASKS:
        ours = []
        for name in names:
            per_seed = methods[name].get(f"{task}/random")
            if not per_seed:
                ours.append("-")
                continue
            cvg, joint = cell_stat(per_seed, "cvg")[0], cell_stat(per_seed, "joint")[0]
            ours.append("-" if cvg is None else f"{cvg:.2f} / {joint:.2f}")
        theirs = [f"{c:.2f} / {j:.2f}" for c, j in (PAPER_CVG[task][n] for n in paper)]
        lines.append(f"| {SHORT[task]} | " + " | ".join(ours + theirs) + " |")
    avg = []
    for name in names:
        tasks = tasks_of(methods[name], "random")
        if len(tasks) < len(TASKS):
            avg.append(f"({len(tasks)} of {len(TASKS)} tasks)")
            continue
        avg.append(f"{macro(methods[name], tasks, 'random', 'cvg')[0]:.2f} / "
                   f"{macro(methods[name], tasks, 'random', 'joint')[0]:.2f}")
    paper_avg = [" / ".join(f"{sum(PAPER_CVG[t][n][i] for t in TASKS) / len(TASKS):.2f}" for i in (0, 1))
                 for n in paper]
    lines.append("| Avg. | " + " | ".join(avg + paper_avg) + " |")
    return lines


def report(methods: dict, sources: list[str]) -> str:
    out = ["# BAVO-Bench results table (the paper's format)", "",
           "Written by `python scripts/results_table.py " + " ".join(sources) + "`; what it means, the "
           "recipe and the state of each method: [README.md](README.md#where-the-learned-policies-stand).",
           "",
           "## Macro over tasks (the paper's Table 1)", "",
           "SR and TPS in %, mean over the tasks a method has (`tasks`), mean ± std over training seeds (one "
           "value where there is one seed). A method with fewer than five tasks is not comparable to the "
           "paper's five-task macro.", "", *macro_table(methods), "",
           "## Random-time: CVG (pp) / Joint = SR x CVG / 100 (the paper's Table 2)", "",
           *cvg_table(methods), "",
           "## Per-task SR (%) [95 % Wilson interval over all episodes] (successes / episodes)", "",
           *per_task_table(methods, "sr"), "",
           "## Per-task TPS (%)", "", *per_task_table(methods, "tps"), ""]
    return "\n".join(out)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--grid", type=Path, default=None, help="a `bavo-eval --grid` results.json")
    p.add_argument(
        "--run",
        action="append",
        default=[],
        metavar="LABEL=results.json",
        help="a bavo-eval results.json and the method label it gets (repeat the label for more files)",
    )
    p.add_argument("--name", action="append", default=[], metavar="METHOD=LABEL",
                   help="show the grid's METHOD as LABEL (repeat)")
    p.add_argument("--output", type=Path, default=None, help="write the Markdown here (default: print it)")
    args = p.parse_args(argv)
    if args.grid is None and not args.run:
        p.error("give --grid results.json and/or --run LABEL=results.json")
    methods: dict = {}
    if args.grid is not None:
        if not args.grid.is_file():
            p.error(f"no grid results file at {args.grid}")
        names = {}
        for item in args.name:
            method, sep, label = item.partition("=")
            if not sep or not method or not label:
                p.error(f"--name must be METHOD=LABEL, got {item!r}")
            names[method] = label
        grid_methods = methods_of_grid(json.loads(args.grid.read_text()))
        unknown = sorted(set(names) - set(grid_methods))
        if unknown:
            p.error(f"--name: the grid has no method {', '.join(unknown)} (it has {', '.join(grid_methods)})")
        methods.update({names.get(m, m): cells for m, cells in grid_methods.items()})
    runs: dict[str, list[Path]] = {}
    for item in args.run:
        label, sep, path = item.partition("=")
        if not sep or not label or not path:
            p.error(f"--run must be LABEL=path/to/results.json, got {item!r}")
        if not Path(path).is_file():
            p.error(f"no results file at {path}")
        runs.setdefault(label, []).append(Path(path))
    methods.update(methods_of_runs(runs))
    sources = [f"--grid {args.grid}"] if args.grid is not None else []
    sources += [f'--name "{n}"' for n in args.name] + [f'--run "{r}"' for r in args.run]
    text = report(methods, sources)
    if args.output:
        args.output.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
