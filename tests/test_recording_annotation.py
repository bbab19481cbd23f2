"""`occlusion_annotation`: one step's occlusion columns of a recorded episode, from hand-built `info`."""

from types import SimpleNamespace

import numpy as np
import pytest

from lerobot_bavo.datasets.recording import occlusion_annotation

# Drawer Stowing's shape: the front, then the object, then the front again; transitions at depths 1 and 3.
TASK = SimpleNamespace(stage_targets=("drawer_front", "object", "drawer_front"), stage_transitions=(1, 3))


def occlusion(index: int, target: str, started: bool, visibility: float | None = 0.1) -> dict:
    return {"event": {"index": index, "occluder_pos": np.array([0.1, -0.2, 0.3]),
                      "occluder_quat": np.array([1.0, 0.0, 0.0, 0.0])},
            "event_started": started, "target": target, "visibility": visibility}


def test_clean_steps_carry_the_no_event_values():
    a = occlusion_annotation(TASK, None, progress=2, target_stage=1)
    columns = (a["occlusion_event"], a["event_start"], a["occlusion_target"], a["visibility"])
    assert columns == (-1, 0.0, -1, -1.0)
    np.testing.assert_array_equal(a["occluder_pose"], np.zeros(7))


@pytest.mark.parametrize("progress, stage", [(0, 0), (1, 1), (2, 1)])
def test_an_event_start_takes_the_stage_reached_at_that_step(progress, stage):
    target = TASK.stage_targets[stage]
    a = occlusion_annotation(TASK, occlusion(2, target, started=True), progress=progress, target_stage=-1)
    assert (a["occlusion_event"], a["event_start"], a["occlusion_target"]) == (2, 1.0, stage)
    np.testing.assert_array_equal(a["occluder_pose"], [0.1, -0.2, 0.3, 1.0, 0.0, 0.0, 0.0])


def test_a_target_repeated_in_the_stages_is_matched_at_the_current_depth():
    # "drawer_front" is stage 0 and stage 2: at depth 3 the event's target is stage 2, not the first match.
    a = occlusion_annotation(TASK, occlusion(4, "drawer_front", started=True), progress=3, target_stage=1)
    assert a["occlusion_target"] == 2
    # an event whose target is not the current stage's (not aligned with the stages): the first match
    a = occlusion_annotation(TASK, occlusion(5, "drawer_front", started=True), progress=1, target_stage=1)
    assert a["occlusion_target"] == 0


def test_the_target_stays_fixed_for_the_event_span_and_unknown_visibility_is_minus_one():
    # after the start the milestone depth may pass a transition; the event's target does not change
    a = occlusion_annotation(TASK, occlusion(2, "object", started=False, visibility=None), progress=3,
                             target_stage=1)
    assert (a["occlusion_target"], a["event_start"], a["visibility"]) == (1, 0.0, -1.0)
