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
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
from pathlib import Path

from lerobot_bavo.datasets.metadata import SIDECAR, read_sidecar
from lerobot_bavo.datasets.views import drop_stale_episode_columns, view_source


def parse_source(text: str) -> tuple[Path, int]:
    """'ROOT:EPISODES' -> (root, episodes); a clear error otherwise."""
    root, sep, count = text.rpartition(":")
    if not sep or not root or not count.isdigit() or int(count) < 1:
        raise argparse.ArgumentTypeError(f"--source wants ROOT:EPISODES (a positive count), got {text!r}")
    return Path(root), int(count)


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


def mixed_record(records: list[dict], counts: list[int], roots: list[Path], repo_id: str) -> dict:
    """The joined view's collection record: the first source's settings with the mix's condition, and the
    episodes it kept from each source (episode index renumbered, seed as recorded)."""
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
            {"root": str(view_source(root)), "episodes": count, "condition": cond}
            for root, count, cond in zip(roots, counts, conditions, strict=True)
        ],
    }


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--source", action="append", type=parse_source, required=True,
                    help="ROOT:EPISODES, a training view and how many of its first episodes to keep; repeat")
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

    roots = [root for root, _ in args.source]
    counts = [count for _, count in args.source]
    records = [read_record(root) for root in roots]
    with tempfile.TemporaryDirectory(dir=args.output.parent) as tmp:
        heads = []
        for i, (root, count) in enumerate(args.source):
            info = json.loads((root / "meta" / "info.json").read_text())
            if count > info["total_episodes"]:
                raise SystemExit(f"{root} has {info['total_episodes']} episodes, fewer than {count}")
            clean = clean_copy(root, Path(tmp) / f"clean{i}")
            dataset = LeRobotDataset(f"local/{root.name}", root=clean)
            if count == info["total_episodes"]:
                heads.append(dataset)
                continue
            part = split_dataset(dataset, {f"head{i}": list(range(count))}, output_dir=Path(tmp) / f"s{i}")
            heads.append(part[f"head{i}"])
        merge_datasets(heads, output_repo_id=repo_id, output_dir=args.output)
    source = view_source(args.output)
    (source / SIDECAR).parent.mkdir(parents=True, exist_ok=True)
    (source / SIDECAR).write_text(json.dumps(mixed_record(records, counts, roots, repo_id), indent=1))
    info = json.loads((args.output / "meta" / "info.json").read_text())
    print(f"{args.output}: {info['total_episodes']} episodes, {info['total_frames']} frames; record at "
          f"{source / SIDECAR}")


if __name__ == "__main__":
    main()
