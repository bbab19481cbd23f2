"""Training views of a BAVO dataset: copies that keep only what one family of policies reads.

Why: `lerobot-train` loads *every* feature of a dataset for every sample, and gives every
`observation.*` key the policy's observation steps. On these 2-core machines that dominates
training time: for a ManiFlow/A-FAR batch the full BAVO schema costs far more per sample (video
decoding, point pixels, camera pose, annotations, all unused) than the point-cloud view
(docs/results/costs.md). LeRobot's built-in image policies (ACT, Diffusion) additionally cannot read our
flattened point cloud at evaluation (the env returns it as (N, 6), the dataset stats are flat),
so they must be trained on a copy without it.

Two views, each written with LeRobot's own `dataset_tools.remove_feature` (so stats, episode
metadata and videos stay consistent):

- `points`: state, action, point cloud and the cached teacher features (`maniflow`, `afar`), plus, for
  base-frame clouds of datasets with `annotation.occluder_pose`, the training-only per-point label
  `observation.teacher.occluder` (1 on the benchmark occluder) that the occluder-dropout recipe reads, and
  for datasets with occlusion annotations the training-only frame label `observation.teacher.recovering`
  (a copy of `annotation.occlusion_active`: 1 while the demonstrator recovers the view) that
  `--policy.recovery_weight` reads;
- `images`: state, action and the active-camera video (`act`, `diffusion`, ...);
- `state`: state, action and the privileged object poses `observation.environment_state`
  (the privileged-state rung of the failure ladder: `maniflow` without perception).

    python -m lerobot_bavo.datasets.views --root outputs/datasets/bavo_cube_handoff --view points
    # -> outputs/datasets/bavo_cube_handoff_points, repo id <repo_id>_points
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from lerobot.utils.constants import DEFAULT_FEATURES  # bookkeeping columns every LeRobot dataset has

from lerobot_bavo.datasets import schema as S

VIEW_KEEPS = {
    "points": (S.OBS_STATE, S.ACTION, S.OBS_POINT_CLOUD, *S.TEACHER_KEYS),
    "images": (S.OBS_STATE, S.ACTION, S.OBS_IMAGE),
    "state": (S.OBS_STATE, S.ACTION, S.OBS_ENV_STATE),
}


def removed_features(features: dict, view: str) -> list[str]:
    """The feature names `view` drops from a dataset with these `features` (info.json's)."""
    if view not in VIEW_KEEPS:
        raise ValueError(f"unknown view {view!r}; expected one of {sorted(VIEW_KEEPS)}")
    keep = set(VIEW_KEEPS[view]) | set(DEFAULT_FEATURES)
    missing = [k for k in VIEW_KEEPS[view] if k not in features]
    if missing:
        raise ValueError(f"the dataset has no {missing} (needed by the {view!r} view); is it a BAVO dataset "
                         "collected with images / teacher features?")
    return [k for k in features if k not in keep]


def view_source(root: Path) -> Path:
    """The dataset folder a view folder was made from (`<root>_<view>` -> `<root>`, as `make_view` names it);
    any other folder is its own source. Only the name is read: the view copy has no `bavo-collect` record,
    its source has, so code that needs the record (collection settings, point frame) looks there."""
    root = Path(root)
    for view in VIEW_KEEPS:
        if root.name.endswith(f"_{view}"):
            return root.with_name(root.name[: -len(view) - 1])
    return root


def make_view(root: Path, view: str, repo_id: str | None = None, output_root: Path | None = None):
    """Write the `view` copy of the BAVO dataset at `root`; returns the new `LeRobotDataset`.

    The copy goes to `<root>_<view>` with repo id `<repo_id>_<view>` unless given. An existing
    output folder is an error (LeRobot would mix files), not silently overwritten.
    """
    from lerobot.datasets.dataset_tools import modify_features
    from lerobot.datasets.io_utils import load_episodes

    from lerobot_bavo.datasets.hub import load_bavo_dataset, read_sidecar
    from lerobot_bavo.runtime.files import restore_default_mode

    root = Path(root)
    record = read_sidecar(root)
    if repo_id is None:
        if record is None:
            raise ValueError(f"{root} has no bavo-collect record; pass --repo-id")
        repo_id = record["repo_id"]
    source = load_bavo_dataset(repo_id, root=root)
    output_root = Path(output_root) if output_root else root.with_name(f"{root.name}_{view}")
    if output_root.exists():
        raise FileExistsError(f"{output_root} exists; remove it or pass another --output-root")
    drop = removed_features(source.meta.features, view)
    point_frame = (record or {}).get("settings", {}).get("point_frame", "base")
    added = {}
    if view == "points" and S.ANN_OCCLUDER_POSE in source.meta.features and point_frame == "base":
        labels = occluder_point_labels(source)
        added[S.TEACHER_OCCLUDER] = (labels, {"dtype": "float32", "shape": [labels.shape[1]], "names": None})
    if view == "points" and S.ANN_ACTIVE in source.meta.features:
        from lerobot_bavo.datasets.fast import column_array

        active = column_array(source.hf_dataset.data.column(S.ANN_ACTIVE)).astype(np.float32).reshape(-1, 1)
        added[S.TEACHER_RECOVERING] = (active, {"dtype": "float32", "shape": [1], "names": None})
    view_ds = modify_features(source, add_features=added or None, remove_features=drop,
                              output_dir=output_root, repo_id=f"{source.repo_id}_{view}")
    restore_default_mode(Path(output_root).glob("videos/*/*/*.mp4"))  # copies keep the source's 0600 mp4s
    if drop_stale_episode_columns(output_root):
        # the episode table just rewritten, read as LeRobot's metadata reads it
        view_ds.meta.episodes = load_episodes(Path(output_root))
    return view_ds


def stale_episode_columns(columns, features) -> list[str]:
    """Episode-metadata columns about features a dataset no longer has (`stats/<key>/...`,
    `videos/<key>/...`). LeRobot 0.6.1's `modify_features` keeps them when it drops a feature, and its
    `split_dataset` then fails re-aggregating them (an image's statistics in a dataset without that image)."""
    return [c for c in columns if c.split("/")[0] in ("stats", "videos") and c.split("/")[1] not in features]


def drop_stale_episode_columns(root: Path) -> int:
    """Rewrite `root/meta/episodes/*/*.parquet` without `stale_episode_columns`; returns how many columns
    went (0: nothing rewritten). Views made before this existed still carry them; this mends them in place."""
    import json

    import pandas as pd

    features = json.loads((Path(root) / "meta" / "info.json").read_text())["features"]
    dropped = 0
    for file in sorted((Path(root) / "meta" / "episodes").glob("*/*.parquet")):
        table = pd.read_parquet(file)
        stale = stale_episode_columns(table.columns, features)
        if stale:
            table.drop(columns=stale).to_parquet(file, index=False)
            dropped += len(stale)
    return dropped


def occluder_point_labels(source, rows_per_block: int = 4096) -> np.ndarray:
    """(frames, N) float32: 1 where a frame's cloud point lies on the benchmark occluder (`points_on_occluder`
    with the frame's `annotation.occluder_pose`), in the dataset's row order. Base-frame clouds only."""
    from lerobot_bavo.datasets.fast import column_array
    from lerobot_bavo.envs.occlusion import points_on_occluder

    table = source.hf_dataset.data
    cloud = column_array(table.column(S.OBS_POINT_CLOUD))
    pose = column_array(table.column(S.ANN_OCCLUDER_POSE))
    n = cloud.shape[1] // S.POINT_CHANNELS
    out = np.zeros((len(cloud), n), dtype=np.float32)
    for a in range(0, len(cloud), rows_per_block):
        xyz = cloud[a:a + rows_per_block].reshape(-1, n, S.POINT_CHANNELS)[..., :3]
        out[a:a + rows_per_block] = points_on_occluder(xyz, pose[a:a + rows_per_block])
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--root", type=Path, required=True, help="the BAVO dataset folder (bavo-collect --root)"
    )
    parser.add_argument("--view", choices=sorted(VIEW_KEEPS), required=True,
                        help="points: for maniflow/afar; images: for LeRobot's image policies; "
                             "state: privileged object poses for a state-only maniflow")
    parser.add_argument(
        "--repo-id", default=None, help="the dataset's repo id (default: from its collection record)"
    )
    parser.add_argument(
        "--output-root", type=Path, default=None, help="where the copy goes (default <root>_<view>)"
    )
    args = parser.parse_args(argv)
    try:  # the source is checked whole first (`hub.load_bavo_dataset`): a damaged file is named, not copied
        ds = make_view(args.root, args.view, args.repo_id, args.output_root)
    except (FileNotFoundError, FileExistsError, ValueError) as e:
        raise SystemExit(f"lerobot_bavo.datasets.views: {e}") from None
    print(
        f"wrote {ds.root} (repo id {ds.repo_id}): {ds.meta.total_episodes} episodes, {ds.meta.total_frames} "
        "frames, "
        f"features {[k for k in ds.meta.features if k not in DEFAULT_FEATURES]}"
    )


if __name__ == "__main__":
    main()
