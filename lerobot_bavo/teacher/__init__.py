"""4D teacher for A-FAR: the query protocol, the simulator-exact teacher and the relation math.

- `protocol`: `Teacher` protocol, `EpisodeClip`, query layout (u, v, t_src, t_tgt, t_cam), clips
  of 32 frames around an anchor (paper, Appendix B).
- `simulator`: `SimulatorTeacher` (exact answers from simulator state) and `teacher_targets`
  (the per-frame cache written into datasets as `observation.teacher.*`).
- `relations`: pure torch relation functions shared with the A-FAR loss.

See `lerobot_bavo/teacher/README.md` for why real D4RT weights are not used and how to plug in a
learned teacher.
"""

from lerobot_bavo.teacher.protocol import (
    ANCHOR_INDEX,
    CLIP_LENGTH,
    FUTURE_INDEX,
    QUERY_FIELDS,
    EpisodeClip,
    Teacher,
    clip_frames,
    make_clip,
    normalized_uv,
    point_queries,
)
from lerobot_bavo.teacher.simulator import SimulatorTeacher, teacher_targets

__all__ = [
    "ANCHOR_INDEX",
    "CLIP_LENGTH",
    "FUTURE_INDEX",
    "QUERY_FIELDS",
    "EpisodeClip",
    "SimulatorTeacher",
    "Teacher",
    "clip_frames",
    "make_clip",
    "normalized_uv",
    "point_queries",
    "teacher_targets",
]
