"""Inference-only checkpoints (what `scripts/ship_checkpoint.py` ships): only the EMA weights are stored, the
policy loads from them with the same actions as from the full checkpoint, and the completeness check still
refuses a checkpoint that lacks an inference tensor. `--half` stores those weights in float16 (the loaded
float32 model holds exactly the rounded values) and `--trim-stats` keeps only the statistics the
normalisers read (they normalise bit for bit as before)."""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import pytest
import torch
from lerobot.configs import FeatureType, PolicyFeature
from safetensors.torch import load_file, save_file

from lerobot_bavo.policies import AfarConfig, AfarPolicy

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "scripts"))
from ship_checkpoint import (  # noqa: E402
    keep_inference_statistics,
    keep_inference_weights,
    store_half_precision,
    weights_in_half_precision,
)

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


def test_half_precision_weights_load_as_their_float16_rounding(tmp_path):
    policy = _policy()
    light, half = tmp_path / "light", tmp_path / "half"
    policy.save_pretrained(light)
    keep_inference_weights(light / "model.safetensors", {"use_ema_for_inference": True})
    shutil.copytree(light, half)
    stored = load_file(str(light / "model.safetensors"))
    n_float = sum(v.dtype == torch.float32 for v in stored.values())
    assert store_half_precision(half / "model.safetensors") == n_float > 0
    halved = load_file(str(half / "model.safetensors"))
    assert halved["ema_step"].dtype == torch.long  # the integer buffer is kept as it is
    assert {v.dtype for k, v in halved.items() if k != "ema_step"} == {torch.float16}
    ratio = (half / "model.safetensors").stat().st_size / (light / "model.safetensors").stat().st_size
    assert 0.49 < ratio < 0.52
    assert weights_in_half_precision(half / "model.safetensors")
    assert not weights_in_half_precision(light / "model.safetensors")
    assert store_half_precision(half / "model.safetensors") == 0  # re-shipping in place changes nothing

    a, b = AfarPolicy.from_pretrained(light).eval(), AfarPolicy.from_pretrained(half).eval()
    for (name, p), q in zip(a.ema_model.named_parameters(), b.ema_model.parameters()):
        assert q.dtype == torch.float32, name  # LeRobot's loader casts into the float32 model
        assert torch.equal(q, p.half().float()), name
    # rounding moves the actions (normalised units) a little, not a lot
    diff = (_actions(a) - _actions(b)).abs().max().item()
    assert 0 < diff < 0.05


def test_half_precision_refuses_a_tensor_float16_cannot_hold(tmp_path):
    file = tmp_path / "model.safetensors"
    save_file({"w": torch.tensor([1.0, 7.0e4])}, str(file))
    with pytest.raises(SystemExit, match="'w' exceeds float16's range"):
        store_half_precision(file)


# the shipped demo policy's processors: real statistics of a 512-point self-filtered dataset
SHIPPED = Path(__file__).resolve().parent.parent / "checkpoints" / "afar_cube_handoff_sf"


def _processors(folder: Path):
    from lerobot.policies.factory import make_pre_post_processors

    from lerobot_bavo.checkpoints import load_policy_config

    return make_pre_post_processors(policy_cfg=load_policy_config(folder), pretrained_path=str(folder))


def test_trimmed_statistics_normalise_exactly_as_the_full_ones(tmp_path):
    full, trimmed = tmp_path / "full", tmp_path / "trimmed"
    full.mkdir()
    for f in SHIPPED.iterdir():
        if f.name == "config.json" or f.name.startswith(("policy_preprocessor", "policy_postprocessor")):
            shutil.copy(f, full / f.name)
    shutil.copytree(full, trimmed)
    # MIN_MAX for state, cloud and action in the preprocessor, action in the postprocessor: 2 x 4 entries
    assert keep_inference_statistics(trimmed) == (8, len(_all_stats(full)) - 8)
    assert set(_all_stats(trimmed)) == {f"{feature}.{stat}" for feature in (
        "pre:observation.state", "pre:observation.point_cloud", "pre:action", "post:action")
        for stat in ("min", "max")}
    assert sum(f.stat().st_size for f in trimmed.glob("*.safetensors")) < 40_000

    (pre_a, post_a), (pre_b, post_b) = _processors(full), _processors(trimmed)
    g = torch.Generator().manual_seed(0)
    batch = {"observation.state": torch.rand(1, 21, generator=g),
             "observation.point_cloud": torch.rand(1, 512, 6, generator=g), "task": ["hand over the cube"]}
    out_a, out_b = pre_a(dict(batch)), pre_b(dict(batch))
    for key in ("observation.state", "observation.point_cloud"):
        assert not torch.equal(out_a[key], batch[key].reshape(out_a[key].shape))  # it did normalise
        assert torch.equal(out_a[key], out_b[key]), key
    action = torch.rand(1, 21, generator=g) * 2 - 1
    assert torch.equal(post_a(action), post_b(action))


def test_trimming_refuses_statistics_a_normaliser_lacks(tmp_path):
    for f in SHIPPED.iterdir():
        if f.name.startswith(("policy_preprocessor", "policy_postprocessor")):
            shutil.copy(f, tmp_path / f.name)
    post = next(tmp_path.glob("policy_postprocessor_*.safetensors"))
    stats = load_file(str(post))
    del stats["action.max"]
    save_file(stats, str(post))
    with pytest.raises(SystemExit, match=r"lacks statistics .*'action.max'"):
        keep_inference_statistics(tmp_path)


def _all_stats(folder: Path) -> list[str]:
    """Every statistic in the folder's processor state files, as 'pre:key' / 'post:key'."""
    stats = []
    for f in sorted(folder.glob("policy_*.safetensors")):
        side = f.name.split("_")[1].removesuffix("processor")  # policy_preprocessor_step_4_... -> "pre"
        stats += [f"{side}:{key}" for key in load_file(str(f))]
    return stats
