"""`--policy.recovery_weight`: the recovery frames' weight in ManiFlow's / A-FAR's action losses (a weighted
mean over samples), read from the training-only label `observation.teacher.recovering` of the points view;
and `--policy.sample_weights`, the per-frame weights `scripts/mix_views.py` writes
(`observation.teacher.sample_weight`)."""

from __future__ import annotations

import math

import pytest
import torch
from lerobot.configs import FeatureType, PolicyFeature

from lerobot_bavo.features import TEACHER_RECOVERING, TEACHER_SAMPLE_WEIGHT
from lerobot_bavo.policies import ManiFlowConfig, ManiFlowPolicy

N_POINTS = 8


def make_policy(**overrides) -> ManiFlowPolicy:
    inputs = {"observation.point_cloud": PolicyFeature(FeatureType.STATE, (N_POINTS * 6,)),
              "observation.state": PolicyFeature(FeatureType.STATE, (21,))}
    outputs = {"action": PolicyFeature(FeatureType.ACTION, (21,))}
    cfg = ManiFlowConfig(input_features=inputs, output_features=outputs, preset="cpu_fast", device="cpu",
                         points_per_step=N_POINTS, **overrides)
    torch.manual_seed(0)
    return ManiFlowPolicy(cfg)


def make_batch(policy: ManiFlowPolicy, b: int = 4) -> dict:
    g = torch.Generator().manual_seed(1)
    to, h = policy.config.n_obs_steps, policy.config.horizon
    return {"observation.point_cloud": torch.randn(b, to, N_POINTS * 6, generator=g),
            "observation.state": torch.randn(b, to, 21, generator=g),
            "action": torch.randn(b, h, 21, generator=g),
            "action_is_pad": torch.zeros(b, h, dtype=torch.bool)}


def loss_of(policy: ManiFlowPolicy, batch: dict) -> float:
    torch.manual_seed(123)  # the same noise, times and consistency draws for every call
    with torch.no_grad():
        return float(policy.forward(batch)[0])


@pytest.mark.parametrize("bad", [0.0, -1.0, math.nan, math.inf])
def test_a_weight_must_be_finite_and_positive(bad):
    with pytest.raises(ValueError, match="recovery_weight"):
        make_policy(recovery_weight=bad)


def test_weights_by_hand_from_the_last_observation_step():
    policy = make_policy(recovery_weight=3.0)
    # (B, To, 1); the last observation step counts
    labels = torch.tensor([[[0.0], [1.0]], [[1.0], [0.0]], [[1.0], [1.0]]])
    assert policy.recovery_weights({TEACHER_RECOVERING: labels}).tolist() == [3.0, 1.0, 3.0]
    with pytest.raises(KeyError, match="recovering"):
        policy.recovery_weights({})
    assert make_policy().recovery_weights({}) is None  # weight 1: nothing to read, no label needed


def test_uniform_weights_leave_the_loss_as_it_is_and_uneven_ones_change_it():
    plain = make_policy()
    weighted = make_policy(recovery_weight=4.0)
    weighted.load_state_dict(plain.state_dict())
    batch = make_batch(plain)
    to = plain.config.n_obs_steps
    reference = loss_of(plain, batch)
    for every in (0.0, 1.0):  # a weighted mean with equal weights is the mean
        labels = torch.full((4, to, 1), every)
        assert loss_of(weighted, {**batch, TEACHER_RECOVERING: labels}) == pytest.approx(reference, rel=1e-5)
    labels = torch.zeros(4, to, 1)
    labels[0, -1] = 1.0
    assert loss_of(weighted, {**batch, TEACHER_RECOVERING: labels}) != pytest.approx(reference, rel=1e-4)



def test_sample_weights_read_the_last_step_and_multiply_the_recovery_weight():
    policy = make_policy(recovery_weight=3.0, sample_weights=True)
    recovering = torch.tensor([[[0.0], [1.0]], [[1.0], [0.0]], [[0.0], [0.0]]])
    sample = torch.tensor([[[9.0], [0.5]], [[9.0], [2.0]], [[9.0], [0.0]]])  # the last step counts
    batch = {TEACHER_RECOVERING: recovering, TEACHER_SAMPLE_WEIGHT: sample}
    assert policy.loss_weights(batch).tolist() == [1.5, 2.0, 0.0]
    assert make_policy(sample_weights=True).loss_weights({TEACHER_SAMPLE_WEIGHT: sample}).tolist() == [
        0.5, 2.0, 0.0]
    assert make_policy().loss_weights({TEACHER_SAMPLE_WEIGHT: sample}) is None  # off: the label is ignored
    with pytest.raises(KeyError, match="sample_weight"):
        make_policy(sample_weights=True).loss_weights({})


def test_sample_weights_give_the_loss_recovery_weight_gives_for_the_same_weights():
    """The same per-sample weights, given as a recovery weight of 4 on samples 0 and 2 or as sample-weight
    labels 4, 1, 4, 1, weight the action losses alike; labels all 1 leave the loss unweighted."""
    plain = make_policy()
    by_recovery = make_policy(recovery_weight=4.0)
    by_label = make_policy(sample_weights=True)
    by_recovery.load_state_dict(plain.state_dict())
    by_label.load_state_dict(plain.state_dict())
    batch = make_batch(plain)
    to = plain.config.n_obs_steps
    recovering = torch.zeros(4, to, 1)
    recovering[[0, 2], -1] = 1.0
    labels = torch.ones(4, to, 1)
    labels[[0, 2], -1] = 4.0
    expected = loss_of(by_recovery, {**batch, TEACHER_RECOVERING: recovering})
    assert loss_of(by_label, {**batch, TEACHER_SAMPLE_WEIGHT: labels}) == pytest.approx(expected, rel=1e-5)
    ones = torch.ones(4, to, 1)
    assert loss_of(by_label, {**batch, TEACHER_SAMPLE_WEIGHT: ones}) == pytest.approx(loss_of(plain, batch),
                                                                                     rel=1e-5)


def test_occluder_dropout_can_spare_the_recovery_frames():
    """With `occluder_dropout_in_recovery=false` a recovery frame keeps the panel's points where they are
    even at dropout probability 1; the other frames lose them, as with the recipe."""
    from lerobot_bavo.features import TEACHER_OCCLUDER

    policy = make_policy(occluder_dropout=1.0, occluder_dropout_in_recovery=False)
    policy.config.points_per_step = 4
    n = N_POINTS
    cloud = torch.arange(2 * 2 * n * 6, dtype=torch.float32).reshape(2, 2, n * 6)
    labels = torch.zeros(2, 2, n)
    labels[:, :, :3] = 1  # the first three points are the panel's
    recovering = torch.tensor([[[0.0], [1.0]], [[1.0], [0.0]]])  # sample 0 recovers (its last step), 1 not
    batch = {"observation.point_cloud": cloud, TEACHER_OCCLUDER: labels, TEACHER_RECOVERING: recovering}
    seen = policy.training_batch(batch)["observation.point_cloud"].reshape(2, 2, n, 6)
    assert torch.equal(seen[0], cloud.reshape(2, 2, n, 6)[0])  # kept as stored
    assert torch.equal(seen[1, :, :5], cloud.reshape(2, 2, n, 6)[1, :, 3:])  # panel moved behind
    with pytest.raises(KeyError, match="recovering"):
        policy.training_batch({"observation.point_cloud": cloud, TEACHER_OCCLUDER: labels})
    # the recipe's default drops the panel in recovery frames too
    recipe = make_policy(occluder_dropout=1.0)
    recipe.config.points_per_step = 4
    seen = recipe.training_batch(batch)["observation.point_cloud"].reshape(2, 2, n, 6)
    assert torch.equal(seen[0, :, :5], cloud.reshape(2, 2, n, 6)[0, :, 3:])


def test_the_weights_apply_to_the_named_action_dims_only():
    """`loss_weight_dims`: by hand, 2 samples x 2 steps x 3 dims, the second step of sample 1 padded."""
    from lerobot_bavo.policies.maniflow.modeling_maniflow import weighted_loss_mask

    pad = torch.ones(2, 2, 3)
    pad[1, 1] = 0.0
    weights = torch.tensor([0.0, 4.0])
    every = weighted_loss_mask(weights, None, 3, pad)
    assert every.tolist() == [[[0, 0, 0], [0, 0, 0]], [[4, 4, 4], [0, 0, 0]]]
    some = weighted_loss_mask(weights, (0, 2), 3, pad)
    assert some.tolist() == [[[0, 1, 0], [0, 1, 0]], [[4, 1, 4], [0, 0, 0]]]


@pytest.mark.parametrize("bad", [(21,), (-1,), (3, 3)])
def test_loss_weight_dims_must_be_distinct_action_indices(bad):
    with pytest.raises(ValueError, match="loss_weight_dims"):
        make_policy(loss_weight_dims=bad)


def test_weights_on_every_action_dim_are_the_weights_on_all():
    """Naming all 21 dims gives the loss of None (the default); naming some gives another."""
    plain = make_policy(sample_weights=True)
    labels = torch.ones(4, plain.config.n_obs_steps, 1)
    labels[[0, 2], -1] = 0.0
    batch = {**make_batch(plain), TEACHER_SAMPLE_WEIGHT: labels}
    reference = loss_of(plain, batch)
    for dims, same in ((tuple(range(21)), True), (tuple(range(14)), False)):
        other = make_policy(sample_weights=True, loss_weight_dims=dims)
        other.load_state_dict(plain.state_dict())
        assert (loss_of(other, batch) == pytest.approx(reference, rel=1e-5)) is same
