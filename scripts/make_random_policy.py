#!/usr/bin/env python
"""Write a randomly initialised LeRobot checkpoint (a built-in policy) that fits a BAVO-Bench env.

`lerobot-eval` needs `--policy.path`; this makes one without a dataset or pretrained weights, so the
env can be smoke-tested end to end (the policy moves the arms randomly around the home pose):

    python scripts/make_random_policy.py --output-dir /tmp/bavo_random_act
    HF_HUB_OFFLINE=1 lerobot-eval --policy.path=/tmp/bavo_random_act --env.type=bavo \\
        --env.task=cube_handoff --env.episode_length=50 --eval.n_episodes=2 --eval.batch_size=1 \\
        --eval.use_async_envs=false --policy.device=cpu --output_dir=/tmp/bavo_eval_smoke

The directory holds what `lerobot-eval` loads: `config.json` + `model.safetensors` (the policy)
and `policy_preprocessor.json` / `policy_postprocessor.json` with their normaliser stats. The
policy's inputs are `observation.state` and `observation.images.active` (the built-in policies
cannot use point clouds; the env's extra `observation.point_*` keys pass through unused). The
image size given here must match the `--env.image_height/--env.image_width` used at evaluation.
The stats are synthetic: state and action centred on the home pose, actions with a small spread
(`--action-std-fraction` of each joint's range), images with ImageNet statistics.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

POLICY_TYPES = ("act", "diffusion")
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


def small_policy_config(policy_type: str, device: str):
    """A small CPU-friendly config of a built-in LeRobot policy, with no pretrained backbone."""
    from lerobot.policies import make_policy_config

    common = {"device": device, "push_to_hub": False, "pretrained_backbone_weights": None}
    if policy_type == "act":
        return make_policy_config(
            "act", **common, chunk_size=20, n_action_steps=20, dim_model=128, n_heads=4,
            dim_feedforward=512, n_encoder_layers=2, n_decoder_layers=1, use_vae=False,
        )
    if policy_type == "diffusion":
        import importlib.util

        if importlib.util.find_spec("diffusers") is None:
            raise ImportError(
                "--policy-type diffusion needs diffusers: pip install 'lerobot[diffusion]==0.6.1'"
            )
        return make_policy_config(
            "diffusion", **common, horizon=16, n_action_steps=8, drop_n_last_frames=7,
            down_dims=(64, 128), diffusion_step_embed_dim=32, spatial_softmax_num_keypoints=16,
            num_inference_steps=10,
        )
    raise ValueError(f"unknown policy type {policy_type!r}; expected one of {POLICY_TYPES}")


def synthetic_stats(image_key: str, action_std_fraction: float) -> dict:
    """Normaliser stats (mean/std/min/max) for state, action and the camera, as float32 tensors."""
    import numpy as np
    import torch
    from lerobot.utils.constants import ACTION, OBS_STATE

    from lerobot_bavo.sim import constants as C

    lo, hi = (np.asarray(b, dtype=np.float32) for b in C.action_bounds())
    home = np.clip(np.asarray(C.HOME_ACTION, dtype=np.float32), lo, hi)
    half = action_std_fraction * (hi - lo)

    def t(x) -> torch.Tensor:
        return torch.as_tensor(np.asarray(x, dtype=np.float32))

    img_shape = (3, 1, 1)
    return {
        OBS_STATE: {"mean": t(home), "std": t((hi - lo) / 4), "min": t(lo), "max": t(hi)},
        ACTION: {
            "mean": t(home),
            "std": t(half),
            "min": t(np.maximum(home - half, lo)),
            "max": t(np.minimum(home + half, hi)),
        },
        image_key: {
            "mean": t(np.reshape(IMAGENET_MEAN, img_shape)),
            "std": t(np.reshape(IMAGENET_STD, img_shape)),
            "min": t(np.zeros(img_shape)),
            "max": t(np.ones(img_shape)),
        },
    }


def make_random_policy(
    output_dir: Path,
    policy_type: str = "act",
    task: str = "cube_handoff",
    image_height: int = 240,
    image_width: int = 320,
    n_points: int = 256,
    seed: int = 0,
    device: str = "cpu",
    action_std_fraction: float = 0.02,
) -> Path:
    """Build, randomly initialise and save a policy plus its processors; returns `output_dir`."""
    import torch
    from lerobot.envs.utils import env_to_policy_features
    from lerobot.policies import make_pre_post_processors
    from lerobot.policies.factory import get_policy_class
    from lerobot.utils.constants import OBS_STATE

    from lerobot_bavo.envs.configs import BavoEnvConfig
    from lerobot_bavo.features import OBS_IMAGE

    env_cfg = BavoEnvConfig(task=task, image_height=image_height, image_width=image_width, n_points=n_points)
    features = env_to_policy_features(env_cfg)
    cfg = small_policy_config(policy_type, device)
    cfg.output_features = {k: ft for k, ft in features.items() if k == "action"}
    cfg.input_features = {k: features[k] for k in (OBS_STATE, OBS_IMAGE)}

    torch.manual_seed(seed)
    policy = get_policy_class(cfg.type)(cfg)
    stats = synthetic_stats(OBS_IMAGE, action_std_fraction)
    preprocessor, postprocessor = make_pre_post_processors(cfg, dataset_stats=stats)

    output_dir.mkdir(parents=True, exist_ok=True)
    policy.save_pretrained(output_dir)
    preprocessor.save_pretrained(output_dir)
    postprocessor.save_pretrained(output_dir)
    (output_dir / "bavo_random_policy.json").write_text(json.dumps({
        "policy_type": policy_type, "task": task, "image_height": image_height, "image_width": image_width,
        "n_points": n_points, "seed": seed, "action_std_fraction": action_std_fraction,
        "note": "randomly initialised; for smoke-testing lerobot-eval only",
    }, indent=2))
    return output_dir


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--output-dir", type=Path, required=True, help="where to write the checkpoint")
    parser.add_argument("--policy-type", choices=POLICY_TYPES, default="act",
                        help="built-in LeRobot policy (diffusion needs the lerobot[diffusion] extra)")
    parser.add_argument("--task", default="cube_handoff", help="BAVO-Bench task the features come from")
    parser.add_argument("--image-height", type=int, default=240, help="must match --env.image_height")
    parser.add_argument("--image-width", type=int, default=320, help="must match --env.image_width")
    parser.add_argument("--n-points", type=int, default=256, help="must match --env.n_points")
    parser.add_argument("--seed", type=int, default=0, help="torch seed of the random initialisation")
    parser.add_argument("--device", default="cpu", help="device stored in config.json (cpu, cuda)")
    parser.add_argument("--action-std-fraction", type=float, default=0.02,
                        help="action spread around the home pose, as a fraction of each joint's range")
    args = parser.parse_args(argv)

    from lerobot_bavo import register_lerobot_types

    register_lerobot_types()  # the "bavo" env type (and the policy types) for LeRobot's factories

    out = make_random_policy(
        args.output_dir, args.policy_type, args.task, args.image_height, args.image_width, args.n_points,
        args.seed, args.device, args.action_std_fraction,
    )
    print(f"wrote a random {args.policy_type} checkpoint to {out}")


if __name__ == "__main__":
    main()
