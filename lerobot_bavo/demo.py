"""`bavo-demo`: a short end-to-end run of BAVO-Bench: a learned A-FAR policy recovering its view.

By default it runs the shipped A-FAR checkpoint (`checkpoints/afar_cube_handoff_sf`, trained on CPU from
100 scripted Stage demonstrations with self-filtered point clouds, see its README.md) and the privileged
scripted expert on Cube Handoff under Stage Occlusion, on held-out seeds (1000, 1001, ...;
demonstrations used seeds below 1000). For each it prints Success Rate and Task Progress Score (paper Sec.
3.3) and writes one mp4 per episode: the third-person view beside the active-camera view, with a red
border on the frames just after each occlusion event (the occluder is placed on the camera-to-target
line of sight, and the policy must move the camera arm to see again).

Examples:
  bavo-demo                                    # shipped A-FAR + expert, cube_handoff, stage, 3 seeds
  bavo-demo --agents expert --condition clean  # the expert alone, no occluder
  bavo-demo --agents afar --policy outputs/train/afar/checkpoints/last/pretrained_model
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from lerobot_bavo.runtime.process import one_thread_unless_set

# Before numpy / torch load: on a busy 2-core machine torch's default thread pool (one thread per core)
# slows a policy episode down many times over; the user's own setting wins.
one_thread_unless_set()

# The checkpoint shipped in the repository (see its README.md for how it was trained and how to push it).
SHIPPED_CHECKPOINT = Path(__file__).resolve().parent.parent / "checkpoints" / "afar_cube_handoff_sf"
AGENTS = ("afar", "expert")


def run_demo(task: str, condition: str, seeds: list[int], output_dir: Path, agents: tuple[str, ...] = AGENTS,
             policy_path: Path = SHIPPED_CHECKPOINT, video: bool = True, video_every: int = 2,
             trust_remote_code: bool = False) -> dict[str, list[dict]]:
    """Roll out each agent for each seed; return {agent: per-episode records} (and write videos).

    `afar` is the LeRobot checkpoint at `policy_path`, loaded like `bavo-eval --policy` (processor steps
    are checked before anything is imported unless `trust_remote_code`); `expert` is the scripted expert.
    """
    from tqdm import tqdm

    from lerobot_bavo.envs.bavo_env import BavoEnv
    from lerobot_bavo.eval.rollout import env_kwargs_for_policy, make_agent, run_episode
    from lerobot_bavo.metrics import success_rate, task_progress_score

    unknown = [a for a in agents if a not in AGENTS]
    if unknown:
        raise ValueError(f"unknown agent(s) {unknown}; expected any of {AGENTS}")
    if "afar" in agents and not (Path(policy_path) / "config.json").is_file():
        raise FileNotFoundError(f"no policy checkpoint at {policy_path} (expected config.json there); pass "
                                "--policy DIR or --agents expert")
    output_dir.mkdir(parents=True, exist_ok=True)
    results: dict[str, list[dict]] = {}
    for name in agents:
        # the policy's env gives the observations its checkpoint records (point count, image size)
        extra = env_kwargs_for_policy(str(policy_path)) if name == "afar" else {}
        env = BavoEnv(task=task, condition=condition, **extra)
        if name == "expert":
            agent = make_agent("expert", env)
        else:
            agent = make_agent(str(policy_path), env, trust_remote_code=trust_remote_code)
        one_thread_unless_set()  # torch is loaded by now (the afar agent): its pool, too
        records = []
        for i, seed in enumerate(seeds):
            path = output_dir / f"{name}_{task}_{condition}_seed{seed}.mp4" if video else None
            t0 = time.perf_counter()
            # one bar per episode, in control steps, so the progress moves from the first second
            with tqdm(
                total=env.max_episode_steps,
                unit="step",
                leave=False,
                desc=f"{name} on {task}/{condition}: episode {i + 1}/{len(seeds)} (seed {seed})",
            ) as bar:
                record = run_episode(env, agent, seed, video_path=path, video_every=video_every,
                                     on_step=lambda info, bar=bar: bar.update(1))
            record["wall_s"] = time.perf_counter() - t0
            records.append(record)
            tqdm.write(f"{name:6s} seed {seed}: {'success' if record['success'] else 'failure'} "
                       f"(milestone {record['progress']}/5 after {record['steps']} steps, "
                       f"{record.get('num_events', 0)} occlusion events, {record['wall_s']:.1f} s)"
                       + (f" -> {path}" if video else ""))
        env.close()
        results[name] = records
    print(f"\n{task} / {condition}, seeds {seeds[0]}..{seeds[-1]}:")
    for name, records in results.items():
        sr = success_rate([r["success"] for r in records])
        tps = task_progress_score([r["progress"] for r in records])
        print(f"  {name:6s} SR {sr:5.1f} %  TPS {tps:5.1f} %  ({len(records)} episodes)")
    return results


def main(argv: list[str] | None = None) -> None:
    from lerobot_bavo.envs.conditions import CONDITIONS

    parser = argparse.ArgumentParser(prog="bavo-demo", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="cube_handoff", help="benchmark task (default: cube_handoff)")
    parser.add_argument("--condition", default="stage", choices=tuple(CONDITIONS),
                        help="visibility condition (default: stage)")
    parser.add_argument("--agents", default=",".join(AGENTS),
                        help="comma-separated agents to run, from: afar (a LeRobot checkpoint), expert "
                             "(default: afar,expert)")
    parser.add_argument("--policy", type=Path, default=SHIPPED_CHECKPOINT,
                        help="checkpoint directory of the 'afar' agent (default: the shipped %(default)s)")
    parser.add_argument(
        "--episodes", type=int, default=3, help="number of seeded episodes per agent (default: 3)"
    )
    parser.add_argument(
        "--seed",
        type=int,
        default=1000,
        help="first seed; episodes use seed, seed+1, ... (default 1000: not a demonstration seed)",
    )
    parser.add_argument("--output-dir", type=Path, default=Path("outputs/demo"), help="where videos go")
    parser.add_argument("--no-video", action="store_true", help="skip writing mp4 files")
    parser.add_argument("--trust-remote-code", action="store_true",
                        help="load checkpoint processor steps that are neither LeRobot's nor this package's "
                             "(they can run arbitrary code: only for checkpoints you trust)")
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error(f"--episodes must be >= 1, got {args.episodes}")
    if args.seed < 0:
        parser.error(f"--seed must be >= 0, got {args.seed}")
    agents = tuple(a.strip() for a in args.agents.split(",") if a.strip())
    bad = [a for a in agents if a not in AGENTS]
    if bad or not agents:
        parser.error(f"--agents: unknown {bad}; choose from {', '.join(AGENTS)}")
    run_demo(args.task, args.condition, list(range(args.seed, args.seed + args.episodes)), args.output_dir,
             agents=agents, policy_path=args.policy, video=not args.no_video,
             trust_remote_code=args.trust_remote_code)


if __name__ == "__main__":
    main()
