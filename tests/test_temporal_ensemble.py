"""Temporal ensembling of overlapping action chunks (`policies/ensemble.py`, `temporal_ensemble_coeff`):
ACT's weights by hand, which chunks cover which step, and the policy's actions against the chunks it
generated."""

from __future__ import annotations

import math

import pytest
import torch
from test_policies import ACTION_DIM, make_afar, make_maniflow, observation, randomize_zero_init

from lerobot_bavo.datasets.lerobot_private import policy_action_queue
from lerobot_bavo.policies.ensemble import ChunkEnsemble, ensemble_weights, ensembled_action


def test_weights_are_acts_exponential_oldest_first():
    # coeff = ln 2: raw weights 1, 1/2, 1/4 -> 4/7, 2/7, 1/7
    torch.testing.assert_close(ensemble_weights(3, math.log(2.0), dtype=torch.float64),
                               torch.tensor([4 / 7, 2 / 7, 1 / 7], dtype=torch.float64))
    torch.testing.assert_close(ensemble_weights(4, 0.0), torch.full((4,), 0.25))
    # a negative coefficient favours the newest
    w = ensemble_weights(3, -1.0)
    assert w[2] > w[1] > w[0]
    with pytest.raises(ValueError, match="at least one"):
        ensemble_weights(0, 0.01)


def test_ensembled_action_is_the_weighted_mean():
    a, b = torch.tensor([[0.0, 3.0]]), torch.tensor([[3.0, 0.0]])
    torch.testing.assert_close(ensembled_action([a, b], 0.0), torch.tensor([[1.5, 1.5]]))
    # ln 2: 2/3 on the older, 1/3 on the newer
    torch.testing.assert_close(ensembled_action([a, b], math.log(2.0)), torch.tensor([[1.0, 2.0]]))


def test_chunks_cover_the_steps_they_predict_and_expire():
    """Interval 2, chunks of 3 steps whose entries encode (chunk, offset) as 10 * chunk + offset; coeff 0
    (the plain mean), so each step's action is checked by hand."""
    ens = ChunkEnsemble(coeff=0.0, interval=2)

    def chunk(k: int) -> torch.Tensor:
        return torch.tensor([10.0 * k + i for i in range(3)]).reshape(1, 3, 1)

    expected = {
        0: [0.0],          # chunk 0, offset 0
        1: [1.0],          # chunk 0, offset 1
        2: [2.0, 10.0],    # chunk 0 offset 2, chunk 1 offset 0
        3: [11.0],         # chunk 0 has run out
        4: [12.0, 20.0],
        5: [21.0],
    }
    for step, values in expected.items():
        assert ens.needs_chunk() == (step % 2 == 0)
        if ens.needs_chunk():
            ens.add(chunk(step // 2))
        assert ens.pop().item() == pytest.approx(sum(values) / len(values))
    ens.reset()
    assert ens.step == 0
    with pytest.raises(RuntimeError, match="no stored chunk"):
        ens.pop()
    with pytest.raises(ValueError, match="interval"):
        ens.add(torch.zeros(1, 1, 1))
    with pytest.raises(ValueError, match="finite"):
        ChunkEnsemble(float("nan"), 2)


def test_config_needs_overlapping_chunks_and_a_finite_coefficient():
    make_maniflow(temporal_ensemble_coeff=0.01, n_action_steps=4)  # horizon 16, To 2: 15 predicted
    with pytest.raises(ValueError, match="n_action_steps` must be < horizon - n_obs_steps \\+ 1 = 15"):
        make_maniflow(temporal_ensemble_coeff=0.01, n_action_steps=15)
    with pytest.raises(ValueError, match="temporal_ensemble_coeff` must be a finite number"):
        make_maniflow(temporal_ensemble_coeff=float("inf"), n_action_steps=4)


@pytest.mark.parametrize("make", [make_maniflow, make_afar])
def test_policy_executes_the_ensemble_of_its_own_chunks(make):
    """With the same weights and the same noise per call, an ensembling policy (interval 4, coeff ln 2)
    generates the plain policy's chunks (interval 4, so its 4 executed actions are each chunk's first 4), and
    executes at each step the weighted mean of the stored chunks' predictions for it, gripper dims snapped."""
    from lerobot_bavo.policies.maniflow.modeling_maniflow import snap_binary_dims

    torch.manual_seed(0)
    plain = make(n_action_steps=4, binary_action_dims=())
    randomize_zero_init(plain, seed=0)
    ens = make(n_action_steps=4, binary_action_dims=(), temporal_ensemble_coeff=math.log(2.0))
    ens.load_state_dict(plain.state_dict())
    snapping = make(n_action_steps=4, temporal_ensemble_coeff=math.log(2.0))
    snapping.load_state_dict(plain.state_dict())
    for p in (plain, ens, snapping):
        p.eval()
        p.reset()
    obs = observation()
    noises = [torch.randn(1, 16, ACTION_DIM, generator=torch.Generator().manual_seed(k)) for k in range(3)]
    chunks = []  # the full chunks (from the current step on) of calls 0, 1, 2 (steps 0, 4, 8)
    for k in range(3):
        chunks.append(plain.generate_actions({kk: v[:, None].expand(-1, 2, *v.shape[1:])
                                              for kk, v in obs.items()}, noise=noises[k])[:, 1:])
    for step in range(12):
        noise = noises[step // 4] if step % 4 == 0 else None
        got = ens.select_action(dict(obs), noise=noise)
        snapped = snapping.select_action(dict(obs), noise=noise)
        covering = [c[:, step - 4 * k] for k, c in enumerate(chunks) if 0 <= step - 4 * k < 15]
        raw = [2.0 ** -i for i in range(len(covering))]
        want = sum(w * a for w, a in zip(raw, covering)) / sum(raw)
        torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-6)
        # snapped twice: each chunk as generated (a weighted vote of open / closed), then the mean
        voted = sum(w * snap_binary_dims(a, (6, 13)) for w, a in zip(raw, covering)) / sum(raw)
        torch.testing.assert_close(snapped, snap_binary_dims(voted, (6, 13)), rtol=1e-5, atol=1e-6)
        if step < 4:  # one chunk covers the first interval: the plain policy's action
            torch.testing.assert_close(got, plain.select_action(dict(obs), noise=noise), rtol=1e-5, atol=1e-6)
    assert len(policy_action_queue(ens)) == 0  # the ensemble, not the queue, holds what is to come


def test_lerobot_cli_flags_turn_it_on():
    """`lerobot-eval --policy.temporal_ensemble_coeff=0.01 --policy.n_action_steps=4` parses to the setting
    (draccus, as LeRobot's CLIs parse it); without the flag it is off."""
    import draccus
    from test_policies import _Cli

    on = draccus.parse(_Cli, args=["--policy.type=afar", "--policy.temporal_ensemble_coeff=0.01",
                                   "--policy.n_action_steps=4"]).policy
    assert (on.temporal_ensemble_coeff, on.n_action_steps) == (0.01, 4)
    assert draccus.parse(_Cli, args=["--policy.type=maniflow"]).policy.temporal_ensemble_coeff is None
