"""Short planned gripper switches held back at inference (`policies/switches.py`, `binary_min_run`): the rule
by hand, the config's checks, and a policy's executed gripper commands for chunks designed to contain a short
opening, a real release and a switch at the horizon's end."""

from __future__ import annotations

import pytest
import torch
from test_policies import ACTION_DIM, make_afar, make_maniflow, observation

from lerobot_bavo.policies.switches import hold_run_levels, hold_short_switches

C, O = -1.0, 1.0  # closed, open (normalised)  # noqa: E741


@pytest.mark.parametrize(
    ("plan", "executed", "min_run", "want"),
    [
        # a chunk that starts a closing ramp from open while the gripper is held closed: the 3-step opening
        # comes back to closed before 4 steps, so it is held back
        ([O, O, O, C, C, C, C, C], C, 4, [C] * 8),
        # the same opening lasting 4 steps is a switch there and back
        ([O, O, O, O, C, C, C, C], C, 4, [O, O, O, O, C, C, C, C]),
        # a release planned to the horizon's end passes, however short its run within the plan
        ([C, C, C, C, C, C, O, O], C, 4, [C, C, C, C, C, C, O, O]),
        # a grasp from open, planned to the end
        ([O, O, O, C, C, C, C, C], O, 4, [O, O, O, C, C, C, C, C]),
        # a short closing in the middle of an open plan is held back; the later long one is kept
        ([O, C, O, O, C, C, C, C], O, 3, [O, O, O, O, C, C, C, C]),
        # no executed level yet (an episode's first chunk): the plan's first level is the current one
        ([O, C, C, O, O, O], None, 3, [O, O, O, O, O, O]),
        # a short run followed by a third level is a switch, not a blip (multi-level snapping)
        ([0.4, 0.4, C, C, C], O, 4, [0.4, 0.4, C, C, C]),
    ],
)
def test_hold_run_levels_by_hand(plan, executed, min_run, want):
    assert hold_run_levels(plan, executed, min_run) == want


def test_tensor_form_acts_on_the_chosen_dims_only_and_keeps_its_input():
    plan = torch.full((2, 6, 4), 0.3)
    plan[:, :, 1] = torch.tensor([O, O, C, C, C, C])
    plan[:, :, 3] = torch.tensor([O, O, C, C, C, C])
    executed = torch.tensor([[0.0, C, 0.0, O], [0.0, O, 0.0, C]])
    kept = plan.clone()
    out = hold_short_switches(plan, (1, 3), 3, executed)
    assert torch.equal(plan, kept)
    assert out[0, :, 1].tolist() == [C] * 6  # closed executed: the 2-step opening is held back
    assert out[0, :, 3].tolist() == [O, O, C, C, C, C]  # open executed: a grasp to the end
    assert out[1, :, 1].tolist() == [O, O, C, C, C, C]
    assert out[1, :, 3].tolist() == [C] * 6
    assert torch.equal(out[:, :, [0, 2]], plan[:, :, [0, 2]])
    assert torch.equal(hold_short_switches(plan, (), 3, executed), plan)


@pytest.mark.parametrize("bad", [0, 1, -3, 2.5, True])
def test_bad_values_are_refused(bad):
    with pytest.raises(ValueError, match="binary_min_run` must be an integer >= 2"):
        make_maniflow(binary_min_run=bad)


def test_refused_without_binary_dims_or_with_ensembling():
    with pytest.raises(ValueError, match="there are none"):
        make_maniflow(binary_min_run=4, binary_action_dims=())
    with pytest.raises(ValueError, match="Set one of them"):
        make_maniflow(binary_min_run=4, n_action_steps=4, temporal_ensemble_coeff=0.01)


def designed_chunks(policy, chunks):
    """Make `policy.generate_actions` return the given (horizon, A) chunks in turn (normalised, snapped)."""
    queue = list(chunks)

    def generate(batch, noise=None, generator=None):
        return queue.pop(0)[None].clone()

    policy.generate_actions = generate


@pytest.mark.parametrize("make", [make_maniflow, make_afar])
def test_policy_executes_a_release_but_not_a_chunk_start_blip(make):
    """n_obs_steps 2, horizon 16, 4 executed per chunk, min run 4, left gripper (dim 6). Chunk 1 closes
    it; chunk 2 plans it open for the first 2 executed steps, then closed (held back: executed closed
    throughout); chunk 3 plans a release to the horizon's end (executed). Without the setting, chunk 2's
    blip is executed."""
    chunks = []
    for levels in ([C] * 16, [C, O, O] + [C] * 13, [C, C, O] + [O] * 13):
        chunk = torch.zeros(16, ACTION_DIM)
        chunk[:, 6] = torch.tensor(levels)
        chunks.append(chunk)
    executed = {}
    for min_run in (None, 4):
        policy = make(n_action_steps=4, binary_min_run=min_run)
        policy.eval()
        policy.reset()
        designed_chunks(policy, chunks)
        obs = observation()
        executed[min_run] = [policy.select_action(dict(obs))[0, 6].item() for _ in range(12)]
    assert executed[4] == [C] * 4 + [C] * 4 + [C, O, O, O]
    assert executed[None] == [C] * 4 + [O, O, C, C] + [C, O, O, O]


def test_lerobot_cli_flag_turns_it_on():
    import draccus
    from test_policies import _Cli

    on = draccus.parse(_Cli, args=["--policy.type=afar", "--policy.binary_min_run=12"]).policy
    assert on.binary_min_run == 12
    assert draccus.parse(_Cli, args=["--policy.type=maniflow"]).policy.binary_min_run is None
