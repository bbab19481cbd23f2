"""Keep a results grid's evaluation runs in the repository, so that a later session on a fresh machine (where
`outputs/` is gone) re-runs only the cells that were never evaluated.

    python scripts/grid_runs.py save      # [--output-dir outputs/eval/grid_table] [--archive DIR]
    python scripts/grid_runs.py restore   # the same options; DIR defaults to docs/results/grid_table
    bavo-eval --grid configs/grid_table.yaml --output-dir outputs/eval/grid_table --workers 2   # the rest

`save` copies every run under `<output-dir>/runs/` that has episodes (`runs/<method>/<label>[/<task>]/`, the
layout `bavo-eval --grid` and `scripts/train_task.sh recipe` write) to the same path under the archive: its
`run.json` (seed, checkpoint digest, point frame), its `results.md`, and its per-episode log `episodes.jsonl`
gzipped (~110 KB per 120 policy episodes; a fixed gzip header, so an unchanged log gives the same bytes, and
an archived log whose records are unchanged is left as it is).
The log is the measurement itself: every SR, TPS, CVG and Joint of the run is computed from it.

`restore` writes every archived run back into `<output-dir>/runs/...` where that run has no episode log yet.
`bavo-eval` resumes a run only when its `run.json` names the same seed, checkpoint digest (sha256 of the
weights and config) and point frame, so restored episodes count only for the very checkpoint they were
measured with: a changed checkpoint is refused with a message, never mixed in.
"""

from __future__ import annotations

import argparse
import gzip
import json
import shutil
from pathlib import Path

from lerobot_bavo.eval.run import read_episode_records

ARCHIVE = Path("docs/results/grid_table")
FILES = ("run.json", "results.md")
LOG, PACKED = "episodes.jsonl", "episodes.jsonl.gz"


def run_folders(root: Path, marker: str) -> list[Path]:
    """The run folders under `root/runs` (those holding `marker`), relative to `root`, sorted."""
    return sorted(p.parent.relative_to(root) for p in (root / "runs").rglob(marker))


def gzip_bytes(data: bytes) -> bytes:
    return gzip.compress(data, compresslevel=9, mtime=0)


def save(output_dir: Path, archive: Path) -> int:
    saved = 0
    for rel in run_folders(output_dir, LOG):
        folder, dest = output_dir / rel, archive / rel
        log = folder / LOG
        n = len(read_episode_records(log))  # read-only: a run may still be writing
        dest.mkdir(parents=True, exist_ok=True)
        for name in FILES:
            if (folder / name).is_file():
                shutil.copyfile(folder / name, dest / name)
        # complete records only: a run still being written may end in a line cut short, which bavo-eval
        # would otherwise append its next record to after a restore
        data = log.read_bytes()
        data = data[: data.rfind(b"\n") + 1]
        packed = dest / PACKED
        # an archived log with the same records stays as it is, whatever compressor wrote it (older runs
        # were packed with other gzip settings): rewriting it would only churn bytes in the repository
        if not (packed.is_file() and gzip.decompress(packed.read_bytes()) == data):
            packed.write_bytes(gzip_bytes(data))
        print(f"saved {n:4d} episodes: {folder} -> {dest}")
        saved += 1
    return saved


def restore(output_dir: Path, archive: Path) -> int:
    restored = 0
    for rel in run_folders(archive, PACKED):
        src, folder = archive / rel, output_dir / rel
        packed = src / PACKED
        if (folder / LOG).exists():
            print(f"kept     {folder}: it has an episode log already")
            continue
        folder.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(src / "run.json", folder / "run.json")
        (folder / LOG).write_bytes(gzip.decompress(packed.read_bytes()))
        n = len(read_episode_records(folder / LOG))
        print(f"restored {n:4d} episodes: {src} -> {folder}")
        restored += 1
    return restored


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("action", choices=("save", "restore"))
    parser.add_argument("--output-dir", type=Path, default=Path("outputs/eval/grid_table"))
    parser.add_argument("--archive", type=Path, default=ARCHIVE,
                        help="the committed runs (default %(default)s)")
    args = parser.parse_args(argv)
    if args.action == "save":
        n = save(args.output_dir, args.archive)
    else:
        n = restore(args.output_dir, args.archive)
    print(json.dumps({"action": args.action, "runs": n}))


if __name__ == "__main__":
    main()
