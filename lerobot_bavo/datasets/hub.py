"""Loading (with schema and file checks), statistics fix-up and Hub upload of BAVO datasets.

Everything goes through LeRobot's own API: `LeRobotDataset(repo_id, root=...)` to load (offline
with a local `root`), `LeRobotDataset.push_to_hub` to upload (it creates the `v3.0` tag that
loading by repo id needs). A real push needs a Hugging Face token: run `hf auth login`
(or set `HF_TOKEN`) first.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np

from lerobot_bavo.datasets import schema as S
from lerobot_bavo.datasets.metadata import (  # noqa: F401  (also offered here, where they were first)
    CODEBASE_VERSION,
    SIDECAR,
    read_info,
    read_sidecar,
    read_stats,
)

logger = logging.getLogger(__name__)

# Files pushed to the Hub (LeRobot's own ignore list only drops `images/`; our staging area and
# LeRobot's temporary encoder folders must not be uploaded).
PUSH_PATTERNS = ["data/*", "meta/*", "videos/*", "README.md"]


def check_files(root: str | Path, info: dict | None = None, check_videos: bool = True) -> None:
    """Check the metadata and every committed file of a local dataset, reading them whole
    (`verify.check_committed_files`: parquet pages and row counts, mp4 frame counts).

    Raises ValueError naming the first missing or unreadable file, or when the frame / episode counts in the
    files disagree with `meta/info.json` (e.g. a collection killed while writing).
    """
    from lerobot_bavo.datasets.verify import check_committed_files

    root = Path(root)
    check_committed_files(root, info if info is not None else read_info(root), check_videos=check_videos)


def load_bavo_dataset(repo_id: str, root: str | Path | None = None, n_points: int | None = None,
                      require_teacher: bool = True, check_videos: bool = True, **kwargs):
    """`LeRobotDataset(repo_id, root, **kwargs)` after validating the BAVO schema and the files.

    With a local `root` (or an existing `$HF_LEROBOT_HOME/<repo_id>`), the metadata, the schema
    (required keys and shapes for `n_points`, the teacher cache) and every file are checked
    first, so a corrupted or mismatched dataset gives a ValueError naming the feature or file.
    Without a local copy the dataset is loaded (downloaded) by LeRobot and then checked.
    `video_backend` defaults to "pyav" (torchcodec needs a system FFmpeg).

    Raises:
        FileNotFoundError: no dataset at `root`.
        ValueError: schema mismatch (missing feature, wrong shape/dtype, missing teacher cache)
            or a corrupted / inconsistent file.
    """
    from lerobot.datasets.lerobot_dataset import LeRobotDataset
    from lerobot.utils.constants import HF_LEROBOT_HOME

    kwargs.setdefault("video_backend", "pyav")
    local = Path(root) if root is not None else HF_LEROBOT_HOME / repo_id
    if root is not None or (local / "meta" / "info.json").exists():
        info = read_info(local)
        S.check_features(info["features"], n_points=n_points, require_teacher=require_teacher)
        check_files(local, info, check_videos=check_videos)
        read_stats(local)
    try:
        ds = LeRobotDataset(repo_id, root=root, **kwargs)
    except (FileNotFoundError, ValueError):
        raise
    except Exception as e:
        raise ValueError(
            f"LeRobot could not load dataset {repo_id!r} from {local}: {type(e).__name__}: {e}"
        ) from e
    S.check_features(ds.meta.features, n_points=n_points, require_teacher=require_teacher)
    return ds


# ------------------------------------------------------------------ statistics
def retile_point_cloud_stats(root: str | Path, per_channel: dict | None = None) -> dict:
    """Replace the per-element stats of `observation.point_cloud` in `meta/stats.json` by exact
    per-channel stats (over all frames and points) tiled to the flat (N * 6,) layout.

    LeRobot computes statistics per element of a flat feature; for farthest-point-sampled points
    the slot index is arbitrary, so per-element min/max would normalise each slot differently.
    Tiled per-channel stats make LeRobot's element-wise normaliser equal to ManiFlow's per-channel
    `limits` normalisation. Run it again after LeRobot's `delete_episodes` / `merge_datasets`,
    which re-aggregate per-element episode stats. Returns the per-channel (6,) stats.

    `per_channel`: the stats `point_cloud_channel_stats(root)` gives, when computed elsewhere (`bavo-collect`
    splits the channels between its workers, `merge_channel_stats`); computed here when None.
    """
    root = Path(root)
    info = read_info(root)
    n = S.infer_n_points(info["features"])
    if per_channel is None:
        per_channel = point_cloud_channel_stats(root)
    stats_path = root / "meta" / "stats.json"
    stats = json.loads(stats_path.read_text()) if stats_path.exists() else {}
    tiled = S.tile_channel_stats(per_channel, n)
    stats[S.OBS_POINT_CLOUD] = {k: np.asarray(v).tolist() for k, v in tiled.items()}
    tmp = stats_path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(stats, indent=4))
    tmp.replace(stats_path)
    return per_channel


def point_cloud_channel_stats(root: str | Path, channels: list[int] | None = None) -> dict:
    """`schema.channel_stats` of every point of every frame of the dataset at `root` (all its data files), for
    the point channels `channels` (default: all 6), each (len(channels),): the subsets of a split put together
    (`merge_channel_stats`) are the statistics of all channels, bit for bit."""
    import pyarrow.parquet as pq

    chunks = []
    for p in sorted((Path(root) / "data").glob("*/*.parquet")):
        col = pq.read_table(p, columns=[S.OBS_POINT_CLOUD], use_threads=False).column(0)
        flat = np.asarray(col.combine_chunks().flatten().to_numpy(zero_copy_only=False), dtype=np.float32)
        chunks.append(flat.reshape(-1, S.POINT_CHANNELS))
    if not chunks:
        raise ValueError(f"dataset at {root} has no data files")
    return S.channel_stats(np.concatenate(chunks), channels=channels)


def point_cloud_stats_job(job: dict) -> dict:
    """`point_cloud_channel_stats(job["root"], job["channels"])`, as a worker-pool job."""
    return point_cloud_channel_stats(job["root"], job["channels"])


def merge_channel_stats(parts: list[dict]) -> dict:
    """The statistics of all channels from those of consecutive channel subsets, in channel order."""
    return {k: parts[0][k] if k == "count" else np.concatenate([p[k] for p in parts]) for k in parts[0]}


# ------------------------------------------------------------------ Hub
def push_dataset(root: str | Path, repo_id: str, private: bool | None = None, push_videos: bool = True,
                 card_kwargs: dict | None = None) -> None:
    """Upload a finished local BAVO dataset with LeRobot's `push_to_hub` (creates the v3.0 tag).

    The dataset card pushed is LeRobot's template filled with our description (the same text as
    the local README.md). Needs `hf auth login` (or `HF_TOKEN`) for a real push.
    """
    from lerobot_bavo.datasets.card import card_kwargs_for

    root = Path(root)
    sidecar = read_sidecar(root)
    if sidecar is not None and sidecar.get("pending_commit"):
        raise ValueError(
            f"{root} has an unfinished commit: re-run `bavo-collect` with the same arguments first"
        )
    ds = load_bavo_dataset(repo_id, root=root)
    kwargs = card_kwargs_for(root, repo_id) if card_kwargs is None else card_kwargs
    ds.push_to_hub(private=private, push_videos=push_videos, allow_patterns=PUSH_PATTERNS, **kwargs)
