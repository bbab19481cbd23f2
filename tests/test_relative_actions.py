"""`--policy.relative_action_dims`: ManiFlow / A-FAR predicting their chunk relative to the current state
(`policies/relative.py`), and the flags a dataset gives (`datasets/relative_actions.py`)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from test_policies import (
    ACT,
    STATE,
    make_afar,
    make_maniflow,
    observation,
    randomize_zero_init,
    synthetic_batch,
)

from lerobot_bavo.datasets.relative_actions import (
    chunk_offsets,
    dataset_relative_flags,
    main,
    minmax_normalised,
    relative_action_scales,
)
from lerobot_bavo.policies.relative import as_index, current_state, to_absolute, to_relative

JOINTS = (0, 1, 2, 3, 4, 5, 7, 8, 9, 10, 11, 12, 14, 15, 16, 17, 18, 19, 20)


def test_relative_chunk_by_hand_and_back():
    chunk = torch.tensor([[[0.5, 0.9, -0.2], [0.7, 1.0, 0.0]]])  # (B=1, H=2, A=3)
    state = torch.tensor([[[9.0, 9.0, 9.0], [0.4, -0.5, 0.1]]])  # (B, To=2, S): the last step counts
    dims, scales = as_index((0, 2)), torch.tensor([0.5, 0.25])
    rel = to_relative(chunk, state, dims, scales)
    expected = torch.tensor([[[(0.5 - 0.4) / 0.5, 0.9, (-0.2 - 0.1) / 0.25],
                              [(0.7 - 0.4) / 0.5, 1.0, (0.0 - 0.1) / 0.25]]])
    assert torch.allclose(rel, expected)
    assert torch.allclose(to_absolute(rel, state, dims, scales), chunk)
    # no relative dims: the chunk itself
    assert to_relative(chunk, state, as_index(()), torch.tensor([])) is chunk


def test_current_state_takes_the_last_observation_step():
    s = torch.arange(12.0).reshape(2, 3, 2)
    assert current_state(s).tolist() == [[4.0, 5.0], [10.0, 11.0]]
    assert current_state(s[:, -1]).tolist() == [[4.0, 5.0], [10.0, 11.0]]
    assert current_state(torch.tensor([1.0, 2.0])).tolist() == [[1.0, 2.0]]
    with pytest.raises(ValueError, match="state of shape"):
        current_state(torch.zeros(1, 1, 1, 1))


def test_chunk_offsets_pad_at_episode_ends_and_scales_take_the_quantile():
    # one dimension, two episodes: actions 0, 1, 2 | 10, 20; state 0 everywhere
    a = np.array([[0.0], [1.0], [2.0], [10.0], [20.0]])
    s = np.zeros_like(a)
    ep = np.array([0, 0, 0, 1, 1])
    off = chunk_offsets(a, s, ep, first=-1, horizon=3)  # k = -1, 0, 1
    # episode 0: k=-1 -> a[0,0,1]; k=0 -> a[0,1,2]; k=1 -> a[1,2,2]; episode 1: [10,10], [10,20], [20,20]
    assert sorted(off[:, 0].tolist()) == sorted([0, 0, 1, 0, 1, 2, 1, 2, 2, 10, 10, 10, 20, 20, 20])
    assert relative_action_scales(a, s, ep, (0,), first=-1, horizon=3, quantile=1.0) == [20.0]
    # a joint that never moves gets the floor, not 0
    assert relative_action_scales(np.zeros((3, 1)), np.zeros((3, 1)), np.zeros(3), (0,), 0, 2) == [0.001]
    with pytest.raises(ValueError, match="quantile"):
        relative_action_scales(a, s, ep, (0,), 0, 2, quantile=0.0)


def test_minmax_normalised_is_lerobots_formula():
    stats = {"min": [0.0, -2.0], "max": [4.0, 2.0]}
    x = np.array([[1.0, 0.0], [4.0, -2.0]])
    assert minmax_normalised(x, stats).tolist() == [[-0.5, 0.0], [1.0, -1.0]]


def _config_error(**kw) -> str:
    with pytest.raises(ValueError) as err:
        make_maniflow(**kw)
    return str(err.value)


def test_config_refuses_what_cannot_be_made_relative():
    assert "one scale per entry" in _config_error(relative_action_dims=(0, 1),
                                                  relative_action_scales=(0.5, 0.5, 1))
    assert "> 0" in _config_error(relative_action_dims=(0,), relative_action_scales=(0.0,))
    assert "distinct" in _config_error(relative_action_dims=(1, 1), relative_action_scales=(0.5,))
    assert "binary command" in _config_error(relative_action_dims=(0, 6), relative_action_scales=(0.5,))
    assert "hidden" in _config_error(relative_action_dims=(14,), relative_action_scales=(0.5,),
                                     ignored_state_dims=(14,))
    assert "21-dim" in _config_error(relative_action_dims=(21,), relative_action_scales=(0.5,))
    # one scale for all is broadcast
    policy = make_maniflow(relative_action_dims=(0, 1, 2), relative_action_scales=(0.5,))
    assert policy.config.relative_action_scales == (0.5, 0.5, 0.5)


@pytest.mark.parametrize("make", [make_maniflow, make_afar], ids=["maniflow", "afar"])
def test_inference_adds_the_state_to_the_predicted_steps(make):
    """Same weights, same noise: the relative policy's actions are the absolute policy's sampled values
    read as scaled steps from the current state (clipping and snapping off, so nothing else differs)."""
    dims, scales = (0, 4, 15), (0.5, 0.25, 2.0)
    plain = make(clip_actions=False, binary_action_dims=())
    rel = make(clip_actions=False, binary_action_dims=(), relative_action_dims=dims,
               relative_action_scales=scales)
    randomize_zero_init(plain)
    rel.load_state_dict(plain.state_dict())
    plain.eval(), rel.eval()
    batch = {k: v[:, None].expand(-1, 2, *v.shape[1:]) for k, v in observation().items()}
    noise = torch.randn(1, 16, 21, generator=torch.Generator().manual_seed(3))
    a_plain = plain.generate_actions(batch, noise=noise)
    a_rel = rel.generate_actions(batch, noise=noise)
    expected = a_plain.clone()
    s = batch[STATE][:, -1]
    for d, sc in zip(dims, scales, strict=True):
        expected[..., d] = a_plain[..., d] * sc + s[:, None, d]
    assert torch.allclose(a_rel, expected, atol=1e-6)
    assert not torch.allclose(a_rel, a_plain)


@pytest.mark.parametrize("make", [make_maniflow, make_afar], ids=["maniflow", "afar"])
def test_training_loss_is_the_absolute_loss_on_the_relative_targets(make):
    dims, scales = JOINTS, (0.4,)
    plain = make()
    rel = make(relative_action_dims=dims, relative_action_scales=scales)
    rel.load_state_dict(plain.state_dict())
    batch = synthetic_batch(teacher=make is make_afar)
    targets = to_relative(batch[ACT], batch[STATE], as_index(dims), torch.tensor(scales * len(dims)))

    def loss(policy, b):
        with torch.random.fork_rng(), torch.no_grad():
            torch.manual_seed(7)
            return float(policy.forward(b)[0])

    assert loss(rel, batch) == pytest.approx(loss(plain, {**batch, ACT: targets}), rel=1e-6)
    assert loss(rel, batch) != pytest.approx(loss(plain, batch), rel=1e-3)


def _write_dataset(root, action, state, episode):
    import pyarrow as pa
    import pyarrow.parquet as pq

    (root / "meta").mkdir(parents=True)
    (root / "data" / "chunk-000").mkdir(parents=True)
    stats = {"action": {"min": action.min(0).tolist(), "max": action.max(0).tolist()},
             "observation.state": {"min": state.min(0).tolist(), "max": state.max(0).tolist()}}
    (root / "meta" / "stats.json").write_text(json.dumps(stats))
    table = pa.table({"action": list(action.astype(np.float32)),
                      "observation.state": list(state.astype(np.float32)),
                      "episode_index": episode.astype(np.int64)})
    pq.write_table(table, root / "data" / "chunk-000" / "file-000.parquet")


def test_dataset_flags_from_a_small_dataset(tmp_path, capsys):
    rng = np.random.default_rng(0)
    t = 40
    state = np.cumsum(rng.normal(0, 0.01, (t, 21)), axis=0)
    action = state + rng.normal(0, 0.02, (t, 21))
    episode = np.repeat([0, 1], t // 2)
    _write_dataset(tmp_path / "ds", action, state, episode)
    dims, scales = dataset_relative_flags(tmp_path / "ds")
    assert dims == JOINTS
    # independently: the same quantile over normalised values, offsets -1 ... 14
    an = 2 * (action - action.min(0)) / (action.max(0) - action.min(0)) - 1
    sn = 2 * (state - state.min(0)) / (state.max(0) - state.min(0)) - 1
    rows = []
    for e in (0, 1):
        idx = np.flatnonzero(episode == e)
        for k in range(-1, 15):
            j = np.clip(np.arange(len(idx)) + k, 0, len(idx) - 1)
            rows.append(np.abs(an[idx][j] - sn[idx]))
    expected = np.quantile(np.concatenate(rows), 0.99, axis=0)[list(JOINTS)]
    assert scales == pytest.approx(np.round(np.maximum(expected, 1e-3), 4).tolist(), abs=1e-4)
    main(["--root", str(tmp_path / "ds")])
    line = capsys.readouterr().out.strip()
    assert line.startswith("--policy.relative_action_dims=[0,1,2,3,4,5,7,")
    assert " --policy.relative_action_scales=[" in line
    # the printed flags make a valid config
    flags = dict(part.split("=", 1) for part in line.split())
    make_maniflow(relative_action_dims=tuple(json.loads(flags["--policy.relative_action_dims"])),
                  relative_action_scales=tuple(json.loads(flags["--policy.relative_action_scales"])))
    with pytest.raises(SystemExit, match="not BAVO's"):
        _write_dataset(tmp_path / "small", action[:, :5], state[:, :5], episode)
        main(["--root", str(tmp_path / "small")])
