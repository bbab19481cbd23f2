#!/usr/bin/env bash
# Issue 27's choice among the one-seed Cube Handoff variants of the 200 Stage + 200 Random-time data at peak lr
# 1e-3, on 80 more validation seeds (docs/results/learning_rate.md, "Plan: one variant chosen on 120 validation
# seeds"). Each candidate (training seed 1000, shipped under checkpoints/) runs Stage on seeds 1040-1119; the
# script then prints each one's Stage successes over those 80 episodes and over all 120 validation episodes
# (1000-1119, with its 1000-1039 log committed under docs/results/learning_rate/). No test seed takes part.
#
#   bash scripts/cube_variant_choice.sh            # ~3-4 min per candidate alone on the 2-core machine
#
# Run it again after a stop: bavo-eval resumes each evaluation from its last finished episode.
set -euo pipefail
cd "$(dirname "$0")/.."
WORKERS=${WORKERS:-2}
candidates="mixsr400sf mixs400r200sf mixsr400sfcw25 mixsr400sfodr mixsr400sfco25"
for c in $candidates; do
    OPENBLAS_NUM_THREADS=1 bavo-eval --policy "checkpoints/afar_cube_handoff_${c}_b2x_lr1e3" --tasks cube_handoff \
        --conditions stage --episodes 80 --seed 1040 --workers "$WORKERS" --videos 0 \
        --output-dir "outputs/eval/val2_afar_cube_handoff_${c}_b2x_lr1e3"
done
python - $candidates <<'PY'
import sys
from pathlib import Path

from lerobot_bavo.eval.run import condition_successes, read_episode_records

def stage_successes(path, seeds):
    wins, episodes = condition_successes(read_episode_records(Path(path)), "stage", seeds)
    if episodes != len(seeds):
        sys.exit(f"{path}: {episodes} Stage episodes on seeds {min(seeds)}-{max(seeds)}, expected {len(seeds)}")
    return wins

print("| candidate (seed 1000) | Stage, seeds 1000-1039 | Stage, seeds 1040-1119 | Stage, all 120 |")
print("|---|---|---|---|")
for c in sys.argv[1:]:
    first = stage_successes(f"docs/results/learning_rate/cube_handoff_afar_{c}_b2x_lr1e3_val.jsonl.gz",
                            set(range(1000, 1040)))
    more = stage_successes(f"outputs/eval/val2_afar_cube_handoff_{c}_b2x_lr1e3/episodes.jsonl", set(range(1040, 1120)))
    print(f"| {c} | {first} / 40 | {more} / 80 | {first + more} / 120 ({100 * (first + more) / 120:.1f} %) |")
PY
