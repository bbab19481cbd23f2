"""The dataset-session API: one run's hold on a BAVO dataset folder (`DatasetSession`).

Why a module of its own: `bavo-collect`, its writer and `bavo-teleop` all write datasets the same way (lock,
open and check, stage, commit in a LeRobot writer session that rolls back if interrupted, finish). They share
these public methods; the scheduling of expert episodes stays in `collect.py`, the LeRobot writer session in
`writer.py`.
"""

from __future__ import annotations

import json
import logging
import shutil
import time

import numpy as np

from lerobot_bavo.datasets import schema as S
from lerobot_bavo.datasets.collect_config import STAGING, CollectConfig, CollectionError
from lerobot_bavo.datasets.collection_record import CollectionRecord
from lerobot_bavo.datasets.lerobot_format import create_dataset
from lerobot_bavo.datasets.metadata import SIDECAR
from lerobot_bavo.datasets.staging import STAGED_SUFFIXES, seed_of, staged_path, staged_video
from lerobot_bavo.datasets.transaction import SnapshotMissing, WriterSessionSnapshot, remove_stray_dirs
from lerobot_bavo.datasets.verify import check_committed_files
from lerobot_bavo.datasets.video_codec import DEFAULT_VIDEO_CODEC, encoder_record, recorded_video_codec
from lerobot_bavo.datasets.video_codec import record_entry as video_codec_record_entry
from lerobot_bavo.datasets.writer import WriterSession
from lerobot_bavo.runtime.files import restore_default_mode

logger = logging.getLogger("bavo-collect")


class DatasetSession:
    """One run's hold on one BAVO dataset folder: its lock, collection record, staging folder and
    writer-session snapshot, and the steps every writer of the dataset takes (the public seam of the
    collection pipeline).

    `bavo-collect` (`collect.Collector`, a subclass that adds the worker pool and the seed scheduler), the
    writer (`writer.WriterSession` / `StreamingWriter`) and `bavo-teleop` (`teleop.session.HumanDataset`) all
    go
    through these methods:

    - `lock()` takes the folder's exclusive lock (close it when done);
    - `open()` creates or reopens the dataset (settings checked, an interrupted commit rolled back, counts and
      committed files checked);
    - `scan_staging(first_seed)` finds episodes a killed run staged but did not commit; `drop_staged(seed)`
      deletes one;
    - `commit(batch, discards, next_seed)` appends staged episodes in one writer session, rolled back if
      interrupted; the writer itself calls `save_record()`, `verify_videos(...)` and `rollback()`;
    - `finish(run_stats, wall)` writes the statistics, the record and the dataset card (and pushes).
    """

    def __init__(self, cfg: CollectConfig):
        self.cfg = cfg
        self.root = cfg.resolved_root()
        self.staging = self.root / STAGING
        # a dataset being continued keeps its own codec unless one is asked for (then it must match: `open`)
        self.settings = cfg.record_settings(cfg.video_codec or DEFAULT_VIDEO_CODEC)
        self.record: CollectionRecord | None = None
        self.snapshot = WriterSessionSnapshot(self.root, self.staging / "snapshot")

    @property
    def video_codec(self) -> str:
        """The codec this run records video with: the one its settings name (`video_codec.py`)."""
        return recorded_video_codec(self.settings) or DEFAULT_VIDEO_CODEC

    def save_record(self) -> None:
        self.record.save(self.root)

    def open(self) -> None:
        """Create the dataset, or reopen it: check settings, roll back a pending commit, check counts."""
        from lerobot_bavo.datasets.metadata import read_info, read_stats

        info_path = self.root / "meta" / "info.json"
        if not info_path.exists():
            if self.root.exists() and any(p.name != STAGING for p in self.root.iterdir()):
                raise CollectionError(
                    f"{self.root} exists and is not a LeRobot dataset; choose another --root"
                )
            if self.root.exists():
                shutil.rmtree(self.root)
            from lerobot_bavo.envs.tasks import environment_state_dim

            features = S.build_features(self.cfg.settings, use_videos=self.cfg.use_videos,
                                        env_state_dim=environment_state_dim(self.cfg.task))
            if self.cfg.use_videos:
                encoder_record(self.video_codec)  # fails here if this PyAV build cannot encode the codec
            # what `LeRobotDataset.create(...).finalize()` writes (meta/info.json), without importing LeRobot
            create_dataset(self.root, S.FPS, features, use_videos=self.cfg.use_videos,
                           robot_type="bavo_av_aloha")
        record = CollectionRecord.load(self.root)
        info = read_info(self.root)
        # LeRobot.resume would fail on it later with a bare JSONDecodeError
        read_stats(self.root, check_nan=False)
        if record is None:
            if info["total_episodes"] != 0:
                raise CollectionError(
                    f"{self.root} holds a LeRobot dataset ({info['total_episodes']} episodes) that "
                    "bavo-collect did not "
                    f"make (no {SIDECAR}); choose another --root"
                )
            record = CollectionRecord(
                repo_id=self.cfg.repo_id, settings=self.settings, next_seed=self.cfg.seed
            )
        else:
            recorded_codec = recorded_video_codec(record.settings)
            if self.cfg.video_codec is None and recorded_codec is not None and self.cfg.use_videos:
                self.use_video_codec(recorded_codec)
            self.check_settings(record.settings)
        self.record = record
        S.check_features(info["features"], n_points=self.cfg.settings.n_points)
        expected_shape = (self.cfg.settings.image_height, self.cfg.settings.image_width, 3)
        if tuple(info["features"][S.OBS_IMAGE]["shape"]) != expected_shape:
            raise CollectionError(
                f"{self.root} stores images of shape {info['features'][S.OBS_IMAGE]['shape']}, "
                f"this run records {expected_shape}"
            )
        self.staging.mkdir(parents=True, exist_ok=True)
        for tmp in self.staging.glob("*.tmp"):
            tmp.unlink()
        if record.pending_commit is not None:
            logger.warning("rolling back an interrupted commit of seeds %s", record.pending_commit.seeds)
            self.rollback()
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
            raise CollectionError(
                f"{e}. The committed episodes must be whole to continue this dataset (LeRobot would "
                "otherwise fetch missing metadata from the Hub, or keep a damaged file): restore "
                "the file, or collect into another --root"
            ) from None
        self.save_record()

    def use_video_codec(self, codec: str) -> None:
        """Record video with `codec` (the settings keep any entry added since construction, e.g. teleop's)."""
        self.settings.pop("video_codec", None)
        self.settings.update(video_codec_record_entry(codec, self.cfg.use_videos))

    def check_settings(self, recorded: dict) -> None:
        """Refuse to continue a dataset recorded with other settings. Both sides' keys are compared: options
        that are recorded only when used (execution noise, a codec other than the legacy one, teleop's human
        source) must be absent on both sides or equal. The codec is compared as `recorded_video_codec` reads
        it, so a record made before the choice existed reads as 'libsvtav1'."""
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

    def rollback(self) -> None:
        try:
            self.snapshot.restore()
        except SnapshotMissing as e:
            raise CollectionError(
                f"{self.root}: an interrupted commit of seeds {self.record.pending_commit.seeds} cannot be "
                "rolled "
                f"back because {e}; start a new collection in another --root"
            ) from None
        self.record.pending_commit = None
        self.save_record()

    # -------------------------------------------------------------- staging
    def scan_staging(self, first_seed: int) -> dict[int, dict]:
        """Finished attempts a killed run left staged (seed >= first_seed), to reuse instead of re-running."""
        found = {}
        for p in self.staging.glob("seed_*.json"):
            seed = seed_of(p)
            if seed < first_seed:
                self.drop_staged(seed)
                continue
            summary = json.loads(p.read_text())
            video = staged_video(self.staging, summary)
            if summary.get("kept") and (not staged_path(self.staging, seed, ".npz").exists()
                                        or (video is not None and not video.exists())):
                p.unlink()  # marker without data: redo the episode
                continue
            found[seed] = summary
        for suffix in STAGED_SUFFIXES[:-1]:
            for p in self.staging.glob(f"seed_*{suffix}"):
                if seed_of(p) not in found:
                    p.unlink()
        return found

    def drop_staged(self, seed: int) -> None:
        for suffix in STAGED_SUFFIXES:
            staged_path(self.staging, seed, suffix).unlink(missing_ok=True)

    # -------------------------------------------------------------- commit
    def commit(
        self, batch: list[dict], discards: list[dict], next_seed: int, timings: dict | None = None
    ) -> None:
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

    def verify_videos(self, first_index: int, batch: list[dict]) -> None:
        """Every committed episode's video segment must cover all its frames (no dropped frames), and the data
        and video files holding the episodes must read whole (`verify.check_committed_files`, as on
        resume)."""
        if not self.cfg.use_videos:
            return
        import pyarrow.dataset as pads

        # Only the two timestamp columns of the new rows are needed. `io_utils.load_episodes` would
        # build a `datasets.Dataset` of the whole episode table with its per-feature stats (~3 s for
        # a few episodes, growing with the dataset); a column-selective pyarrow scan takes ms.
        key = S.OBS_IMAGE
        columns = ["episode_index", f"videos/{key}/from_timestamp", f"videos/{key}/to_timestamp"]
        table = pads.dataset(self.root / "meta" / "episodes", format="parquet").to_table(columns=columns,
                                                                                         use_threads=False)
        rows = {int(e): (f, t) for e, f, t in zip(*(table.column(c).to_pylist() for c in columns))}
        for i, b in enumerate(batch):
            start, stop = rows[first_index + i]
            duration = stop - start
            if abs(duration - b["length"] / S.FPS) > 0.5 / S.FPS:
                raise CollectionError(
                    f"episode {first_index + i} (seed {b['seed']}): video covers {duration:.3f} s for "
                    f"{b['length']} "
                    "frames (dropped frames in the encoder?)"
                )
        from lerobot_bavo.datasets.metadata import read_info

        try:  # and the files holding them: every frame there, the last pictures decodable, the parquet whole
            check_committed_files(self.root, read_info(self.root),
                                  episode_indices={first_index + i for i in range(len(batch))})
        except ValueError as e:
            raise CollectionError(
                f"after writing episodes {first_index}..{first_index + len(batch) - 1}: {e}"
            ) from None

    # -------------------------------------------------------------- lock and end
    def lock(self):
        """An exclusive lock on the dataset's resolved path, so two runs never write one dataset (not even
        through a symlinked spelling of --root)."""
        from lerobot_bavo.runtime.process import LockedError, exclusive_lock

        try:
            return exclusive_lock(self.root, "bavo-collect")
        except LockedError as e:
            raise CollectionError(str(e)) from None

    def finish(self, run_stats: dict, wall: float, point_cloud_stats: dict | None = None) -> dict:
        """The end of a run: the per-channel point-cloud statistics (`hub.retile_point_cloud_stats`;
        `point_cloud_stats`: already computed, `hub.point_cloud_channel_stats`), the record, the card, the
        push. Returns the run's summary."""
        from lerobot_bavo.datasets.card import write_card
        from lerobot_bavo.datasets.hub import retile_point_cloud_stats

        t0 = time.perf_counter()
        per_channel = retile_point_cloud_stats(self.root, point_cloud_stats)
        run_stats.update(finished=time.strftime("%Y-%m-%d %H:%M:%S"), wall_s=round(wall, 1),
                         committed_after=len(self.record.episodes))
        self.record.runs.append(run_stats)
        self.record.complete = len(self.record.episodes) >= self.cfg.episodes
        self.record.extra["point_cloud_channel_stats"] = {
            k: np.asarray(v).tolist() for k, v in per_channel.items() if k in ("min", "max", "mean", "std")
        }
        if self.cfg.command:
            self.record.extra["command"] = self.cfg.command
        self.save_record()
        shutil.rmtree(self.staging, ignore_errors=True)
        write_card(self.root, self.cfg.repo_id)
        summary = {
            "root": str(self.root),
            "episodes": len(self.record.episodes),
            "frames": self.record.frames,
            "discarded": len(self.record.discarded),
            "attempts_this_run": run_stats["attempts"],
            "new_this_run": run_stats["committed_after"] - run_stats["committed_before"],
            "wall_s": round(wall, 1),
            "finish_s": round(time.perf_counter() - t0, 1),
        }
        if self.cfg.push_to_hub:
            from lerobot_bavo.datasets.hub import push_dataset

            try:
                push_dataset(self.root, self.cfg.repo_id, private=self.cfg.private)
            except Exception as e:
                raise CollectionError(
                    f"the dataset is complete at {self.root} but the upload to {self.cfg.repo_id!r} failed "
                    f"({type(e).__name__}: {e}). Log in with `hf auth login` (or set HF_TOKEN) and "
                    "re-run the same command: nothing is recollected."
                ) from e
            summary["pushed"] = self.cfg.repo_id
        return summary
