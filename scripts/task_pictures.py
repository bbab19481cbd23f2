"""Render a picture per task for the docs: third-person + active-camera views at reset (top row)
and at success (bottom row), from the scripted expert's rollout.

    python scripts/task_pictures.py [--tasks cube_handoff,...] [--seed 0] [--output-dir docs/tasks]
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")


def task_picture(task: str, seed: int, output_dir: Path) -> Path:
    import imageio.v2 as imageio
    import numpy as np

    from lerobot_bavo.envs.bavo_env import BavoEnv
    from lerobot_bavo.experts import make_expert

    env = BavoEnv(task=task, render_height=240)
    obs, info = env.reset(seed=seed)
    expert = make_expert(env)
    expert.reset()
    first = env.render()
    while True:
        obs, _, terminated, truncated, info = env.step(expert.act(obs, info))
        if terminated or truncated:
            break
    last = env.render()
    env.close()
    if not info["is_success"]:
        raise RuntimeError(f"{task}: the expert did not succeed with seed {seed}; pick another seed")
    output_dir.mkdir(parents=True, exist_ok=True)
    path = output_dir / f"{task}.png"
    imageio.imwrite(path, np.concatenate([first, last], axis=0))
    return path


def main() -> None:
    from lerobot_bavo.envs.tasks import TASKS

    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--tasks", default=",".join(TASKS), help="comma-separated task names")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--output-dir", type=Path, default=Path("docs/tasks"))
    args = parser.parse_args()
    for task in args.tasks.split(","):
        print(task_picture(task, args.seed, args.output_dir))


if __name__ == "__main__":
    main()
