"""Checks of a local dataset's metadata and committed files, before LeRobot opens it or anything copies it.

Why:
- LeRobot's `LeRobotDatasetMetadata` fetches `meta/` from the Hub repo its repo id names, into the local
  folder, whenever a local metadata file is missing (`meta/episodes/`, `meta/tasks.parquet`). A resumed
  `bavo-collect` must never reach the Hub, so `metadata_problems` is checked before LeRobot opens the dataset.
- The file check read only parquet footers and opened the mp4 containers. A parquet file with damaged pages,
  or an mp4 cut short (LeRobot writes them `faststart`, index first, so a cut-off file still opens), passed:
  a resumed collection kept it and the views builder copied it, both with exit 0, and training failed on it.
  `check_committed_files` reads every parquet page and compares each file's rows with what the episode
  metadata says it holds, and demuxes every mp4 (and decodes its last group of pictures), comparing its frame
  count with the episodes stored in it. Cost: seconds for a 100-episode dataset, mostly parquet reads
  (docs/results/costs.md).
"""

from __future__ import annotations

from pathlib import Path

EPISODES_DIR = Path("meta") / "episodes"
TASKS_FILE = Path("meta") / "tasks.parquet"


def metadata_problems(root: str | Path, info: dict) -> list[str]:
    """What LeRobot needs in `meta/` to open the dataset at `root` without the Hub, and is missing: the task
    table when `info` counts tasks, the episode table when it counts episodes."""
    root = Path(root)
    problems = []
    if info.get("total_tasks", 0) and not (root / TASKS_FILE).is_file():
        problems.append(f"{root / TASKS_FILE} is missing ({info['total_tasks']} task(s) in meta/info.json)")
    if info.get("total_episodes", 0) and not sorted((root / EPISODES_DIR).glob("*/*.parquet")):
        problems.append(
            f"{root / EPISODES_DIR} holds no episode table ({info['total_episodes']} episode(s) in "
            "meta/info.json)"
        )
    return problems


def parquet_rows(path: Path, what: str) -> int:
    """Rows of the parquet file at `path`, reading every page (not just the footer); ValueError naming it."""
    import pyarrow.parquet as pq

    try:
        f = pq.ParquetFile(path)
        # a row group at a time (an episode, in a LeRobot data file), on this thread: Arrow's reader threads
        # and small batches cost 2-4x the CPU for the same pages (docs/results/costs.md)
        rows = sum(f.read_row_group(i, use_threads=False).num_rows for i in range(f.num_row_groups))
    except Exception as e:  # pyarrow raises ArrowInvalid / OSError / others for damaged files
        raise ValueError(f"corrupted {what} file {path}: {type(e).__name__}: {e}") from e
    if rows != f.metadata.num_rows:
        raise ValueError(f"corrupted {what} file {path}: its pages hold {rows} rows, its footer says "
                         f"{f.metadata.num_rows}")
    return rows


def video_frames(path: Path) -> int:
    """Frames in the first video stream of the mp4 at `path`: every packet is read, and the packets from the
    last keyframe on are decoded (a file cut short has fewer packets than its index promises, or a last group
    of pictures that does not decode). ValueError naming the file otherwise."""
    import av

    try:
        with av.open(str(path)) as container:
            if not container.streams.video:
                raise ValueError("no video stream")
            stream = container.streams.video[0]
            count, tail = 0, []
            for packet in container.demux(stream):
                if packet.size == 0:  # the demuxer's flush packet
                    continue
                count += 1
                tail = [packet] if packet.is_keyframe else tail + [packet]
            decoder = stream.codec_context  # nothing was decoded yet: it starts clean at the keyframe
            decoded = sum(len(decoder.decode(p)) for p in tail) + len(decoder.decode(None))
            if decoded != len(tail):
                raise ValueError(f"its last {len(tail)} packets decode to {decoded} frames")
    except Exception as e:  # av.error.* (InvalidDataError, EOFError ...), ValueError
        raise ValueError(f"corrupted video file {path}: {type(e).__name__}: {e}") from e
    return count


def _episode_rows(root: Path, columns: list[str]) -> list[dict]:
    """The `columns` of every episode row of `meta/episodes/`, each file read whole (ValueError naming a bad
    one)."""
    import pyarrow.parquet as pq

    rows = []
    for path in sorted((root / EPISODES_DIR).glob("*/*.parquet")):
        parquet_rows(path, "episode metadata")
        try:
            table = pq.read_table(path, columns=columns, use_threads=False)
        except Exception as e:
            raise ValueError(f"corrupted episode metadata file {path}: {type(e).__name__}: {e}") from e
        rows += table.to_pylist()
    return rows


def episode_files(
    root: str | Path, info: dict, episodes: list[dict]
) -> dict[Path, tuple[str, int, set[int]]]:
    """Every data and video file the episode rows name -> ("data" or "video", the frames its episodes add up
    to, their indices)."""
    root = Path(root)
    video_keys = [k for k, f in info["features"].items() if isinstance(f, dict) and f.get("dtype") == "video"]
    out: dict[Path, tuple[str, int, set[int]]] = {}
    for e in episodes:
        paths = [("data", info["data_path"].format(chunk_index=int(e["data/chunk_index"]),
                                                   file_index=int(e["data/file_index"])))]
        paths += [
            (
                "video",
                info["video_path"].format(
                    video_key=k,
                    chunk_index=int(e[f"videos/{k}/chunk_index"]),
                    file_index=int(e[f"videos/{k}/file_index"]),
                ),
            )
            for k in video_keys
        ]
        for kind, rel in paths:
            _, frames, indices = out.get(root / rel, (kind, 0, set()))
            out[root / rel] = (kind, frames + int(e["length"]), indices | {int(e["episode_index"])})
    return out


def check_committed_files(root: str | Path, info: dict, check_videos: bool = True,
                          episode_indices: set[int] | None = None) -> None:
    """Raise ValueError naming the first problem of the dataset at `root` (`info`: its meta/info.json):
    missing metadata (`metadata_problems`), an episode table that disagrees with info.json, and for every data
    / video file the episode table names: missing, unreadable, or holding another number of rows / frames than
    its episodes' lengths add up to. `episode_indices`: check only the files holding these episodes (a
    commit's). Files no episode names are not read (a rolled-back writer leaves none)."""
    root = Path(root)
    problems = metadata_problems(root, info)
    if problems:
        raise ValueError(f"dataset at {root} is incomplete: " + "; ".join(problems))
    video_keys = [k for k, f in info["features"].items() if isinstance(f, dict) and f.get("dtype") == "video"]
    columns = ["episode_index", "length", "data/chunk_index", "data/file_index"]
    columns += [f"videos/{k}/{c}" for k in video_keys for c in ("chunk_index", "file_index")]
    episodes = _episode_rows(root, columns) if info.get("total_episodes", 0) else []
    n_frames = sum(int(e["length"]) for e in episodes)
    if len(episodes) != info.get("total_episodes") or n_frames != info.get("total_frames"):
        raise ValueError(
            f"dataset at {root} is inconsistent: meta/info.json declares {info.get('total_episodes')} "
            "episodes / "
            f"{info.get('total_frames')} frames, the episode table holds {len(episodes)} / {n_frames} "
            "(an interrupted write? `bavo-collect` with the same arguments repairs its own datasets)"
        )
    for path, (kind, frames, indices) in sorted(episode_files(root, info, episodes).items()):
        if (kind == "video" and not check_videos) or (
            episode_indices is not None and not indices & episode_indices
        ):
            continue
        if not path.is_file():
            raise ValueError(f"dataset at {root} is incomplete: {kind} file {path} is missing")
        found = parquet_rows(path, "data") if kind == "data" else video_frames(path)
        if found != frames:
            unit = "rows" if kind == "data" else "frames"
            raise ValueError(
                f"corrupted {kind} file {path}: {found} {unit}, its episodes hold {frames} frames"
                + ("" if kind == "data" else " (cut short?)")
            )
