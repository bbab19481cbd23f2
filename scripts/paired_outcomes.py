"""Paired success counts and exact McNemar p-values of two `bavo-eval` runs on the same episode seeds.

Why: the write-ups in docs/results/ compare checkpoints (another recipe, another schedule) evaluated on the
same test seeds; pairing the episodes by (task, condition, seed) and testing only the discordant ones is
sharper than comparing two SRs with their own intervals. Several `A=B` pairs (e.g. one per training seed)
are pooled: their discordant counts add up.

    python scripts/paired_outcomes.py \\
        outputs/eval/test_cube_sf_b2x_s1000/episodes.jsonl=docs/results/grid_table/runs/afar-self-filter/s1000/cube_handoff/episodes.jsonl.gz

A plan's gate on the pooled net change (A's successes minus B's): `--min-gain stage=12` asks for at least 12
more, `--max-loss clean=12` for at most 12 fewer; with any of them the exit status is 0 when every one is met
and 1 otherwise, and the last line says which.
"""

from __future__ import annotations

import argparse

from lerobot_bavo.eval.run import paired_episode_logs, read_episode_records
from lerobot_bavo.metrics import mcnemar_exact_p


def paired_counts(a: list[dict], b: list[dict]) -> dict[str, tuple[int, int, int, int]]:
    """Per condition (episodes in both runs, A's successes, won by A only, won by B only), the episodes
    matched on (task, condition, seed)."""
    b_by_key = {(r["task"], r["condition"], r["seed"]): bool(r["success"]) for r in b}
    counts: dict[str, list[int]] = {}
    for r in a:
        key = (r["task"], r["condition"], r["seed"])
        if key not in b_by_key:
            continue
        won_a, won_b = bool(r["success"]), b_by_key[key]
        c = counts.setdefault(r["condition"], [0, 0, 0, 0])
        c[0] += 1
        c[1] += won_a
        c[2] += won_a and not won_b
        c[3] += won_b and not won_a
    return {cond: tuple(c) for cond, c in counts.items()}


def condition_count(text: str) -> tuple[str, int]:
    """'stage=12' -> ('stage', 12), for the gate flags."""
    cond, sep, count = text.partition("=")
    if not sep or not cond or not count.isdigit():
        raise argparse.ArgumentTypeError(f"expected CONDITION=COUNT (e.g. stage=12), not {text!r}")
    return cond, int(count)


def gate_failures(pooled: dict[str, list[int]], min_gain: list[tuple[str, int]],
                  max_loss: list[tuple[str, int]]) -> list[str]:
    """The gate's unmet conditions, in words; the net change of a condition is A only - B only."""
    unmet = []
    for cond, need in min_gain:
        net = pooled[cond][2] - pooled[cond][3] if cond in pooled else None
        if net is None or net < need:
            unmet.append(f"{cond} net {net} < +{need}")
    for cond, most in max_loss:
        net = pooled[cond][2] - pooled[cond][3] if cond in pooled else None
        if net is None or net < -most:
            unmet.append(f"{cond} net {net} < -{most}")
    return unmet


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("pairs", nargs="+", metavar="A_LOG=B_LOG", type=paired_episode_logs,
                        help="two episode logs (episodes.jsonl or .jsonl.gz) of runs on the same seeds")
    parser.add_argument("--min-gain", type=condition_count, action="append", default=[],
                        metavar="CONDITION=N", help="gate: A wins at least N more episodes than B (net)")
    parser.add_argument("--max-loss", type=condition_count, action="append", default=[],
                        metavar="CONDITION=N", help="gate: A loses at most N episodes against B (net)")
    args = parser.parse_args(argv)
    pooled: dict[str, list[int]] = {}
    for a_path, b_path in args.pairs:
        counts = paired_counts(read_episode_records(a_path), read_episode_records(b_path))
        if not counts:
            parser.error(f"{a_path} and {b_path} share no (task, condition, seed) episode")
        for cond, c in counts.items():
            pooled[cond] = [x + y for x, y in zip(pooled.get(cond, [0, 0, 0, 0]), c, strict=True)]
    for cond, (n, wins_a, only_a, only_b) in sorted(pooled.items()):
        print(f"{cond}: {n} paired episodes, A won {wins_a}, B {wins_a - only_a + only_b}; "
              f"A only {only_a}, B only {only_b}; McNemar exact p = {mcnemar_exact_p(only_a, only_b):.3f}")
    if args.min_gain or args.max_loss:
        unmet = gate_failures(pooled, args.min_gain, args.max_loss)
        print("gate passed" if not unmet else "gate not passed: " + "; ".join(unmet))
        raise SystemExit(1 if unmet else 0)


if __name__ == "__main__":
    main()
