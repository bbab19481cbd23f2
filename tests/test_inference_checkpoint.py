"""Inference-only checkpoints (what `scripts/ship_checkpoint.py` ships): only the EMA weights are stored, the
policy loads from them with the same actions as from the full checkpoint, and the completeness check still
refuses a checkpoint that lacks an inference tensor."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
import torch
from lerobot.configs import FeatureType, PolicyFeature
from safetensors.torch import load_file, save_file

from lerobot_bavo.policies import AfarConfig, AfarPolicy

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "scripts"))
from ship_checkpoint import keep_inference_weights  # noqa: E402

N = 16


def _policy() -> AfarPolicy:
    inputs = {"observation.point_cloud": PolicyFeature(FeatureType.STATE, (N * 6,)),
              "observation.state": PolicyFeature(FeatureType.STATE, (21,))}
    cfg = AfarConfig(
        input_features=inputs,
        output_features={"action": PolicyFeature(FeatureType.ACTION, (21,))},
        preset="cpu_fast",
        device="cpu",
        points_per_step=8,
    )
    torch.manual_seed(0)
    policy = AfarPolicy(cfg)
    with torch.no_grad():  # EMA and training copies differ, as after training
        for p in policy.model.parameters():
            p.add_(0.05 * torch.randn_like(p))
        for p in policy.ema_model.parameters():
            p.add_(0.05 * torch.randn_like(p))
    return policy


def _actions(policy) -> torch.Tensor:
    g = torch.Generator().manual_seed(1)
    obs = {
        "observation.point_cloud": torch.rand(1, N, 6, generator=g),
        "observation.state": torch.rand(1, 21, generator=g),
    }
    policy.reset()
    return policy.select_action(obs, generator=torch.Generator().manual_seed(2))


def test_inference_only_checkpoint_acts_like_the_full_one(tmp_path):
    from lerobot_bavo.checkpoints import CheckpointMismatchError, check_weights_complete

    policy = _policy()
    full, light = tmp_path / "full", tmp_path / "light"
    policy.save_pretrained(full)
    policy.save_pretrained(light)
    kept, dropped = keep_inference_weights(light / "model.safetensors", {"use_ema_for_inference": True})
    stored = load_file(str(light / "model.safetensors"))
    assert kept == len(stored) == len(policy.inference_state_keys()) and dropped > 0
    assert not any(k.startswith("model.") for k in stored)
    assert (light / "model.safetensors").stat().st_size < 0.55 * (full / "model.safetensors").stat().st_size

    a, b = AfarPolicy.from_pretrained(full).eval(), AfarPolicy.from_pretrained(light).eval()
    check_weights_complete(a, full)
    check_weights_complete(b, light)
    torch.testing.assert_close(_actions(a), _actions(b), rtol=0, atol=0)
    # the training copy of the light checkpoint starts from the EMA weights (fine-tuning from a shipped one)
    for (name, p), q in zip(b.model.named_parameters(), b.ema_model.parameters()):
        assert torch.equal(p, q), name

    del stored[next(iter(stored))]  # one inference tensor gone: refused, naming it
    save_file(stored, str(light / "model.safetensors"))
    with pytest.raises(CheckpointMismatchError, match="missing"):
        check_weights_complete(b, light)
