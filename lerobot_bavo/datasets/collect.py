"""`bavo-collect`: scripted-expert demonstrations -> a LeRobot v3.0 dataset with cached teacher targets.

    bavo-collect --task cube_handoff --condition stage --episodes 100 --repo-id <user>/bavo_cube_handoff \\
        [--root DIR] [--workers 2] [--push-to-hub]

How it works:
- Episodes are keyed by seed: attempt k uses seed `--seed` + k for the env (layout, occlusion
  schedule) and the expert (timing jitter). The dataset holds the first `--episodes` successful
  seeds, in seed order; unsuccessful attempts are discarded and counted.
- Worker processes (`--workers`, spawn, one env + expert + renderer each, one BLAS/torch thread)
  record an episode, compute its teacher targets and stage it as `<root>/.bavo_staging/seed_*.npz`
  plus a `seed_*.json` marker written last (atomic renames).
- The main process is the only writer into the LeRobotDataset. Every `--commit-every` episodes it
  opens the dataset with `LeRobotDataset.resume`, appends the staged episodes in seed order,
  `finalize()`s, and only then records them in `meta/bavo_collection.json` (the collection record).
- Resume: re-running the same command continues where a killed run stopped. LeRobot keeps its
  parquet writers open until `finalize()`, so a kill inside a commit leaves unreadable files. Each
  commit therefore first snapshots `meta/info.json`, `meta/stats.json`, `meta/tasks.parquet` and
  the list of data / video / episode files (a resumed LeRobot writer only ever adds new files)
  and marks the commit pending in the record; a pending commit found at start-up is rolled back
  (new files deleted, metadata restored) and redone from the staged episodes, which are deleted
  only after the record says they are committed. Finished episodes are never lost or duplicated.
- At the end: exact per-channel point-cloud statistics (`hub.retile_point_cloud_stats`), the
  dataset card (README.md), and optionally `push_to_hub` (needs `huggingface-cli login`).
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import contextlib
import json
import logging
import multiprocessing
import os
import shlex
import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from lerobot_bavo.datasets import schema as S
from lerobot_bavo.datasets.hub import SIDECAR
from lerobot_bavo.features import POINT_FRAMES, ObservationSettings

logger = logging.getLogger("bavo-collect")

STAGING = ".bavo_staging"
RECORD_FORMAT = 1
MANAGED_DIRS = ("data", "videos", os.path.join("meta", "episodes"))
SNAPSHOT_FILES = (os.path.join("meta", "info.json"), os.path.join("meta", "stats.json"),
                  os.path.join("meta", "tasks.parquet"))


@dataclass
class CollectConfig:
    """Arguments of a collection (the CLI's flags).

    Args:
        task, condition: benchmark task and visibility condition.
        episodes: number of successful episodes wanted in the dataset.
        repo_id: `<user>/<name>`; also the default local folder `$HF_LEROBOT_HOME/<repo_id>`.
        root: local dataset folder (default: LeRobot's).
        workers: worker processes; 0 runs episodes in this process (tests, debugging).
        seed: seed of the first attempt (demonstration seeds should stay clear of eval seeds, 1000+).
        commit_every: episodes appended per LeRobot writer session (resume granularity).
        settings: observation settings (image size, points, frame, fovy).
        episode_length: control-step limit per episode (None: the task's own).
        keep_failures: keep unsuccessful episodes too (tests / debugging only).
        use_videos: store the active image as video (LeRobot's default codec).
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
    seed: int = 0
    commit_every: int = 10
    settings: ObservationSettings = field(default_factory=ObservationSettings)
    episode_length: int | None = None
    keep_failures: bool = False
    use_videos: bool = True
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
        if self.commit_every < 1:
            raise ValueError(f"--commit-every must be >= 1, got {self.commit_every}")
        if self.seed < 0:
            raise ValueError(f"--seed must be >= 0, got {self.seed}")
        if "/" not in self.repo_id:
            raise ValueError(f"--repo-id must look like '<user>/<name>', got {self.repo_id!r}")

    def resolved_root(self) -> Path:
        if self.root is not None:
            return Path(self.root)
        from lerobot.utils.constants import HF_LEROBOT_HOME

        return Path(HF_LEROBOT_HOME) / self.repo_id

    def record_settings(self) -> dict:
        """What must match for a run to continue an existing dataset."""
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
            "use_videos": self.use_videos,
            "teacher": {"name": "simulator-exact", "clip_length": S.CLIP_LENGTH, "anchor_index": S.ANCHOR_INDEX,
                        "n_future": S.N_FUTURE, "visibility_tol_m": 0.01},
        }


# ================================================================== worker side
_RECORDER = None
_RECORDER_KEY = None


def _init_worker(parent: int | None = None) -> None:
    from lerobot_bavo.runtime import init_worker

    init_worker(parent)


def run_job(job: dict) -> dict:
    """Record one seeded episode, compute its teacher targets and stage it; returns its summary.

    Runs in a worker process (or in-process with --workers 0). Writes `<staging>/seed_<seed>.npz`
    (dataset columns) when the episode is kept, then `<staging>/seed_<seed>.json` (the summary)
    as the completion marker; both through atomic renames.
    """
    global _RECORDER, _RECORDER_KEY
    from lerobot_bavo.datasets.recording import EpisodeRecorder

    settings = ObservationSettings(**job["settings"])
    key = (job["task"], job["condition"], settings, job["episode_length"])
    if _RECORDER_KEY != key:
        if _RECORDER is not None:
            _RECORDER.close()
        _RECORDER = EpisodeRecorder(job["task"], job["condition"], settings, job["episode_length"])
        _RECORDER_KEY = key
    cpu0 = time.process_time()
    record = _RECORDER.record(int(job["seed"]))
    return stage_episode(record, Path(job["staging"]), record.success or job["keep_failures"], cpu0)


def stage_episode(record, staging: Path, kept: bool, cpu0: float | None = None) -> dict:
    """Compute a recorded episode's teacher targets and stage it for `Collector._commit`; returns its summary.

    Writes `<staging>/seed_<seed>.npz` (dataset columns) when `kept`, then `<staging>/seed_<seed>.json`
    (the summary) as the completion marker; both through atomic renames. Also used by `bavo-teleop`.
    """
    from lerobot_bavo.datasets.recording import episode_frames
    from lerobot_bavo.teacher.simulator import teacher_targets

    cpu0 = time.process_time() if cpu0 is None else cpu0
    seed = int(record.seed)
    summary = {"seed": seed, "success": record.success, "kept": kept, "length": record.length,
               "progress": record.final_progress, "recoveries": record.recoveries,
               "episode_s": round(record.timings["episode_s"], 3), "source": record.source}
    if kept:
        t0 = time.perf_counter()
        targets = teacher_targets(record, n_future=S.N_FUTURE, clip_length=S.CLIP_LENGTH, anchor_index=S.ANCHOR_INDEX)
        summary["teacher_s"] = round(time.perf_counter() - t0, 3)
        summary["valid_frames"] = int(targets["valid"].sum())
        cols = episode_frames(record, targets)
        t0 = time.perf_counter()
        tmp = staging / f"seed_{seed:08d}.npz.tmp"
        with open(tmp, "wb") as f:
            np.savez(f, **{_npz_key(k): v for k, v in cols.items()})
        os.replace(tmp, staging / f"seed_{seed:08d}.npz")
        summary["stage_s"] = round(time.perf_counter() - t0, 3)
    summary["cpu_s"] = round(time.process_time() - cpu0, 3)
    _write_json_atomic(staging / f"seed_{seed:08d}.json", summary)
    return summary


def _npz_key(feature: str) -> str:
    return feature.replace(".", "__")


def _feature_key(npz_key: str) -> str:
    return npz_key.replace("__", ".")


def _write_json_atomic(path: Path, obj) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(obj, indent=1))
    os.replace(tmp, path)


# ================================================================== main side
class CollectionError(RuntimeError):
    pass


class _SerialExecutor:
    """Runs jobs at submit time in this process (--workers 0)."""

    def submit(self, fn, *args):
        fut = cf.Future()
        try:
            fut.set_result(fn(*args))
        except BaseException as e:  # noqa: BLE001 (re-raised by fut.result())
            if isinstance(e, KeyboardInterrupt):
                raise
            fut.set_exception(e)
        return fut

    def shutdown(self, wait=True, cancel_futures=False):
        pass


class Collector:
    """One `bavo-collect` run on one dataset folder (see the module docstring)."""

    def __init__(self, cfg: CollectConfig):
        self.cfg = cfg
        self.root = cfg.resolved_root()
        self.staging = self.root / STAGING
        self.settings = cfg.record_settings()
        self.record: dict = {}
        self._committing = False

    # -------------------------------------------------------------- record (sidecar)
    @property
    def record_path(self) -> Path:
        return self.root / SIDECAR

    def _save_record(self) -> None:
        _write_json_atomic(self.record_path, self.record)

    def _open(self) -> None:
        """Create the dataset, or reopen it: check settings, roll back a pending commit, check counts."""
        from lerobot.datasets.lerobot_dataset import LeRobotDataset

        from lerobot_bavo.datasets.hub import read_info, read_sidecar, read_stats

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
                                       use_videos=self.cfg.use_videos)
            ds.finalize()
            del ds
        record = read_sidecar(self.root)
        info = read_info(self.root)
        read_stats(self.root, check_nan=False)  # LeRobot.resume would fail on it later with a bare JSONDecodeError
        if record is None:
            if info["total_episodes"] != 0:
                raise CollectionError(
                    f"{self.root} holds a LeRobot dataset ({info['total_episodes']} episodes) that bavo-collect did not "
                    f"make (no {SIDECAR}); choose another --root")
            record = {"format": RECORD_FORMAT, "repo_id": self.cfg.repo_id, "settings": self.settings,
                      "episodes": [], "discarded": [], "next_seed": self.cfg.seed, "pending_commit": None,
                      "runs": [], "complete": False}
        else:
            self._check_settings(record["settings"])
        self.record = record
        S.check_features(info["features"], n_points=self.cfg.settings.n_points)
        expected_shape = (self.cfg.settings.image_height, self.cfg.settings.image_width, 3)
        if tuple(info["features"][S.OBS_IMAGE]["shape"]) != expected_shape:
            raise CollectionError(f"{self.root} stores images of shape {info['features'][S.OBS_IMAGE]['shape']}, "
                                  f"this run records {expected_shape}")
        self.staging.mkdir(parents=True, exist_ok=True)
        for tmp in self.staging.glob("*.tmp"):
            tmp.unlink()
        if record.get("pending_commit"):
            logger.warning("rolling back an interrupted commit of seeds %s", record["pending_commit"]["seeds"])
            self._rollback()
        else:
            shutil.rmtree(self.staging / "snapshot", ignore_errors=True)
        self._remove_stray_dirs()
        info = read_info(self.root)
        if info["total_episodes"] != len(self.record["episodes"]):
            raise CollectionError(
                f"{self.root}: meta/info.json has {info['total_episodes']} episodes but {SIDECAR} records "
                f"{len(self.record['episodes'])}; the dataset was modified outside bavo-collect")
        self._save_record()

    def _check_settings(self, recorded: dict) -> None:
        diffs = {k: (recorded.get(k), v) for k, v in self.settings.items()
                 if k not in ("task_description", "stage_targets") and recorded.get(k) != v}
        if diffs:
            text = ", ".join(f"{k}: dataset {a!r} vs now {b!r}" for k, (a, b) in diffs.items())
            raise CollectionError(f"{self.root} was collected with other settings ({text}); "
                                  "use the same arguments to continue it, or another --root")

    # -------------------------------------------------------------- snapshot / rollback
    def _managed_files(self) -> list[str]:
        out = []
        for d in MANAGED_DIRS:
            base = self.root / d
            if base.exists():
                out += [str(p.relative_to(self.root)) for p in base.rglob("*") if p.is_file()]
        return sorted(out)

    def _snapshot(self) -> None:
        snap = self.staging / "snapshot"
        shutil.rmtree(snap, ignore_errors=True)
        snap.mkdir(parents=True)
        present = []
        for rel in SNAPSHOT_FILES:
            src = self.root / rel
            if src.exists():
                shutil.copy2(src, snap / Path(rel).name)
                present.append(rel)
        _write_json_atomic(snap / "files.json", {"files": self._managed_files(), "meta": present})

    def _rollback(self) -> None:
        snap = self.staging / "snapshot"
        if not (snap / "files.json").exists():
            raise CollectionError(
                f"{self.root}: an interrupted commit of seeds {self.record['pending_commit']['seeds']} cannot be rolled "
                f"back because its snapshot ({snap}) is gone; start a new collection in another --root")
        listing = json.loads((snap / "files.json").read_text())
        keep = set(listing["files"])
        for rel in self._managed_files():
            if rel not in keep:
                (self.root / rel).unlink()
        for rel in SNAPSHOT_FILES:
            dst = self.root / rel
            if rel in listing["meta"]:
                shutil.copy2(snap / Path(rel).name, dst)
            elif dst.exists():
                dst.unlink()
        for d in MANAGED_DIRS:  # drop directories left empty
            base = self.root / d
            if base.exists():
                for p in sorted(base.rglob("*"), key=lambda p: len(p.parts), reverse=True):
                    if p.is_dir() and not any(p.iterdir()):
                        p.rmdir()
        self.record["pending_commit"] = None
        self._save_record()
        shutil.rmtree(snap, ignore_errors=True)

    def _remove_stray_dirs(self) -> None:
        """LeRobot's temporary encoder / image folders left by a killed writer."""
        for p in self.root.iterdir():
            if p.is_dir() and p.name not in ("data", "videos", "meta", STAGING):
                shutil.rmtree(p, ignore_errors=True)

    # -------------------------------------------------------------- staging
    def _staged_path(self, seed: int, suffix: str) -> Path:
        return self.staging / f"seed_{seed:08d}{suffix}"

    def _scan_staging(self, first_seed: int) -> dict[int, dict]:
        found = {}
        for p in self.staging.glob("seed_*.json"):
            seed = int(p.stem.split("_")[1])
            if seed < first_seed:
                self._drop_staged(seed)
                continue
            summary = json.loads(p.read_text())
            if summary.get("kept") and not self._staged_path(seed, ".npz").exists():
                p.unlink()  # marker without data: redo the episode
                continue
            found[seed] = summary
        for p in self.staging.glob("seed_*.npz"):
            seed = int(p.stem.split("_")[1])
            if seed not in found:
                p.unlink()
        return found

    def _drop_staged(self, seed: int) -> None:
        for suffix in (".npz", ".json"):
            self._staged_path(seed, suffix).unlink(missing_ok=True)

    # -------------------------------------------------------------- commit
    def _commit(self, batch: list[dict], discards: list[dict], next_seed: int) -> None:
        """Append `batch` (summaries of staged kept episodes, seed order) to the dataset."""
        t0 = time.perf_counter()
        self._snapshot()
        self.record["pending_commit"] = {"seeds": [b["seed"] for b in batch], "next_seed": next_seed}
        self._save_record()
        self._committing = True
        first_index = self._write_batch(batch)
        for i, b in enumerate(batch):
            self.record["episodes"].append({"episode_index": first_index + i, "seed": b["seed"], "length": b["length"],
                                            "recoveries": b.get("recoveries")})
        self.record["discarded"].extend({"seed": d["seed"], "progress": d["progress"], "length": d["length"]}
                                        for d in discards)
        self.record["next_seed"] = next_seed
        self.record["pending_commit"] = None
        self.record["complete"] = False
        self._save_record()
        self._committing = False
        for b in batch:
            self._drop_staged(b["seed"])
        for d in discards:
            self._drop_staged(d["seed"])
        shutil.rmtree(self.staging / "snapshot", ignore_errors=True)
        logger.info("committed %d episodes (seeds %s) in %.1f s", len(batch), [b["seed"] for b in batch],
                    time.perf_counter() - t0)

    def _write_batch(self, batch: list[dict]) -> int:
        """One LeRobot writer session: resume, add the staged episodes, finalize. Returns the first new index."""
        from lerobot.datasets.lerobot_dataset import LeRobotDataset

        max_len = max(b["length"] for b in batch)
        # The streaming encoder's queue must hold a whole episode: when it is full LeRobot drops frames.
        ds = LeRobotDataset.resume(self.cfg.repo_id, root=self.root, video_backend="pyav",
                                   streaming_encoding=self.cfg.use_videos, encoder_queue_maxsize=max_len + 16)
        first_index = ds.meta.total_episodes
        description = self.settings["task_description"]
        try:
            with _skip_noop_image_embedding():
                for b in batch:
                    with np.load(self._staged_path(b["seed"], ".npz")) as z:
                        # a dataset begun before a newer optional annotation existed keeps its own features
                        cols = {_feature_key(k): z[k] for k in z.files
                                if _feature_key(k) in ds.features or _feature_key(k) not in S.OPTIONAL_ANNOTATION_KEYS}
                    n = cols[S.ACTION].shape[0]
                    if n != b["length"]:
                        raise CollectionError(f"staged episode seed {b['seed']} has {n} frames, its marker says {b['length']}")
                    if S.ANN_SOURCE not in ds.features:  # a dataset collected before the column existed
                        cols.pop(S.ANN_SOURCE, None)
                    for t in range(n):
                        frame = {k: v[t] for k, v in cols.items()}
                        frame["task"] = description
                        ds.add_frame(frame)
                    ds.save_episode()
            ds.finalize()
        except BaseException:
            _abandon(ds)
            raise
        self._verify_videos(first_index, batch)
        return first_index

    def _verify_videos(self, first_index: int, batch: list[dict]) -> None:
        """Every committed episode's video segment must cover all its frames (no dropped frames)."""
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
        self._open()
        requested = cfg.episodes
        committed = len(self.record["episodes"])
        resolved_upto = int(self.record["next_seed"])
        results = self._scan_staging(resolved_upto)
        run_stats = {"started": time.strftime("%Y-%m-%d %H:%M:%S"), "requested": requested,
                     "committed_before": committed, "workers": cfg.workers, "attempts": 0,
                     "reused_staged": len(results)}
        batch: list[dict] = []
        discards: list[dict] = []
        max_discards = int(cfg.max_discard_ratio * requested) + 10
        bar = _progress(total=requested, initial=committed, enabled=cfg.progress)
        bar.set_postfix(discarded=len(self.record["discarded"]))
        executor = None
        in_flight: dict[cf.Future, int] = {}
        try:
            if committed < requested:
                executor = self._executor()
            while committed < requested:
                # resolve finished attempts in seed order
                while (resolved_upto in results and committed + len(batch) < requested
                       and len(batch) < cfg.commit_every):
                    summary = results.pop(resolved_upto)
                    resolved_upto += 1
                    if summary["kept"]:
                        batch.append(summary)
                        bar.update(1)
                    else:
                        discards.append(summary)
                        total_discards = len(self.record["discarded"]) + len(discards)
                        bar.set_postfix(discarded=total_discards)
                        if total_discards > max_discards:
                            raise CollectionError(
                                f"{total_discards} unsuccessful expert episodes for {committed + len(batch)} kept: the "
                                f"expert for {cfg.task!r} under {cfg.condition!r} fails too often; aborting")
                if batch and (len(batch) >= cfg.commit_every or committed + len(batch) >= requested):
                    self._commit(batch, discards, resolved_upto)
                    committed += len(batch)
                    batch, discards = [], []
                    continue
                if committed >= requested:
                    break
                # keep the workers busy, without attempting more episodes than could be needed
                window = max(1, 2 * cfg.workers)
                while len(in_flight) < window:
                    seed = resolved_upto
                    busy = set(in_flight.values())
                    while seed in results or seed in busy:
                        seed += 1
                    gap = bool(results) and seed < max(results)  # staged results wait for this seed
                    ahead = sum(1 for r in results.values() if r["kept"])
                    if not gap and committed + len(batch) + ahead + len(in_flight) >= requested:
                        break
                    job = {"task": cfg.task, "condition": cfg.condition, "settings": cfg.settings.to_dict(),
                           "episode_length": cfg.episode_length, "keep_failures": cfg.keep_failures,
                           "seed": seed, "staging": str(self.staging)}
                    in_flight[executor.submit(run_job, job)] = seed
                    run_stats["attempts"] += 1
                if not in_flight:
                    if resolved_upto in results:
                        continue
                    raise CollectionError("internal error: nothing in flight and nothing to resolve")
                done, _ = cf.wait(list(in_flight), return_when=cf.FIRST_COMPLETED)
                for fut in done:
                    seed = in_flight.pop(fut)
                    results[seed] = fut.result()  # a worker's exception propagates here
        except BaseException:
            if self._committing:
                logger.warning("interrupted during a commit: rolling it back")
                self._rollback()
                self._committing = False
            raise
        finally:
            bar.close()
            if executor is not None:
                executor.shutdown(wait=False, cancel_futures=True)
        return self._finish(run_stats, time.perf_counter() - t_start)

    def _executor(self):
        if self.cfg.workers == 0:
            return _SerialExecutor()
        os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
        os.environ.setdefault("OMP_NUM_THREADS", "1")
        return cf.ProcessPoolExecutor(max_workers=self.cfg.workers, mp_context=multiprocessing.get_context("spawn"),
                                      initializer=_init_worker, initargs=(os.getpid(),))

    def _finish(self, run_stats: dict, wall: float) -> dict:
        from lerobot_bavo.datasets.card import write_card
        from lerobot_bavo.datasets.hub import retile_point_cloud_stats

        t0 = time.perf_counter()
        per_channel = retile_point_cloud_stats(self.root)
        run_stats.update(finished=time.strftime("%Y-%m-%d %H:%M:%S"), wall_s=round(wall, 1),
                         committed_after=len(self.record["episodes"]))
        self.record["runs"].append(run_stats)
        self.record["complete"] = len(self.record["episodes"]) >= self.cfg.episodes
        self.record["point_cloud_channel_stats"] = {k: np.asarray(v).tolist() for k, v in per_channel.items()
                                                    if k in ("min", "max", "mean", "std")}
        if self.cfg.command:
            self.record["command"] = self.cfg.command
        self._save_record()
        shutil.rmtree(self.staging, ignore_errors=True)
        write_card(self.root, self.cfg.repo_id)
        summary = {
            "root": str(self.root), "episodes": len(self.record["episodes"]),
            "frames": sum(e["length"] for e in self.record["episodes"]),
            "discarded": len(self.record["discarded"]), "attempts_this_run": run_stats["attempts"],
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


def _abandon(ds) -> None:
    """Drop a LeRobot writer after an error without letting its finalizers write anything more.

    The interrupted commit is rolled back from the snapshot; LeRobot's `__del__` safety nets
    would otherwise flush buffered episode metadata into files the rollback deletes.
    """
    writer, meta = getattr(ds, "writer", None), getattr(ds, "meta", None)
    try:
        if writer is not None:
            writer.cancel_pending_videos()
            writer._pq_writer = None
            writer._finalized = True
        if meta is not None:
            meta._metadata_buffer = []
            meta._pq_writer = None
            meta._finalized = True
        ds._is_finalized = True
    except Exception:  # best effort
        pass


@contextlib.contextmanager
def _skip_noop_image_embedding():
    """Skip LeRobot 0.6.1's per-row `embed_images` pass when no column holds embeddable images.

    `DatasetWriter._save_episode_data` calls `io_utils.embed_images`, a row-by-row `datasets.map`
    of `embed_table_storage`, on every episode. With images stored as video no column needs
    embedding, so that pass returns the table unchanged, yet it costs ~13 ms per frame (about
    half of the writer's time). This shim returns the dataset as is in exactly that case.
    """
    import lerobot.datasets.dataset_writer as writer_mod
    from datasets.features.features import require_storage_embed

    original = writer_mod.embed_images

    def embed_images(dataset):
        if any(require_storage_embed(f) for f in dataset.features.values()):
            return original(dataset)
        return dataset

    writer_mod.embed_images = embed_images
    try:
        yield
    finally:
        writer_mod.embed_images = original


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
    p.add_argument("--workers", type=int, default=2, help="worker processes (0: in this process)")
    p.add_argument("--seed", type=int, default=0, help="seed of the first attempt")
    p.add_argument("--commit-every", type=int, default=10, help="episodes per dataset write session")
    p.add_argument("--image-height", type=int, default=240)
    p.add_argument("--image-width", type=int, default=320)
    p.add_argument("--n-points", type=int, default=256)
    p.add_argument("--point-frame", default="base", choices=POINT_FRAMES)
    p.add_argument("--episode-length", type=int, default=None, help="control-step limit (default: the task's)")
    p.add_argument("--keep-failures", action="store_true", help="keep unsuccessful episodes (debugging only)")
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
    os.environ.setdefault("SVT_LOG", "1")  # SVT-AV1 (LeRobot's default video codec): errors only
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
            workers=args.workers, seed=args.seed, commit_every=args.commit_every,
            settings=ObservationSettings(args.image_height, args.image_width, args.n_points, args.point_frame),
            episode_length=args.episode_length, keep_failures=args.keep_failures, push_to_hub=args.push_to_hub,
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
