"""Does a grasp land when the gripper waits for the arm to arrive? (issue 27, a probe, not a fix)

Why: `scripts/grasp_trace.py --policy ...` showed, on Dustpan Sweeping (validation seeds 1000-1005), that the
failed first grasps closed 2-3 cm above the handle while the arm's joint targets of that same step already
put the gripper at the handle's height: the policy's chunk closes the gripper on the step its arm command
arrives, and the position controllers are still 3-4 cm behind. The scripted expert's arm is 4 mm from its
target when it closes. This probe rolls out the same seeded episodes twice, as the policy acts and with a
wrapper that holds a closing gripper command (and the arm targets of that step, pausing the chunk) until
the measured arm joints are within `--tol` rad of those targets, or `--max-wait` steps have passed; the
policy is not called while it waits. It reads only the policy's own output and the arm's measured joints
(the proprioception in `observation.state`), nothing privileged. Seeds default to validation seeds.

    python scripts/settle_probe.py --policy checkpoints/afar_dustpan_sweeping_sf --task dustpan_sweeping \
        --condition stage --seeds 1000-1009 [--tol 0.02] [--max-wait 10]
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from lerobot_bavo.envs.bavo_env import BavoEnv
from lerobot_bavo.eval.rollout import env_kwargs_for_policy, make_agent, run_episode
from lerobot_bavo.sim import constants as C

ARMS = {"left": (C.LEFT_ARM, C.ACTION_NAMES.index("left_gripper")),
        "right": (C.RIGHT_ARM, C.ACTION_NAMES.index("right_gripper"))}


class SettleBeforeClose:
    """Wraps an agent: a gripper command that newly falls below `closed` (raw command, 1 = open) while that
    arm's measured joints are more than `tol` rad from the step's joint targets is held back, with the arm
    targets of that step, until the arm arrives or `max_wait` steps have passed."""

    def __init__(self, agent, tol: float, max_wait: int, closed: float = 0.5):
        self.agent, self.tol, self.max_wait, self.closed = agent, tol, max_wait, closed
        self.waits: list[int] = []

    def reset(self, seed=None):
        self.agent.reset(seed=seed)
        self.held, self.wait, self.last = None, 0, None

    def _lag(self, obs, action, side) -> float:
        arm, _ = ARMS[side]
        return float(np.max(np.abs(np.asarray(obs["agent_pos"], np.float64)[arm] - action[arm])))

    def act(self, obs, info):
        if self.held is not None:
            action, side = self.held
            self.wait += 1
            if self._lag(obs, action, side) <= self.tol or self.wait >= self.max_wait:
                self.waits.append(self.wait)
                self.held = None
                self.last = action
                return action
            return self._open(action, side)
        action = self.agent.act(obs, info)
        if self.last is not None:
            for side, (_, g) in ARMS.items():
                closing = action[g] < self.closed <= self.last[g]
                if closing and self._lag(obs, action, side) > self.tol:
                    self.held, self.wait = (action, side), 0
                    return self._open(action, side)
        self.last = action
        return action

    def _open(self, action, side):
        out = action.copy()
        out[ARMS[side][1]] = self.last[ARMS[side][1]]
        return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--policy", required=True)
    ap.add_argument("--task", required=True)
    ap.add_argument("--condition", default="stage")
    ap.add_argument("--seeds", default="1000-1009", help="first-last (inclusive); validation seeds")
    ap.add_argument("--tol", type=float, default=0.02, help="rad, max over the arm's six joints")
    ap.add_argument("--max-wait", type=int, default=10, help="control steps")
    args = ap.parse_args()
    first, last = (int(s) for s in args.seeds.split("-"))
    env = BavoEnv(task=args.task, condition=args.condition, **env_kwargs_for_policy(args.policy))
    agent = make_agent(args.policy, env)
    gated = SettleBeforeClose(agent, args.tol, args.max_wait)
    rows = []
    for seed in range(first, last + 1):
        plain = run_episode(env, agent, seed)
        gated.waits = []
        held = run_episode(env, gated, seed)
        rows.append({"seed": seed, "plain": [plain["success"], plain["progress"]],
                     "settle": [held["success"], held["progress"]], "waits": gated.waits})
        print(json.dumps(rows[-1]), flush=True)
    env.close()
    n = len(rows)
    print(f"{args.policy} {args.task} {args.condition} seeds {args.seeds}, tol {args.tol} rad, max wait "
          f"{args.max_wait}: SR plain {sum(r['plain'][0] for r in rows)}/{n}, settle "
          f"{sum(r['settle'][0] for r in rows)}/{n}; mean milestones "
          f"{np.mean([r['plain'][1] for r in rows]):.2f} vs {np.mean([r['settle'][1] for r in rows]):.2f}")


if __name__ == "__main__":
    main()
