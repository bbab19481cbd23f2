"""Where a policy's episode stops, and whether its arms are held there (issue 27, a probe, not a fix).

Why: A-FAR trained on Cube Handoff's Stage + Random-time demonstrations stops under Stage at the right
arm's lift and the handoff (M1-M3) about three times as often as the Stage-only recipe
(docs/results/random_time.md). The Random-time demonstrations contain no re-grasps, but their expert holds
both arms still while the camera restores the view, at whatever point of the task the event struck (48.7 %
of their steps against 35.1 % in the Stage ones; `scripts/demo_stats.py`). If the policy copies that wait
where no event asks for it, its arms travel much less after the last milestone it reaches than before it;
if it fails the grasp or drops the object, they keep moving. Any task: milestones come from the env's `info`.

A learned policy's command is never exactly still (its chunks differ by ~20 mrad), so travel is measured
over a window: the largest change of any of the two arms' 12 joint commands (rad) across `--window` steps
(24 = two executed chunks of 12). Per episode this prints the step each milestone was first reached and, for
an episode that fails, the median travel before and after the step its last milestone was reached, the share
of windows after it that travel less than `--held` rad (the expert's waits travel 0), the share of steps after
it with the target hidden (visibility < 0.5), and the task's milestone tests at the last step (e.g. on Cube
Handoff m1 = the right fingers touch the cube, m2 = the right hand holds it lifted, m3 = both hold it).
With `--hold-tests m2,m3,m4` (the tests that mean "a hand holds the object") it also finds the last step any
of them held, i.e. where the object was let go of or slipped, and prints both grippers' commands there and
`--after` steps later (the policy's gripper commands, 1 = open): a gripper commanded open is a release, one
still commanded closed a slip.

With `--camera-phases` each episode also gets, per phase between consecutive milestones (phase k runs from
the step milestone k was first reached to the step milestone k + 1 was, or to the episode's end when it never
was; phase 0 starts at reset), the phase's length (steps), the camera arm's mean speed (mrad per step: the
largest change of any of its 7 joint commands from one step to the next) and the share of its steps with the
target hidden, and the run ends with their medians per phase, split by whether the episodes went on to the
next milestone (`--pool LOG ...` prints that table pooled over saved `--output` logs, rolling nothing out).
Why: every way of adding Random-time demonstrations to Cube Handoff's Stage ones costs Stage at the lift and
the handoff, also when the Random-time frames teach the camera arm only
(docs/results/random_time.md); a policy that learned to move the camera at any moment may move it where the
Stage demonstrations hold it and lose the target (docs/results/learning_rate.md).

    python scripts/arm_hold_trace.py --policy checkpoints/afar_cube_handoff_mixsr200sf \\
        [--task cube_handoff] [--condition stage] [--seeds 1000-1019] [--output trace.jsonl]

Seeds default to validation seeds (1000+); test seeds (2000+) are for reporting only.
"""

from __future__ import annotations

import argparse
import gzip
import json
from pathlib import Path

import numpy as np

from lerobot_bavo.envs.bavo_env import BavoEnv
from lerobot_bavo.eval.rollout import (
    CommandLog,
    env_kwargs_for_policy,
    make_agent,
    run_episode,
    target_hidden,
)
from lerobot_bavo.eval.run import episode_log_path
from lerobot_bavo.sim import constants as C

ARMS = np.r_[C.LEFT_ARM, C.RIGHT_ARM]


def milestone_steps(progress: list[int]) -> list[int | None]:
    """The first step (0-based) at which each of the five milestones counts as reached; None if never."""
    return [next((i for i, p in enumerate(progress) if p >= m), None) for m in range(1, 6)]


def window_travel(commands: np.ndarray, window: int) -> np.ndarray:
    """For each step t, the largest change of any column of `commands` (T x joints, rad) from t to t + window;
    empty when the series is not longer than the window."""
    if len(commands) <= window:
        return np.zeros(0)
    return np.abs(commands[window:] - commands[:-window]).max(axis=1)


def travel_around_stop(progress: list[int], commands: np.ndarray, hidden: list[bool], window: int,
                       held: float) -> dict:
    """Arm travel (median over windows, mrad) before and after the step the last reached milestone was first
    reached, the share of windows after it below `held` rad, and the share of steps after it with the target
    hidden. `commands` is the per-step action (T x action dims)."""
    last = max(progress) if progress else 0
    stop = progress.index(last) if last > 0 else 0
    before = window_travel(commands[:stop, ARMS], window)
    after = window_travel(commands[stop:, ARMS], window)

    def median_mrad(x: np.ndarray) -> float | None:
        return round(1000 * float(np.median(x)), 1) if len(x) else None

    return {
        "stop_step": stop,
        "after_steps": int(len(progress) - stop),
        "travel_before_mrad": median_mrad(before),
        "travel_after_mrad": median_mrad(after),
        "held_share": round(float(np.mean(after < held)), 3) if len(after) else None,
        "hidden_share": round(float(np.mean(hidden[stop:])), 3) if len(progress) > stop else None,
    }


def release_or_slip(held: list[bool], commands: np.ndarray, after: int) -> dict:
    """The last step at which `held` (per step: a hand holds the object) is true, and both grippers' commands
    there and `after` steps later (clipped to the episode); empty if the object was never held."""
    steps = [i for i, h in enumerate(held) if h]
    if not steps:
        return {}
    last = steps[-1]
    later = min(last + after, len(commands) - 1)
    grippers = (C.LEFT_GRIPPER, C.RIGHT_GRIPPER)
    return {"last_held_step": last,
            "grippers_at_last_held": [round(float(commands[last, g]), 2) for g in grippers],
            "grippers_after": [round(float(commands[later, g]), 2) for g in grippers]}


def phase_bounds(progress: list[int]) -> list[tuple[int, int, bool]]:
    """(start, end, completed) per phase entered: phase k spans [first step with progress >= k, first step
    with progress >= k + 1), or to len(progress) with completed False when milestone k + 1 is never
    reached."""
    bounds, start = [], 0
    for end in milestone_steps(progress):
        if end is None:
            bounds.append((start, len(progress), False))
            break
        bounds.append((start, end, True))
        start = end
    return bounds


def phase_camera(commands: np.ndarray, hidden: list[bool], start: int, end: int) -> dict:
    """Length, camera-arm mean speed (mrad/step, the largest joint-command change into each step) and hidden
    share of the steps [start, end). `commands` is T x 21 (the action layout of `lerobot_bavo.sim.constants`).
    """
    cam = commands[:, C.CAMERA_ARM]
    steps = np.abs(np.diff(cam[max(start - 1, 0):end], axis=0)).max(axis=1) if end > start else np.zeros(0)
    return {"steps": end - start,
            "cam_mrad_per_step": round(1000 * float(steps.mean()), 2) if len(steps) else None,
            "hidden_share": round(float(np.mean(hidden[start:end])), 3) if end > start else None}


def read_jsonl(path: Path) -> list[dict]:
    """The JSON lines of an --output log, gzipped or not (its rows are not bavo-eval's episode records, so
    `read_episode_records` does not take them)."""
    with (gzip.open(path, "rt") if path.suffix == ".gz" else open(path)) as f:
        return [json.loads(line) for line in f if line.strip()]


def median_text(values: list) -> str:
    """The median of the values that are not None, two decimals; '-' when there are none."""
    values = [v for v in values if v is not None]
    return f"{np.median(values):.2f}" if values else "-"


def print_phase_table(rows: list[dict]) -> None:
    """Medians per phase over the episodes that entered it, split by whether they reached the next milestone,
    and how many of those phases had the target hidden for at least half their steps (the view lost)."""
    print("| phase | went on | episodes | steps | camera mrad/step | target hidden | view lost |")
    print("|---|---|---|---|---|---|---|")
    for k in range(5):
        for done in (True, False):
            ph = [p for r in rows for p in r["phases"] if p["phase"] == k and p["completed"] == done]
            if not ph:
                continue
            steps, cam, hidden = (median_text([p[key] for p in ph])
                                  for key in ("steps", "cam_mrad_per_step", "hidden_share"))
            lost = sum((p["hidden_share"] or 0.0) >= 0.5 for p in ph)
            went_on = "yes" if done else "no"
            print(f"| M{k} -> M{k + 1} | {went_on} | {len(ph)} | {steps} | {cam} | {hidden} | {lost} |")


def main() -> None:
    from lerobot_bavo.envs.tasks import TASKS

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--policy", help="a checkpoint folder, or `expert` (required unless --pool)")
    ap.add_argument("--task", default="cube_handoff", choices=sorted(TASKS))
    ap.add_argument("--condition", default="stage", choices=["clean", "stage", "random"])
    ap.add_argument("--seeds", default="1000-1019", help="first-last (inclusive); validation seeds")
    ap.add_argument("--window", type=int, default=24, help="steps over which arm travel is measured")
    ap.add_argument("--held", type=float, default=0.05,
                    help="travel (rad) per window below which the arms count as held (~ a policy's jitter)")
    ap.add_argument("--hold-tests", default="",
                    help="tests that mean a hand holds the object, comma-separated (Cube Handoff: m2,m3,m4)")
    ap.add_argument("--after", type=int, default=6, help="steps after the last held step to read grippers at")
    ap.add_argument("--camera-phases", action="store_true",
                    help="per phase between milestones: length, camera-arm speed and target-hidden share")
    ap.add_argument("--output", help="also write one JSON line per episode here")
    ap.add_argument("--pool", nargs="+", metavar="LOG", type=episode_log_path,
                    help="roll nothing out: print the camera-phase table pooled over these --camera-phases "
                         "--output logs (.jsonl or .jsonl.gz), e.g. the training seeds of one method")
    args = ap.parse_args()
    if args.pool:
        logs = {log: read_jsonl(log) for log in args.pool}
        if missing := [log for log, rows in logs.items() if not any("phases" in r for r in rows)]:
            ap.error(f"--pool: {', '.join(map(str, missing))} hold no camera phases "
                     "(written without --camera-phases?)")
        rows = [row for log_rows in logs.values() for row in log_rows]
        print(f"{len(rows)} episodes, {sum(r['success'] for r in rows)} successes")
        print_phase_table(rows)
        return
    if not args.policy:
        ap.error("--policy is required (or --pool LOG ...)")
    hold_tests = [t for t in args.hold_tests.split(",") if t]
    first, last = (int(s) for s in args.seeds.split("-"))
    env = BavoEnv(task=args.task, condition=args.condition, **env_kwargs_for_policy(args.policy))
    agent = CommandLog(make_agent(args.policy, env))
    base = env.unwrapped
    known = base.task.evaluate(base.model, base.data)  # the task's test names (values unused)
    if unknown := [t for t in hold_tests if t not in known]:
        env.close()
        ap.error(f"--hold-tests {','.join(unknown)}: not tests of {args.task}; its tests: {', '.join(known)}")
    progress: list[int] = []
    hidden: list[bool] = []
    held: list[bool] = []

    def on_step(info):
        progress.append(int(info["progress"]))
        hidden.append(target_hidden(info))
        if hold_tests:
            tests = base.task.evaluate(base.model, base.data)
            held.append(any(tests[t] for t in hold_tests))

    rows = []
    if args.output:
        open(args.output, "w").close()
    for seed in range(first, last + 1):
        progress.clear()
        hidden.clear()
        held.clear()
        record = run_episode(env, agent, seed, on_step=on_step)
        commands = np.array(agent.commands[:len(progress)])
        row = {"seed": seed, "success": record["success"], "progress": record["progress"],
               "milestone_steps": milestone_steps(progress)}
        if args.camera_phases:
            row["phases"] = [dict(phase=k, completed=done, **phase_camera(commands, hidden, start, end))
                             for k, (start, end, done) in enumerate(phase_bounds(progress))]
        if not record["success"]:
            row.update(travel_around_stop(progress, commands, hidden, args.window, args.held))
            row["tests_at_end"] = [k for k, v in base.task.evaluate(base.model, base.data).items() if v]
            if hold_tests:
                row.update(release_or_slip(held, commands, args.after))
        rows.append(row)
        print(json.dumps(row), flush=True)
        if args.output:
            with open(args.output, "a") as out:
                out.write(json.dumps(row) + "\n")
    env.close()
    stopped = [r for r in rows if not r["success"]]
    stops = np.bincount([r["progress"] for r in stopped], minlength=6).tolist()

    def median(key: str) -> float:
        values = [r[key] for r in stopped if r.get(key) is not None]
        return float(np.median(values)) if values else float("nan")

    print(f"{args.policy} {args.task} {args.condition} seeds {args.seeds}: {len(rows)} episodes, "
          f"{len(rows) - len(stopped)} successes; stopped at M0-M5 {stops}; arm travel per {args.window} "
          f"steps before / after the last milestone, median over stopped episodes: "
          f"{median('travel_before_mrad'):.0f} / {median('travel_after_mrad'):.0f} mrad; "
          f"held share after it {median('held_share'):.2f}")
    if args.camera_phases:
        print_phase_table(rows)


if __name__ == "__main__":
    main()
