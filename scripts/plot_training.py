#!/usr/bin/env python
"""Plot loss curves from `lerobot-train` console logs (no wandb needed).

`lerobot-train` prints one line every `--log_freq` steps, e.g.

    INFO ... step:1K smpl:32K ep:75 epch:0.75 loss:0.412 grdn:0.9 lr:9.9e-05 ... loss_fm:0.31 loss_ct:0.10

Each value is the average over the last `log_freq` steps. The step counter is printed rounded
(`1K`), so the exact step of the i-th line is recovered as `(i + 1) * log_freq`, plus the step a
resumed run started from; a line whose rounded counter disagrees with that raises an error instead
of silently mislabeling the curve. Every `loss*` or `*_loss` key found is plotted (total, ManiFlow's flow and
consistency parts, A-FAR's relational terms), one panel per key, one line per run.

    python scripts/plot_training.py --log-freq 25 --output docs/results/training_cube_handoff.png \\
        maniflow=outputs/train/maniflow.log afar=outputs/train/afar.log act=outputs/train/act.log
"""

from __future__ import annotations

import argparse
import contextlib
import re
from pathlib import Path

_LINE = re.compile(r"step:(\S+) smpl:\S+ ep:\S+ epch:\S+ (.*)$")
_PAIR = re.compile(r"(\w+):(\S+)")
_SUFFIX = {"": 1, "K": 1_000, "M": 1_000_000}


def _rounded_step(text: str) -> tuple[float, float]:
    """The interval [lo, hi] a `format_big_number` step string (`950`, `2K`) can stand for.

    Python rounds half to even (`2500 -> "2K"`, `1500 -> "2K"`), so both ends are included."""
    match = re.fullmatch(r"(\d+)([KM]?)", text)
    if match is None:
        raise ValueError(f"unreadable step counter {text!r}")
    value, unit = int(match.group(1)), _SUFFIX[match.group(2)]
    if unit == 1:
        return value, value
    return (value - 0.5) * unit, (value + 0.5) * unit


def parse_log(path: Path, log_freq: int, start_step: int = 0) -> dict[str, list[tuple[int, float]]]:
    """{metric: [(step, value), ...]} for every numeric metric on the log's training lines."""
    series: dict[str, list[tuple[int, float]]] = {}
    index = 0
    # tqdm writes carriage returns into the same stream; split on them too.
    for raw in path.read_text(errors="replace").replace("\r", "\n").splitlines():
        match = _LINE.search(raw)
        if match is None:
            continue
        step = start_step + (index + 1) * log_freq
        lo, hi = _rounded_step(match.group(1))
        if not lo <= step <= hi:
            raise ValueError(
                f"{path}: line {index + 1} says step {match.group(1)} but log_freq={log_freq} and "
                f"start_step={start_step} put it at {step}; pass the run's --log_freq"
            )
        for key, value in _PAIR.findall(match.group(2)):
            with contextlib.suppress(ValueError):
                series.setdefault(key, []).append((step, float(value)))
        index += 1
    if not series:
        raise ValueError(f"{path}: no `lerobot-train` metric lines found")
    return series


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("runs", nargs="+", help="NAME=LOGFILE pairs, one per training run")
    parser.add_argument("--log-freq", type=int, required=True, help="the runs' --log_freq")
    parser.add_argument("--output", type=Path, required=True, help="PNG to write")
    parser.add_argument("--title", default="", help="figure title")
    args = parser.parse_args(argv)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = {}
    for spec in args.runs:
        name, sep, path = spec.partition("=")
        if not sep:
            parser.error(f"expected NAME=LOGFILE, got {spec!r}")
        runs[name] = parse_log(Path(path), args.log_freq)
    keys = sorted({k for s in runs.values() for k in s if k.startswith("loss") or k.endswith("_loss")},
                  key=lambda k: (k != "loss", k))
    cols = min(3, len(keys))
    rows = (len(keys) + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.2 * rows), squeeze=False)
    for ax, key in zip(axes.flat, keys):
        for i, (name, series) in enumerate(runs.items()):
            if key in series:  # one colour per run across panels, also where only some runs log the key
                steps, values = zip(*series[key])
                ax.plot(steps, values, label=name, lw=1.2, color=f"C{i}")
        ax.set_title(key)
        ax.set_xlabel("training step")
        ax.set_yscale("log")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    for ax in list(axes.flat)[len(keys):]:
        ax.axis("off")
    if args.title:
        fig.suptitle(args.title)
    fig.tight_layout()
    args.output.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.output, dpi=110)
    for name, series in runs.items():
        last = series["loss"][-1] if "loss" in series else None
        first = series["loss"][0] if "loss" in series else None
        print(f"{name}: {len(series.get('loss', []))} points, loss {first} -> {last}")
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
