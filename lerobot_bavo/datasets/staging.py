"""Record one seeded expert episode and stage it for the dataset writer (the worker side of `bavo-collect`).

A job is a dict (task, condition, settings, episode_length, keep_failures, seed, staging folder, and
`video`: the writer's encoder settings when the dataset stores video); `run_job` runs in a pool worker (or
in-process), records the episode with the scripted expert, computes its teacher targets and, when the
episode is kept, builds its per-episode dataset parts (`episode_payload.build_payload`: the active camera's
mp4 and the statistics the writer used to compute) and writes `seed_<seed>.mp4` (with video), then
`seed_<seed>.npz` (the dataset columns, without the pixels when they are in the mp4, and the statistics),
and then `seed_<seed>.json` (its summary, the completion marker), all through atomic renames. The writer in
the main process reads them back (`load_staged`, `staged_video`) in seed order.

On Ray (`bavo-collect --executor ray`) a worker may be on another machine, so `ship_job` stages the
episode in a private temporary folder and returns the staged files' bytes instead; the main process
writes them into its staging folder (`receive_shipped`), exactly the files `run_job` would have written.

The recorder (env, expert, renderers) is kept per worker process between jobs of the same settings
(`runtime.pool.ProcessCache`): building it costs far more than a frame.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np

from lerobot_bavo.datasets import schema as S
from lerobot_bavo.datasets.collection_record import write_json_atomic
from lerobot_bavo.experts.perturbation import ExecutionNoise
from lerobot_bavo.features import ObservationSettings
from lerobot_bavo.runtime.pool import ProcessCache

_RECORDERS = ProcessCache(close=lambda recorder: recorder.close())


STAGED_SUFFIXES = (".mp4", ".npz", ".json")  # an episode's staged files, in the order they are written


def staged_path(staging: Path, seed: int, suffix: str) -> Path:
    """`<staging>/seed_<seed>{.mp4,.npz,.json}`: an episode's video (when the worker encoded it), columns and
    statistics, and summary (the completion marker)."""
    return Path(staging) / f"seed_{seed:08d}{suffix}"


def seed_of(path: Path) -> int:
    return int(path.stem.split("_")[1])


def _npz_key(feature: str) -> str:
    return feature.replace(".", "__")


def _feature_key(npz_key: str) -> str:
    return npz_key.replace("__", ".")


def load_staged(staging: Path, seed: int) -> dict[str, np.ndarray]:
    """The dataset columns of a staged episode, (T, ...) per feature (see `load_staged_payload`)."""
    return load_staged_payload(staging, seed)[0]


def load_staged_payload(staging: Path, seed: int) -> tuple[dict[str, np.ndarray], dict[str, dict]]:
    """(columns, statistics) of a staged episode: (T, ...) per feature, and the per-feature statistics its
    worker computed (`episode_payload.build_payload`; empty for an episode staged without them)."""
    from lerobot_bavo.datasets.episode_payload import stats_from_arrays

    with np.load(staged_path(staging, seed, ".npz")) as z:
        return stats_from_arrays({_feature_key(k): z[k] for k in z.files})


def staged_video(staging: Path, summary: dict) -> Path | None:
    """The mp4 its worker encoded for a staged episode, or None when the writer must encode the frames."""
    return staged_path(staging, int(summary["seed"]), ".mp4") if summary.get("video") else None


def _recorder(job: dict):
    """This process's recorder for `job`'s task, condition, settings and episode length (built once)."""
    from lerobot_bavo.datasets.recording import EpisodeRecorder

    settings = ObservationSettings(**job["settings"])
    decoys = int(job.get("decoy_panels") or 0)
    key = (job["task"], job["condition"], settings, job["episode_length"], decoys)
    return _RECORDERS.get(key, lambda: EpisodeRecorder(job["task"], job["condition"], settings,
                                                        job["episode_length"], decoy_panels=decoys))


def warm_job(job: dict) -> None:
    """Build this worker's recorder for `job` without recording anything: `bavo-collect` sends one per worker
    before its own start-up (importing LeRobot, opening the dataset: seconds of one core), so the workers'
    set-up (imports, model, GL contexts) runs meanwhile instead of after it."""
    _recorder(job)


def run_job(job: dict) -> dict:
    """Record one seeded episode with the scripted expert and stage it (`stage_episode`); returns its
    summary."""
    recorder = _recorder(job)
    cpu0 = time.process_time()
    noise = ExecutionNoise(**job["execution_noise"]) if job.get("execution_noise") else None
    record = recorder.record(int(job["seed"]), execution_noise=noise,
                             events_outside_contacts=bool(job.get("events_outside_contacts")),
                             square_grasps=bool(job.get("square_grasps")))
    return stage_episode(record, Path(job["staging"]), record.success or job["keep_failures"], cpu0,
                         video=job.get("video"))


def stage_episode(record, staging: Path, kept: bool, cpu0: float | None = None,
                  video: dict | None = None) -> dict:
    """Compute a recorded episode's teacher targets and stage it for the writer; returns its summary.

    When `kept`, builds the episode's dataset parts (`episode_payload.build_payload`; with `video`, the
    writer's encoder settings, the active camera's mp4 too) and writes `<staging>/seed_<seed>.mp4` (with
    `video`) and `<staging>/seed_<seed>.npz` (columns and statistics); then `<staging>/seed_<seed>.json` (the
    summary, whose "video" says whether the mp4 is there) as the completion marker; all through atomic
    renames. Also used by `bavo-teleop`.
    """
    from lerobot_bavo.datasets.episode_payload import build_payload, stats_to_arrays
    from lerobot_bavo.datasets.recording import episode_frames
    from lerobot_bavo.teacher.simulator import teacher_targets

    cpu0 = time.process_time() if cpu0 is None else cpu0
    seed = int(record.seed)
    summary = {"seed": seed, "success": record.success, "kept": kept, "length": record.length,
               "progress": record.final_progress, "recoveries": record.recoveries,
               "episode_s": round(record.timings["episode_s"], 3), "source": record.source}
    if kept:
        t0 = time.perf_counter()
        targets = teacher_targets(
            record, n_future=S.N_FUTURE, clip_length=S.CLIP_LENGTH, anchor_index=S.ANCHOR_INDEX
        )
        summary["teacher_s"] = round(time.perf_counter() - t0, 3)
        summary["valid_frames"] = int(targets["valid"].sum())
        cols = episode_frames(record, targets)
        t0 = time.perf_counter()
        video_tmp = staged_path(staging, seed, ".mp4.tmp")
        cols, stats = build_payload(cols, S.OBS_IMAGE, video, video_tmp if video else None)
        if video:
            os.replace(video_tmp, staged_path(staging, seed, ".mp4"))
        summary["video"] = bool(video)
        summary["payload_s"] = round(time.perf_counter() - t0, 3)
        t0 = time.perf_counter()
        tmp = staged_path(staging, seed, ".npz.tmp")
        with open(tmp, "wb") as f:
            np.savez(f, **{_npz_key(k): v for k, v in {**cols, **stats_to_arrays(stats)}.items()})
        os.replace(tmp, staged_path(staging, seed, ".npz"))
        summary["stage_s"] = round(time.perf_counter() - t0, 3)
    summary["cpu_s"] = round(time.process_time() - cpu0, 3)
    write_json_atomic(staged_path(staging, seed, ".json"), summary)
    return summary


def ship_job(job: dict) -> dict:
    """`run_job` for a worker that may not share the main process's disk (a Ray task): stages the episode in a
    private temporary folder and returns {"summary", "npz", "mp4"} (the staged files' bytes, None where not
    written). A retried task (its worker was lost) starts over in a new folder; nothing is left behind on the
    worker."""
    import tempfile

    with tempfile.TemporaryDirectory(prefix="bavo_ship_") as tmp:
        summary = run_job({**job, "staging": tmp})
        shipped = {"summary": summary}
        for suffix in (".npz", ".mp4"):
            path = staged_path(Path(tmp), summary["seed"], suffix)
            shipped[suffix[1:]] = path.read_bytes() if path.exists() else None
        return shipped


def receive_shipped(shipped: dict, staging: Path) -> dict:
    """Write a `ship_job` result into `staging` as `run_job` would (video, columns, then the summary as the
    completion marker, all through atomic renames); returns the summary."""
    summary = shipped["summary"]
    seed = int(summary["seed"])
    for suffix in (".mp4", ".npz"):
        data = shipped.get(suffix[1:])
        if data is not None:
            tmp = staged_path(staging, seed, suffix + ".tmp")
            tmp.write_bytes(data)
            os.replace(tmp, staged_path(staging, seed, suffix))
    write_json_atomic(staged_path(staging, seed, ".json"), summary)
    return summary
