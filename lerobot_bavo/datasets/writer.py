"""The writer side of `bavo-collect`: writer sessions (one per commit), fed episode by episode.

A commit is one writer session (`CommitSession`): snapshot the dataset's metadata and file list, mark the
commit pending in the collection record, open the writer, append staged episodes in seed order (`add`), then
finish the files, check them and record the episodes (`close`). Anything that interrupts it before the record
is saved rolls it back from the snapshot (`abort`); the staged episodes are deleted only after the record says
they are committed, so a rolled-back commit is redone from them by the next run. Two writers fill that frame:
`WriterSession` is LeRobot's (`LeRobotDataset.resume`, `save_episode`, `finalize`, with the shortcuts of
`lerobot_private`), used by `bavo-teleop` and for datasets without video; `direct_writer.DirectWriterSession`
writes the same files without importing LeRobot (issue 30), used by `bavo-collect` when its workers encode the
videos.

What an episode costs LeRobot's writer (issue 30): its worker has already encoded the video and computed the
statistics (`episode_payload.py`), so `add` hands LeRobot one prepared buffer (`_save_prebuilt`) and LeRobot
only assigns indices, writes the parquet rows and episode metadata and appends the mp4; an episode staged
without a video (a dataset without video, `bavo-teleop`) is fed frame by frame as before, with its worker's
statistics.

Why episode by episode (`StreamingWriter`): the writer was a large part of collection CPU (LeRobot's video
stream, parquet, statistics) before issue 30 moved most of it to the workers. When the main loop wrote a
whole batch of `--commit-every` episodes at once, the 2 x `--workers` attempts in flight ran out during the
commit, and the last batch was written after every worker had finished, leaving cores idle. Now each kept
episode is written as soon as it and every lower seed are resolved (quicker than the attempts in flight keep
the workers busy for), into a session opened at the batch's first episode and closed at its last, so the
sessions hold exactly the same episodes as before (the same files, the same record). Writing from a
background thread instead was tried and gave the same wall time and CPU, so the simpler synchronous writer
was kept (the measurements: docs/results/costs.md).
"""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import time
from pathlib import Path

import numpy as np

from lerobot_bavo.datasets import schema as S
from lerobot_bavo.datasets.collect_config import CollectionError
from lerobot_bavo.datasets.collection_record import PendingCommit
from lerobot_bavo.datasets.episode_payload import image_frame_stats
from lerobot_bavo.datasets.lerobot_private import (
    abandon_writer,
    arrow_episode_tables,
    deferred_stats_writes,
    deferred_video_frame_stats,
    exact_fast_episode_stats,
    memoized_task_index,
    prebuilt_episode_videos,
    skip_noop_image_embedding,
)
from lerobot_bavo.datasets.staging import load_staged_payload, staged_video
from lerobot_bavo.datasets.video_codec import encoder_threads, rgb_encoder
from lerobot_bavo.runtime.files import restore_default_mode

logger = logging.getLogger("bavo-collect")

# what a worker reports about an episode's cost (`staging.stage_episode`), kept in the commit's timings
WORKER_COST_KEYS = ("seed", "length", "episode_s", "teacher_s", "payload_s", "stage_s", "cpu_s")
ENCODER_QUEUE_SLACK = 16  # frames beyond the longest episode LeRobot's streaming encoder queue can hold


class CommitSession:
    """One commit: a writer session appending staged episodes to the dataset of `session`, then recorded.

    What every writer does around its files (this class): snapshot the dataset and mark the commit pending
    before anything is written, load each staged episode (`add`), and at `close` check the new files, record
    the episodes in the collection record (the commit point) and delete their staged files; `abort` rolls the
    dataset back to the snapshot. How the files are written is the subclass's: `WriterSession` (LeRobot's
    writer) and `direct_writer.DirectWriterSession` (the same files without LeRobot), through four hooks:
    `_open_writer()` (returns the first new episode index), `_append(summary, columns, stats, n)`,
    `_finish_writing()` (every file whole and closed) and `_drop_writer()` (abandon without writing more).

    Args:
        session: the `session.DatasetSession` whose dataset, record, snapshot and staging folder are used.
        timings: the run's timings; appends `episode_write_s` per episode (seconds), `session_s` per session
            (open + finalize seconds) and one `commits` entry per session (`end_s` since `run_t0`, seconds
            spent writing, CPU seconds of this process meanwhile, and each episode's worker-side costs).
        run_t0: `time.perf_counter()` at the start of the run.
    """

    def __init__(self, session, timings: dict | None = None, run_t0: float | None = None):
        self.session = session
        self.timings = {} if timings is None else timings
        self.run_t0 = run_t0  # perf_counter at the run's start, for the commit's `end_s`
        self.kept: list[dict] = []
        self.discards: list[dict] = []
        self._busy_s, self._cpu_s = 0.0, 0.0
        self._overhead_s = 0.0  # session open + finalize, the per-session cost
        t0, c0 = time.perf_counter(), time.process_time()
        session.snapshot.take()
        record = session.record
        record.pending_commit = PendingCommit([], record.next_seed)
        session.save_record()
        # from here until `close` saves the record, the session is pending: any interruption rolls it back
        try:
            self.first_index = self._open_writer()
        except BaseException:
            self.abort()
            raise
        self._account(t0, c0, overhead=True)

    def _account(self, t0: float, c0: float, overhead: bool = False) -> float:
        dt = time.perf_counter() - t0
        self._busy_s += dt
        self._cpu_s += time.process_time() - c0  # this process, so LeRobot's encoder threads too
        if overhead:
            self._overhead_s += dt
        return dt

    def add_discard(self, summary: dict) -> None:
        """An unsuccessful attempt resolved before this session's last episode: recorded when it closes."""
        self.discards.append(summary)

    def add(self, summary: dict) -> None:
        """Append the staged episode of `summary` (its columns and the statistics its worker computed)."""
        t0, c0 = time.perf_counter(), time.process_time()
        session = self.session
        seed = int(summary["seed"])
        # the record names the seeds this pending session holds (and the next seed if it closed now)
        session.record.pending_commit = PendingCommit([b["seed"] for b in self.kept] + [seed], seed + 1)
        session.save_record()
        columns, stats = load_staged_payload(session.staging, seed)
        # a dataset begun before a newer optional annotation existed keeps its own features
        features = self._feature_names()
        cols = {k: v for k, v in columns.items() if k in features or k not in S.OPTIONAL_ANNOTATION_KEYS}
        n = cols[S.ACTION].shape[0]
        if n != summary["length"]:
            raise CollectionError(
                f"staged episode seed {seed} has {n} frames, its marker says {summary['length']}"
            )
        self._append(summary, cols, stats, n)
        self.kept.append(summary)
        self.timings.setdefault("episode_write_s", []).append(round(self._account(t0, c0), 3))

    def close(self, next_seed: int | None = None) -> int:
        """Finalize, check the videos, record the episodes (the commit point), delete their staged files.
        `next_seed` defaults to the seed after the last episode. Returns the first new episode index."""
        t0, c0 = time.perf_counter(), time.process_time()
        session, record = self.session, self.session.record
        if next_seed is None:
            next_seed = int(self.kept[-1]["seed"]) + 1 if self.kept else record.next_seed
        try:
            self._finish_writing()
            # LeRobot's concatenated mp4s are 0600
            restore_default_mode(session.root.glob("videos/*/*/*.mp4"))
            session.verify_videos(self.first_index, self.kept)
            for i, b in enumerate(self.kept):
                record.episodes.append({"episode_index": self.first_index + i, "seed": b["seed"],
                                        "length": b["length"], "recoveries": b.get("recoveries")})
            record.discarded.extend({"seed": d["seed"], "progress": d["progress"], "length": d["length"]}
                                    for d in self.discards)
            record.next_seed = next_seed
            record.pending_commit = None
            record.complete = False
            session.save_record()
        except BaseException:
            logger.warning("interrupted during a commit: rolling it back")
            self.abort()
            raise
        for s in self.kept + self.discards:
            session.drop_staged(s["seed"])
        session.snapshot.discard()
        self._account(t0, c0, overhead=True)
        self.timings.setdefault("session_s", []).append(round(self._overhead_s, 3))
        self.timings.setdefault("commits", []).append({
            "end_s": None if self.run_t0 is None else round(time.perf_counter() - self.run_t0, 3),
            "busy_s": round(self._busy_s, 3), "cpu_s": round(self._cpu_s, 3),
            "episodes": [{k: b[k] for k in WORKER_COST_KEYS if k in b} for b in self.kept]})
        logger.info("committed %d episodes (seeds %s) in %.1f s of writing", len(self.kept),
                    [b["seed"] for b in self.kept], self._busy_s)
        return self.first_index

    def abort(self) -> None:
        """Drop the session and roll the dataset back to its snapshot (nothing of it stays)."""
        self._drop_writer()
        self.session.rollback()

    # the subclass's part
    def _open_writer(self) -> int:
        raise NotImplementedError

    def _feature_names(self):
        raise NotImplementedError

    def _append(self, summary: dict, cols: dict, stats: dict, n: int) -> None:
        raise NotImplementedError

    def _finish_writing(self) -> None:
        raise NotImplementedError

    def _drop_writer(self) -> None:
        raise NotImplementedError


class WriterSession(CommitSession):
    """A commit through LeRobot's writer (`LeRobotDataset.resume`, `save_episode`, `finalize`), with the
    shortcuts of `lerobot_private` (the same files). `bavo-teleop` and datasets without video use it; an
    episode staged with its mp4 is handed over as one prepared buffer (`_save_prebuilt`), one without frame by
    frame (`add_frame`).

    Args:
        session, timings, run_t0: as `CommitSession`'s.
        max_frames: the longest episode this session may get (LeRobot's streaming encoder drops frames
            once its queue is full, so the queue must hold a whole episode).
    """

    def __init__(self, session, max_frames: int, timings: dict | None = None, run_t0: float | None = None):
        self.max_frames = max_frames
        self._patches = contextlib.ExitStack()
        self.ds = None
        super().__init__(session, timings, run_t0)

    def _open_writer(self) -> int:
        from lerobot.datasets.lerobot_dataset import LeRobotDataset

        try:
            import datasets

            datasets.disable_progress_bars()
        except Exception:
            pass
        session = self.session
        cfg = session.cfg
        codec = session.video_codec
        self.ds = LeRobotDataset.resume(
            cfg.repo_id,
            root=session.root,
            video_backend="pyav",
            streaming_encoding=cfg.use_videos,
            encoder_queue_maxsize=self.max_frames + ENCODER_QUEUE_SLACK,
            rgb_encoder=rgb_encoder(codec),
            encoder_threads=encoder_threads(codec),
        )
        self._known_stats: dict = {}  # the next episode's statistics from its worker
        self._patches.enter_context(skip_noop_image_embedding())
        self._patches.enter_context(exact_fast_episode_stats(self._known_stats))
        self._stats_write = self._patches.enter_context(deferred_stats_writes())
        self._patches.enter_context(memoized_task_index(self.ds))
        self._patches.enter_context(deferred_video_frame_stats())
        self._patches.enter_context(arrow_episode_tables())
        return self.ds.meta.total_episodes

    def _feature_names(self):
        return self.ds.features

    def _append(self, summary: dict, cols: dict, stats: dict, n: int) -> None:
        """As one prepared buffer when its worker encoded the video (`_save_prebuilt`), else frame by frame
        (`add_frame`); either way with the statistics its worker computed."""
        session, ds = self.session, self.ds
        self._known_stats.clear()
        self._known_stats.update({k: v for k, v in stats.items() if k in cols})
        video = staged_video(session.staging, summary)
        if video is not None and session.cfg.use_videos:
            self._save_prebuilt(cols, n, video, image_frame_stats(stats.get(S.OBS_IMAGE)))
        else:
            description = session.settings["task_description"]
            for t in range(n):
                frame = {k: v[t] for k, v in cols.items()}
                frame["task"] = description
                ds.add_frame(frame)
            ds.save_episode()
        self._known_stats.clear()

    def _save_prebuilt(self, cols: dict, n: int, video, video_stats: dict | None) -> None:
        """`save_episode` of one buffer holding the whole episode, with the worker's mp4 and frame statistics
        (`lerobot_private.PrebuiltVideos`): what LeRobot's `add_frame` calls would have gathered (the same
        keys in the same order, the same arrays; frame indices and timestamps as `add_frame` numbers them),
        checked once with LeRobot's `validate_frame` on the first frame instead of on every frame."""
        import tempfile

        from lerobot.datasets.feature_utils import validate_frame

        ds = self.ds
        features = ds.meta.features
        first = {k: v[0] for k, v in cols.items()}
        first["task"] = description = self.session.settings["task_description"]
        for key, ft in features.items():  # the pixels are in the mp4: a blank frame stands in for the check
            if ft["dtype"] == "video":
                first[key] = np.zeros(ft["shape"], dtype=np.uint8)
        validate_frame(first, features)
        buffer: dict = {"size": n, "task": [description] * n}
        for key in features:
            if key == "episode_index":
                buffer[key] = ds.meta.total_episodes
            elif key == "frame_index":
                buffer[key] = np.arange(n)
            elif key == "timestamp":
                buffer[key] = np.arange(n) / ds.meta.fps
            elif features[key]["dtype"] == "video":
                buffer[key] = [None] * n
            else:
                buffer[key] = cols.get(key, [])
        # LeRobot moves (or appends) the mp4 into the dataset and deletes its folder: give it a hard link in a
        # folder of its own, so the staged file stays until the commit is recorded (resume)
        folder = Path(tempfile.mkdtemp(dir=self.session.root))
        link = folder / video.name
        try:
            os.link(video, link)
        except OSError:
            shutil.copyfile(video, link)
        with prebuilt_episode_videos(ds) as videos:  # this episode only: others may come frame by frame
            videos.put({S.OBS_IMAGE: (link, video_stats)})
            ds.save_episode(episode_data=buffer)

    def _finish_writing(self) -> None:
        self.ds.finalize()
        self._stats_write.flush()
        self._patches.close()

    def _drop_writer(self) -> None:
        if self.ds is not None:
            abandon_writer(self.ds)
        self._patches.close()


class StreamingWriter:
    """Appends a run's resolved attempts to the dataset as they come, `commit_every` kept episodes per
    session, the last session ending at the `needed`-th kept episode.

    The main loop calls `put` with every resolved attempt in seed order (a kept episode is written before
    `put` returns), `finish` at the end and `abort` when it is interrupted: an open session that has not
    reached its commit point is rolled back, and its episodes stay staged for the next run.
    """

    def __init__(self, open_session, needed: int, commit_every: int):
        self.open_session = open_session  # () -> a new CommitSession
        self.needed, self.commit_every = needed, commit_every
        self.written = 0  # kept episodes saved into a session (committed or in the open one)
        self._session: CommitSession | None = None
        self._held: list[dict] = []  # attempts discarded while no session was open: they go into the next one

    def put(self, summary: dict) -> None:
        """One resolved attempt, in seed order: a discard joins the open (or next) session; a kept episode is
        appended, opening a session first if none is open, and closes it at its `commit_every`-th episode or
        at the `needed`-th of the run. An error rolls the open session back and propagates."""
        try:
            if not summary["kept"]:
                (self._session.add_discard if self._session is not None else self._held.append)(summary)
                return
            if self._session is None:
                self._session = self.open_session()
                for d in self._held:
                    self._session.add_discard(d)
                self._held = []
            self._session.add(summary)
            self.written += 1
            if len(self._session.kept) >= self.commit_every or self.written >= self.needed:
                done, self._session = self._session, None
                done.close()  # rolls itself back if it fails
        except BaseException:
            self.abort()
            raise

    def finish(self) -> None:
        """The end of the run: a session still open (fewer kept episodes than needed were put) never reached
        its commit point, so it is rolled back."""
        self.abort()

    def abort(self) -> None:
        """Roll back the open session, if any (nothing of it stays in the dataset)."""
        if self._session is not None:
            done, self._session = self._session, None
            logger.warning("interrupted during a commit: rolling it back")
            done.abort()
