"""BAVO-Bench demonstration datasets (LeRobot v3.0): schema, collection (`bavo-collect`), loading, Hub.

- `schema`: the one feature schema (flat array layouts) and the reshaping helpers
  (`unflatten_point_cloud`, ...), used by the policies too; its keys and `ObservationSettings`
  come from `lerobot_bavo.features`.
- `recording`: one scripted-expert episode with the privileged state the teacher needs.
- `collect`: the `bavo-collect` CLI (parallel workers, resume, dataset card, push).
- `hub`: `load_bavo_dataset` (schema + file checks), `push_dataset`, point-cloud statistics.
- `verify`: the metadata and committed-file checks run before a dataset is continued or copied.
- `card`: the dataset card.
"""

from lerobot_bavo.datasets.hub import load_bavo_dataset, push_dataset, retile_point_cloud_stats
from lerobot_bavo.datasets.schema import (
    build_features,
    check_features,
    unflatten_camera_pose,
    unflatten_point_cloud,
    unflatten_point_pixels,
    unflatten_teacher,
)

__all__ = [
    "build_features",
    "check_features",
    "load_bavo_dataset",
    "push_dataset",
    "retile_point_cloud_stats",
    "unflatten_camera_pose",
    "unflatten_point_cloud",
    "unflatten_point_pixels",
    "unflatten_teacher",
]
