"""The JSON metadata files of a local BAVO dataset, read with errors that name the file.

`meta/info.json` (LeRobot's), `meta/stats.json` (LeRobot's) and `meta/bavo_collection.json` (the
`bavo-collect` record, `SIDECAR`). Only the standard library: every part of `datasets/` (card, hub, the
collection pipeline) reads these, so this module sits below all of them.
"""

from __future__ import annotations

import json
from pathlib import Path

SIDECAR = Path("meta") / "bavo_collection.json"
CODEBASE_VERSION = "v3.0"
# A joined view's `mixed_from` entries (`scripts/mix_views.py --weigh W --source ROOT:N:WEIGHT`) record
# WEIGHT under the key for W: the weight, in the action losses, of the source's frames W names.
MIX_WEIGHT_KEYS = {"outside-recovery": "outside_recovery_weight", "recovery": "recovery_weight",
                   "all": "all_frames_weight"}


def read_info(root: str | Path) -> dict:
    """`meta/info.json` of a local dataset, with clear errors for a missing or corrupted file."""
    path = Path(root) / "meta" / "info.json"
    if not path.is_file():
        raise FileNotFoundError(f"no LeRobot dataset at {root}: {path} does not exist")
    try:
        info = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise ValueError(f"corrupted dataset metadata {path}: not valid JSON ({e})") from e
    if not isinstance(info, dict) or not isinstance(info.get("features"), dict):
        raise ValueError(
            f"corrupted dataset metadata {path}: no 'features' object (got "
            f"{type(info.get('features')).__name__ if isinstance(info, dict) else type(info).__name__})"
        )
    version = info.get("codebase_version")
    if version != CODEBASE_VERSION:
        raise ValueError(f"{path}: dataset format {version!r}, expected LeRobot {CODEBASE_VERSION!r}")
    return info


def read_stats(root: str | Path, check_nan: bool = True) -> dict:
    """`meta/stats.json` of a local dataset ({} if absent), with errors naming the file for bad JSON or NaN.

    NaN statistics would make every normalised value NaN and a training run learn nothing, silently.
    `check_nan=False` checks only that the file reads (LeRobot's own loader fails on it with a bare
    `JSONDecodeError`), for callers that only append episodes and let LeRobot recompute the statistics."""
    import math

    path = Path(root) / "meta" / "stats.json"
    if not path.is_file():
        return {}
    try:
        stats = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise ValueError(f"corrupted dataset statistics {path}: not valid JSON ({e})") from e
    if not isinstance(stats, dict):
        raise ValueError(
            f"corrupted dataset statistics {path}: expected an object, got {type(stats).__name__}"
        )

    if not check_nan:
        return stats

    def has_nan(v) -> bool:
        if isinstance(v, list):
            return any(has_nan(x) for x in v)
        return isinstance(v, float) and math.isnan(v)

    bad = sorted(f"{k}.{name}" for k, d in stats.items() if isinstance(d, dict)
                 for name, v in d.items() if name in ("min", "max", "mean", "std") and has_nan(v))
    if bad:
        raise ValueError(f"dataset statistics {path} hold NaN in {bad[:6]}{' ...' if len(bad) > 6 else ''}; "
                         "recompute them (or re-collect the episodes whose features are NaN)")
    return stats


def read_sidecar(root: str | Path) -> dict | None:
    """The `bavo-collect` record of a dataset (None if absent); errors name the file if it is malformed."""
    path = Path(root) / SIDECAR
    if not path.is_file():
        return None
    try:
        record = json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise ValueError(f"corrupted collection record {path}: {e}") from e
    if not isinstance(record, dict) or not isinstance(record.get("settings"), dict):
        raise ValueError(f"corrupted collection record {path}: no 'settings' object")
    return record
