"""`bavo-collect`: scripted-expert demonstrations -> a LeRobot v3.0 dataset with cached teacher targets.

    bavo-collect --task cube_handoff --condition stage --episodes 100 --repo-id <user>/bavo_cube_handoff \\
        [--root DIR] [--workers 2] [--executor {local,ray} [--ray-address ADDR]] [--push-to-hub]

How it works:
- Episodes are keyed by seed: attempt k uses seed `--seed` + k for the env (layout, occlusion
  schedule) and the expert (timing jitter). The dataset holds the first `--episodes` successful
  seeds, in seed order; unsuccessful attempts are discarded and counted.
- Worker processes (`--workers`, spawn, one env + expert + renderer each, one BLAS thread, no LeRobot or
  PyTorch import: `WorkerPool(light_import=True)`) record an episode, compute its teacher targets and stage it as
  `<root>/.bavo_staging/seed_*.npz` plus a `seed_*.json` marker written last (atomic renames). The pool
  starts first, with one warm-up job per worker (`staging.warm_job`: build the recorder), and this process
  imports LeRobot only when it opens the dataset (the `bavo-collect` command imports `lerobot_bavo` without
  registering LeRobot types), so both set-ups run side by side. Workers and this process keep freed memory
  for reuse (`runtime.process.retain_freed_memory`).
- `--executor ray`: every episode rollout is a Ray task instead (on a private local Ray with `--workers`
  CPUs, or the cluster at `--ray-address`). A Ray worker may be on another machine, so it returns the
  staged files' bytes and this process writes them into the same staging folder; everything after
  (the writer, resume, the record) is the same. A worker lost mid-episode is retried by Ray.
- The main process is the only writer into the LeRobotDataset. It appends each kept episode as soon as
  it and every lower seed are resolved (`writer.StreamingWriter`; the attempts in flight keep the workers
  busy meanwhile); every `--commit-every` episodes form one LeRobot writer session (`LeRobotDataset.resume`,
  the episodes in seed order, `finalize()`), and only then are they recorded in
  `meta/bavo_collection.json` (the collection record).
- Resume: re-running the same command continues where a killed run stopped. LeRobot keeps its
  parquet writers open until `finalize()`, so a kill inside a commit leaves unreadable files. Each
  commit therefore first snapshots `meta/info.json`, `meta/stats.json`, `meta/tasks.parquet` and
  the list of data / video / episode files (a resumed LeRobot writer only ever adds new files)
  and marks the commit pending in the record; a pending commit found at start-up is rolled back
  (new files deleted, metadata restored) and redone from the staged episodes, which are deleted
  only after the record says they are committed. Finished episodes are never lost or duplicated.
- The active camera is stored as video (`video_codec.py`): x264 for a new dataset (GOP 2, CRF 20, one thread, SSE4.2
  SIMD: the same quality as LeRobot's SVT-AV1 for ~4x less CPU, and reproducible bytes), `--vcodec libsvtav1` for
  LeRobot's AV1 (what earlier versions wrote); a dataset being continued keeps its own codec.
- At the end: exact per-channel point-cloud statistics (`hub.retile_point_cloud_stats`), the
  dataset card (README.md), and optionally `push_to_hub` (needs `huggingface-cli login`).

Where each job lives: this module has the CLI, its config and the run (`Collector`, `SeedScheduler`);
`staging.py` records and stages one episode (the worker side); `writer.py` is the writer side (a commit's
writer session, fed episode by episode); `collection_record.py` is the record; `transaction.py`
snapshots and rolls back a writer session; `lerobot_private.py` holds every use of LeRobot's private
internals; `runtime/pool.py` is the worker pool `bavo-eval` uses too.
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import json
import logging
import os
import shlex
import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from lerobot_bavo.datasets import schema as S
from lerobot_bavo.datasets.collection_record import CollectionRecord
from lerobot_bavo.datasets.hub import SIDECAR
from lerobot_bavo.datasets.staging import (
    receive_shipped,
    run_job,
    seed_of,
    ship_job,
    staged_path,
    warm_job,
)
from lerobot_bavo.datasets.transaction import (
    SnapshotMissing,
    WriterSessionSnapshot,
    remove_stray_dirs,
)
from lerobot_bavo.datasets.verify import check_committed_files
from lerobot_bavo.datasets.video_codec import (
    DEFAULT_VIDEO_CODEC,
    VIDEO_CODECS,
    check_video_codec,
    quiet_libav,
    recorded_video_codec,
    rgb_encoder,
)
from lerobot_bavo.datasets.video_codec import record_entry as video_codec_record_entry
from lerobot_bavo.datasets.writer import StreamingWriter, WriterSession
from lerobot_bavo.experts.perturbation import ExecutionNoise
from lerobot_bavo.features import POINT_FRAMES, ObservationSettings
from lerobot_bavo.runtime.files import restore_default_mode
from lerobot_bavo.runtime.pool import WorkerPool, add_executor_arguments, executor_problem

logger = logging.getLogger("bavo-collect")

STAGING = ".bavo_staging"


@dataclass
class CollectConfig:
    """Arguments of a collection (the CLI's flags).

    Args:
        task, condition: benchmark task and visibility condition.
        episodes: number of successful episodes wanted in the dataset.
        repo_id: `<user>/<name>`; also the default local folder `$HF_LEROBOT_HOME/<repo_id>`.
        root: local dataset folder (default: LeRobot's).
        workers: worker processes; 0 runs episodes in this process (tests, debugging). With executor "ray" and
            no ray_address: the CPUs of the private local Ray (>= 1).
        executor: "local" (`WorkerPool`) or "ray" (`RayPool`: episode rollouts as Ray tasks).
        ray_address: with executor "ray", the cluster to use (`ray start --head` prints it); None: a private Ray.
        seed: seed of the first attempt (demonstration seeds should stay clear of eval seeds, 1000+).
        commit_every: episodes appended per LeRobot writer session (resume granularity).
        settings: observation settings (image size, points, frame, fovy).
        episode_length: control-step limit per episode (None: the task's own).
        keep_failures: keep unsuccessful episodes too (tests / debugging only).
        execution_noise: DART-style noise on the executed arm joint targets; the dataset records the
            expert's clean actions (`experts/perturbation.py`). Off by default.
        use_videos: store the active image as video.
        video_codec: that video's codec (`datasets/video_codec.py`): "h264" or "libsvtav1" (LeRobot's default AV1).
            None: "h264" for a new dataset, the dataset's own codec when continuing one.
        push_to_hub, private: upload when done.
        max_discard_ratio: abort when more than this many discards per wanted episode (plus 10) occur.
        progress: show a progress bar.
        command: the command line, recorded in the collection record and the dataset card.
    """

    task: str
    condition: str
    episodes: int
    repo_id: str
    root: Path | None = None
    workers: int = 2
    executor: str = "local"
    ray_address: str | None = None
    seed: int = 0
    commit_every: int = 10
    settings: ObservationSettings = field(default_factory=ObservationSettings)
    episode_length: int | None = None
    keep_failures: bool = False
    execution_noise: ExecutionNoise = field(default_factory=ExecutionNoise)
    use_videos: bool = True
    video_codec: str | None = None
    push_to_hub: bool = False
    private: bool | None = None
    max_discard_ratio: float = 2.0
    progress: bool = True
    command: str | None = None

    def __post_init__(self):
        if self.episodes < 1:
            raise ValueError(f"--episodes must be >= 1, got {self.episodes}")
        if self.workers < 0:
            raise ValueError(f"--workers must be >= 0, got {self.workers}")
        if (problem := executor_problem(self.executor, self.ray_address, self.workers)) is not None:
            raise ValueError(problem)
        if self.commit_every < 1:
            raise ValueError(f"--commit-every must be >= 1, got {self.commit_every}")
        if self.seed < 0:
            raise ValueError(f"--seed must be >= 0, got {self.seed}")
        if self.video_codec is not None:
            check_video_codec(self.video_codec)
        if "/" not in self.repo_id:
            raise ValueError(f"--repo-id must look like '<user>/<name>', got {self.repo_id!r}")

    def resolved_root(self) -> Path:
        if self.root is not None:
            return Path(self.root)
        from lerobot.utils.constants import HF_LEROBOT_HOME

        return Path(HF_LEROBOT_HOME) / self.repo_id

    def record_settings(self, video_codec: str = DEFAULT_VIDEO_CODEC) -> dict:
        """What must match for a run to continue an existing dataset, recording video with `video_codec`."""
        from lerobot_bavo.envs.tasks import make_task

        task = make_task(self.task)
        return {
            "task": self.task,
            "task_description": task.description,
            "stage_targets": list(task.stage_targets),
            "condition": self.condition,
            **self.settings.to_dict(),
            "fps": S.FPS,
            "episode_length": self.episode_length,
            "base_seed": self.seed,
            "keep_failures": self.keep_failures,
            # Only when on, so that the records of collections made before the option existed still match.
            **({"execution_noise": self.execution_noise.to_dict()} if self.execution_noise.enabled else {}),
            "use_videos": self.use_videos,
            # Only when not the codec of datasets made before the choice existed (their records name none).
            **video_codec_record_entry(video_codec, self.use_videos),
            "teacher": {"name": "simulator-exact", "clip_length": S.CLIP_LENGTH, "anchor_index": S.ANCHOR_INDEX,
                        "n_future": S.N_FUTURE, "visibility_tol_m": 0.01},
        }


# ================================================================== main side
class CollectionError(RuntimeError):
    pass


class SeedScheduler:
    """Which seeds to attempt next, and the finished attempts in seed order.

    Attempts finish out of order (several workers); the dataset holds episodes in seed order. So a
    finished attempt waits in `results` until every lower seed is resolved, and no more attempts are in
    flight than could still be needed (finished-and-kept plus in-flight covers what is wanted), except
    to fill a gap below a finished seed.
    """

    def __init__(self, next_seed: int, staged: dict[int, dict], receive=None):
        self.next_seed = next_seed  # the first seed not yet resolved
        self.results: dict[int, dict] = dict(staged)  # finished, not yet resolved
        self.in_flight: dict[cf.Future, int] = {}
        self.receive = receive  # a job's result -> its summary (Ray: writes the shipped files); None: the result

    def resolved(self):
        """Finished summaries in seed order, each removed as it is handed out (stop whenever you like)."""
        while self.next_seed in self.results:
            summary = self.results.pop(self.next_seed)
            self.next_seed += 1
            yield summary

    def seeds_to_attempt(self, wanted: int, window: int) -> list[int]:
        """Seeds to submit now: at most `window` in flight, and no more than `wanted` kept episodes need."""
        seeds: list[int] = []
        busy = set(self.in_flight.values())
        ahead = sum(1 for r in self.results.values() if r["kept"])
        seed = self.next_seed
        while len(self.in_flight) + len(seeds) < window:
            while seed in self.results or seed in busy:
                seed += 1
            gap = bool(self.results) and seed < max(self.results)  # staged results wait for this seed
            if not gap and ahead + len(self.in_flight) + len(seeds) >= wanted:
                break
            seeds.append(seed)
            seed += 1
        return seeds

    def submit(self, pool: WorkerPool, fn, job: dict) -> None:
        self.in_flight[pool.submit(fn, job)] = job["seed"]

    def wait(self) -> None:
        """Block until at least one attempt in flight finishes; a worker's exception propagates here."""
        if not self.in_flight:
            if self.next_seed in self.results:
                return
            raise CollectionError("internal error: nothing in flight and nothing to resolve")
        done, _ = cf.wait(list(self.in_flight), return_when=cf.FIRST_COMPLETED)
        for fut in done:
            seed = self.in_flight.pop(fut)
            result = fut.result()
            self.results[seed] = result if self.receive is None else self.receive(result)


class Collector:
    """One `bavo-collect` run on one dataset folder (see the module docstring)."""

    def __init__(self, cfg: CollectConfig):
        self.cfg = cfg
        self.root = cfg.resolved_root()
        self.staging = self.root / STAGING
        # a dataset being continued keeps its own codec unless one is asked for (then it must match: `_open`)
        self.settings = cfg.record_settings(cfg.video_codec or DEFAULT_VIDEO_CODEC)
        self.record: CollectionRecord | None = None
        self.snapshot = WriterSessionSnapshot(self.root, self.staging / "snapshot")

    @property
    def video_codec(self) -> str:
        """The codec this run records video with: the one its settings name (`video_codec.py`)."""
        return recorded_video_codec(self.settings) or DEFAULT_VIDEO_CODEC

    def _save_record(self) -> None:
        self.record.save(self.root)

    def _open(self) -> None:
        """Create the dataset, or reopen it: check settings, roll back a pending commit, check counts."""
        from lerobot.datasets.lerobot_dataset import LeRobotDataset

        from lerobot_bavo.datasets.hub import read_info, read_stats

        info_path = self.root / "meta" / "info.json"
        if not info_path.exists():
            if self.root.exists() and any(p.name != STAGING for p in self.root.iterdir()):
                raise CollectionError(f"{self.root} exists and is not a LeRobot dataset; choose another --root")
            if self.root.exists():
                shutil.rmtree(self.root)
            from lerobot_bavo.envs.tasks import environment_state_dim

            features = S.build_features(self.cfg.settings, use_videos=self.cfg.use_videos,
                                        env_state_dim=environment_state_dim(self.cfg.task))
            ds = LeRobotDataset.create(self.cfg.repo_id, S.FPS, features, root=self.root, robot_type="bavo_av_aloha",
                                       use_videos=self.cfg.use_videos, rgb_encoder=rgb_encoder(self.video_codec))
            ds.finalize()
            del ds
        record = CollectionRecord.load(self.root)
        info = read_info(self.root)
        read_stats(self.root, check_nan=False)  # LeRobot.resume would fail on it later with a bare JSONDecodeError
        if record is None:
            if info["total_episodes"] != 0:
                raise CollectionError(
                    f"{self.root} holds a LeRobot dataset ({info['total_episodes']} episodes) that bavo-collect did not "
                    f"make (no {SIDECAR}); choose another --root")
            record = CollectionRecord(repo_id=self.cfg.repo_id, settings=self.settings, next_seed=self.cfg.seed)
        else:
            recorded_codec = recorded_video_codec(record.settings)
            if self.cfg.video_codec is None and recorded_codec is not None and self.cfg.use_videos:
                self._use_video_codec(recorded_codec)
            self._check_settings(record.settings)
        self.record = record
        S.check_features(info["features"], n_points=self.cfg.settings.n_points)
        expected_shape = (self.cfg.settings.image_height, self.cfg.settings.image_width, 3)
        if tuple(info["features"][S.OBS_IMAGE]["shape"]) != expected_shape:
            raise CollectionError(f"{self.root} stores images of shape {info['features'][S.OBS_IMAGE]['shape']}, "
                                  f"this run records {expected_shape}")
        self.staging.mkdir(parents=True, exist_ok=True)
        for tmp in self.staging.glob("*.tmp"):
            tmp.unlink()
        if record.pending_commit is not None:
            logger.warning("rolling back an interrupted commit of seeds %s", record.pending_commit.seeds)
            self._rollback()
        else:
            self.snapshot.discard()
        remove_stray_dirs(self.root, keep=(STAGING,))
        info = read_info(self.root)
        if info["total_episodes"] != len(self.record.episodes):
            raise CollectionError(
                f"{self.root}: meta/info.json has {info['total_episodes']} episodes but {SIDECAR} records "
                f"{len(self.record.episodes)}; the dataset was modified outside bavo-collect")
        restore_default_mode(self.root.glob("videos/*/*/*.mp4"))  # the 0600 mp4s of earlier runs
        try:  # before LeRobot opens it: a missing meta/ file would make LeRobot fetch meta/ from the Hub repo
            check_committed_files(self.root, info, check_videos=self.cfg.use_videos)
        except ValueError as e:
            raise CollectionError(f"{e}. The committed episodes must be whole to continue this dataset (LeRobot would "
                                  "otherwise fetch missing metadata from the Hub, or keep a damaged file): restore "
                                  "the file, or collect into another --root") from None
        self._save_record()

    def _use_video_codec(self, codec: str) -> None:
        """Record video with `codec` (the settings keep any entry added since construction, e.g. teleop's)."""
        self.settings.pop("video_codec", None)
        self.settings.update(video_codec_record_entry(codec, self.cfg.use_videos))

    def _check_settings(self, recorded: dict) -> None:
        """Refuse to continue a dataset recorded with other settings. Both sides' keys are compared: options that
        are recorded only when used (execution noise, a codec other than the legacy one, teleop's human source)
        must be absent on both sides or equal. The codec is compared as `recorded_video_codec` reads it, so a
        record made before the choice existed reads as 'libsvtav1'."""
        def view(settings: dict) -> dict:
            return {**settings, "video_codec": recorded_video_codec(settings)}

        was, now = view(recorded), view(self.settings)
        keys = [*now, *(k for k in was if k not in now)]
        diffs = {k: (was.get(k), now.get(k)) for k in keys
                 if k not in ("task_description", "stage_targets") and was.get(k) != now.get(k)}
        if diffs:
            text = ", ".join(f"{k}: dataset {a!r} vs now {b!r}" for k, (a, b) in diffs.items())
            raise CollectionError(f"{self.root} was collected with other settings ({text}); "
                                  "use the same arguments to continue it, or another --root")

    def _rollback(self) -> None:
        try:
            self.snapshot.restore()
        except SnapshotMissing as e:
            raise CollectionError(
                f"{self.root}: an interrupted commit of seeds {self.record.pending_commit.seeds} cannot be rolled "
                f"back because {e}; start a new collection in another --root") from None
        self.record.pending_commit = None
        self._save_record()

    # -------------------------------------------------------------- staging
    def _scan_staging(self, first_seed: int) -> dict[int, dict]:
        """Finished attempts a killed run left staged (seed >= first_seed), to reuse instead of re-running."""
        found = {}
        for p in self.staging.glob("seed_*.json"):
            seed = seed_of(p)
            if seed < first_seed:
                self._drop_staged(seed)
                continue
            summary = json.loads(p.read_text())
            if summary.get("kept") and not staged_path(self.staging, seed, ".npz").exists():
                p.unlink()  # marker without data: redo the episode
                continue
            found[seed] = summary
        for p in self.staging.glob("seed_*.npz"):
            if seed_of(p) not in found:
                p.unlink()
        return found

    def _drop_staged(self, seed: int) -> None:
        for suffix in (".npz", ".json"):
            staged_path(self.staging, seed, suffix).unlink(missing_ok=True)

    # -------------------------------------------------------------- commit
    def _commit(self, batch: list[dict], discards: list[dict], next_seed: int, timings: dict | None = None) -> None:
        """Append `batch` (summaries of staged kept episodes, seed order) to the dataset in one writer session
        (`writer.WriterSession`), here and now; an interruption (error, Ctrl+C) before the record is saved
        rolls the session back. `bavo-teleop` commits each human episode this way; `bavo-collect` writes its
        episodes into sessions as they are resolved (`writer.StreamingWriter`)."""
        session = WriterSession(self, max(b["length"] for b in batch), timings)
        try:
            for d in discards:
                session.add_discard(d)
            for b in batch:
                session.add(b)
        except BaseException:
            logger.warning("interrupted during a commit: rolling it back")
            session.abort()
            raise
        session.close(next_seed)

    def _verify_videos(self, first_index: int, batch: list[dict]) -> None:
        """Every committed episode's video segment must cover all its frames (no dropped frames), and the data and
        video files holding the episodes must read whole (`verify.check_committed_files`, as on resume)."""
        if not self.cfg.use_videos:
            return
        import pyarrow.dataset as pads

        # Only the two timestamp columns of the new rows are needed. `io_utils.load_episodes` would
        # build a `datasets.Dataset` of the whole episode table with its per-feature stats (~3 s for
        # a few episodes, growing with the dataset); a column-selective pyarrow scan takes ms.
        key = S.OBS_IMAGE
        columns = ["episode_index", f"videos/{key}/from_timestamp", f"videos/{key}/to_timestamp"]
        table = pads.dataset(self.root / "meta" / "episodes", format="parquet").to_table(columns=columns)
        rows = {int(e): (f, t) for e, f, t in zip(*(table.column(c).to_pylist() for c in columns))}
        for i, b in enumerate(batch):
            start, stop = rows[first_index + i]
            duration = stop - start
            if abs(duration - b["length"] / S.FPS) > 0.5 / S.FPS:
                raise CollectionError(
                    f"episode {first_index + i} (seed {b['seed']}): video covers {duration:.3f} s for {b['length']} "
                    "frames (dropped frames in the encoder?)")
        from lerobot_bavo.datasets.hub import read_info

        try:  # and the files holding them: every frame there, the last pictures decodable, the parquet whole
            check_committed_files(self.root, read_info(self.root),
                                  episode_indices={first_index + i for i in range(len(batch))})
        except ValueError as e:
            raise CollectionError(f"after writing episodes {first_index}..{first_index + len(batch) - 1}: {e}") from None

    # -------------------------------------------------------------- run
    def _lock(self):
        """An exclusive lock on the dataset's resolved path, so two runs never write one dataset (not even
        through a symlinked spelling of --root)."""
        from lerobot_bavo.runtime.process import LockedError, exclusive_lock

        try:
            return exclusive_lock(self.root, "bavo-collect")
        except LockedError as e:
            raise CollectionError(str(e)) from None

    def run(self) -> dict:
        lock = self._lock()
        try:
            return self._run()
        finally:
            lock.close()

    def _run(self) -> dict:
        cfg = self.cfg
        t_start = time.perf_counter()
        early_pool = None
        if cfg.executor == "local" and cfg.workers > 0:
            # Start the workers' set-up now, beside this process's own (LeRobot import, dataset open)
            early_pool = self._pool()
            for _ in range(cfg.workers):
                early_pool.submit(warm_job, self._job(seed=-1))
        try:
            return self._run_with(early_pool, t_start)
        finally:
            if early_pool is not None:
                early_pool.shutdown(cancel=True, wait=False)

    def _run_with(self, early_pool, t_start: float) -> dict:
        cfg = self.cfg
        self._open()
        requested = cfg.episodes
        committed = len(self.record.episodes)
        on_ray = cfg.executor == "ray"
        sched = SeedScheduler(self.record.next_seed, self._scan_staging(self.record.next_seed),
                              receive=(lambda shipped: receive_shipped(shipped, self.staging)) if on_ray else None)
        job_fn = ship_job if on_ray else run_job
        run_stats = {"started": time.strftime("%Y-%m-%d %H:%M:%S"), "requested": requested,
                     "committed_before": committed, "workers": cfg.workers, "executor": cfg.executor, "attempts": 0,
                     "reused_staged": len(sched.results)}
        timings: dict[str, list] = {}
        needed = requested - committed
        discarded = len(self.record.discarded)
        max_discards = int(cfg.max_discard_ratio * requested) + 10
        bar = _progress(total=requested, initial=committed, enabled=cfg.progress)
        bar.set_postfix(discarded=discarded)
        pool = (early_pool or self._pool()) if needed > 0 else None
        window = pool.max_in_flight if on_ray and pool is not None else max(1, 2 * cfg.workers)
        writer = None
        if needed > 0:
            from lerobot_bavo.envs.tasks import TASKS

            max_frames = cfg.episode_length or TASKS.lookup(cfg.task).max_episode_steps
            writer = StreamingWriter(self, needed, cfg.commit_every, max_frames, timings, run_t0=t_start)
        try:
            while writer is not None and writer.written < needed:
                for summary in sched.resolved():  # finished attempts, in seed order
                    writer.put(summary)  # a kept episode is written now; its session commits at its last one
                    if summary["kept"]:
                        bar.update(1)
                    else:
                        discarded += 1
                        self._check_discards(discarded, max_discards, committed + writer.written, bar)
                    if writer.written >= needed:
                        break
                if writer.written >= needed:
                    break
                for seed in sched.seeds_to_attempt(wanted=needed - writer.written, window=window):
                    sched.submit(pool, job_fn, self._job(seed))
                    run_stats["attempts"] += 1
                sched.wait()
            if writer is not None:
                writer.finish()
        except BaseException:
            if writer is not None:
                writer.abort()  # rolls back a session that has not reached its commit point
            raise
        finally:
            bar.close()
            if pool is not None:
                pool.shutdown(cancel=True, wait=False)
        run_stats["timings"] = timings
        return self._finish(run_stats, time.perf_counter() - t_start)

    def _pool(self):
        """Where episodes run: `WorkerPool` (local processes) or `RayPool` (Ray tasks; at most 2 x the cluster's
        CPUs in flight). Ray is imported only for --executor ray."""
        if self.cfg.executor == "ray":
            from lerobot_bavo.runtime.ray_pool import RayPool

            return RayPool(self.cfg.workers, address=self.cfg.ray_address)
        return WorkerPool(self.cfg.workers, light_import=True)  # expert episodes: no LeRobot / PyTorch in workers

    def _job(self, seed: int) -> dict:
        cfg = self.cfg
        return {"task": cfg.task, "condition": cfg.condition, "settings": cfg.settings.to_dict(),
                "episode_length": cfg.episode_length, "keep_failures": cfg.keep_failures, "seed": seed,
                "staging": str(self.staging),
                "execution_noise": cfg.execution_noise.to_dict() if cfg.execution_noise.enabled else None}

    def _check_discards(self, total: int, limit: int, kept: int, bar) -> None:
        bar.set_postfix(discarded=total)
        if total > limit:
            raise CollectionError(
                f"{total} unsuccessful expert episodes for {kept} kept: the expert for {self.cfg.task!r} under "
                f"{self.cfg.condition!r} fails too often; aborting")

    def _finish(self, run_stats: dict, wall: float) -> dict:
        from lerobot_bavo.datasets.card import write_card
        from lerobot_bavo.datasets.hub import retile_point_cloud_stats

        t0 = time.perf_counter()
        per_channel = retile_point_cloud_stats(self.root)
        run_stats.update(finished=time.strftime("%Y-%m-%d %H:%M:%S"), wall_s=round(wall, 1),
                         committed_after=len(self.record.episodes))
        self.record.runs.append(run_stats)
        self.record.complete = len(self.record.episodes) >= self.cfg.episodes
        self.record.extra["point_cloud_channel_stats"] = {k: np.asarray(v).tolist() for k, v in per_channel.items()
                                                          if k in ("min", "max", "mean", "std")}
        if self.cfg.command:
            self.record.extra["command"] = self.cfg.command
        self._save_record()
        shutil.rmtree(self.staging, ignore_errors=True)
        write_card(self.root, self.cfg.repo_id)
        summary = {
            "root": str(self.root), "episodes": len(self.record.episodes), "frames": self.record.frames,
            "discarded": len(self.record.discarded), "attempts_this_run": run_stats["attempts"],
            "new_this_run": run_stats["committed_after"] - run_stats["committed_before"], "wall_s": round(wall, 1),
            "finish_s": round(time.perf_counter() - t0, 1),
        }
        if self.cfg.push_to_hub:
            from lerobot_bavo.datasets.hub import push_dataset

            try:
                push_dataset(self.root, self.cfg.repo_id, private=self.cfg.private)
            except Exception as e:
                raise CollectionError(
                    f"the dataset is complete at {self.root} but the upload to {self.cfg.repo_id!r} failed "
                    f"({type(e).__name__}: {e}). Log in with `huggingface-cli login` (or set HF_TOKEN) and re-run the "
                    "same command: nothing is recollected.") from e
            summary["pushed"] = self.cfg.repo_id
        return summary


def _progress(total: int, initial: int, enabled: bool):
    from tqdm import tqdm

    return tqdm(total=total, initial=initial, unit="ep", desc="episodes", disable=not enabled, dynamic_ncols=True)


def collect(cfg: CollectConfig) -> dict:
    """Run (or continue) a collection; returns a summary dict."""
    return Collector(cfg).run()


# ================================================================== CLI
def build_parser() -> argparse.ArgumentParser:
    from lerobot_bavo.envs.conditions import CONDITIONS

    p = argparse.ArgumentParser(prog="bavo-collect", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", required=True, help="benchmark task, e.g. cube_handoff")
    p.add_argument("--condition", default="stage", choices=tuple(CONDITIONS),
                   help="visibility condition (the paper trains on stage)")
    p.add_argument("--episodes", type=int, required=True, help="successful episodes wanted")
    p.add_argument("--repo-id", required=True, help="<user>/<name>, e.g. me/bavo_cube_handoff")
    p.add_argument("--root", type=Path, default=None, help="local dataset folder (default $HF_LEROBOT_HOME/<repo-id>)")
    add_executor_arguments(p, 2, "worker processes (0: in this process)",
                           "where episode rollouts run: local worker processes (default) or Ray tasks, this process "
                           "staying the only dataset writer")
    p.add_argument("--seed", type=int, default=0, help="seed of the first attempt")
    p.add_argument("--commit-every", type=int, default=10, help="episodes per dataset write session")
    p.add_argument("--image-height", type=int, default=240)
    p.add_argument("--image-width", type=int, default=320)
    p.add_argument("--n-points", type=int, default=256)
    p.add_argument("--point-frame", default="base", choices=POINT_FRAMES)
    p.add_argument("--episode-length", type=int, default=None, help="control-step limit (default: the task's)")
    p.add_argument("--vcodec", default=None, choices=VIDEO_CODECS,
                   help="codec of the active camera's video: h264 (x264, GOP 2, CRF 20, preset faster; the default "
                        "for a new dataset: the same quality as AV1 for ~4x less CPU) or libsvtav1 (LeRobot's default "
                        "AV1: GOP 2, CRF 30, preset 12; what bavo-collect wrote before). Default: h264 for a new "
                        "dataset, the dataset's own codec when continuing one")
    p.add_argument("--keep-failures", action="store_true", help="keep unsuccessful episodes (debugging only)")
    p.add_argument("--execution-noise", type=float, default=0.0, metavar="RAD",
                   help="DART-style demonstrations: execute the expert's arm joint targets plus a slowly varying "
                        "random offset of this standard deviation in radians (AR(1), correlation 0.9 per step; "
                        "grippers and camera untouched) while recording its clean targets, so the data show "
                        "corrections back to the plan. 0 (default): off. The cube_handoff runs used 0.01")
    p.add_argument("--execution-noise-clean-contacts", action="store_true",
                   help="with --execution-noise: no noise during the expert's approach/grasp/release phases "
                        "(its `contact_phases`)")
    p.add_argument("--push-to-hub", action="store_true", help="upload when done (needs `huggingface-cli login`)")
    p.add_argument("--private", action="store_true", help="create the Hub repository private")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    return p


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    for name, low in (("episodes", 1), ("workers", 0), ("seed", 0), ("commit_every", 1), ("n_points", 2)):
        if getattr(args, name) < low:
            parser.error(f"--{name.replace('_', '-')} must be >= {low}, got {getattr(args, name)}")
    if args.root is not None and args.root.exists() and not args.root.is_dir():
        parser.error(f"--root {args.root} exists and is not a folder")
    if args.root is not None:
        parent = next((p for p in args.root.absolute().parents if p.exists()), None)
        if parent is not None and not parent.is_dir():
            parser.error(f"--root {args.root}: {parent} is not a folder")
    os.environ.setdefault("SVT_LOG", "1")  # SVT-AV1 (--vcodec libsvtav1): errors only
    quiet_libav()
    from lerobot_bavo.runtime.process import retain_freed_memory

    retain_freed_memory()  # this process reads every staged episode (~110-310 MB each) back: reuse the pages
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    for noisy in ("lerobot", "datasets", "libav", "huggingface_hub"):
        logging.getLogger(noisy).setLevel(logging.WARNING)
    try:
        import datasets

        datasets.disable_progress_bars()
    except Exception:
        pass
    argv_text = " ".join(shlex.quote(a) for a in (sys.argv[1:] if argv is None else argv))
    try:
        cfg = CollectConfig(
            task=args.task, condition=args.condition, episodes=args.episodes, repo_id=args.repo_id, root=args.root,
            workers=args.workers, executor=args.executor, ray_address=args.ray_address, seed=args.seed,
            commit_every=args.commit_every,
            settings=ObservationSettings(args.image_height, args.image_width, args.n_points, args.point_frame),
            episode_length=args.episode_length, keep_failures=args.keep_failures, video_codec=args.vcodec,
            execution_noise=ExecutionNoise(std=args.execution_noise,
                                           clean_contacts=args.execution_noise_clean_contacts), push_to_hub=args.push_to_hub,
            private=True if args.private else None, progress=not args.no_progress,
            command=f"bavo-collect {argv_text}",
        )
        summary = collect(cfg)
    except (CollectionError, ValueError) as e:
        print(f"bavo-collect: error: {e}", file=sys.stderr)
        return 2
    print(json.dumps(summary, indent=1))
    print(f"kept {summary['episodes']} episodes ({summary['frames']} frames), discarded {summary['discarded']} "
          f"unsuccessful attempts; dataset at {summary['root']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
