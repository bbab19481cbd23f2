"""The command low-pass at inference (`policies/smoothing.py`, `smoothed_action_dims`,
`action_smoothing_alpha`): the filter by hand, its reset, the config's checks, and a policy's sent actions
against its unfiltered commands."""

from __future__ import annotations

import pytest
import torch
from test_policies import ACTION_DIM, make_afar, make_maniflow, observation, randomize_zero_init

from lerobot_bavo.policies.smoothing import ActionLowPass, low_pass_step


def test_low_pass_by_hand():
    # alpha 0.25 on dim 1 only: commands 0, 4, 4, 0 on dim 1 are sent as 0, 1, 1.75, 1.3125
    lp = ActionLowPass(dims=(1,), alpha=0.25)
    sent = [lp(torch.tensor([[9.0, u]]))[0].tolist() for u in (0.0, 4.0, 4.0, 0.0)]
    assert sent == [[9.0, 0.0], [9.0, 1.0], [9.0, 1.75], [9.0, 1.3125]]
    assert low_pass_step(torch.tensor(2.0), torch.tensor(6.0), 0.5).item() == 4.0


def test_first_command_passes_through_and_reset_restarts():
    lp = ActionLowPass(dims=(0, 2), alpha=0.5)
    first = torch.tensor([[1.0, 2.0, 3.0]])
    assert torch.equal(lp(first), first)
    assert torch.equal(lp(torch.tensor([[3.0, 0.0, 5.0]])), torch.tensor([[2.0, 0.0, 4.0]]))
    lp.reset()
    again = torch.tensor([[7.0, 7.0, 7.0]])
    assert torch.equal(lp(again), again)


def test_alpha_one_and_no_dims_send_the_commands_unchanged_and_inputs_are_not_modified():
    commands = [torch.randn(2, 5, generator=torch.Generator().manual_seed(k)) for k in range(4)]
    for lp in (ActionLowPass(dims=(0, 3), alpha=1.0), ActionLowPass(dims=(), alpha=0.25)):
        for c in commands:
            kept = c.clone()
            assert torch.equal(lp(c), kept)
            assert torch.equal(c, kept)


def test_jitter_keeps_the_expected_share_of_its_spread():
    """White jitter of std 1 through the filter keeps sqrt(alpha / (2 - alpha)) of its std (0.378 at 0.25)."""
    lp = ActionLowPass(dims=(0,), alpha=0.25)
    g = torch.Generator().manual_seed(0)
    out = torch.stack([lp(torch.randn(1, 1, generator=g, dtype=torch.float64))[0, 0] for _ in range(20000)])
    assert out[100:].std().item() == pytest.approx((0.25 / 1.75) ** 0.5, rel=0.05)


@pytest.mark.parametrize("alpha", [0.0, -0.1, 1.5, float("nan")])
def test_bad_alpha_is_refused(alpha):
    with pytest.raises(ValueError, match="action_smoothing_alpha` must be in \\(0, 1\\]"):
        make_maniflow(smoothed_action_dims=(14,), action_smoothing_alpha=alpha)


def test_bad_dims_are_refused():
    with pytest.raises(ValueError, match="distinct indices"):
        make_maniflow(smoothed_action_dims=(14, 14), action_smoothing_alpha=0.5)
    with pytest.raises(ValueError, match=f"must index the {ACTION_DIM}-dim action; \\[{ACTION_DIM}\\]"):
        make_maniflow(smoothed_action_dims=(ACTION_DIM,), action_smoothing_alpha=0.5)
    with pytest.raises(ValueError, match="also `binary_action_dims`"):
        make_maniflow(smoothed_action_dims=(6, 14), action_smoothing_alpha=0.5)  # 6: the left gripper


@pytest.mark.parametrize("make", [make_maniflow, make_afar])
def test_policy_sends_its_commands_low_passed_on_the_chosen_dims(make):
    """Same weights, same noise per call: the smoothing policy's actions are the plain policy's commands with
    dims 14-20 filtered by hand and every other dim unchanged, over two chunks; reset restarts the filter."""
    torch.manual_seed(0)
    plain = make(n_action_steps=4)
    randomize_zero_init(plain, seed=0)
    smooth = make(n_action_steps=4, smoothed_action_dims=tuple(range(14, 21)), action_smoothing_alpha=0.25)
    smooth.load_state_dict(plain.state_dict())
    obs = observation()
    noises = [torch.randn(1, 16, ACTION_DIM, generator=torch.Generator().manual_seed(k)) for k in range(2)]
    for _episode in range(2):
        for p in (plain, smooth):
            p.eval()
            p.reset()
        previous = None
        for step in range(8):
            noise = noises[step // 4] if step % 4 == 0 else None
            command = plain.select_action(dict(obs), noise=noise)
            got = smooth.select_action(dict(obs), noise=noise)
            want = command.clone()
            if previous is not None:
                want[:, 14:21] = previous + 0.25 * (command[:, 14:21] - previous)
            torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-6)
            previous = want[:, 14:21]
        assert not torch.allclose(got[:, 14:21], command[:, 14:21])  # the filter did act


def test_lerobot_cli_flags_turn_it_on():
    import draccus
    from test_policies import _Cli

    on = draccus.parse(_Cli, args=["--policy.type=afar", "--policy.smoothed_action_dims=[14,15,16]",
                                   "--policy.action_smoothing_alpha=0.25"]).policy
    assert (tuple(on.smoothed_action_dims), on.action_smoothing_alpha) == ((14, 15, 16), 0.25)
    off = draccus.parse(_Cli, args=["--policy.type=maniflow"]).policy
    assert (tuple(off.smoothed_action_dims), off.action_smoothing_alpha) == ((), 1.0)
