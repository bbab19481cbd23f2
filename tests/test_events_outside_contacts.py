"""Occlusion events held out of the expert's contact phases (`BavoEnv.hold_occlusion_events`,
`bavo-collect --events-outside-contacts`): a held event starts at the first step after the hold, the
schedule is otherwise unchanged, and only collections that ask for it are affected."""

from __future__ import annotations

import numpy as np
import pytest

from lerobot_bavo.datasets.collect import CollectConfig, build_parser
from lerobot_bavo.datasets.recording import EpisodeRecorder
from lerobot_bavo.envs.bavo_env import BavoEnv
from lerobot_bavo.experts.base import in_contact_phase
from lerobot_bavo.features import ObservationSettings
from lerobot_bavo.sim import constants as C

SEED = 4


@pytest.fixture(scope="module")
def env():
    env = BavoEnv(task="cube_handoff", condition="random", n_points=32, image_height=48, image_width=64,
                  render_mode=None)
    yield env
    env.close()


def event_steps(env, held_steps: set[int], n_steps: int, seed: int = SEED) -> tuple[list[int], list[int]]:
    """The env steps at which events started (0: the one at reset) when events are held for the steps in
    `held_steps` (a step's number is `elapsed_steps` after it), and the episode's sampled triggers."""
    _, info = env.reset(seed=seed)
    started = [0] if info["occlusion"]["event_started"] else []
    action = np.asarray(C.HOME_ACTION, dtype=np.float32)
    for step in range(1, n_steps + 1):
        env.hold_occlusion_events(step in held_steps)
        _, _, _, _, info = env.step(action)
        assert info["elapsed_steps"] == step
        if info["occlusion"]["event_started"]:
            started.append(step)
    return started, info["occlusion"]["triggers"]


def test_a_held_event_starts_at_the_first_step_after_the_hold(env):
    free, triggers = event_steps(env, set(), 10)
    t1, t2, t3 = triggers[:3]
    assert t2 - t1 > 60 and t3 - t2 > 60  # the schedule's gap rule, so the steps below are unambiguous
    # never held: the events start at reset and at each trigger
    assert event_steps(env, set(), t2 + 1)[0] == [0, t1, t2]
    # held over the first trigger: it waits until the step after the hold, the next one is untouched
    held = set(range(t1 - 3, t1 + 5))
    assert event_steps(env, held, t2 + 1)[0] == [0, t1 + 5, t2]
    # held over two triggers: one event after the hold, not two
    held = set(range(t1, t2 + 2))
    assert event_steps(env, held, t3 + 1)[0] == [0, t2 + 2, t3]
    # a hold that ends before the trigger changes nothing
    assert event_steps(env, set(range(1, t1)), t1 + 1)[0] == [0, t1]


def test_reset_lifts_the_hold_and_forgets_a_pending_event(env):
    _, triggers = event_steps(env, set(), 1)
    t1 = triggers[0]
    env.reset(seed=SEED)
    env.hold_occlusion_events(True)
    action = np.asarray(C.HOME_ACTION, dtype=np.float32)
    for _ in range(t1 + 1):  # the first trigger falls due while held: pending
        env.step(action)
    _, info = env.reset(seed=SEED)
    assert info["occlusion"]["event_started"] and info["occlusion"]["num_events"] == 1  # the reset event
    _, _, _, _, info = env.step(action)
    assert not info["occlusion"]["event_started"]  # the pending one went with the old episode


class PhasedAgent:
    """Holds the arms at home; in phase "grasp" (its only contact phase) for the steps in `grasp_steps`
    (numbered as `elapsed_steps` after them), "reach" otherwise."""

    contact_phases = frozenset({"grasp"})
    recovering = False

    def __init__(self, grasp_steps: set[int]):
        self.grasp_steps, self.step, self.phase = grasp_steps, 0, "idle"

    def reset(self):
        self.step, self.phase = 0, "idle"

    def act(self, obs, info):
        self.step += 1
        self.phase = "grasp" if self.step in self.grasp_steps else "reach"
        return np.asarray(C.HOME_ACTION, dtype=np.float32)


def test_recorder_holds_events_only_in_contact_phases_and_only_when_asked(env):
    t1 = event_steps(env, set(), 1)[1][0]
    grasp = set(range(t1 - 2, t1 + 4))
    rec = EpisodeRecorder("cube_handoff", "random", ObservationSettings(48, 64, 32), episode_length=t1 + 8)
    try:
        plain = rec.record(SEED, agent=PhasedAgent(grasp))
        outside = rec.record(SEED, agent=PhasedAgent(grasp), events_outside_contacts=True)
    finally:
        rec.close()
    # frame k is the observation after k steps: an event started at step k is marked at frame k
    assert np.flatnonzero(plain.event_start).tolist() == [0, t1]
    assert np.flatnonzero(outside.event_start).tolist() == [0, t1 + 4]
    np.testing.assert_array_equal(plain.action, outside.action)


def test_in_contact_phase():
    class Expert:
        contact_phases = frozenset({"grasp", "release"})
        phase = "grasp"

    assert in_contact_phase(Expert())
    Expert.phase = "carry"
    assert not in_contact_phase(Expert())
    assert not in_contact_phase(object())  # a human operator declares no phases


def test_collection_settings_record_it_and_refuse_it_without_occlusion():
    base = CollectConfig(task="cube_handoff", condition="random", episodes=1, repo_id="a/b")
    assert "events_outside_contacts" not in base.record_settings()  # older records still match
    on = CollectConfig(task="cube_handoff", condition="random", episodes=1, repo_id="a/b",
                       events_outside_contacts=True)
    assert on.record_settings()["events_outside_contacts"] is True
    with pytest.raises(ValueError, match="--events-outside-contacts needs an occluded condition"):
        CollectConfig(task="cube_handoff", condition="clean", episodes=1, repo_id="a/b",
                      events_outside_contacts=True)
    args = build_parser().parse_args(["--task", "cube_handoff", "--condition", "random", "--episodes", "1",
                                      "--repo-id", "a/b", "--events-outside-contacts"])
    assert args.events_outside_contacts
