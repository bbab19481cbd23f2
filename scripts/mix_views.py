"""One training view made of the first episodes of several views (issue 27's data variants).

Why: the paper trains on 100 Stage demonstrations. A documented variant asks whether demonstrations from
other visibility conditions (e.g. 50 Stage + 50 Random-time) help a policy under those conditions, at the
same number of demonstrations. `bavo-collect` records one condition per dataset (its settings are checked
when a collection continues), so each condition is collected on its own and the training views are joined
here with LeRobot's own `dataset_tools.split_dataset` / `merge_datasets` (statistics re-aggregated, episode
indices renumbered).

The joined view has no `bavo-collect` run of its own. Code that reads the collection record of a view's
source folder (`view_source`: the point frame a checkpoint was trained in, the card's data summary) finds
one written here: the first source's settings, with `condition` naming the mix (e.g. `stage+random`) and a
`mixed_from` list of the sources, their episode counts and conditions.

    python scripts/mix_views.py --output outputs/datasets/bavo_cube_handoff_mixsr_dart_points \\
        --source outputs/datasets/bavo_cube_handoff_dart_points:50 \\
        --source outputs/datasets/bavo_cube_handoff_dart_random_points:50

A source given as ROOT:EPISODES:WEIGHT is kept for its view recoveries: its frames outside the
demonstrator's recoveries (the points view's label `observation.teacher.recovering` is 0) weigh WEIGHT in the
action losses, every other frame 1. With `--weigh recovery` it is the other way round: the source's recovery
frames weigh WEIGHT, its other frames 1; with `--weigh all` every frame of the source weighs WEIGHT. The
joined view then carries the per-frame label
`observation.teacher.sample_weight`, which `--policy.sample_weights=true` reads (0 leaves only the recoveries
of that source in the losses, or only its other frames, or none; `--policy.loss_weight_dims` limits the weight
to some action dimensions, so `--weigh all` with WEIGHT 0 and the arms' dims leaves the source teaching the
camera arm only).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import shutil
import tempfile
from pathlib import Path

import numpy as np

from lerobot_bavo.datasets.metadata import MIX_WEIGHT_KEYS, SIDECAR, read_sidecar
from lerobot_bavo.datasets.views import drop_stale_episode_columns, view_source
from lerobot_bavo.features import TEACHER_RECOVERING, TEACHER_SAMPLE_WEIGHT

WEIGH = tuple(MIX_WEIGHT_KEYS)  # which frames of a ROOT:EPISODES:WEIGHT source weigh WEIGHT


def parse_source(text: str) -> tuple[Path, int, float | None]:
    """'ROOT:EPISODES' or 'ROOT:EPISODES:WEIGHT' -> (root, episodes, weight or None); a clear error
    otherwise."""
    head, sep, last = text.rpartition(":")
    weight = None
    if sep and head.rpartition(":")[1] and head.rpartition(":")[2].isdigit():  # ROOT:EPISODES:WEIGHT
        try:
            weight = float(last)
        except ValueError:
            weight = math.nan
        if not (math.isfinite(weight) and weight >= 0.0):
            raise argparse.ArgumentTypeError(
                f"--source ROOT:EPISODES:WEIGHT wants a finite WEIGHT >= 0, got {last!r} in {text!r}")
        text = head
    root, sep, count = text.rpartition(":")
    if not sep or not root or not count.isdigit() or int(count) < 1:
        raise argparse.ArgumentTypeError(
            f"--source wants ROOT:EPISODES[:WEIGHT] (a positive count), got {text!r}")
    return Path(root), int(count), weight


def frame_weights(episode_index: np.ndarray, recovering: np.ndarray, episode_weight: np.ndarray,
                  weigh: str = "outside-recovery") -> np.ndarray:
    """(frames, 1) float32 loss weights: the weight of the frame's episode (`episode_weight[episode_index]`, 1
    for episodes of an unweighted source) on the frames `weigh` names, 1 on the others. `weigh`:
    "outside-recovery", the frames the demonstrator did not spend recovering the view (`recovering` <= 0.5),
    "recovery", those it did, or "all", every frame."""
    if weigh not in WEIGH:
        raise ValueError(f"weigh must be one of {WEIGH}, got {weigh!r}")
    recovering = np.asarray(recovering).reshape(-1) > 0.5
    weighted = {"outside-recovery": ~recovering, "recovery": recovering,
                "all": np.ones_like(recovering)}[weigh]
    episode = np.asarray(episode_weight, dtype=np.float32)[np.asarray(episode_index).reshape(-1)]
    return np.where(weighted, episode, np.float32(1.0)).astype(np.float32).reshape(-1, 1)


def read_record(view_root: Path) -> dict:
    """The `bavo-collect` record of the dataset the view `view_root` was made from (`read_sidecar`)."""
    try:
        record = read_sidecar(view_source(view_root))
    except ValueError as e:  # a malformed record: read_sidecar's message names the file
        raise SystemExit(f"{view_root}: {e}") from e
    if record is None:
        raise SystemExit(f"{view_root}: no collection record at {view_source(view_root) / SIDECAR}")
    return record


def clean_copy(view_root: Path, into: Path) -> Path:
    """A copy of the view's `meta/` (the data files linked, not copied) at `into`, without the stale
    episode columns that views made before `make_view` dropped them still carry
    (`drop_stale_episode_columns`)."""
    shutil.copytree(view_root / "meta", into / "meta")
    (into / "data").symlink_to((view_root / "data").resolve(), target_is_directory=True)
    drop_stale_episode_columns(into)
    return into


def mixed_record(records: list[dict], counts: list[int], roots: list[Path], repo_id: str,
                 weights: list[float | None] | None = None, weigh: str = "outside-recovery") -> dict:
    """The joined view's collection record: the first source's settings with the mix's condition, and the
    episodes it kept from each source (episode index renumbered, seed as recorded) and, for weighted sources,
    the weight of the frames `weigh` names."""
    weights = weights or [None] * len(records)
    settings = dict(records[0]["settings"])
    conditions = [r["settings"]["condition"] for r in records]
    settings["condition"] = "+".join(conditions)
    episodes, offset = [], 0
    for record, count in zip(records, counts, strict=True):
        for ep in record["episodes"][:count]:
            episodes.append({**ep, "episode_index": offset + ep["episode_index"]})
        offset += count
    return {
        "format": records[0].get("format", 1),
        "repo_id": repo_id,
        "settings": settings,
        "episodes": episodes,
        "mixed_from": [
            {"root": str(view_source(root)), "episodes": count, "condition": cond,
             **({} if weight is None else {MIX_WEIGHT_KEYS[weigh]: weight})}
            for root, count, cond, weight in zip(roots, counts, conditions, weights, strict=True)
        ],
    }


def add_sample_weights(joined, counts: list[int], weights: list[float | None], output: Path,
                       weigh: str = "outside-recovery"):
    """Write `joined` (a LeRobotDataset) to `output` with the per-frame `observation.teacher.sample_weight`
    (`frame_weights`), using LeRobot's own `dataset_tools.modify_features`."""
    from lerobot.datasets.dataset_tools import modify_features

    from lerobot_bavo.datasets.fast import column_array

    episode_weight = np.concatenate([np.full(count, 1.0 if w is None else w, dtype=np.float32)
                                     for count, w in zip(counts, weights, strict=True)])
    table = joined.hf_dataset.data
    labels = frame_weights(column_array(table.column("episode_index")),
                           column_array(table.column(TEACHER_RECOVERING)), episode_weight, weigh)
    spec = {"dtype": "float32", "shape": [1], "names": None}
    modify_features(joined, add_features={TEACHER_SAMPLE_WEIGHT: (labels, spec)}, output_dir=output,
                    repo_id=joined.repo_id)
    drop_stale_episode_columns(output)


@contextlib.contextmanager
def arrow_cache_in(folder: Path):
    """Keep the Arrow tables Hugging Face `datasets` caches while this script loads views in `folder`.

    The sources are loaded from temporary clean copies, so what `datasets` would cache for them under
    ~/.cache/huggingface/datasets (gigabytes per mix: docs/training.md, "Disk") is keyed by folders that are
    gone when the script ends and could never be reused. The user's setting is restored on exit."""
    import datasets.config

    before = datasets.config.HF_DATASETS_CACHE
    datasets.config.HF_DATASETS_CACHE = folder
    try:
        yield folder
    finally:
        datasets.config.HF_DATASETS_CACHE = before


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--source", action="append", type=parse_source, required=True,
                    help="ROOT:EPISODES[:WEIGHT], a training view and how many of its first episodes to "
                         "keep; with WEIGHT, the frames --weigh names weigh WEIGHT in the action losses "
                         "(--policy.sample_weights=true); repeat")
    ap.add_argument("--weigh", choices=WEIGH, default="outside-recovery",
                    help="which frames of a ROOT:EPISODES:WEIGHT source weigh WEIGHT: those outside the view "
                         "recoveries (default), the recoveries, or all its frames; the other frames weigh 1")
    ap.add_argument("--output", type=Path, required=True, help="the joined view's folder (ends in _points)")
    ap.add_argument("--repo-id", default=None, help="default local/<output folder name>")
    args = ap.parse_args(argv)
    if args.output.exists():
        raise SystemExit(f"{args.output} exists; remove it first")
    if view_source(args.output) == args.output:
        raise SystemExit(f"{args.output}: name the joined folder as a view (<name>_points), so that its "
                         "collection record is found")
    repo_id = args.repo_id or f"local/{args.output.name}"

    from lerobot.datasets.dataset_tools import merge_datasets, split_dataset
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    roots = [root for root, _, _ in args.source]
    counts = [count for _, count, _ in args.source]
    weights = [weight for _, _, weight in args.source]
    records = [read_record(root) for root in roots]
    with (tempfile.TemporaryDirectory(dir=args.output.parent) as tmp,
          arrow_cache_in(Path(tmp) / "hf_datasets")):
        heads = []
        for i, (root, count, _) in enumerate(args.source):
            info = json.loads((root / "meta" / "info.json").read_text())
            if count > info["total_episodes"]:
                raise SystemExit(f"{root} has {info['total_episodes']} episodes, fewer than {count}")
            if weights[i] is not None and TEACHER_RECOVERING not in info["features"]:
                raise SystemExit(f"{root} has no '{TEACHER_RECOVERING}' label to keep its recoveries by; "
                                 "make its points view again (python -m lerobot_bavo.datasets.views)")
            clean = clean_copy(root, Path(tmp) / f"clean{i}")
            dataset = LeRobotDataset(f"local/{root.name}", root=clean)
            if count == info["total_episodes"]:
                heads.append(dataset)
                continue
            part = split_dataset(dataset, {f"head{i}": list(range(count))}, output_dir=Path(tmp) / f"s{i}")
            heads.append(part[f"head{i}"])
        if all(weight is None for weight in weights):
            merge_datasets(heads, output_repo_id=repo_id, output_dir=args.output)
        else:
            add_sample_weights(merge_datasets(heads, output_repo_id=repo_id, output_dir=Path(tmp) / "joined"),
                               counts, weights, args.output, args.weigh)
    source = view_source(args.output)
    (source / SIDECAR).parent.mkdir(parents=True, exist_ok=True)
    record = mixed_record(records, counts, roots, repo_id, weights, args.weigh)
    (source / SIDECAR).write_text(json.dumps(record, indent=1))
    info = json.loads((args.output / "meta" / "info.json").read_text())
    print(f"{args.output}: {info['total_episodes']} episodes, {info['total_frames']} frames; record at "
          f"{source / SIDECAR}")


if __name__ == "__main__":
    main()
