"""`bavo-eval`: evaluate a policy on BAVO-Bench tasks x conditions x seeds.

Writes, under --output-dir:
  results.json   the run's settings and, for every (task, condition) cell: sr (%), tps (%),
                 cvg (pp; null where no event was retained, i.e. outside Random-time), joint
                 (SR x CVG / 100), n_episodes, and the per-episode records;
  results.md     the same as a Markdown table, with macro averages over tasks per condition;
  episodes.jsonl one line per finished episode (the resume log);
  videos/        the first --videos episodes of every cell, occlusion events marked in red.
With --rerun DIR, also one rerun recording per episode run, DIR/<task>_<condition>_seed<seed>.rrd (open it
with `bavo-view --rrd FILE`; `--rerun <output-dir>/videos` puts them next to the videos): the point cloud,
camera, RGB, occluder, visibility, progress, milestones and the policy's predicted action chunks, all
from the rollout's own observations and info.

Resumable: each episode's record is appended to episodes.jsonl as soon as the episode ends (completion
order, whichever worker ran it); finished episodes (and so finished cells) found in --output-dir are kept,
and only missing ones run; the run is keyed on a digest of the checkpoint's files (not its path: a moved
checkpoint resumes, one replaced at the same path is refused instead of mixed in), and every
record carries that digest. A torn last line of episodes.jsonl (a full disk, a kill mid-write) is
dropped with a warning; one run at a time may write an output folder (a lock on its real path).
results.json and results.md are written together through temporary files (`runtime.files`): a full disk
leaves the previous pair whole, and the run ends with a message.

Safety: checkpoints name processor classes that LeRobot imports. Only LeRobot's and this
package's processor steps and audited policy types are loaded; --trust-remote-code lifts that for
checkpoints you trust. The env is built with the point count, image size and object-pose input the
checkpoint records, and the point frame its training dataset records (--point-frame when no file
records it; a conflicting --point-frame is refused).

Executors: `--executor local` (default) runs episodes in --workers local processes; `--executor ray` runs
every episode as a Ray task (pip install 'lerobot_env_bavo[ray]'), on a private local Ray with --workers CPUs,
or on the cluster at --ray-address (`ray start --head` prints it). Records are written by this process as
episodes finish, so resume, the lock and results.json are the same; a Ray worker lost mid-episode is retried.

Grid: `--grid FILE.yaml` runs methods x tasks x conditions x training seeds in one command (the file lists
them; `configs/grid_expert.yaml` is an example, `lerobot_bavo/eval/grid.py` documents the format). Each
(method, training seed) is an ordinary run under <output-dir>/runs/<method>/<label>/, so a killed grid re-run
with the same command does only the unfinished episodes (and cells); <output-dir>/results.json holds every
cell, results.md the table of mean ± std over training seeds, results.png SR / TPS / CVG per condition.
--tasks, --conditions, --episodes, --seed and --policy come from the file then; --workers, --executor,
--ray-address and --videos apply (--videos defaults to 0 with --grid).

Policies: a LeRobot checkpoint directory (`.../pretrained_model`), `expert`
(the privileged scripted expert with camera recovery) or `expert-frozen-camera` (same
manipulation, camera arm never moves; its CVG is exactly 0 by construction).

Examples:
  bavo-eval --policy expert --tasks cube_handoff --conditions clean,stage,random --episodes 20 \\
      --output-dir outputs/eval/expert
  bavo-eval --policy outputs/train/afar/checkpoints/last/pretrained_model --episodes 20 \\
      --output-dir outputs/eval/afar
  bavo-eval --grid configs/grid_expert.yaml --output-dir outputs/eval/grid_expert
"""

from __future__ import annotations

import argparse
from pathlib import Path

from lerobot_bavo.eval.run import (  # noqa: F401  (the library's names, as `lerobot_bavo.eval.cli` offered them)
    RESULTS_VERSION,
    append_record,
    claim_output_dir,
    env_kwargs_for_run,
    evaluate,
    markdown_table,
    read_episode_log,
    run_job,
    summarize_cell,
    write_results,
)
from lerobot_bavo.runtime.pool import add_executor_arguments, executor_problem


def build_parser() -> argparse.ArgumentParser:
    """`bavo-eval`'s arguments. Options the grid file also sets default to None, so that `check_arguments`
    can tell a flag given beside `--grid` from one left alone."""
    from lerobot_bavo.features import POINT_FRAMES

    parser = argparse.ArgumentParser(prog="bavo-eval", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument(
        "--policy",
        default=None,
        help="LeRobot checkpoint dir (.../pretrained_model), 'expert' or 'expert-frozen-camera' "
        "(required unless --grid)",
    )
    parser.add_argument(
        "--grid",
        type=Path,
        default=None,
        metavar="FILE.yaml",
        help="run the grid of methods x tasks x conditions x training seeds the file lists (see "
        "above and configs/grid_expert.yaml) instead of one --policy",
    )
    parser.add_argument("--tasks", default=None, help="comma-separated tasks (default: all registered)")
    parser.add_argument(
        "--conditions", default=None, help="comma-separated conditions (default clean,stage,random)"
    )
    parser.add_argument(
        "--episodes", type=int, default=None, help="episodes per (task, condition) (default 20)"
    )
    parser.add_argument(
        "--seed", type=int, default=None, help="first seed (default 1000, LeRobot's start seed)"
    )
    parser.add_argument("--output-dir", type=Path, required=True, help="where results and videos go")
    add_executor_arguments(parser, 1, "parallel worker processes (default 1)",
                           "where episodes run: local worker processes (default) or Ray tasks")
    parser.add_argument(
        "--videos", type=int, default=None, help="episodes recorded per cell (default 1; 0 with --grid)"
    )
    parser.add_argument(
        "--rerun",
        type=Path,
        default=None,
        metavar="DIR",
        help="also write one rerun recording (.rrd) per episode run into DIR (view with bavo-view --rrd)",
    )
    parser.add_argument(
        "--trust-remote-code",
        action="store_true",
        help="load processor steps and policy types that are neither LeRobot's audited ones nor "
        "lerobot_bavo's (they run arbitrary code when loaded: only for checkpoints you trust)",
    )
    parser.add_argument(
        "--point-frame",
        choices=POINT_FRAMES,
        default=None,
        help="frame of the env's point clouds when nothing records the checkpoint's (default: the "
        "frame its own bavo_inputs.json records, else its training dataset's, else base); a conflicting "
        "value is refused",
    )
    return parser


def check_arguments(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Refuse flags that conflict with `--grid` or are out of range, then fill in, in place, the defaults
    that `--help` names (here rather than in `add_argument`, which would hide whether a flag was given)."""
    from lerobot_bavo.envs.tasks import TASKS

    if args.grid is not None:
        given = [
            f"--{name.replace('_', '-')}"
            for name in ("policy", "tasks", "conditions", "episodes", "seed", "point_frame", "rerun")
            if getattr(args, name) is not None
        ]
        if given:
            parser.error(f"{', '.join(given)} cannot be used with --grid (the grid file sets them)")
    elif args.policy is None:
        parser.error("--policy (or --grid FILE.yaml) is required")
    defaults = {"tasks": ",".join(TASKS), "conditions": "clean,stage,random", "episodes": 20, "seed": 1000,
                "videos": 0 if args.grid is not None else 1}
    for name, value in defaults.items():
        if getattr(args, name) is None:
            setattr(args, name, value)
    for name, low in (("episodes", 1), ("seed", 0), ("workers", 1), ("videos", 0)):
        if getattr(args, name) < low:
            parser.error(f"--{name} must be >= {low}, got {getattr(args, name)}")


def main(argv: list[str] | None = None) -> None:
    parser = build_parser()
    args = parser.parse_args(argv)
    check_arguments(parser, args)
    from lerobot_bavo import register_lerobot_types
    from lerobot_bavo.checkpoints import CheckpointMismatchError, UntrustedCheckpointError
    from lerobot_bavo.eval.rollout import EXPERT_POLICIES

    # After the arguments are checked (`--help` and usage errors answer at once), before any worker is forked:
    # the workers inherit LeRobot's "bavo" / "maniflow" / "afar" types instead of each importing them. A
    # scripted expert needs neither LeRobot nor PyTorch: importing them (seconds of CPU) would only delay
    # the workers' start and make this process the run's serial part (issue 30).
    if args.grid is not None or args.policy not in EXPERT_POLICIES:
        register_lerobot_types()
    if args.grid is not None:
        if (problem := executor_problem(args.executor, args.ray_address, args.workers)) is not None:
            raise SystemExit(f"bavo-eval: {problem}")
        from lerobot_bavo.eval.grid import GridError, load_grid, run_grid

        try:
            grid = load_grid(args.grid)
        except GridError as e:
            raise SystemExit(f"bavo-eval: {e}") from None
        try:
            run_grid(grid, args.output_dir, workers=args.workers, videos=args.videos, executor=args.executor,
                     ray_address=args.ray_address, trust_remote_code=args.trust_remote_code)
        except (CheckpointMismatchError, UntrustedCheckpointError) as e:
            raise SystemExit(f"bavo-eval: {e}") from None
        return
    try:
        evaluate(
            args.policy,
            args.tasks.split(","),
            args.conditions.split(","),
            args.episodes,
            args.seed,
            args.output_dir,
            workers=args.workers,
            videos=args.videos,
            trust_remote_code=args.trust_remote_code,
            point_frame=args.point_frame,
            rerun_dir=args.rerun,
            executor=args.executor,
            ray_address=args.ray_address,
        )
    except (CheckpointMismatchError, UntrustedCheckpointError) as e:  # raised while a worker loads the policy
        raise SystemExit(f"bavo-eval: {e}") from None


if __name__ == "__main__":
    main()
