"""What the policy's cloud points lie on along a scripted-expert episode, with and without the robot
self-filter (issue 27).

Why: on Block Stacking and Drawer Stowing the point-cloud policies fail at the first object they must pick
up, while a privileged-state policy (object poses) succeeds (docs/results/first_grasp.md). This counts, every
`--every` steps of one expert episode, how many of the first `--read` cloud points (what a policy reads: the
FPS prefix) lie on the robot (geom group 1), on each Stage target, on the occluder and on the rest, for the
cloud the env gives and for the same view with the robot's own pixels dropped (`self_filter`). The expert's
actions do not depend on the cloud, so both clouds see the same states.

    python scripts/cloud_composition.py --task block_stacking [--condition clean] [--seed 1000]

Seeds default to a validation seed (1000+), never the test seeds (2000+).
"""

from __future__ import annotations

import argparse

import numpy as np

from lerobot_bavo.envs.bavo_env import BavoEnv
from lerobot_bavo.envs.tasks import TASKS
from lerobot_bavo.eval.rollout import make_agent, run_episode
from lerobot_bavo.sim import constants as C
from lerobot_bavo.sim.rendering import SceneRenderer


def composition(seg: np.ndarray, pixels: np.ndarray, groups: np.ndarray, targets: dict) -> dict:
    """Points per category: 'robot', each target name, 'occluder', 'other'. `seg` is the geom id per pixel,
    `pixels` the points' (u, v), `groups` the geom group per geom id, `targets` name -> geom ids."""
    ids = seg[pixels[:, 1], pixels[:, 0]]
    seen = ids >= 0
    group = np.where(seen, groups[np.where(seen, ids, 0)], -1)
    out = {"robot": int((group == C.GROUP_ROBOT).sum())}
    claimed = group == C.GROUP_ROBOT
    for name, geoms in targets.items():
        on = np.isin(ids, np.asarray(geoms)) & ~claimed
        out[name] = int(on.sum())
        claimed |= on
    out["occluder"] = int(((group == C.GROUP_OCCLUDER) & ~claimed).sum())
    out["other"] = int(len(ids) - sum(out.values()))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--task", required=True, choices=[name for name, _ in TASKS.items()])
    ap.add_argument("--condition", default="clean")
    ap.add_argument("--seed", type=int, default=1000)
    ap.add_argument("--every", type=int, default=20, help="control steps between counts")
    ap.add_argument("--read", type=int, default=128, help="points the policy reads (the FPS prefix)")
    args = ap.parse_args()
    env = BavoEnv(task=args.task, condition=args.condition, render_mode=None)
    s = env.obs_settings
    renderer = SceneRenderer(env.model, s.image_height, s.image_width)
    agent = make_agent("expert", env)
    act = agent.act
    rows = []

    def counting_act(obs, info):
        step = int(info["elapsed_steps"])
        if step % args.every == 0:
            rgb, depth = obs["pixels"]["active"], env.observation_depth
            seg = renderer.render_segmentation(env.data, C.ACTIVE_CAMERA)
            row = {"step": step}
            for label, self_filter in (("plain", False), ("self_filter", True)):
                _, pixels = env.point_cloud_of_view(rgb, depth, self_filter=self_filter)
                row[label] = composition(seg, pixels[: args.read], env.model.geom_group,
                                         env.task.target_geoms)
            rows.append(row)
        return act(obs, info)

    agent.act = counting_act
    record = run_episode(env, agent, args.seed)
    renderer.close()
    env.close()
    names = list(rows[0]["plain"])
    print(f"{args.task} ({args.condition}, seed {args.seed}, expert reached M{record['progress']}): the "
          f"first {args.read} of {s.n_points} points, plain cloud | self-filtered cloud")
    print("step  " + "  ".join(f"{n:>10s}" for n in names))
    for row in rows:
        print(f"{row['step']:4d}  " + "  ".join(f"{row['plain'][n]:4d} | {row['self_filter'][n]:3d}"
                                               for n in names))


if __name__ == "__main__":
    main()
