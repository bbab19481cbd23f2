"""Cube Handoff: the right wrist's yaw when a policy first closes its gripper, against the cube's (issue 27).

Why: the learned policies' Stage failures run out of time at the lift, after grasps whose fingers stop wide
apart (a hold across the cube, not square to its faces), and the failed episodes are those whose cube lies
turned by 15 degrees or more. This logs, per episode, the cube's face yaw at reset (the yaw of its face normal
nearest the world x axis, in [-45, 45] degrees: the turn the scripted expert gives its wrist) and the
gripper's closing-axis yaw at the first step the right gripper command falls below 0.5 (0 = fingers closing
along -y, as the expert's top-down grasp at yaw 0), with the episode's outcome. The summary gives the
correlation of the two yaws and the successes by the misalignment between them (wrapped to [-45, 45]).

    python scripts/grasp_yaw.py --policy checkpoints/afar_cube_handoff_mixs400r200sf_b2x_lr1e3_ftstage \
        --condition stage --seeds 1000-1039 --output outputs/grasp_yaw/afar_ft_s1000.jsonl
    python scripts/grasp_yaw.py --pool outputs/grasp_yaw/afar_ft_s1000.jsonl

Seeds default to the validation seeds (1000+); test seeds (2000+) are for reporting only.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

BINS = ((0, 10), (10, 20), (20, 30), (30, 46))  # |misalignment| bins, degrees


def wrap90(deg: float) -> float:
    """An angle difference in degrees wrapped to [-45, 45): a box's side faces are 90 degrees apart."""
    return (deg + 45.0) % 90.0 - 45.0


def summarise(rows: list[dict]) -> str:
    closed = [r for r in rows if r["grip_yaw"] is not None]
    lines = [f"{len(rows)} episodes, {sum(r['success'] for r in rows)} successes; "
             f"{len(rows) - len(closed)} never closed the right gripper"]
    if len(closed) >= 2:
        cube = np.array([r["cube_yaw"] for r in closed])
        grip = np.array([r["grip_yaw"] for r in closed])
        lines.append(f"wrist yaw against cube yaw: correlation {np.corrcoef(grip, cube)[0, 1]:.2f}, slope "
                     f"{np.polyfit(cube, grip, 1)[0]:.2f}; wrist yaw sd {grip.std():.1f} deg")
    for lo, hi in BINS:
        chosen = [r for r in closed if lo <= abs(wrap90(r["grip_yaw"] - r["cube_yaw"])) < hi]
        lines.append(f"|misalignment| {lo}-{hi} deg: {sum(r['success'] for r in chosen)} of {len(chosen)} "
                     "succeed")
    for lo, hi in ((0, 15), (15, 46)):
        chosen = [r for r in rows if lo <= abs(r["cube_yaw"]) < hi]
        wins = sum(r["success"] for r in chosen)
        lines.append(f"|cube yaw| {lo}-{hi} deg: {wins} of {len(chosen)} succeed")
    return "\n".join(lines)


def trace_episode(env, agent, seed: int, condition: str) -> dict:
    """One episode: the cube's face yaw at reset and the right wrist's closing-axis yaw at the first step its
    gripper command falls below 0.5 (degrees; None if it never closes), with the outcome."""
    from lerobot_bavo.eval.rollout import run_episode
    from lerobot_bavo.sim import constants as C
    from lerobot_bavo.sim.transforms import closing_yaw, face_yaw

    dim = C.ACTION_NAMES.index("right_gripper")
    seen: dict = {}

    def log(obs, info, action):
        u = env.unwrapped
        if "cube_yaw" not in seen:
            seen["cube_yaw"] = float(np.degrees(face_yaw(u.data.xmat[u.task.cube_body].reshape(3, 3))))
        if float(action[dim]) < 0.5 and "grip_yaw" not in seen:
            grip = u.data.site("right_gripper_center").xmat.reshape(3, 3)
            seen["grip_yaw"] = float(np.degrees(closing_yaw(grip)))
            seen["close_step"] = int(info["elapsed_steps"])

    record = run_episode(env, agent, seed, on_act=log)
    return {"task": "cube_handoff", "condition": condition, "seed": seed, "success": bool(record["success"]),
            "cube_yaw": seen["cube_yaw"], "grip_yaw": seen.get("grip_yaw"),
            "close_step": seen.get("close_step")}


def main() -> None:
    from lerobot_bavo.eval.run import read_episode_records, record_episodes

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--policy", help="a checkpoint folder (pretrained_model)")
    ap.add_argument("--condition", default="stage")
    ap.add_argument("--seeds", default="1000-1039", help="first-last (inclusive)")
    ap.add_argument("--output", type=Path, help="JSON-lines log, one episode per line")
    ap.add_argument("--pool", type=Path, nargs="+", help="summarise these logs instead of rolling out")
    args = ap.parse_args()
    if args.pool:
        print(summarise([row for path in args.pool for row in read_episode_records(path)]))
        return
    if not args.policy:
        ap.error("--policy is required unless --pool is given")
    first, last = (int(s) for s in args.seeds.split("-"))

    from lerobot_bavo.envs.bavo_env import BavoEnv
    from lerobot_bavo.eval.rollout import env_kwargs_for_policy, make_agent

    env = BavoEnv(task="cube_handoff", condition=args.condition, **env_kwargs_for_policy(args.policy))
    agent = make_agent(args.policy, env)
    try:
        rows = record_episodes(range(first, last + 1),
                               lambda seed: trace_episode(env, agent, seed, args.condition), args.output)
    finally:
        env.close()
    print(summarise(rows))


if __name__ == "__main__":
    main()
