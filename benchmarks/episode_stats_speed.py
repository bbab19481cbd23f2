"""Per-episode statistics: LeRobot 0.6.1's `compute_episode_stats` against
`lerobot_bavo.datasets.episode_stats` (the exact, histogram-free version `bavo-collect`'s writer uses, issue
11), side by side in one run.

Records one real Stage episode of a task at the default settings (240 x 320, 256 points), builds its dataset
columns as the writer hands them to LeRobot (images excluded: both use LeRobot's code for those), then times
both functions on the same columns, alternating, and prints CPU ms per episode, the ratio, and whether the
results are identical (keys, shapes, dtypes, bytes).

Then the same for the video feature's streaming image statistics: the episode's frames fed one at a time,
down-sampled as LeRobot's encoder thread does, to LeRobot's `RunningQuantileStats` and to
`lerobot_bavo.datasets.video_stats.DeferredFrameStats` (updates replayed once per episode).

    python benchmarks/episode_stats_speed.py [--task cube_handoff] [--repeats 3]
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MUJOCO_GL", "egl")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--task", default="cube_handoff")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()

    from lerobot.datasets.compute_stats import compute_episode_stats as lerobot_stats

    from lerobot_bavo.datasets import schema as S
    from lerobot_bavo.datasets.episode_stats import compute_episode_stats as bavo_stats
    from lerobot_bavo.datasets.episode_stats import writer_stats_inputs
    from lerobot_bavo.datasets.recording import EpisodeRecorder, episode_frames
    from lerobot_bavo.features import ObservationSettings
    from lerobot_bavo.teacher.simulator import teacher_targets

    recorder = EpisodeRecorder(args.task, "stage", ObservationSettings())
    try:
        record = recorder.record(args.seed)
    finally:
        recorder.close()
    targets = teacher_targets(
        record, n_future=S.N_FUTURE, clip_length=S.CLIP_LENGTH, anchor_index=S.ANCHOR_INDEX
    )
    cols, features = writer_stats_inputs(
        {k: v for k, v in episode_frames(record, targets).items() if k != S.OBS_IMAGE}
    )
    dims = sum(int(v.reshape(len(v), -1).shape[1]) for v in cols.values())
    print(
        f"{args.task} seed {args.seed}: {record.length} frames, {len(cols)} numeric features, {dims} "
        "dimensions"
    )

    times = {"lerobot": [], "bavo": []}
    results = {}
    for _ in range(args.repeats):
        for name, fn in (("lerobot", lerobot_stats), ("bavo", bavo_stats)):
            c0 = time.process_time()
            results[name] = fn(cols, features)
            times[name].append(time.process_time() - c0)
    a, b = results["lerobot"], results["bavo"]
    identical = list(a) == list(b) and all(
        list(a[f]) == list(b[f]) and all(a[f][k].dtype == b[f][k].dtype and a[f][k].shape == b[f][k].shape
                                         and a[f][k].tobytes() == b[f][k].tobytes() for k in a[f]) for f in a)
    best = {k: min(v) for k, v in times.items()}
    print(f"CPU per episode (best of {args.repeats}): LeRobot {best['lerobot'] * 1000:.0f} ms, "
          f"lerobot_bavo {best['bavo'] * 1000:.0f} ms, ratio {best['lerobot'] / best['bavo']:.1f}x; "
          f"identical: {identical}")

    from lerobot.datasets.compute_stats import RunningQuantileStats, auto_downsample_height_width

    from lerobot_bavo.datasets.video_stats import DeferredFrameStats

    def frame_stats(cls):
        tracker = cls()
        for frame in record.rgb:  # what `_CameraEncoderThread.run` hands to the tracker, per frame
            small = auto_downsample_height_width(frame.transpose(2, 0, 1))
            tracker.update(small.transpose(1, 2, 0).reshape(-1, small.shape[0]))
        return tracker.get_statistics()

    times = {"lerobot": [], "bavo": []}
    for _ in range(args.repeats):
        for name, cls in (("lerobot", RunningQuantileStats), ("bavo", DeferredFrameStats)):
            c0 = time.process_time()
            results[name] = frame_stats(cls)
            times[name].append(time.process_time() - c0)
    a, b = results["lerobot"], results["bavo"]
    identical = list(a) == list(b) and all(
        a[k].dtype == b[k].dtype and a[k].tobytes() == b[k].tobytes() for k in a
    )
    best = {k: min(v) for k, v in times.items()}
    print(
        f"streaming image statistics, {record.length} frames {record.rgb.shape[1]} x {record.rgb.shape[2]} "
        f"(best of {args.repeats}): LeRobot {best['lerobot'] * 1000:.0f} ms, lerobot_bavo "
        f"{best['bavo'] * 1000:.0f} ms, ratio {best['lerobot'] / best['bavo']:.1f}x; identical: {identical}"
    )


if __name__ == "__main__":
    main()
