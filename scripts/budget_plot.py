"""Plot and tabulate Stage SR / TPS against training samples from bavo-eval results of checkpoints.

Each argument is LABEL:STEP:BATCH:RESULTS_JSON (a checkpoint of the run LABEL after STEP optimiser steps of
BATCH samples, and the results.json bavo-eval wrote for it). Writes a PNG (SR and TPS against samples, log
x axis, the paper's 6.4 M samples marked) and prints a Markdown table. Extrapolations are not drawn as data.

    python scripts/budget_plot.py --output docs/results/budget_cube_handoff.png \\
        afar:1000:64:outputs/eval/afar_s1000_001000/results.json ...
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path

PAPER_SAMPLES = 100_000 * 64


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("points", nargs="+", help="LABEL:STEP:BATCH:RESULTS_JSON")
    p.add_argument("--condition", default="stage")
    p.add_argument("--task", default="cube_handoff")
    p.add_argument("--output", type=Path, required=True)
    args = p.parse_args()
    series: dict[str, list[tuple[int, float, float, int, int, int]]] = defaultdict(list)
    for spec in args.points:
        label, step, batch, path = spec.split(":", 3)
        cell = json.loads(Path(path).read_text())["cells"][f"{args.task}/{args.condition}"]
        series[label].append((int(step) * int(batch), cell["sr"], cell["tps"], cell["n_episodes"], int(step), int(batch)))
    print(f"| policy | samples | steps x batch | {args.condition} SR (%) | {args.condition} TPS (%) | episodes |")
    print("|---|---|---|---|---|---|")
    for label, pts in series.items():
        for samples, sr, tps, n, step, batch in sorted(pts):
            print(f"| {label} | {samples:,} | {step} x {batch} | {sr:.1f} | {tps:.1f} | {n} |")

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    for ax, idx, name in ((axes[0], 1, "SR"), (axes[1], 2, "TPS")):
        for label, pts in series.items():
            pts = sorted(pts)
            ax.plot([q[0] for q in pts], [q[idx] for q in pts], "o-", label=label)
        ax.axvline(PAPER_SAMPLES, color="grey", ls="--")
        ax.text(PAPER_SAMPLES, 50, " paper's budget\n (6.4 M; not run)", color="grey", fontsize=8)
        ax.set_xscale("log")
        ax.set_xlim(3e4, 1.2e7)
        ax.set_ylim(-3, 103)
        ax.set_xlabel("training samples (steps x batch)")
        ax.set_ylabel(f"{args.condition} {name} (%)")
        ax.grid(alpha=0.3)
    axes[0].legend()
    fig.suptitle(f"{args.task}, {args.condition} occlusion: checkpoints of one CPU run per policy "
                 "(cosine schedule over the largest budget)", fontsize=9)
    fig.tight_layout()
    args.output.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.output, dpi=120)
    print(f"\nwrote {args.output}")


if __name__ == "__main__":
    main()
