"""How much of the spread between training seeds is the evaluation's own sampling noise.

Why: the results on Cube Handoff are read as three-seed means of SR over 40 test episodes per seed, and the
seed-to-seed spread (a standard deviation of 4-14 points) is larger than every effect measured on the
400 + 200 data. Two things make that spread: the training seed (a different policy) and the 40 episodes
each policy is scored on (Binomial(40, p) / 40 has a standard deviation of sqrt(p (1 - p) / 40), 7.7 points
at p = 0.6). If the observed variance between seeds is about the binomial one, the training seed adds little
and the spread is the evaluation's: more episodes per seed, not more seeds, would sharpen a reading.

For every grid method with all of the wanted training seeds on the task, per condition: the mean SR p, the
observed variance of the per-seed SRs (n - 1 in the denominator) and the variance p (1 - p) / episodes that
binomial sampling alone gives; then, per condition, the ratio of their sums over the methods.

    python scripts/seed_spread.py --runs docs/results/grid_table/runs --task cube_handoff
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

from lerobot_bavo.eval.run import read_episode_records
from lerobot_bavo.metrics import success_rate

CONDITIONS = ("clean", "stage", "random")


def binomial_variance(rate: float, episodes: int) -> float:
    """Variance of an SR (a fraction) measured on `episodes` independent episodes of success rate `rate`."""
    if episodes < 1:
        raise ValueError(f"need at least one episode, got {episodes}")
    return rate * (1.0 - rate) / episodes


def seed_spread(rates: list[float], episodes: int) -> tuple[float, float, float]:
    """(mean, observed variance between seeds, binomial variance at the mean) of per-seed SRs (fractions)."""
    if len(rates) < 2:
        raise ValueError(f"need SRs of at least two training seeds, got {len(rates)}")
    mean = statistics.fmean(rates)
    return mean, statistics.variance(rates), binomial_variance(mean, episodes)


def seed_rates(method_dir: Path, seeds: list[str], task: str, condition: str,
               episodes: int) -> list[float] | None:
    """Per-seed SRs of one grid method's runs (`<method>/<seed>/<task>/episodes.jsonl[.gz]`); None when a seed
    has no log or a log does not hold exactly `episodes` episodes of the condition."""
    rates = []
    for seed in seeds:
        logs = sorted((method_dir / seed / task).glob("episodes.jsonl*"))
        if not logs:
            return None
        cell = [r for r in read_episode_records(logs[0]) if r["condition"] == condition]
        if len(cell) != episodes:
            return None
        rates.append(success_rate([r["success"] for r in cell]) / 100.0)
    return rates


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=Path, required=True,
                        help="a grid's runs folder (<method>/<seed>/<task>)")
    parser.add_argument("--task", required=True, help="the task whose runs are read, e.g. cube_handoff")
    parser.add_argument("--seeds", default="s1000,s1001,s1002", help="the training seeds' folder names")
    parser.add_argument("--episodes", type=int, default=40, help="episodes per condition and seed (40)")
    args = parser.parse_args(argv)
    if not args.runs.is_dir():
        sys.exit(f"--runs: no folder {args.runs}")
    seeds = [s for s in args.seeds.split(",") if s]
    print("| method | condition | mean SR % | SD between seeds | binomial SD |")
    print("|---|---|---|---|---|")
    sums = {c: [0.0, 0.0, 0] for c in CONDITIONS}
    for method_dir in sorted(p for p in args.runs.iterdir() if p.is_dir()):
        for condition in CONDITIONS:
            rates = seed_rates(method_dir, seeds, args.task, condition, args.episodes)
            if rates is None:
                continue
            mean, observed, binomial = seed_spread(rates, args.episodes)
            sums[condition][0] += observed
            sums[condition][1] += binomial
            sums[condition][2] += 1
            print(f"| {method_dir.name} | {condition} | {100 * mean:.1f} | {100 * observed ** 0.5:.1f} | "
                  f"{100 * binomial ** 0.5:.1f} |")
    print()
    for condition, (observed, binomial, n) in sums.items():
        if n == 0:
            print(f"{condition}: no method with all of {', '.join(seeds)}")
            continue
        ratio = observed / binomial if binomial > 0 else float("nan")
        print(f"{condition}: {n} methods; SD between seeds {100 * (observed / n) ** 0.5:.1f} points, "
              f"binomial {100 * (binomial / n) ** 0.5:.1f}; variance ratio {ratio:.2f}")


if __name__ == "__main__":
    main()
