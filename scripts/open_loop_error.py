"""Open-loop action error of a trained checkpoint on its own training frames (a failure-ladder diagnostic).

Why: a behaviour-cloned policy that fails closed loop either has not fit its demonstrations (large error
here, a budget/capacity problem) or fits them and drifts off them closed loop (small error here, a
covariate-shift problem). This script measures the first: for every `--every`-th frame of the chosen
episodes it feeds the policy the recorded observation window (the same `n_obs_steps` frames
`lerobot-train` gives it, clamped at the episode start), samples one chunk with a fixed noise seed, and
compares the `n_action_steps` executed actions with the recorded ones (clamped at the episode end).

Units: arm and camera-arm joints in radians (mean absolute error over the 19 joint dims), grippers in
the action's own [0, 1] units. Also prints the "lead slope": the least-squares slope of the predicted
(target - current state) against the recorded one over the arm joints, 1.0 when the policy leads the
state by as much as the demonstrator did, below 1 when it lags.

    python scripts/open_loop_error.py --policy outputs/train/RUN/checkpoints/last/pretrained_model \\
        --root outputs/datasets/bavo_cube_handoff_state --episodes 0,1,2 --every 25
"""

from __future__ import annotations

import argparse
import dataclasses
import os
from pathlib import Path

import numpy as np

os.environ.setdefault("OMP_NUM_THREADS", "1")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("--policy", required=True, help="a pretrained_model directory")
    ap.add_argument("--root", required=True, help="the training view the checkpoint was trained on")
    ap.add_argument("--episodes", default="0,1,2", help="comma-separated episode indices (default 0,1,2)")
    ap.add_argument("--every", type=int, default=25, help="evaluate every k-th frame (default 25)")
    ap.add_argument("--seed", type=int, default=0, help="noise seed of the sampled chunks (default 0)")
    ap.add_argument("--draws", type=int, default=1,
                    help="chunks sampled per frame; >= 2 also prints their spread (default 1)")
    ap.add_argument("--noise-scale", type=float, default=None,
                    help="sample at this noise_scale instead of the checkpoint's (default: the checkpoint's)")
    args = ap.parse_args()
    if args.draws < 1:
        ap.error(f"--draws must be >= 1, got {args.draws}")

    import pandas as pd
    import torch
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.policies.factory import get_policy_class, make_pre_post_processors

    import lerobot_bavo.policies  # noqa: F401  (registers the policy types)
    from lerobot_bavo.sim.constants import CAMERA_ARM, GRIPPER_INDICES

    torch.set_num_threads(1)
    path = Path(args.policy)
    cfg = PreTrainedConfig.from_pretrained(path)
    cfg.device = "cpu"
    if args.noise_scale is not None:
        if not hasattr(cfg, "noise_scale"):
            ap.error(f"--noise-scale needs a maniflow or afar checkpoint; {path} is a {cfg.type} one")
        try:  # a copy built through the config's own checks
            cfg = dataclasses.replace(cfg, noise_scale=args.noise_scale)
        except ValueError as e:
            ap.error(f"--noise-scale: {e}")
    policy = get_policy_class(cfg.type).from_pretrained(path, config=cfg).eval()
    pre, post = make_pre_post_processors(policy_cfg=cfg, pretrained_path=str(path))
    obs_keys = list(cfg.input_features)
    to, n_exec = cfg.n_obs_steps, cfg.n_action_steps

    files = sorted(Path(args.root, "data").rglob("*.parquet"))
    df = pd.concat([pd.read_parquet(f) for f in files], ignore_index=True)
    joints = [i for i in range(21) if i not in GRIPPER_INDICES]
    arm = [i for i in joints if i < CAMERA_ARM.start]  # the two manipulation arms' 12 joints
    errs_j, errs_g, lead_pred, lead_true, spreads, errs_arm = [], [], [], [], [], []
    gen = torch.Generator().manual_seed(args.seed)
    for ep in (int(e) for e in args.episodes.split(",")):
        rows = df[df["episode_index"] == ep].sort_values("frame_index")
        if rows.empty:
            raise SystemExit(f"episode {ep} is not in {args.root}")
        cols = {k: np.stack(rows[k].to_numpy()).astype(np.float32) for k in [*obs_keys, "action"]}
        n = len(rows)
        for i in range(0, n, args.every):
            window = np.clip(np.arange(i - to + 1, i + 1), 0, n - 1)
            batch = {k: torch.from_numpy(cols[k][window])[None] for k in obs_keys}
            batch["task"] = [""]
            batch = pre(batch)
            true = cols["action"][np.clip(np.arange(i, i + n_exec), 0, n - 1)]
            state = cols["observation.state"][i]
            draws = []
            for _ in range(args.draws):
                with torch.inference_mode():
                    chunk = policy.predict_action_chunk(batch, generator=gen)
                pred = post(chunk).squeeze(0).numpy()
                draws.append(pred)
                errs_j.append(np.abs(pred[:, joints] - true[:, joints]).mean())
                errs_arm.append(np.abs(pred[:, arm] - true[:, arm]).mean())
                errs_g.append(np.abs(pred[:, list(GRIPPER_INDICES)] - true[:, list(GRIPPER_INDICES)]).mean())
                lead_pred.append((pred[:, joints] - state[joints]).ravel())
                lead_true.append((true[:, joints] - state[joints]).ravel())
            if args.draws > 1:
                spreads.append(np.stack(draws)[:, :, arm].std(axis=0).mean())
    lp, lt = np.concatenate(lead_pred), np.concatenate(lead_true)
    slope = float(lp @ lt / max(lt @ lt, 1e-12))
    print(f"{path}: {len(errs_j)} chunks; joint MAE {np.mean(errs_j):.4f} rad (max {np.max(errs_j):.4f}); "
          f"gripper MAE {np.mean(errs_g):.3f}; lead slope {slope:.2f}; "
          f"noise_scale {getattr(policy.config, 'noise_scale', '-')}")
    if spreads:
        print(f"manipulation arms: spread across {args.draws} draws {1000 * np.mean(spreads):.1f} mrad, "
              f"error per draw {1000 * np.mean(errs_arm):.1f} mrad")


if __name__ == "__main__":
    main()
