"""Plot and tabulate Stage SR / TPS against training samples from bavo-eval results of checkpoints.

Each argument is LABEL[@SEED]:STEP:BATCH:RESULTS_JSON (a checkpoint of the run LABEL, training seed SEED,
after STEP optimiser steps of BATCH samples, and the results.json bavo-eval wrote for it). Runs of the same
LABEL with several training seeds at one budget are drawn as their mean (line) and each seed (dots), and
tabulated as mean ± std over seeds, as the paper reports. Writes a PNG (SR and TPS against samples, log x
axis, the paper's 6.4 M samples marked) and prints a Markdown table.

With --extrapolate, a straight line in log10(samples) is fitted to each policy's mean TPS and SR and drawn
dashed from its largest measured budget to the paper's 6.4 M samples, printed in a separate table and labelled
"extrapolation" everywhere: it is a guess from a few CPU-scale points, not a measurement.

    python scripts/budget_plot.py --output docs/results/budget_cube_handoff.png --extrapolate \\
        afar@s1000:1000:64:outputs/eval/afar_s1000_001000/results.json ...
"""

from __future__ import annotations

import argparse
import json
import math
from collections import defaultdict
from pathlib import Path

PAPER_SAMPLES = 100_000 * 64


def log_linear_fit(xs: list[float], ys: list[float]) -> tuple[float, float]:
    """Least-squares (a, b) of y = a + b * log10(x); b = 0 when fewer than two distinct budgets."""
    lx = [math.log10(x) for x in xs]
    mx, my = sum(lx) / len(lx), sum(ys) / len(ys)
    var = sum((v - mx) ** 2 for v in lx)
    b = sum((v - mx) * (y - my) for v, y in zip(lx, ys)) / var if var > 0 else 0.0
    return my - b * mx, b


def mean_std(values: list[float]) -> tuple[float, float]:
    m = sum(values) / len(values)
    return m, (sum((v - m) ** 2 for v in values) / (len(values) - 1)) ** 0.5 if len(values) > 1 else 0.0


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("points", nargs="+", help="LABEL[@SEED]:STEP:BATCH:RESULTS_JSON")
    p.add_argument("--condition", default="stage")
    p.add_argument("--task", default="cube_handoff")
    p.add_argument("--output", type=Path, required=True)
    p.add_argument(
        "--extrapolate",
        action="store_true",
        help="draw and print a log-linear extrapolation to the paper's 6.4 M samples (labelled as such)",
    )
    args = p.parse_args()
    # series[label][samples] = list of (seed, sr, tps, n_episodes, step, batch)
    series: dict[str, dict[int, list[tuple]]] = defaultdict(lambda: defaultdict(list))
    for spec in args.points:
        label, step, batch, path = spec.split(":", 3)
        label, _, seed = label.partition("@")
        cell = json.loads(Path(path).read_text())["cells"][f"{args.task}/{args.condition}"]
        samples = int(step) * int(batch)
        series[label][samples].append(
            (seed or "-", cell["sr"], cell["tps"], cell["n_episodes"], int(step), int(batch))
        )
    c = args.condition
    print(
        f"| policy | samples | steps x batch | training seeds | {c} SR (%) | {c} TPS (%) | episodes per seed "
        "|"
    )
    print("|---|---|---|---|---|---|---|")
    means: dict[str, list[tuple[int, float, float]]] = {}
    for label, budgets in series.items():
        means[label] = []
        for samples in sorted(budgets):
            runs = budgets[samples]
            sr, sr_sd = mean_std([r[1] for r in runs])
            tps, tps_sd = mean_std([r[2] for r in runs])
            means[label].append((samples, sr, tps))
            pm = (lambda m, s: f"{m:.1f} ± {s:.1f}") if len(runs) > 1 else (lambda m, s: f"{m:.1f}")
            print(
                f"| {label} | {samples:,} | {runs[0][4]} x {runs[0][5]} | {', '.join(r[0] for r in runs)} | "
                f"{pm(sr, sr_sd)} | {pm(tps, tps_sd)} | {'/'.join(str(r[3]) for r in runs)} |"
            )
    fits = {}
    if args.extrapolate:
        print(
            f"\n| policy | extrapolation to {PAPER_SAMPLES:,} samples (log-linear fit, NOT measured) | {c} "
            "SR (%) | "
            f"{c} TPS (%) |\n|---|---|---|---|"
        )
        for label, pts in means.items():
            xs = [q[0] for q in pts]
            fits[label] = [log_linear_fit(xs, [q[i] for q in pts]) for i in (1, 2)]
            guess = [min(100.0, max(0.0, a + b * math.log10(PAPER_SAMPLES))) for a, b in fits[label]]
            print(
                f"| {label} | fit over {len(xs)} budgets ({xs[0]:,} to {xs[-1]:,}) | {guess[0]:.0f} | "
                f"{guess[1]:.0f} |"
            )

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    for ax, idx, name in ((axes[0], 1, "SR"), (axes[1], 2, "TPS")):
        for k, (label, pts) in enumerate(means.items()):
            color = f"C{k}"
            ax.plot([q[0] for q in pts], [q[idx] for q in pts], "o-", color=color, label=label)
            for samples, runs in series[label].items():
                if len(runs) > 1:
                    ax.plot([samples] * len(runs), [r[idx] for r in runs], "x", color=color, alpha=0.7)
            if label in fits:
                a, b = fits[label][idx - 1]
                xs = [pts[-1][0], PAPER_SAMPLES]
                ax.plot(
                    xs,
                    [min(100.0, max(0.0, a + b * math.log10(x))) for x in xs],
                    "--",
                    color=color,
                    alpha=0.6,
                    label=f"{label}: extrapolation (not measured)",
                )
        ax.axvline(PAPER_SAMPLES, color="grey", ls="--")
        ax.text(PAPER_SAMPLES, 50, " paper's budget\n (6.4 M; not run)", color="grey", fontsize=8)
        ax.set_xscale("log")
        ax.set_xlim(3e4, 1.2e7)
        ax.set_ylim(-3, 103)
        ax.set_xlabel("training samples (steps x batch)")
        ax.set_ylabel(f"{args.condition} {name} (%)")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle(
        f"{args.task}, {args.condition} occlusion: checkpoints of CPU runs (cosine schedule over the "
        "largest budget; x = single training seeds)",
        fontsize=9,
    )
    fig.tight_layout()
    args.output.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.output, dpi=120)
    print(f"\nwrote {args.output}")


if __name__ == "__main__":
    main()
