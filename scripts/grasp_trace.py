"""Where the gripper is when it first closes, for a policy and for the scripted expert (issue 27).

Why: the learned policies stop at the first object they must carry on Block Stacking and Drawer Stowing.
On Cube Handoff the same symptom was the gripper closing above the cube (docs/results/ladder_cube_handoff.md,
fourth attempt). This rolls out episodes and logs, for the arm that makes the task's first grasp, the first
step its gripper command falls below `--closed` (commands are in [0, 1], 1 = open) and where the gripper
centre (`<side>_gripper_center` site) then is relative to the object's centre, in the world frame (mm; z up),
with the deepest milestone reached, the closest the gripper came to the object and the lowest command it
sent. The expert's numbers are the reference for a grasp that works.

    python scripts/grasp_trace.py --task block_stacking --policy checkpoints/afar_block_stacking \
        [--condition clean] [--seeds 1000-1003]

Seeds default to the validation seeds (1000+); test seeds (2000+) are for reporting only. `--grasp ARM:BODY`
traces another grasp than the task's first, e.g. Block Stacking's second (`--grasp left:top_block`).
"""

from __future__ import annotations

import argparse
import json

import mujoco
import numpy as np

from lerobot_bavo.envs.bavo_env import BavoEnv
from lerobot_bavo.eval.rollout import env_kwargs_for_policy, make_agent, run_episode
from lerobot_bavo.sim import constants as C

# The first grasp of each task, fingers closing on an object: (arm, object body or geom). It makes M1 except
# on Slide Retrieval, whose M1 is the right gripper pressing the blade with its fingers already closed.
FIRST_GRASP = {
    "cube_handoff": ("right", "cube"),
    "block_stacking": ("right", "base_block"),
    "drawer_stowing": ("left", "block"),
    "dustpan_sweeping": ("left", "dustpan_handle"),
    "slide_retrieval": ("left", "handle_geom"),
}


def object_position(env, name: str) -> np.ndarray:
    """World position (m) of a body's frame, or of a geom's centre where `name` is a geom (a handle is
    one geom of its object's body, and the body's frame can lie a hand's width away from it)."""
    if mujoco.mj_name2id(env.model, mujoco.mjtObj.mjOBJ_BODY, name) >= 0:
        return env.data.body(name).xpos
    if mujoco.mj_name2id(env.model, mujoco.mjtObj.mjOBJ_GEOM, name) >= 0:
        return env.data.geom(name).xpos
    raise SystemExit(f"--grasp: no body or geom named {name!r} in this task's model")


def commanded_site(env, scratch: mujoco.MjData, action: np.ndarray, site: str) -> np.ndarray:
    """World position (m) a site would have with the arms at the joint targets `action` commands (the
    position actuators' set points, through the env's own `action_to_ctrl`), everything else as now: where
    the policy asked the gripper to be, as against where the controllers have brought it."""
    ctrl = env.action_to_ctrl(np.clip(action, env.action_space.low, env.action_space.high))
    scratch.qpos[:] = env.data.qpos
    for i in range(env.model.nu):
        if i not in C.GRIPPER_INDICES:  # a gripper's set point is a finger opening, not where the hand goes
            scratch.qpos[env.model.jnt_qposadr[env.model.actuator_trnid[i, 0]]] = ctrl[i]
    mujoco.mj_kinematics(env.model, scratch)
    return scratch.site(site).xpos.copy()


def trace_episode(env, agent, seed: int, side: str, obj: str, closed: float) -> dict:
    """One episode; the first step the `side` gripper command falls below `closed` and the gripper centre
    minus the object's centre then (world frame, mm), both where it is and where the arm's joint targets
    of that step put it (`commanded_offset_mm`); the closest the gripper centre came to the object's
    centre (mm, and when), and the lowest command sent."""
    scratch = mujoco.MjData(env.model)
    dim = C.ACTION_NAMES.index(f"{side}_gripper")
    seen = {"close_step": None, "offset_mm": None, "commanded_offset_mm": None, "closest_mm": float("inf"),
            "closest_step": None, "min_command": 1.0}

    def log(obs, info, action):
        offset = env.data.site(f"{side}_gripper_center").xpos - object_position(env, obj)
        distance = 1000 * float(np.linalg.norm(offset))
        if distance < seen["closest_mm"]:
            seen["closest_mm"], seen["closest_step"] = round(distance, 1), int(info["elapsed_steps"])
        seen["min_command"] = round(min(seen["min_command"], float(action[dim])), 3)
        if seen["close_step"] is None and float(action[dim]) < closed:
            seen["close_step"] = int(info["elapsed_steps"])
            seen["offset_mm"] = [round(1000 * float(v), 1) for v in offset]
            target = commanded_site(env, scratch, action, f"{side}_gripper_center")
            commanded = target - object_position(env, obj)
            seen["commanded_offset_mm"] = [round(1000 * float(v), 1) for v in commanded]

    record = run_episode(env, agent, seed, on_act=log)
    return {"seed": seed, "progress": record["progress"], "success": record["success"], **seen}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--task", required=True, choices=sorted(FIRST_GRASP))
    ap.add_argument("--policy", default="expert", help="a checkpoint folder or expert (default)")
    ap.add_argument("--condition", default="clean")
    ap.add_argument("--seeds", default="1000-1003", help="first-last (inclusive)")
    ap.add_argument("--closed", type=float, default=0.5, help="a gripper command below this is 'closing'")
    ap.add_argument("--grasp", default=None, metavar="ARM:BODY",
                    help="gripper (left|right) and object body or geom to trace, e.g. left:top_block "
                    "(default: the task's first grasp)")
    args = ap.parse_args()
    first, last = (int(s) for s in args.seeds.split("-"))
    side, obj = FIRST_GRASP[args.task]
    if args.grasp is not None:
        side, _, obj = args.grasp.partition(":")
        if side not in ("left", "right") or not obj:
            ap.error(f"--grasp must be left:BODY or right:BODY, not {args.grasp!r}")
    env = BavoEnv(task=args.task, condition=args.condition, **env_kwargs_for_policy(args.policy))
    env.reset(seed=first)
    object_position(env, obj)  # a wrong name fails here, before any policy is loaded
    agent = make_agent(args.policy, env)
    rows = [trace_episode(env, agent, seed, side, obj, args.closed) for seed in range(first, last + 1)]
    env.close()
    for row in rows:
        print(json.dumps(row))
    offsets = np.array([r["offset_mm"] for r in rows if r["offset_mm"] is not None])
    if len(offsets):
        print(f"{args.policy} on {args.task} ({args.condition}), {side} gripper on {obj}: closes at steps "
              f"{[r['close_step'] for r in rows]}; offset mean (x, y, z) {offsets.mean(0).round(1).tolist()} "
              f"mm, |offset| {np.linalg.norm(offsets, axis=1).round(0).tolist()} mm; milestones "
              f"{[r['progress'] for r in rows]}")
    print(f"closest approach {[r['closest_mm'] for r in rows]} mm at steps "
          f"{[r['closest_step'] for r in rows]}; lowest command {[r['min_command'] for r in rows]}")


if __name__ == "__main__":
    main()
