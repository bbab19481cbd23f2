"""Wall time of a whole `bavo-collect` run for each task (100 Stage episodes, start-up included).

Runs the real command (`bavo-collect --task T --condition stage --episodes N --workers 2`) once per task, one
after the other, each into a fresh folder, and prints per task: wall time from launch to exit (process start,
imports, workers, every episode, the last write), episodes kept and discarded, frames, and bytes per frame
with and without the video. Run it on an otherwise idle machine: the wall time is the figure.

    python benchmarks/collect_all_tasks.py [--episodes 100] [--tasks cube_handoff,...] [--output-dir DIR]
    [--keep]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
TASKS = ("cube_handoff", "block_stacking", "drawer_stowing", "slide_retrieval", "dustpan_sweeping")


def folder_bytes(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file()) if path.exists() else 0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--episodes", type=int, default=100)
    ap.add_argument("--tasks", default=",".join(TASKS))
    ap.add_argument("--condition", default="stage")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument(
        "--output-dir", type=Path, default=None, help="where the datasets go (default: a temporary folder)"
    )
    ap.add_argument("--keep", action="store_true", help="keep the datasets")
    args = ap.parse_args()
    out = args.output_dir or Path(tempfile.mkdtemp(prefix="bavo_collect_all_"))
    exe = Path(sys.executable).with_name("bavo-collect")
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", HF_HUB_OFFLINE="1",
               MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"))
    rows = []
    for task in args.tasks.split(","):
        root = out / task
        shutil.rmtree(root, ignore_errors=True)
        cmd = [str(exe), "--task", task, "--condition", args.condition, "--episodes", str(args.episodes),
               "--repo-id", f"bench/{task}", "--root", str(root), "--workers", str(args.workers)]
        load = os.getloadavg()[0]
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, env=env, capture_output=True, text=True, cwd=REPO)
        wall = time.perf_counter() - t0
        if proc.returncode != 0:
            raise SystemExit(f"{task} failed:\n{proc.stderr[-3000:]}")
        info = json.loads((root / "meta" / "info.json").read_text())
        record = json.loads((root / "meta" / "bavo_collection.json").read_text())
        frames = info["total_frames"]
        video = folder_bytes(root / "videos")
        rest = folder_bytes(root / "data") + folder_bytes(root / "meta")
        rows.append({"task": task, "wall_s": round(wall, 1), "episodes": info["total_episodes"],
                     "discarded": len(record.get("discarded", [])), "frames": frames,
                     "kb_per_frame_without_video": round(rest / frames / 1024, 2),
                     "kb_per_frame_video": round(video / frames / 1024, 2), "load_before": round(load, 2)})
        r = rows[-1]
        print(
            f"{task:18s} {wall / 60:5.1f} min ({wall:6.1f} s)  {r['episodes']} kept, {r['discarded']} "
            "discarded, "
            f"{frames} frames, {r['kb_per_frame_without_video']:.1f} KB/frame without video + "
            f"{r['kb_per_frame_video']:.1f} KB video; load before {load:.2f}",
            flush=True,
        )
        if not args.keep:
            shutil.rmtree(root, ignore_errors=True)
    print(
        "\n| task | wall (min) | episodes kept / discarded | frames | KB/frame without video | video "
        "KB/frame |"
    )
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['task']} | {r['wall_s'] / 60:.1f} | {r['episodes']} / {r['discarded']} | {r['frames']} | "
            f"{r['kb_per_frame_without_video']:.1f} | {r['kb_per_frame_video']:.1f} |"
        )
    print(json.dumps(rows))
    if args.output_dir is None and not args.keep:
        shutil.rmtree(out, ignore_errors=True)


if __name__ == "__main__":
    main()
