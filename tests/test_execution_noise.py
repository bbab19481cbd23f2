"""DART-style execution noise for demonstrations (`experts/perturbation.py`,
`bavo-collect --execution-noise`)."""

from __future__ import annotations

import numpy as np
import pytest

from lerobot_bavo.datasets.collect import CollectConfig, main
from lerobot_bavo.datasets.recording import EpisodeRecorder
from lerobot_bavo.experts.perturbation import PERTURBED_JOINTS, ExecutionNoise, ar1_step
from lerobot_bavo.features import ObservationSettings
from lerobot_bavo.sim import constants as C


def test_ar1_step_hand_computed():
    # x' = rho x + sqrt(1 - rho^2) std eps
    out = ar1_step(np.array([1.0, -2.0]), 0.5, 2.0, np.array([1.0, 0.0]))
    np.testing.assert_allclose(out, [0.5 + np.sqrt(0.75) * 2.0, -1.0])


def test_stationary_std_is_the_configured_one():
    noise = ExecutionNoise(std=0.01, correlation=0.9).process(seed=3)
    action = np.zeros(C.ACTION_DIM)
    offsets = np.stack([noise.perturb(action)[PERTURBED_JOINTS] for _ in range(40_000)])[1000:]
    # 39 K correlated samples (rho 0.9: ~2 K effective per joint, 12 joints): the pooled std is within a few
    # %.
    assert offsets.std() == pytest.approx(0.01, rel=0.05)
    assert abs(offsets.mean()) < 0.002


def test_only_arm_joints_move_and_seed_reproduces():
    action = np.linspace(-1, 1, C.ACTION_DIM).astype(np.float32)
    a = ExecutionNoise(std=0.02).process(seed=7)
    b = ExecutionNoise(std=0.02).process(seed=7)
    c = ExecutionNoise(std=0.02).process(seed=8)
    untouched = np.setdiff1d(np.arange(C.ACTION_DIM), PERTURBED_JOINTS)
    assert set(untouched) == {C.LEFT_GRIPPER, C.RIGHT_GRIPPER, *range(21)[C.CAMERA_ARM]}
    for _ in range(5):
        pa, pb, pc = a.perturb(action), b.perturb(action), c.perturb(action)
        assert pa.dtype == action.dtype
        np.testing.assert_array_equal(pa, pb)
        assert not np.array_equal(pa, pc)
        np.testing.assert_array_equal(pa[untouched], action[untouched])
        assert np.all(pa[PERTURBED_JOINTS] != action[PERTURBED_JOINTS])
    # std 0 is off: the action comes back unchanged
    np.testing.assert_array_equal(ExecutionNoise().process(seed=1).perturb(action), action)


@pytest.mark.parametrize("kwargs", [{"std": -0.01}, {"std": float("nan")}, {"correlation": 1.0}])
def test_bad_noise_is_refused(kwargs):
    with pytest.raises(ValueError, match="execution noise"):
        ExecutionNoise(**kwargs)


def test_recorder_keeps_clean_actions_and_is_seeded():
    rec = EpisodeRecorder("cube_handoff", "clean", ObservationSettings(48, 64, 32), episode_length=40)
    try:
        clean = rec.record(5)
        noisy = rec.record(5, execution_noise=ExecutionNoise(std=0.02))
        again = rec.record(5, execution_noise=ExecutionNoise(std=0.02))
    finally:
        rec.close()
    np.testing.assert_array_equal(noisy.state, again.state)  # same seed, same perturbed episode
    np.testing.assert_array_equal(noisy.action, again.action)
    arm = PERTURBED_JOINTS
    # the arms were pushed off the plan
    assert np.abs(noisy.state[20:, arm] - clean.state[20:, arm]).max() > 0.005
    # The reach phase plans from the cube's pose at reset, in the expert's own joint space: its recorded
    # targets are the clean ones although the executed ones were perturbed.
    np.testing.assert_array_equal(noisy.action, clean.action)


def test_noise_is_part_of_what_a_resumed_collection_must_match():
    base = CollectConfig(task="cube_handoff", condition="stage", episodes=1, repo_id="a/b")
    assert "execution_noise" not in base.record_settings()  # records made before the option still match
    noisy = CollectConfig(task="cube_handoff", condition="stage", episodes=1, repo_id="a/b",
                          execution_noise=ExecutionNoise(std=0.01))
    assert noisy.record_settings()["execution_noise"] == {"std": 0.01, "correlation": 0.9,
                                                                "clean_contacts": False}


def test_cli_refuses_negative_noise(tmp_path, capsys):
    code = main(
        [
            "--task",
            "cube_handoff",
            "--episodes",
            "1",
            "--repo-id",
            "a/b",
            "--root",
            str(tmp_path / "d"),
            "--execution-noise",
            "-0.1",
            "--workers",
            "0",
            "--no-progress",
        ]
    )
    assert code == 2
    assert "execution noise std" in capsys.readouterr().err


def test_contact_phases_are_executed_clean_and_restart_the_offset():
    action = np.zeros(C.ACTION_DIM)
    a = ExecutionNoise(std=0.02).process(seed=4)
    for _ in range(10):
        a.perturb(action)
    assert np.abs(a.offset).max() > 0
    np.testing.assert_array_equal(a.perturb(action, quiet=True), action)  # a contact phase: the plan, exactly
    np.testing.assert_array_equal(a.offset, 0.0)
    # after it, the offset grows again from zero: one step of AR(1) from 0 is sqrt(1 - rho^2) std eps
    first = a.perturb(action)[PERTURBED_JOINTS]
    assert np.abs(first).max() < 5 * np.sqrt(1 - 0.81) * 0.02


@pytest.mark.parametrize("module, name", [("cube_handoff", "CubeHandoffExpert"),
                                          ("block_stacking", "BlockStackingExpert"),
                                          ("dustpan_sweeping", "DustpanSweepingExpert"),
                                          ("drawer_stowing", "DrawerStowingExpert")])
def test_contact_phases_are_phases_of_their_expert(module, name):
    """A misspelt contact phase would silently leave that phase noisy: each must be one the script emits."""
    import importlib
    import inspect

    expert = getattr(importlib.import_module(f"lerobot_bavo.experts.{module}"), name)
    assert expert.contact_phases
    source = inspect.getsource(expert.script)
    for phase in expert.contact_phases:
        assert f'"{phase}"' in source, phase  # phase="..." or a carry's positional phase


def test_quiet_only_in_declared_contact_phases_and_only_when_asked():
    from types import SimpleNamespace

    grasping = SimpleNamespace(phase="grasp", contact_phases=frozenset({"grasp"}))
    reaching = SimpleNamespace(phase="reach", contact_phases=frozenset({"grasp"}))
    assert ExecutionNoise(std=0.01, clean_contacts=True).quiet_for(grasping)
    assert not ExecutionNoise(std=0.01, clean_contacts=True).quiet_for(reaching)
    assert not ExecutionNoise(std=0.01).quiet_for(grasping)  # off by default
    assert not ExecutionNoise(std=0.01, clean_contacts=True).quiet_for(SimpleNamespace())  # no phases: never
