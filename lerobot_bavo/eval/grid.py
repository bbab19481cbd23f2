"""`bavo-eval --grid FILE.yaml`: methods x tasks x conditions x training seeds in one command.

A grid file (YAML) names the cells; `configs/grid_expert.yaml` is an example:

    tasks: [cube_handoff, block_stacking]   # default: all registered tasks
    conditions: [clean, stage, random]      # default: clean, stage, random
    episodes: 5                             # per (method, training seed, task, condition); default 20
    seed: 1000                              # first evaluation seed; default 1000
    methods:
      expert: expert                        # one policy: expert, expert-frozen-camera or a checkpoint folder
      afar:                                 # a training-seed axis: one checkpoint per training seed
        checkpoints: {s1000: outputs/train/afar_s1000/checkpoints/last/pretrained_model,
                      s1001: outputs/train/afar_s1001/checkpoints/last/pretrained_model}
        tasks: [cube_handoff]               # optional: this method on fewer tasks / conditions
      maniflow: [ckpt_seed0, ckpt_seed1]    # a list is a training-seed axis labelled 0, 1, ...
      afar-per-task:                        # single-task policies: `{task}` in a path is the task's name
        checkpoints:
          s1000: checkpoints/afar_{task}
          s1001: {path: checkpoints/afar_{task}_s1001, tasks: [cube_handoff]}  # a seed on fewer tasks
      afar-chosen:                          # a checkpoint named per task (e.g. a setting chosen per task on
        checkpoints:                        # the validation seeds): task -> checkpoint, that seed's tasks
          s1000: {cube_handoff: checkpoints/afar_cube_handoff_lr1e3,
                  block_stacking: checkpoints/afar_block_stacking}

The file is UTF-8 YAML of at most `MAX_GRID_BYTES`, without anchors or aliases (`&name`, `*name`; see
`load_grid`). Relative checkpoint paths are resolved against the current directory. Every (method, training
seed) is one ordinary `bavo-eval` run in `<output-dir>/runs/<method>/<label>/` (its own run.json,
episodes.jsonl, results.json; with a `{task}` checkpoint, one run per task in `.../<label>/<task>/`, which is
also where `bavo-eval --policy checkpoints/afar_<task> --tasks <task>` can be run beforehand), so a killed
grid re-run with the same command keeps every finished episode and with them every finished cell, and runs
only what is missing. A training seed given as `{path: ..., tasks: [...]}` covers only those of its method's
tasks (extra seeds where the budget allowed them, as the paper asks "Cube Handoff first"): a cell's mean ± std
is over the seeds that have it, and the method's mean over tasks over the seeds that have every task. The grid
then writes, in `<output-dir>`:

  results.json  every cell: each training seed's SR / TPS / CVG / Joint and n_episodes, their mean and std
  over
                training seeds, and per method and condition the same for the mean over its tasks;
  results.md    the table: mean ± std over training seeds (std: the sample standard deviation, n - 1; a method
                with one training seed shows its value alone);
  results.png   SR / TPS / CVG per condition, one panel per task and the mean over tasks, bars per method with
                the std over training seeds as error bars.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

from lerobot_bavo.limits import short_repr
from lerobot_bavo.metrics import CELL_METRICS

GRID_VERSION = 1
METRICS = tuple(CELL_METRICS)
# The table and the plot leave Joint out: it is SR x CVG / 100, a product of two columns they show.
SHOWN = tuple(k for k in CELL_METRICS if k != "joint")
DEFAULT_CONDITIONS = ("clean", "stage", "random")
TOP_KEYS = ("tasks", "conditions", "episodes", "seed", "methods")
METHOD_KEYS = ("checkpoints", "tasks", "conditions")
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.+-]*$")
MAX_GRID_BYTES = 1 << 20  # a grid file is a few hundred bytes; YAML parsing in Python costs ~1 s per MB


class GridError(ValueError):
    """A grid file that cannot be run; the message names the file and the offending key or value."""


TASK_FIELD = "{task}"  # in a checkpoint path: one single-task checkpoint per task


@dataclass(frozen=True)
class Method:
    name: str
    # training-seed label -> policy (expert name or checkpoint folder, as written; may hold TASK_FIELD), or
    # task -> checkpoint folder (a checkpoint named per task)
    checkpoints: dict[str, str | dict[str, str]]
    tasks: tuple[str, ...]
    conditions: tuple[str, ...]
    # training-seed label -> the tasks that seed has, where fewer than `tasks` (`{path, tasks}` in the file)
    seed_tasks: dict[str, tuple[str, ...]] = field(default_factory=dict)

    def tasks_of(self, label: str) -> tuple[str, ...]:
        """The tasks training seed `label` is evaluated on (in the method's order)."""
        return self.seed_tasks.get(label, self.tasks)

    def labels_of(self, task: str) -> list[str]:
        """The training seeds that have `task`."""
        return [label for label in self.checkpoints if task in self.tasks_of(label)]

    @property
    def per_task(self) -> bool:
        """Single-task policies (the paper trains one per task): each (training seed, task) is its own run."""
        return any(isinstance(policy, dict) or TASK_FIELD in policy for policy in self.checkpoints.values())

    def policy_of(self, label: str, task: str) -> str:
        """The checkpoint of training seed `label` on `task`: its task's entry, or its path with `{task}`
        filled in."""
        policy = self.checkpoints[label]
        return policy[task] if isinstance(policy, dict) else policy.replace(TASK_FIELD, task)

    def runs(self, output_dir: Path) -> list[tuple[str, str, tuple[str, ...], Path]]:
        """(label, policy, tasks, run folder) of every bavo-eval run this method takes."""
        if not self.per_task:
            return [(label, policy, self.tasks_of(label), run_dir(output_dir, self.name, label))
                    for label, policy in self.checkpoints.items()]
        return [(label, self.policy_of(label, task), (task,), run_dir(output_dir, self.name, label) / task)
                for label in self.checkpoints for task in self.tasks_of(label)]

    def as_dict(self) -> dict:
        checkpoints = {label: ({"path": policy, "tasks": list(self.seed_tasks[label])}
                               if label in self.seed_tasks and not isinstance(policy, dict) else policy)
                       for label, policy in self.checkpoints.items()}
        return {"checkpoints": checkpoints, "tasks": list(self.tasks), "conditions": list(self.conditions)}


@dataclass(frozen=True)
class Grid:
    tasks: tuple[str, ...]
    conditions: tuple[str, ...]
    episodes: int
    seed: int
    methods: tuple[Method, ...] = field(default_factory=tuple)

    def as_dict(self) -> dict:
        return {"tasks": list(self.tasks), "conditions": list(self.conditions), "episodes": self.episodes,
                "seed": self.seed,
                "methods": {m.name: m.as_dict() for m in self.methods}}


# ------------------------------------------------------------------ the grid file
def _names(value, what: str, known, where: str) -> tuple[str, ...]:
    if isinstance(value, str):
        value = [v for v in value.split(",") if v]
    if not isinstance(value, list) or not value or not all(isinstance(v, str) for v in value):
        raise GridError(f"{where}: {what} must be a non-empty list of names, got {short_repr(value)}")
    for v in value:
        if v not in known:
            raise GridError(f"{where}: unknown {what[:-1]} {short_repr(v)}; choose from {', '.join(known)}")
    if len(set(value)) != len(value):
        raise GridError(f"{where}: {what} lists a name twice: {short_repr(value)}")
    return tuple(value)


def _checkpoints(value, where: str) -> tuple[dict[str, str | dict[str, str]], dict[str, object]]:
    """A method's training-seed axis: one policy (label "0"), a list (labels "0", "1", ...) or label ->
    policy, where a policy may be `{path: ..., tasks: [...]}` (that seed on those tasks only) or a mapping
    task -> checkpoint folder (that seed on those tasks, each with its own folder). Returns (label -> policy,
    label -> its raw task list, checked by the caller against the method's tasks)."""
    from lerobot_bavo.envs.tasks import TASKS

    if isinstance(value, str):
        value = [value]
    if isinstance(value, list):
        value = {str(i): v for i, v in enumerate(value)}
    if not isinstance(value, dict) or not value:
        raise GridError(
            f"{where}: give one policy, a list of checkpoints (one per training seed) or a mapping "
            f"label -> checkpoint, got {short_repr(value)}"
        )
    out, seed_tasks = {}, {}
    for label, policy in value.items():
        label = str(label)
        if not _NAME.match(label):
            raise GridError(
                f"{where}: training-seed label {short_repr(label)} must be a plain name (letters, digits, "
                "_ . + -)"
            )
        if isinstance(policy, dict) and policy and not set(map(str, policy)) & {"path", "tasks"}:
            # task -> checkpoint folder
            unknown = sorted(set(map(str, policy)) - set(TASKS))
            if unknown:
                raise GridError(
                    f"{where}: training seed {short_repr(label)} as a mapping is task -> checkpoint (or has "
                    f"the keys path and tasks); unknown task {short_repr(unknown[0])}; choose from "
                    f"{', '.join(TASKS)}"
                )
            seed_tasks[label] = list(policy)
            of_seed = f"{where}: checkpoint of {short_repr(label)}"
            out[label] = {str(task): _policy_path(path, f"{of_seed} on {task}", per_task=True)
                          for task, path in policy.items()}
            continue
        if isinstance(policy, dict):
            unknown = sorted(set(map(str, policy)) - {"path", "tasks"})
            if unknown or "path" not in policy or "tasks" not in policy:
                raise GridError(
                    f"{where}: training seed {short_repr(label)} as a mapping has exactly the keys path and "
                    f"tasks, got {short_repr(sorted(map(str, policy)))}"
                )
            seed_tasks[label] = policy["tasks"]
            policy = policy["path"]
        out[label] = _policy_path(policy, f"{where}: checkpoint of {short_repr(label)}", per_task=False)
    return out, seed_tasks


def _policy_path(value, where: str, per_task: bool) -> str:
    """One policy as written: an expert name or a checkpoint folder. A training seed's path may hold the one
    field TASK_FIELD (one checkpoint per task); a folder already named per task holds none."""
    if not isinstance(value, str) or not value:
        raise GridError(f"{where} must be a path{'' if per_task else ' or an expert name'}, got "
                        f"{short_repr(value)}")
    if per_task and set("{}") & set(value):
        raise GridError(f"{where}: a checkpoint named per task holds no field")
    if set("{}") & set(value.replace(TASK_FIELD, "")):
        raise GridError(f"{where}: the only field a checkpoint path may hold is {TASK_FIELD}")
    return value


def check_policy(policy: str, where: str) -> None:
    """An expert name, or a folder holding a LeRobot checkpoint (config.json); else a `GridError` naming
    it."""
    from lerobot_bavo.eval.rollout import EXPERT_POLICIES

    if policy in EXPERT_POLICIES:
        return
    path = Path(policy)
    try:
        exists, has_config = path.exists(), (path / "config.json").is_file()
    except OSError as e:  # e.g. a name too long for the file system
        raise GridError(
            f"{where}: checkpoint {short_repr(policy)} cannot be looked up ({e.strerror})"
        ) from None
    if not exists:
        raise GridError(
            f"{where}: checkpoint {short_repr(policy)} not found ({path.resolve()}; relative paths are "
            f"resolved against the current directory); or use {' / '.join(EXPERT_POLICIES)}"
        )
    if not has_config:
        raise GridError(
            f"{where}: {short_repr(policy)} is not a LeRobot checkpoint folder (no config.json in "
            f"{path.resolve()})"
        )


def parse_grid(data, source: str = "grid") -> Grid:
    """Validate a grid (the loaded YAML) and fill its defaults; every error names `source` and the key."""
    from lerobot_bavo.envs.conditions import CONDITIONS
    from lerobot_bavo.envs.tasks import TASKS

    if not isinstance(data, dict):
        raise GridError(
            f"{source}: a grid file is a mapping with keys {', '.join(TOP_KEYS)}, got {type(data).__name__}"
        )
    unknown = sorted(set(map(str, data)) - set(TOP_KEYS))
    if unknown:
        raise GridError(
            f"{source}: unknown key {short_repr(unknown)[1:-1]}; a grid file has {', '.join(TOP_KEYS)}"
        )
    tasks = _names(data.get("tasks", list(TASKS)), "tasks", list(TASKS), f"{source}: tasks")
    conditions = _names(data.get("conditions", list(DEFAULT_CONDITIONS)), "conditions", list(CONDITIONS),
                        f"{source}: conditions")
    numbers = {}
    for key, default, low in (("episodes", 20, 1), ("seed", 1000, 0)):
        v = data.get(key, default)
        if not isinstance(v, int) or isinstance(v, bool) or v < low:
            raise GridError(f"{source}: {key} must be an integer >= {low}, got {short_repr(v)}")
        numbers[key] = v
    raw = data.get("methods")
    if not isinstance(raw, dict) or not raw:
        raise GridError(f"{source}: methods must be a non-empty mapping name -> policy or checkpoints, got "
                        f"{short_repr(raw)}")
    methods = []
    for name, spec in raw.items():
        name = str(name)
        where = f"{source}: methods.{short_repr(name)[1:-1]}"
        if not _NAME.match(name):
            raise GridError(f"{where}: a method name must be a plain name (letters, digits, _ . + -)")
        if isinstance(spec, dict):
            unknown = sorted(set(map(str, spec)) - set(METHOD_KEYS))
            if unknown:
                raise GridError(f"{where}: unknown key {short_repr(unknown)[1:-1]}; a method has "
                                f"{', '.join(METHOD_KEYS)}")
            if "checkpoints" not in spec:
                raise GridError(
                    f"{where}: missing key 'checkpoints' (one policy, or one checkpoint per training seed)"
                )
            m_tasks = _names(
                spec.get("tasks", list(tasks)), "tasks", list(tasks), f"{where}.tasks (of the grid's)"
            )
            m_conds = _names(spec.get("conditions", list(conditions)), "conditions", list(conditions),
                             f"{where}.conditions (of the grid's)")
            checkpoints, raw_seed_tasks = _checkpoints(spec["checkpoints"], f"{where}.checkpoints")
        else:
            m_tasks, m_conds = tasks, conditions
            checkpoints, raw_seed_tasks = _checkpoints(spec, where)
        seed_tasks = {}
        for label, value in raw_seed_tasks.items():
            chosen = _names(value, "tasks", list(m_tasks),
                            f"{where}.checkpoints.{label}.tasks (of the method's)")
            seed_tasks[label] = tuple(t for t in m_tasks if t in chosen)
        method = Method(name, checkpoints, m_tasks, m_conds, seed_tasks)
        for label, policy, run_tasks, _ in method.runs(Path(".")):
            of_task = f", task {run_tasks[0]}" if method.per_task else ""
            check_policy(policy, f"{where} (training seed {label}{of_task})")
        methods.append(method)
    return Grid(tasks, conditions, numbers["episodes"], numbers["seed"], tuple(methods))


def _no_aliases_loader():
    """PyYAML's safe loader refusing anchors and aliases (`&name`, `*name`).

    Why: aliases let a few hundred bytes stand for a structure of billions of items (a "billion laughs"
    under `tasks:` took many seconds and gigabytes, in the error message's repr). A grid file never needs
    them."""
    import yaml

    class NoAliasesLoader(yaml.SafeLoader):
        def compose_node(self, parent, index):
            event = self.peek_event()
            if isinstance(event, yaml.AliasEvent) or getattr(event, "anchor", None) is not None:
                raise yaml.composer.ComposerError(
                    None,
                    None,
                    "anchors and aliases (&name, *name) are not allowed in a grid file; write the values out",
                    event.start_mark,
                )
            return super().compose_node(parent, index)

    return NoAliasesLoader


def load_grid(path: str | Path) -> Grid:
    """Read and check a grid file: at most `MAX_GRID_BYTES` of UTF-8 YAML without anchors or aliases; every
    problem is a `GridError` naming the file."""
    import yaml

    path = Path(path)
    try:
        with open(path, "rb") as fh:
            raw = fh.read(MAX_GRID_BYTES + 1)
    except OSError as e:
        raise GridError(f"grid file {path}: cannot read it ({e.strerror})") from None
    if len(raw) > MAX_GRID_BYTES:
        raise GridError(
            f"grid file {path} is over {MAX_GRID_BYTES} bytes; a grid file lists a few methods and "
            "checkpoints"
        )
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as e:
        raise GridError(f"grid file {path} is not UTF-8 text ({e.reason} at byte {e.start})") from None
    try:
        data = yaml.load(text, Loader=_no_aliases_loader())  # noqa: S506 (a safe loader)
    except yaml.YAMLError as e:
        raise GridError(f"grid file {path} is not valid YAML: {e}") from None
    except (RecursionError, ValueError) as e:  # nesting past Python's stack; an integer of > 4300 digits
        raise GridError(f"grid file {path} cannot be read: {short_repr(str(e))}") from None
    return parse_grid(data, f"grid file {path}")


# ------------------------------------------------------------------ aggregation (pure)
def mean_std(values: list[float | None]) -> tuple[float | None, float | None]:
    """Mean and sample standard deviation (n - 1) over training seeds. (None, None) when any value is None (a
    metric that does not exist for that cell, such as CVG outside Random-time) or there are none; std is None
    for a single value."""
    if not values or any(v is None for v in values):
        return None, None
    n = len(values)
    mean = sum(values) / n
    if n < 2:
        return mean, None
    return mean, math.sqrt(sum((v - mean) ** 2 for v in values) / (n - 1))


def aggregate_seeds(per_seed: dict[str, dict]) -> dict:
    """One cell over training seeds: `per_seed` label -> {sr, tps, cvg, joint, ...} -> the same plus mean /
    std."""
    mean, std = {}, {}
    for key in METRICS:
        mean[key], std[key] = mean_std([cell.get(key) for cell in per_seed.values()])
    return {"seeds": per_seed, "mean": mean, "std": std, "n_seeds": len(per_seed)}


def mean_over_tasks(cells: list[dict]) -> dict:
    """The macro average of one training seed's cells of one condition (None for a metric missing in any)."""
    return {key: mean_std([c.get(key) for c in cells])[0] for key in METRICS}


def method_results(method: Method, runs: dict[str, dict]) -> dict:
    """A method's grid cells from its runs' results.json (`runs` label -> results)."""
    cells, over_tasks = {}, {}
    for task in method.tasks:
        for cond in method.conditions:
            key = f"{task}/{cond}"
            per_seed = {label: {k: v for k, v in runs[label]["cells"][key].items() if k != "episodes"}
                        for label in method.labels_of(task)}
            cells[key] = aggregate_seeds(per_seed)
    complete = [label for label in method.checkpoints if method.tasks_of(label) == method.tasks]
    if len(method.tasks) > 1 and complete:  # the macro mean: over the seeds that have every task
        for cond in method.conditions:
            over_tasks[cond] = aggregate_seeds(
                {
                    label: mean_over_tasks([runs[label]["cells"][f"{t}/{cond}"] for t in method.tasks])
                    for label in complete
                }
            )
    return {**method.as_dict(), "cells": cells, "mean_over_tasks": over_tasks}


# ------------------------------------------------------------------ report
def fmt_mean_std(mean: float | None, std: float | None) -> str:
    if mean is None:
        return "-"
    return f"{mean:.1f}" if std is None else f"{mean:.1f} ± {std:.1f}"


def _columns(results: dict) -> list[tuple[str, str]]:
    """(condition, metric) columns of the table: each `SHOWN` metric per condition where any cell has a value
    (SR and TPS always, CVG for Random-time)."""
    cols = []
    for cond in results["conditions"]:
        for metric in SHOWN:
            if any(cell["mean"][metric] is not None for m in results["methods"].values()
                   for key, cell in m["cells"].items() if key.endswith(f"/{cond}")):
                cols.append((cond, metric))
    return cols


def grid_markdown(results: dict) -> str:
    names = {k: label.split(" (")[0] for k, label in CELL_METRICS.items()}  # "SR (%)" -> "SR"
    cols = _columns(results)
    last_seed = results["seed"] + results["episodes"] - 1
    lines = [
        (
            f"{results['episodes']} episodes per cell (seeds {results['seed']}-{last_seed}); values are mean "
            "± std "
            "over training seeds (sample std; one value where a method has one training seed); SR, TPS in %, "
            "CVG in "
            "pp (Random-time only)."
        ),
        "",
    ]
    lines.append("| method | seeds | task | " + " | ".join(f"{c} {names[m]}" for c, m in cols) + " |")
    lines.append("|---|---|---|" + "---|" * len(cols))
    for name, m in results["methods"].items():
        rows = [(t, {c: m["cells"].get(f"{t}/{c}") for c in results["conditions"]}) for t in m["tasks"]]
        if m["mean_over_tasks"]:
            rows.append((f"**mean of {len(m['tasks'])}**", m["mean_over_tasks"]))
        for label, by_cond in rows:
            vals = [
                fmt_mean_std(by_cond[c]["mean"][k], by_cond[c]["std"][k]) if by_cond.get(c) else "-"
                for c, k in cols
            ]
            n_seeds = max((by_cond[c]["n_seeds"] for c in results["conditions"] if by_cond.get(c)), default=0)
            lines.append(f"| {name} | {n_seeds} | {label} | " + " | ".join(vals) + " |")
    return "\n".join(lines) + "\n"


def grid_plot(results: dict) -> bytes:
    """SR / TPS / CVG (rows) per condition, one column per task plus the mean over tasks, a bar per method, as
    PNG bytes (`run_grid` writes them with the other results, all or none)."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tasks = list(results["tasks"])
    panels = tasks + (["mean over tasks"] if len(tasks) > 1 else [])
    methods = list(results["methods"])
    conds = list(results["conditions"])
    fig, axes = plt.subplots(
        len(SHOWN), len(panels), figsize=(max(6.0, 2.6 * len(panels) + 1), 7.5), squeeze=False, sharey="row"
    )
    width = 0.8 / max(1, len(methods))
    for col, panel in enumerate(panels):
        for row, (metric, label) in enumerate((k, CELL_METRICS[k]) for k in SHOWN):
            ax = axes[row][col]
            for i, name in enumerate(methods):
                m = results["methods"][name]
                xs, ys, es = [], [], []
                for j, cond in enumerate(conds):
                    if panel == "mean over tasks":
                        cell = m["mean_over_tasks"].get(cond) if len(m["tasks"]) == len(tasks) else None
                    else:
                        cell = m["cells"].get(f"{panel}/{cond}")
                    if cell is None or cell["mean"][metric] is None:
                        continue
                    xs.append(j - 0.4 + width * (i + 0.5))
                    ys.append(cell["mean"][metric])
                    es.append(cell["std"][metric] or 0.0)
                ax.bar(
                    xs,
                    ys,
                    width,
                    yerr=es,
                    capsize=2,
                    color=f"C{i}",
                    label=name if (row, col) == (0, 0) else None,
                )
            ax.set_xticks(range(len(conds)), conds)
            ax.set_ylim(0, 105)
            if col == 0:
                ax.set_ylabel(label)
            if row == 0:
                ax.set_title(panel, fontsize=10)
    fig.legend(loc="lower center", ncol=max(1, len(methods)), frameon=False)
    fig.suptitle(f"BAVO-Bench grid: mean ± std over training seeds\n{results['episodes']} episodes per cell "
                 f"(seeds {results['seed']}-{results['seed'] + results['episodes'] - 1})", fontsize=11)
    fig.tight_layout(rect=(0, 0.05, 1, 0.96))
    png = io.BytesIO()
    fig.savefig(png, format="png", dpi=110)
    plt.close(fig)
    return png.getvalue()


# ------------------------------------------------------------------ running it
def run_dir(output_dir: Path, method: str, label: str) -> Path:
    return Path(output_dir) / "runs" / method / label


def pending_episodes(grid: Grid, output_dir: Path) -> int:
    """Episodes of the grid not yet in any run's episodes.jsonl (what a run now would do)."""
    from lerobot_bavo.eval.run import read_episode_log

    missing = 0
    for m in grid.methods:
        for _, _, tasks, folder in m.runs(output_dir):
            done = read_episode_log(folder / "episodes.jsonl")
            missing += sum((t, c, grid.seed + i) not in done for t in tasks for c in m.conditions
                           for i in range(grid.episodes))
    return missing


def run_grid(grid: Grid, output_dir: Path, workers: int = 1, videos: int = 0, executor: str = "local",
             ray_address: str | None = None, trust_remote_code: bool = False) -> dict:
    """Run (or resume) every (method, training seed) of the grid, then write results.json / .md / .png."""
    import contextlib

    from lerobot_bavo.eval.run import claim_output_dir, evaluate, write_results

    output_dir = Path(output_dir)
    lock = claim_output_dir(output_dir, "bavo-eval --grid")
    try:
        write_results({output_dir / "grid.json": json.dumps(grid.as_dict(), indent=1)})
        pending = pending_episodes(grid, output_dir)
        total = sum(len(tasks) * len(m.conditions) * grid.episodes
                    for m in grid.methods for _, _, tasks, _ in m.runs(output_dir))
        n_runs = sum(len(m.runs(output_dir)) for m in grid.methods)
        print(f"bavo-eval --grid: {total} episodes in {n_runs} runs; "
              f"{total - pending} finished, {pending} to run")
        with contextlib.ExitStack() as stack:
            if executor == "ray" and pending:  # one Ray for the whole grid (each run's RayPool then uses it)
                from lerobot_bavo.runtime.ray_pool import RayPool

                stack.enter_context(RayPool(workers, address=ray_address))
            runs: dict[str, dict[str, dict]] = {}
            for m in grid.methods:
                runs[m.name] = {label: {"cells": {}} for label in m.checkpoints}
                for label, policy, tasks, folder in m.runs(output_dir):
                    print(f"bavo-eval --grid: method {m.name}, training seed {label}: {policy}")
                    result = evaluate(
                        policy, list(tasks), list(m.conditions), grid.episodes, grid.seed,
                        folder, workers=workers, videos=videos,
                        trust_remote_code=trust_remote_code, executor=executor, ray_address=ray_address)
                    runs[m.name][label]["cells"].update(result["cells"])
        results = {"version": GRID_VERSION, "tasks": list(grid.tasks), "conditions": list(grid.conditions),
                   "episodes": grid.episodes, "seed": grid.seed,
                   "methods": {m.name: method_results(m, runs[m.name]) for m in grid.methods}}
        for m in grid.methods:
            results["methods"][m.name]["runs"] = {
                label if not m.per_task else f"{label}/{tasks[0]}": str(folder)
                for label, _, tasks, folder in m.runs(Path("."))}
        table = grid_markdown(results)
        write_results(
            {
                output_dir / "results.json": json.dumps(results, indent=1),
                output_dir / "results.md": table,
                output_dir / "results.png": grid_plot(results),
            }
        )
        print(table)
        return results
    finally:
        lock.close()
