"""`bavo-collect`'s writer session without LeRobot: the files LeRobot 0.6.1's writer makes, written directly.

Why (issue 30): one process writes a collection's dataset while the workers record, so its CPU is the serial
part of the run. With LeRobot's writer (`writer.WriterSession`) it spent ~2.9 s importing LeRobot's dataset
modules (they import PyTorch, torchvision and `torch._dynamo`), ~1 s opening LeRobot's metadata per session
(`load_episodes` builds a `datasets.Dataset` of every episode row) and ~0.2 s per episode in LeRobot's
bookkeeping around what is really written: on 2 cores with 2 workers that process was ~11 % of all CPU of a
12-episode collection (docs/results/costs.md, "Scaling with workers"). The files themselves are simple: one
parquet file of rows and one mp4 per session, an episode table, `info.json`, `stats.json`, `tasks.parquet`.

`DirectWriterSession` writes them itself with the procedures of `lerobot_format.py`, following LeRobot's own
steps for an append session (`LeRobotDataset.resume`; per episode `save_episode(episode_data=...)` with the
episode's mp4 and statistics from its worker, as `WriterSession._save_prebuilt` hands them over; `finalize`):
- open: `meta/info.json` (as `DatasetInfo` normalises it), the task table, `meta/stats.json` (as
  `load_stats` reads it) and the last episode row (where LeRobot's writer continues: the next data, video and
  episode files);
- per episode: the writer-assigned columns (`episode_index`, `frame_index`, `timestamp`, `index`,
  `task_index`) as LeRobot computes them, the episode statistics (the worker's, image statistics included,
  plus `episode_stats` for the assigned columns), the parquet rows (LeRobot's table and file choice; its page
  encoding but for the list columns, "Data pages" below), the mp4 (moved into a new file, or appended with
  LeRobot's concatenation, or a new file once the current one is full), the video's `info` entry for episode
  0, the episode row (buffered and written ten at a time, LeRobot's file choice included), the counts and the
  running dataset statistics (`aggregate_stats`);
- finish: the parquet writers closed, `info.json` and `stats.json` written once (LeRobot rewrites them after
  every episode; the last version is the one that stays).

Data pages: LeRobot's writer asks Arrow to dictionary-encode every column of the data files. For the wide
float columns (point cloud, teacher targets: values that never repeat) Arrow builds a dictionary of up to 1 MB
per column chunk, finds it too large and falls back to plain encoding: ~0.05 s of CPU per 240 x 320 episode
for pages 30 % larger than plain ones (6.2 vs 4.7 MB per episode) that also decode slower (0.014 vs 0.009 s
per episode). So these files dictionary-encode only the columns of one value per row (episode, frame and
task indices, annotations), where it pays, and store the list columns plain: the same rows, values and Arrow
schema (`tests/test_direct_writer.py` compares the decoded tables; every other file is LeRobot's bytes),
smaller files, a fifth of the writing CPU. LeRobot starts a new data file when its size estimate passes
`data_files_size_in_mb` (100 MB), so a session of more than ~16 full-size episodes (`--commit-every`) puts
more episodes in one file than LeRobot's writer would; `lerobot_encoding=True` writes LeRobot's bytes.

What it does not do, it refuses (`CollectionError` before anything is written): features LeRobot would store
in parquet other than numbers (images, strings, 2-D arrays), an episode staged without its mp4, columns
that are not exactly the features' dtypes and widths. `bavo-collect` uses it whenever the dataset stores
video (every episode's worker encoded its mp4); datasets without video and `bavo-teleop` keep LeRobot's
writer. `tests/test_direct_writer.py` writes the same staged episodes through both, over several sessions, and
compares every file byte for byte (`stats.json` by value: LeRobot's key order varies from run to run; the data
files with `lerobot_encoding`, else by their decoded tables).
"""

from __future__ import annotations

import contextlib
import os
import shutil
from pathlib import Path

import numpy as np

from lerobot_bavo.datasets import lerobot_format as F
from lerobot_bavo.datasets import schema as S
from lerobot_bavo.datasets.collect_config import CollectionError
from lerobot_bavo.datasets.episode_payload import image_frame_stats
from lerobot_bavo.datasets.episode_stats import compute_episode_stats
from lerobot_bavo.datasets.metadata import read_info
from lerobot_bavo.datasets.staging import staged_video
from lerobot_bavo.datasets.video_codec import encoder_record
from lerobot_bavo.datasets.writer import CommitSession


def _link_or_copy(source: Path, target: Path) -> None:
    """`target` becomes `source`'s file (a hard link: the staged mp4 stays until the commit is recorded)."""
    try:
        os.link(source, target)
    except OSError:
        shutil.copyfile(source, target)


class DirectWriterSession(CommitSession):
    """One commit written without LeRobot (see the module docstring); `CommitSession` does the snapshot, the
    record and the checks around it.

    Args:
        session, timings, run_t0: as `writer.CommitSession`'s.
        lerobot_encoding: dictionary-encode every column of the data files, as LeRobot's writer does, so that
            they are LeRobot's bytes too. False (`bavo-collect`): only the columns of one value per row (see
            the module docstring, "Data pages"); every other file is LeRobot's either way.
    """

    def __init__(self, session, timings: dict | None = None, run_t0: float | None = None,
                 lerobot_encoding: bool = False):
        self.lerobot_encoding = lerobot_encoding
        self._data_writer = None  # the open parquet writer of the session's data file
        self._rows_writer = None  # ... and of its episode-table file
        self._appended = 0
        super().__init__(session, timings, run_t0)

    # ------------------------------------------------------------------ open
    def _open_writer(self) -> int:
        root = self.session.root
        self.info = F.normalized_info(read_info(root))
        self.features = {k: {**ft, "shape": tuple(ft["shape"])} for k, ft in self.info["features"].items()}
        self.video_keys = [k for k, ft in self.features.items() if ft["dtype"] == "video"]
        try:
            self.schema = F.arrow_schema(self.features)
        except F.UnsupportedFeature as e:
            raise CollectionError(f"{root}: {e} cannot be written without LeRobot's writer") from None
        if any((self.features[k].get("info") or {}).get("is_depth_map") for k in self.video_keys):
            raise CollectionError(f"{root}: depth videos cannot be written without LeRobot's writer")
        self.tasks = F.read_tasks(root) if self.info["total_tasks"] > 0 else None
        self.stats = F.load_stats(root)
        self.last = None  # the last episode row before this session (where LeRobot's writer continues)
        if self.info["total_episodes"] > 0:
            columns = ["dataset_to_index", "data/chunk_index", "data/file_index", "meta/episodes/chunk_index",
                       "meta/episodes/file_index"]
            columns += [f"videos/{k}/{c}" for k in self.video_keys for c in ("chunk_index", "file_index")]
            self.last = F.last_episode(root, columns)
        self.encoder = encoder_record(self.session.video_codec) if self.video_keys else None
        self._data_at = None  # (chunk, file, next frame index) after the session's last data rows
        self._data_file_start = 0  # the first frame index of the current data file
        self._rows: list[dict] = []  # episode rows not yet written (LeRobot's metadata buffer)
        self._latest_row = None  # the session's last episode row (LeRobot's `meta.latest_episode`)
        return self.info["total_episodes"]

    def _feature_names(self):
        return self.features

    # ------------------------------------------------------------------ one episode
    def _append(self, summary: dict, cols: dict, stats: dict, n: int) -> None:
        session, info, features = self.session, self.info, self.features
        seed = int(summary["seed"])
        video = staged_video(session.staging, summary)
        if self.video_keys and (video is None or not video.exists() or self.video_keys != [S.OBS_IMAGE]):
            raise CollectionError(f"staged episode seed {seed} has no video of its own (videos "
                                  f"{self.video_keys} expected): only LeRobot's writer can encode it")
        unknown = sorted(set(cols) - set(features))
        if unknown:
            raise CollectionError(f"staged episode seed {seed} has columns the dataset lacks: {unknown}")
        episode_index = info["total_episodes"]
        description = session.settings["task_description"]
        if self.tasks is None or description not in self.tasks:  # LeRobot's save_episode_tasks
            F.write_tasks(session.root, [description], had_tasks=self.tasks is not None)
            self.tasks = [*(self.tasks or []), description]
        buffer = self._episode_columns(cols, n, episode_index, self.tasks.index(description), seed)
        known = {k: v for k, v in stats.items() if k in cols}
        episode_stats = compute_episode_stats(buffer, features, known=known)
        table = F.episode_table(buffer, self.schema)
        if table is None:
            expected = {k: (ft["dtype"], ft["shape"]) for k, ft in features.items() if k in buffer}
            got = {k: (str(v.dtype), v.shape[1:] or (1,)) for k, v in buffer.items()}
            raise CollectionError(f"staged episode seed {seed} does not match the dataset's features: "
                                  f"{ {k: (got[k], e) for k, e in expected.items() if got[k] != e} }")
        metadata = self._write_rows(table, n)
        for key in self.video_keys:
            raw = image_frame_stats(stats.get(key))  # the worker's
            if raw is not None:  # LeRobot scales its encoder's statistics to [0, 1]
                episode_stats[key] = {
                    k: v if k == "count" else np.squeeze(v.reshape(1, -1, 1, 1) / 255.0, axis=0)
                    for k, v in raw.items()}
            metadata.update(self._write_video(key, episode_index, video))
        row = {"episode_index": episode_index, "tasks": [description], "length": n}
        row.update(metadata)
        row.update(F.flatten_dict({"stats": episode_stats}))
        self._add_episode_row(row)
        info["total_episodes"] += 1
        info["total_frames"] += n
        info["total_tasks"] = len(self.tasks)
        info["splits"] = {"train": f"0:{info['total_episodes']}"}
        self.stats = episode_stats if self.stats is None else F.aggregate_stats([self.stats, episode_stats])
        self._appended += 1

    def _episode_columns(self, cols: dict, n: int, episode_index: int, task_index: int, seed: int) -> dict:
        """The episode's parquet columns in feature order, as LeRobot's `save_episode` completes and stacks
        them: the writer-assigned ones computed as LeRobot does, (n, 1) features as (n,)."""
        info = self.info
        assigned = {
            "episode_index": lambda: np.full((n,), episode_index),
            "frame_index": lambda: np.arange(n),
            "timestamp": lambda: np.arange(n) / info["fps"],
            "index": lambda: np.arange(info["total_frames"], info["total_frames"] + n),
            "task_index": lambda: np.array([task_index] * n),
        }
        buffer = {}
        for key, ft in self.features.items():
            if ft["dtype"] == "video":
                continue
            if key in assigned:
                value = assigned[key]()
            elif key in cols:
                value = np.asarray(cols[key])
            else:
                raise CollectionError(f"staged episode seed {seed} lacks the dataset's feature {key!r}")
            if ft["shape"] == (1,) and value.ndim == 2 and value.shape[1] == 1:
                value = value.reshape(n)
            buffer[key] = value
        return buffer

    def _write_rows(self, table, n: int) -> dict:
        """LeRobot's `_save_episode_data`: the session's first episode starts the file after the dataset's
        last one; a later one goes to the open file unless it would pass the size limit."""
        root, info = self.session.root, self.info
        if self._data_at is None:
            chunk, file, frame = 0, 0, 0
            self._data_file_start = 0
            if self.last is not None:
                frame = self.last["dataset_to_index"]
                chunk, file = F.next_file(self.last["data/chunk_index"], self.last["data/file_index"],
                                          info["chunks_size"])
                self._data_file_start = frame
        else:
            chunk, file, frame = self._data_at
            latest_mb = F.size_in_mb(root / info["data_path"].format(chunk_index=chunk, file_index=file))
            in_file = frame - self._data_file_start
            per_frame = latest_mb / in_file if in_file > 0 else 0
            if latest_mb + per_frame * n >= info["data_files_size_in_mb"]:
                chunk, file = F.next_file(chunk, file, info["chunks_size"])
                self._close_data_writer()
                self._data_file_start = frame
        if self._data_writer is None:
            path = root / info["data_path"].format(chunk_index=chunk, file_index=file)
            dictionary = True if self.lerobot_encoding else F.scalar_columns(table.schema)
            self._data_writer = F.parquet_writer(path, table.schema, use_dictionary=dictionary)
        self._data_writer.write_table(table)
        self._data_at = (chunk, file, frame + n)
        return {"data/chunk_index": chunk, "data/file_index": file, "dataset_from_index": frame,
                "dataset_to_index": frame + n}

    def _write_video(self, key: str, episode_index: int, staged: Path) -> dict:
        """LeRobot's `_save_episode_video` with the worker's mp4: the session's first episode starts the file
        after the dataset's last one; a later one is appended to the current file (LeRobot's concatenation of
        the file and the mp4, at once: concatenating several at the end would not give the same bytes, the
        mp4's bitrate box records the chain) unless that would pass the size limit. Episode 0 also records
        the video's properties in `info.json`."""
        root, info = self.session.root, self.info
        episode_mb = F.size_in_mb(staged)
        duration = F.video_duration_s(staged)
        latest = self._latest_row
        if episode_index == 0 or latest is None or f"videos/{key}/chunk_index" not in latest:
            chunk, file = 0, 0
            if self.last is not None:
                chunk, file = F.next_file(self.last[f"videos/{key}/chunk_index"],
                                          self.last[f"videos/{key}/file_index"], info["chunks_size"])
            start = 0.0
            path = root / info["video_path"].format(video_key=key, chunk_index=chunk, file_index=file)
            path.parent.mkdir(parents=True, exist_ok=True)
            _link_or_copy(staged, path)
        else:
            chunk, file = latest[f"videos/{key}/chunk_index"][0], latest[f"videos/{key}/file_index"][0]
            path = root / info["video_path"].format(video_key=key, chunk_index=chunk, file_index=file)
            start = latest[f"videos/{key}/to_timestamp"][0]
            if F.size_in_mb(path) + episode_mb >= info["video_files_size_in_mb"]:
                chunk, file = F.next_file(chunk, file, info["chunks_size"])
                path = root / info["video_path"].format(video_key=key, chunk_index=chunk, file_index=file)
                path.parent.mkdir(parents=True, exist_ok=True)
                _link_or_copy(staged, path)
                start = 0.0
            else:
                F.concatenate_videos([path, staged], path)
        if episode_index == 0:  # LeRobot's update_video_info, from the dataset's first video file
            feature = info["features"][key]
            first = root / info["video_path"].format(video_key=key, chunk_index=0, file_index=0)
            feature["info"] = {**(feature.get("info") or {}), **F.video_info(first, self.encoder)}
        return {"episode_index": episode_index, f"videos/{key}/chunk_index": chunk,
                f"videos/{key}/file_index": file, f"videos/{key}/from_timestamp": start,
                f"videos/{key}/to_timestamp": start + duration}

    def _add_episode_row(self, row: dict) -> None:
        """LeRobot's `_save_episode_metadata`: the row's frame range and episode-table file (the file after
        the dataset's last for the session's first row; the current one unless LeRobot's size estimate passes
        the limit), buffered and written every `METADATA_BUFFER_SIZE` rows."""
        root, info = self.session.root, self.info
        row = {key: [value] for key, value in row.items()}
        n = row["length"][0]
        latest = self._latest_row
        if latest is None:
            chunk, file = 0, 0
            if self.last is not None:
                frames = self.last["dataset_to_index"]
                row["dataset_from_index"] = [frames]
                row["dataset_to_index"] = [frames + n]
                chunk, file = F.next_file(self.last["meta/episodes/chunk_index"],
                                          self.last["meta/episodes/file_index"], info["chunks_size"])
            else:
                row["dataset_from_index"] = [0]
                row["dataset_to_index"] = [n]
            row["meta/episodes/chunk_index"] = [chunk]
            row["meta/episodes/file_index"] = [file]
        else:
            chunk, file = latest["meta/episodes/chunk_index"][0], latest["meta/episodes/file_index"][0]
            path = root / F.EPISODES_PATH.format(chunk_index=chunk, file_index=file) \
                if self._rows_writer is None else Path(self._rows_writer.where)
            if path.exists():
                latest_mb = F.size_in_mb(path)
                latest_frames = latest["episode_index"][0]  # (sic: LeRobot divides by the episode index)
                per_frame = latest_mb / latest_frames if latest_frames > 0 else 0.0
                if latest_mb + per_frame * n >= info["data_files_size_in_mb"]:
                    self._flush_rows()
                    chunk, file = F.next_file(chunk, file, info["chunks_size"])
                    self._close_rows_writer()
            row["meta/episodes/chunk_index"] = [chunk]
            row["meta/episodes/file_index"] = [file]
            row["dataset_from_index"] = [latest["dataset_to_index"][0]]
            row["dataset_to_index"] = [latest["dataset_to_index"][0] + n]
        self._rows.append(row)
        self._latest_row = row
        if len(self._rows) >= F.METADATA_BUFFER_SIZE:
            self._flush_rows()

    def _flush_rows(self) -> None:
        """LeRobot's `_flush_metadata_buffer`."""
        if not self._rows:
            return
        table = F.episode_rows_table(self._rows)
        first = self._rows[0]
        if self._rows_writer is None:
            chunk, file = first["meta/episodes/chunk_index"][0], first["meta/episodes/file_index"][0]
            path = self.session.root / F.EPISODES_PATH.format(chunk_index=chunk, file_index=file)
            self._rows_writer = F.parquet_writer(path, table.schema)
        else:
            table = table.select(self._rows_writer.schema.names)
        self._rows_writer.write_table(table)
        self._latest_row = self._rows[-1]
        self._rows.clear()

    # ------------------------------------------------------------------ end
    def _close_data_writer(self) -> None:
        if self._data_writer is not None:
            self._data_writer.close()
            self._data_writer = None

    def _close_rows_writer(self) -> None:
        self._flush_rows()
        if self._rows_writer is not None:
            self._rows_writer.close()
            self._rows_writer = None

    def _finish_writing(self) -> None:
        self._close_data_writer()
        self._close_rows_writer()
        if self._appended:
            F.write_json(self.info, self.session.root / F.INFO_PATH)
            F.write_stats(self.stats, self.session.root)

    def _drop_writer(self) -> None:
        """Close the open files without writing what is buffered (the rollback deletes them anyway)."""
        self._rows = []
        for writer in (self._data_writer, self._rows_writer):
            if writer is not None:
                with contextlib.suppress(Exception):
                    writer.close()
        self._data_writer = self._rows_writer = None
