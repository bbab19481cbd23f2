"""Log an `EpisodeData` into a rerun recording (`.rrd` file, web viewer or native viewer)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lerobot_bavo.viz import entities as E
from lerobot_bavo.viz.episode import EpisodeData

APPLICATION_ID = "bavo_view"
# The 3-D view's initial eye (base frame, m): in front of the table, to the right of the camera arm.
EYE_POSITION = (0.55, -0.75, 0.65)
EYE_TARGET = (0.0, -0.05, 0.15)


def blueprint():
    """The default layout: the 3-D scene beside the active view, the time series below."""
    import rerun.blueprint as rrb

    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Horizontal(
                rrb.Spatial3DView(
                    name="scene (base frame)",
                    origin=E.WORLD,
                    eye_controls=rrb.EyeControls3D(
                        position=EYE_POSITION, look_target=EYE_TARGET, eye_up=(0.0, 0.0, 1.0)
                    ),
                ),
                rrb.Spatial2DView(name="active camera", origin=E.PINHOLE),
                column_shares=[3, 2],
            ),
            rrb.Horizontal(
                rrb.TimeSeriesView(
                    name="visibility and events",
                    origin="plots",
                    contents=[f"+ {E.VISIBILITY}", f"+ {E.EVENT_MARKERS}", f"+ {E.RECOVERING}"],
                ),
                rrb.TimeSeriesView(
                    name="progress and milestones",
                    origin="plots",
                    contents=[f"+ {E.PROGRESS}", f"+ {E.MILESTONES}/**"],
                ),
                rrb.TextLogView(name="events", origin=E.EVENTS),
            ),
            row_shares=[3, 1],
        ),
        collapse_panels=True,
    )


def log_episode(rec, ep: EpisodeData, *, teacher: bool = False, relation_point: int | None = None,
                images: bool = True) -> None:
    """Log every frame of `ep` into the recording stream `rec` on the `frame_index` and `time` timelines."""
    import rerun as rr

    if relation_point is not None and not 0 <= relation_point < ep.n_points:
        raise ValueError(
            f"--relation-point {relation_point} is out of range: the clouds have {ep.n_points} points"
        )
    for path, value in E.static_entities(ep).items():
        rec.log(path, value, static=True)
    for k in range(ep.length):
        rec.set_time(E.TIMELINE, sequence=int(ep.frame_index[k]))
        rec.set_time(E.SECONDS, duration=float(ep.timestamp[k]))
        for path, value in E.frame_entities(ep, k, teacher=teacher, relation_point=relation_point,
                                            images=images).items():
            rec.log(path, value)
    indexes = [rr.TimeColumn(E.TIMELINE, sequence=ep.frame_index.astype(np.int64)),
               rr.TimeColumn(E.SECONDS, duration=ep.timestamp.astype(np.float64))]
    for path, values in E.scalar_columns(ep).items():
        rec.send_columns(path, indexes=indexes, columns=rr.Scalars.columns(scalars=values))
    starts = E.event_frames(ep)
    if len(starts):
        v = ep.visibility[starts].astype(np.float64) if ep.visibility is not None else np.zeros(len(starts))
        rec.send_columns(E.EVENT_MARKERS,
                         indexes=[rr.TimeColumn(E.TIMELINE, sequence=ep.frame_index[starts].astype(np.int64)),
                                  rr.TimeColumn(E.SECONDS, duration=ep.timestamp[starts].astype(np.float64))],
                         columns=rr.Scalars.columns(scalars=np.where(v < 0, 0.0, v)))


def new_recording(ep: EpisodeData):
    import rerun as rr

    return rr.RecordingStream(APPLICATION_ID, recording_id=ep.name.replace(" ", "_"))


def write_rrd(ep: EpisodeData, path: str | Path, **kw) -> Path:
    """Write `ep` to an `.rrd` file (with the default layout) and return its path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    rec = new_recording(ep)
    rec.save(path, default_blueprint=blueprint())
    try:
        rec.send_recording_name(ep.name)
        log_episode(rec, ep, **kw)
    finally:
        rec.flush()
        rec.disconnect()
    return path
