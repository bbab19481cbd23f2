"""Collection throughput (episodes/min) and storage (bytes per frame) of `bavo-collect`.

Runs a small real collection (default: 6 Stage episodes of Cube Handoff, 2 workers, the default
240 x 320 image and 256 points) into a temporary folder and prints:
- wall time, episodes/min overall and in steady state (between the first and the last commit, so
  without the one-off start-up: process spawn, imports, first renderer), and the 100-episode time
  extrapolated as start-up + 100 / steady rate (an extrapolation, not a measurement);
- per-episode costs: simulation + expert + segmentation render in a worker, teacher targets,
  staging, and the main process's LeRobot write (parquet, stats, video encode), in wall time
  and in CPU time; the CPU time gives a contention-free estimate (other processes on a shared
  machine inflate the wall times);
- bytes per frame on disk with and without the video, and per parquet column.

Per-episode cost against episode index (the cost per episode must stay flat as the dataset
grows): the main process's write time of each episode (its `add_frame` calls and `save_episode`,
recorded by the collector in the run's `timings`), each writer session's open + finalize overhead,
and the wall time between commits per episode; printed in groups of 10 with the ratio of the last 10
to the first 10, and plotted with `--plot FILE.png`. A full 100-episode run:

    python benchmarks/collect_throughput.py --episodes 100 --commit-every 10 --plot
    docs/results/collect_cost.png

    python benchmarks/collect_throughput.py [--episodes 6] [--workers 2] [--task cube_handoff] [--keep]

Old against new worker path, side by side in one process (`--compare-paths N`): two recorders of the
same settings, one with the worker's per-frame privileged renders as they were before the
render cuts (`_legacy_privileged_view`: a segmentation pass that also reads depth back, the old id
decode), one as now; they record the same seeds in alternating order, and the benchmark prints CPU ms
per frame of each and their ratio (a ratio stays meaningful on a busy machine), checks that both give
identical privileged arrays, and projects the 100-episode wall time from the last idle-machine run.
No dataset is written:

    python benchmarks/collect_throughput.py --compare-paths 4 [--compare-steps 150]

Whole collections of this checkout against another commit, side by side: `benchmarks/collect_versions.py`.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("SVT_LOG", "1")


def folder_bytes(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file()) if path.exists() else 0


def column_bytes(root: Path) -> dict[str, int]:
    """Compressed bytes per parquet column over all data files."""
    import pyarrow.parquet as pq

    out: dict[str, int] = {}
    for p in sorted((root / "data").glob("*/*.parquet")):
        md = pq.ParquetFile(p).metadata
        for rg in range(md.num_row_groups):
            for c in range(md.num_columns):
                col = md.row_group(rg).column(c)
                name = col.path_in_schema.split(".list.")[0].replace(".list.element", "")
                out[name] = out.get(name, 0) + col.total_compressed_size
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--task", default="cube_handoff")
    ap.add_argument("--condition", default="stage")
    ap.add_argument("--episodes", type=int, default=6)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--commit-every", type=int, default=2)
    ap.add_argument(
        "--root", type=Path, default=None, help="dataset folder (default: a temporary one, removed)"
    )
    ap.add_argument("--keep", action="store_true", help="keep the temporary dataset")
    ap.add_argument("--plot", type=Path, default=None, help="write the per-episode cost curve to this PNG")
    ap.add_argument("--compare-paths", type=int, default=0, metavar="N",
                    help="instead of a collection: old vs new worker path on N seeds each, in one process")
    ap.add_argument(
        "--compare-steps", type=int, default=None, help="episode length limit for --compare-paths"
    )
    args = ap.parse_args()
    if args.compare_paths:
        compare_paths(args.task, args.condition, args.compare_paths, args.compare_steps)
        return

    import datasets

    datasets.disable_progress_bars()
    import lerobot_bavo.datasets.collect as C
    from lerobot_bavo.datasets.video_codec import quiet_libav
    from lerobot_bavo.features import ObservationSettings

    quiet_libav()  # as `bavo-collect` does

    tmp = None
    root = args.root
    if root is None:
        tmp = Path(tempfile.mkdtemp(prefix="bavo_bench_"))
        root = tmp / "ds"
    load0 = os.getloadavg()
    t0 = time.perf_counter()
    summary = C.collect(
        C.CollectConfig(
            task=args.task,
            condition=args.condition,
            episodes=args.episodes,
            repo_id="bench/bavo_throughput",
            root=root,
            workers=args.workers,
            commit_every=args.commit_every,
            settings=ObservationSettings(),
            progress=False,
        )
    )
    wall = time.perf_counter() - t0
    load1 = os.getloadavg()

    # The collector's own record of each commit (`datasets.writer.WriterSession`): when it ended (seconds
    # since the run started), the CPU this process spent writing it (LeRobot's encoder threads included),
    # and its episodes; the workers' summaries give each episode's worker-side costs.
    from lerobot_bavo.datasets.collection_record import CollectionRecord

    commits = [{"t": t0 + c["end_s"], "cpu": c["cpu_s"], "seconds": c["busy_s"], "episodes": c["episodes"]}
               for c in CollectionRecord.load(root).runs[-1].get("timings", {}).get("commits", [])]
    eps = [e for c in commits for e in c["episodes"]]
    frames = summary["frames"]
    startup = commits[0]["t"] - t0 if commits else float("nan")
    n_after = sum(len(c["episodes"]) for c in commits[1:])
    steady = 60.0 * n_after / (commits[-1]["t"] - commits[0]["t"]) if len(commits) > 1 else float("nan")
    first_batch = len(commits[0]["episodes"]) if commits else 0
    # start-up + first batch at the steady rate already counted: extrapolate from the first commit on
    extrap_100 = (
        (commits[0]["t"] - t0) + (100 - first_batch) * 60.0 / steady if steady == steady else float("nan")
    )

    worker_cpu = sum(e.get("cpu_s", 0.0) for e in eps) / max(1, len(eps))
    write_cpu = sum(c["cpu"] for c in commits) / max(1, len(eps))
    cpu_per_ep = worker_cpu + write_cpu
    ideal_rate = 60.0 * min(args.workers, os.cpu_count() or 1) / cpu_per_ep  # all cores busy, no contention
    video = folder_bytes(root / "videos")
    data = folder_bytes(root / "data")
    meta = folder_bytes(root / "meta")
    cols = column_bytes(root)

    mean = lambda k: sum(e.get(k, 0.0) for e in eps) / max(1, len(eps))  # noqa: E731
    write_per_ep = sum(c["seconds"] for c in commits) / max(1, len(eps))
    print(
        f"\n== {args.episodes} x {args.task} / {args.condition}, {args.workers} workers, 240x320, 256 points "
        "=="
    )
    print(f"load average before / after: {load0[0]:.1f} / {load1[0]:.1f} (2 cores)")
    print(
        f"kept {summary['episodes']} episodes ({frames} frames, {frames / max(1, summary['episodes']):.0f} "
        "per episode), "
        f"discarded {summary['discarded']}"
    )
    print(f"wall {wall:.1f} s -> {60 * summary['episodes'] / wall:.2f} episodes/min overall; "
          f"start-up until the first commit {startup:.1f} s")
    print(f"steady state (first -> last commit): {steady:.2f} episodes/min")
    print(f"EXTRAPOLATED 100 episodes: {extrap_100 / 60:.1f} min (target < 15 min)")
    print(
        f"per episode: worker {mean('episode_s'):.1f} s (sim + expert + renders), teacher "
        f"{mean('teacher_s'):.2f} s, "
        f"staging {mean('stage_s'):.2f} s; main-process LeRobot write (parquet + stats + video encode) "
        f"{write_per_ep:.1f} s"
    )
    print(
        f"CPU per episode: worker {worker_cpu:.1f} s + main-process write {write_cpu:.1f} s = "
        f"{cpu_per_ep:.1f} s "
        f"-> on {min(args.workers, os.cpu_count() or 1)} otherwise idle cores at most {ideal_rate:.2f} "
        "episodes/min, "
        f"100 episodes in ~{100 / ideal_rate:.1f} min + start-up (CPU-bound estimate)"
    )
    print(
        f"bytes/frame: without video {(data + meta) / frames / 1024:.1f} KB (data {data / frames / 1024:.1f} "
        "KB, "
        f"meta {meta / frames / 1024:.2f} KB); video {video / frames / 1024:.2f} KB; total "
        f"{(data + meta + video) / frames / 1024:.1f} KB (target <= 40 KB without video)"
    )
    print("parquet bytes/frame per column:")
    for k, v in sorted(cols.items(), key=lambda kv: -kv[1]):
        print(f"  {k:<34} {v / frames:8.0f} B")
    print(
        json.dumps(
            {
                "wall_s": round(wall, 1),
                "startup_s": round(startup, 1),
                "episodes_per_min_overall": round(60 * summary["episodes"] / wall, 2),
                "episodes_per_min_steady": round(steady, 2),
                "extrapolated_100_min": round(extrap_100 / 60, 1),
                "kb_per_frame_without_video": round((data + meta) / frames / 1024, 2),
                "kb_per_frame_video": round(video / frames / 1024, 2),
                "worker_s_per_episode": round(mean("episode_s"), 2),
                "write_s_per_episode": round(write_per_ep, 2),
                "cpu_s_per_episode": round(cpu_per_ep, 2),
                "cpu_bound_100_min": round(100 / ideal_rate, 1),
            }
        )
    )
    per_episode_costs(root, commits, t0, args.plot)
    if tmp is not None and not args.keep:
        shutil.rmtree(tmp)
    elif tmp is not None:
        print(f"dataset kept at {root}")


# Last idle-machine measurement of a whole run (README): 100 Stage Cube Handoff episodes, 2 workers.
BASELINE_100_WALL_S = 578.5
BASELINE_WORKER_CPU_S, BASELINE_WRITER_CPU_S = 6.7, 3.4  # per episode


def _legacy_privileged_view(recorder):
    """The worker's privileged render before the render cuts, verbatim: one segmentation pass that reads
    depth back too (the observation render had already read the same z-buffer), and the old id decode."""
    import mujoco
    import numpy as np

    r, data = recorder._seg, recorder.env.data
    r._update(data, recorder._camera_id, None)
    r._scene.flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = 1
    r._scene.flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = 1
    try:
        mujoco.mjr_render(r._rect, r._scene, r._ctx)
        mujoco.mjr_readPixels(r._rgb, r._depth, r._rect, r._ctx)
    finally:
        r._scene.flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = 0
        r._scene.flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = 0
    rgb = np.flipud(r._rgb).astype(np.int32)
    segid = rgb[..., 0] + rgb[..., 1] * 256 + rgb[..., 2] * 65536 - 1
    ngeom = r._scene.ngeom
    lut = np.full(ngeom + 1, -1, dtype=np.int32)
    for i in range(ngeom):
        g = r._scene.geoms[i]
        if g.objtype == mujoco.mjtObj.mjOBJ_GEOM:
            lut[i] = g.objid
    seg = lut[np.where((segid >= 0) & (segid < ngeom), segid, ngeom)]
    near, far = r._near, r._far
    return seg, np.flipud(near / (1.0 - r._depth * (1.0 - near / far))).astype(np.float32)


def compare_paths(task: str, condition: str, episodes: int, steps: int | None) -> None:
    """CPU ms per recorded frame of the old and the new worker path, same seeds, alternating order."""
    import types

    import numpy as np

    from lerobot_bavo.datasets.recording import EpisodeRecorder
    from lerobot_bavo.features import ObservationSettings

    paths = {name: EpisodeRecorder(task, condition, ObservationSettings(), steps) for name in ("old", "new")}
    paths["old"]._privileged_view = types.MethodType(_legacy_privileged_view, paths["old"])
    for rec in paths.values():
        rec.record(10_000)  # warm-up: first renders, imports
    cpu = dict.fromkeys(paths, 0.0)
    frames = dict.fromkeys(paths, 0)
    identical = True
    for i in range(episodes):
        records = {}
        for name in (("old", "new") if i % 2 == 0 else ("new", "old")):
            c0 = time.process_time()  # the whole process: llvmpipe's render threads included
            records[name] = paths[name].record(i)
            cpu[name] += time.process_time() - c0
            frames[name] += records[name].length
        a, b = records["old"], records["new"]
        same = all(np.array_equal(getattr(a, k), getattr(b, k)) for k in (
            "depth", "body_seg", "rgb", "point_cloud", "visibility", "action", "state"))
        identical &= same
        print(
            f"seed {i}: {a.length} frames; old {1000 * cpu['old'] / frames['old']:.2f} ms/frame, "
            f"new {1000 * cpu['new'] / frames['new']:.2f} ms/frame so far; arrays identical: {same}",
            flush=True,
        )
    old_ms, new_ms = (1000 * cpu[k] / frames[k] for k in ("old", "new"))
    ratio = new_ms / old_ms
    projected = BASELINE_100_WALL_S * (BASELINE_WORKER_CPU_S * ratio + BASELINE_WRITER_CPU_S) / (
        BASELINE_WORKER_CPU_S + BASELINE_WRITER_CPU_S)
    print(f"\n== old vs new worker path: {task} / {condition}, {episodes} seeds each, load average "
          f"{os.getloadavg()[0]:.1f} ==")
    print(f"worker CPU per frame (record(): sim, expert, renders): old {old_ms:.2f} ms, new {new_ms:.2f} ms, "
          f"new / old = {ratio:.3f}; privileged arrays identical: {identical}")
    print(
        f"PROJECTED 100 Stage episodes: {projected:.0f} s = {projected / 60:.1f} min (the idle-machine "
        f"{BASELINE_100_WALL_S} s scaled by CPU per episode: worker {BASELINE_WORKER_CPU_S} s x {ratio:.3f} "
        "+ "
        f"writer {BASELINE_WRITER_CPU_S} s; a projection, not a measurement)"
    )
    print(
        json.dumps(
            {
                "old_ms_per_frame": round(old_ms, 2),
                "new_ms_per_frame": round(new_ms, 2),
                "ratio": round(ratio, 3),
                "identical": bool(identical),
                "projected_100_s": round(projected),
            }
        )
    )
    for rec in paths.values():
        rec.close()


def per_episode_costs(root: Path, commits: list[dict], t0: float, plot: Path | None) -> None:
    """Print (and plot) what each episode cost the writer, against its index in the dataset."""
    import numpy as np

    from lerobot_bavo.datasets.collection_record import CollectionRecord

    timings = CollectionRecord.load(root).runs[-1].get("timings", {})
    write = np.asarray(timings.get("episode_write_s", []), dtype=float)
    sessions = np.asarray(timings.get("session_s", []), dtype=float)
    # wall time from the previous commit's end to this one's, spread over its episodes (NaN for the first
    # commit, whose interval holds the one-off start-up)
    interval, t_prev = [], None
    for c in commits:
        value = float("nan") if t_prev is None else (c["t"] - t_prev) / len(c["episodes"])
        interval += [value] * len(c["episodes"])
        t_prev = c["t"]
    interval = np.asarray(interval)
    if len(write) < 2:
        return
    k = min(10, len(write) // 2)

    def nanmean(x):  # the first commit's episodes have no interval (start-up): NaN, without a warning
        x = x[~np.isnan(x)]
        return float(x.mean()) if len(x) else float("nan")

    print(f"\nper-episode cost against episode index (groups of {k}; seconds):")
    print(f"  {'episodes':>10} {'write':>8} {'wall/episode':>13}")
    for i in range(0, len(write), k):
        print(
            f"  {i:>4}-{min(i + k, len(write)) - 1:<5} {write[i : i + k].mean():8.3f} "
            f"{nanmean(interval[i : i + k]):13.2f}"
        )
    print(f"writer session open + finalize: first {sessions[0]:.2f} s, last {sessions[-1]:.2f} s")
    print(
        f"ratio last {k} / first {k}: write {write[-k:].mean() / write[:k].mean():.2f}, "
        f"wall per episode (after the first commit) "
        f"{nanmean(interval[-k:]) / nanmean(interval[k : 2 * k]):.2f} "
        "(target <= 1.2)"
    )
    if plot is not None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(7, 3.5))
        ax.plot(np.arange(len(write)), write, ".", label="writer: add_frame + save_episode")
        ax.plot(np.arange(len(interval)), interval, "-", label="wall per episode (between commits)")
        ax.set_xlabel("episode index")
        ax.set_ylabel("seconds")
        ax.legend()
        ax.grid(alpha=0.3)
        fig.tight_layout()
        fig.savefig(plot, dpi=120)
        print(f"plot written to {plot}")


if __name__ == "__main__":
    main()
