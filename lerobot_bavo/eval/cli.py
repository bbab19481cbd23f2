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

Resumable: finished episodes (and so finished cells) found in --output-dir are kept, and only
missing ones run; the run is keyed on a digest of the checkpoint's files (not its path: a moved
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

Grid: `--grid FILE.yaml` runs methods x tasks x conditions x training seeds in one command (the file lists them;
`configs/grid_expert.yaml` is an example, `lerobot_bavo/eval/grid.py` documents the format). Each (method,
training seed) is an ordinary run under <output-dir>/runs/<method>/<label>/, so a killed grid re-run with the same
command does only the unfinished episodes (and cells); <output-dir>/results.json holds every cell, results.md the
table of mean ± std over training seeds, results.png SR / TPS / CVG per condition. --tasks, --conditions,
--episodes, --seed and --policy come from the file then; --workers, --executor, --ray-address and --videos apply
(--videos defaults to 0 with --grid).

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
import json
import time
from pathlib import Path

from lerobot_bavo.runtime.pool import ProcessCache, WorkerPool, add_executor_arguments, executor_problem

RESULTS_VERSION = 1


def _close_env_agent(env_agent) -> None:
    env_agent[0].close()


_ENV_AGENT = ProcessCache(close=_close_env_agent)


def _run_job(job: dict) -> dict:
    """One episode in a worker process; envs and agents are cached per (policy, task, condition)."""
    from lerobot_bavo.envs.bavo_env import BavoEnv
    from lerobot_bavo.eval.rollout import env_kwargs_for_policy, make_agent, run_episode

    env_kwargs = job["env_kwargs"] if "env_kwargs" in job else env_kwargs_for_policy(job["policy"])
    key = (job["policy"], job["task"], job["condition"], tuple(sorted(env_kwargs.items())))

    def build():
        env = BavoEnv(task=job["task"], condition=job["condition"], **env_kwargs)
        return env, make_agent(job["policy"], env, trust_remote_code=job.get("trust_remote_code", False))

    env, agent = _ENV_AGENT.get(key, build)
    video = Path(job["video"]) if job.get("video") else None
    rerun = Path(job["rerun"]) if job.get("rerun") else None
    t0 = time.perf_counter()
    record = run_episode(env, agent, job["seed"], video_path=video, rerun_path=rerun)
    record["wall_s"] = round(time.perf_counter() - t0, 2)
    record["task"], record["condition"] = job["task"], job["condition"]
    if job.get("checkpoint_sha256"):
        record["checkpoint_sha256"] = job["checkpoint_sha256"]
    return record


def summarize_cell(records: list[dict]) -> dict:
    """SR, TPS, CVG (pp) and Joint of one (task, condition) cell (paper Sec. 3.3, App. A)."""
    from lerobot_bavo.eval.metrics import aggregate_cvg, joint_score, success_rate, task_progress_score

    sr = success_rate([r["success"] for r in records])
    tps = task_progress_score([r["progress"] for r in records])
    cvg = aggregate_cvg([r.get("episode_cvg") for r in records])
    cvg_pp = None if cvg is None else 100.0 * cvg
    fallbacks = sum(p["fallback"] for r in records for p in r.get("placements", []))
    return {"sr": sr, "tps": tps, "cvg": cvg_pp, "joint": joint_score(sr, cvg_pp),
            "n_episodes": len(records), "occluder_fallbacks": fallbacks,
            "episodes": sorted(records, key=lambda r: r["seed"])}


def markdown_table(results: dict) -> str:
    def fmt(x):
        return "-" if x is None else f"{x:.1f}"

    lines = [f"Policy: `{results['policy']}`, {results['episodes']} episodes per cell, seeds from {results['seed']}.", "",
             "| task | condition | SR (%) | TPS (%) | CVG (pp) | Joint |", "|---|---|---|---|---|---|"]
    cells = results["cells"]
    for task in results["tasks"]:
        for cond in results["conditions"]:
            c = cells.get(f"{task}/{cond}")
            if c:
                lines.append(f"| {task} | {cond} | {fmt(c['sr'])} | {fmt(c['tps'])} | {fmt(c['cvg'])} | {fmt(c['joint'])} |")
    for cond in results["conditions"]:
        cs = [cells[f"{t}/{cond}"] for t in results["tasks"] if f"{t}/{cond}" in cells]
        if len(cs) > 1:
            mean = lambda key: (None if any(c[key] is None for c in cs) else sum(c[key] for c in cs) / len(cs))  # noqa: E731
            lines.append(f"| **mean** | {cond} | {fmt(mean('sr'))} | {fmt(mean('tps'))} | {fmt(mean('cvg'))} | {fmt(mean('joint'))} |")
    return "\n".join(lines) + "\n"


def read_episode_log(log_path: Path) -> dict[tuple[str, str, int], dict]:
    """Finished episodes of `episodes.jsonl`, keyed (task, condition, seed).

    Every record is written as one line ending in a newline, so a last line without one is a torn write
    (a full disk, a kill mid-write): it is dropped (the file is truncated to the last complete line) with
    a warning, and its episode runs again. A line that does not parse anywhere else is corruption: an
    error naming the file and the line."""
    import sys

    done: dict[tuple[str, str, int], dict] = {}
    if not log_path.exists():
        return done
    data = log_path.read_bytes()
    complete = data[: data.rfind(b"\n") + 1]
    if len(complete) < len(data):
        print(f"bavo-eval: warning: dropping an incomplete last line of {log_path} ({len(data) - len(complete)} "
              "bytes, a torn write); its episode runs again", file=sys.stderr)
        with open(log_path, "r+b") as fh:
            fh.truncate(len(complete))
    for number, line in enumerate(complete.decode("utf-8", errors="replace").splitlines(), start=1):
        if not line.strip():
            continue
        try:
            r = json.loads(line)
            done[(r["task"], r["condition"], r["seed"])] = r
        except (json.JSONDecodeError, KeyError, TypeError) as e:
            raise SystemExit(f"bavo-eval: {log_path} line {number} is corrupt ({e}); remove that line (its "
                             "episode then runs again) or use another --output-dir") from None
    return done


def env_kwargs_for_run(policy: str, point_frame: str | None = None) -> dict:
    """The `BavoEnv` settings of a run: what the checkpoint records (`lerobot_bavo.checkpoints.env_settings`), with
    `point_frame` from the command line where nothing records it. A --point-frame that contradicts the
    checkpoint's training data is refused, listing both."""
    import sys

    from lerobot_bavo.checkpoints import CheckpointMismatchError
    from lerobot_bavo.eval.rollout import env_kwargs_for_policy

    try:
        kwargs = dict(env_kwargs_for_policy(policy))
    except CheckpointMismatchError as e:
        raise SystemExit(f"bavo-eval: {e}") from None
    recorded = kwargs.get("point_frame")
    if point_frame is not None and recorded is not None and point_frame != recorded:
        raise SystemExit(f"bavo-eval: --point-frame {point_frame} conflicts with the checkpoint: point_frame: "
                         f"checkpoint {recorded!r} (its training dataset's bavo_collection.json), asked {point_frame!r}")
    if point_frame is not None:
        kwargs["point_frame"] = point_frame
    elif "n_points" in kwargs and recorded is None:
        kwargs["point_frame"] = "base"
        print(f"bavo-eval: warning: nothing on this machine records the point-cloud frame the checkpoint at {policy} "
              "was trained on (its train_config.json names no bavo-collect dataset found here); evaluating on "
              "base-frame clouds, pass --point-frame camera for a camera-frame model", file=sys.stderr)
    return kwargs


def _identity(settings: dict) -> tuple:
    """What must match to resume a run: seed, the checkpoint's digest (the expert's name), the point frame.
    The path is informational (run.json files written before the digest existed still resume)."""
    return (settings.get("seed"), settings.get("checkpoint_sha256") or settings.get("policy"),
            settings.get("point_frame", "base"))


def append_record(log, record: dict) -> None:
    """Append one record to the open (unbuffered, binary) `episodes.jsonl` as one newline-terminated line.

    The newline comes last, so a write cut short (a full disk, a kill) leaves a last line without one, which
    `read_episode_log` recognises and drops. Unbuffered, so nothing is left to flush (and to fail again) when
    the file is closed after a failed write; a failed write ends the run with a message, not a traceback."""
    data = memoryview((json.dumps(record) + "\n").encode())
    try:
        while data:
            data = data[log.write(data):]
    except OSError as e:
        raise SystemExit(f"bavo-eval: writing {log.name} failed ({e.strerror}); free some space and re-run the same "
                         "command: finished episodes are kept and the cut-off last line is dropped") from None




def _make_pool(executor: str, workers: int, jobs: list, ray_address: str | None):
    """The pool episodes run in: local processes (in-process for one worker), or Ray tasks (`RayPool`; Ray is
    imported only here). Both give `imap(fn, jobs)`; Ray's results come in completion order."""
    if executor == "ray" and jobs:
        from lerobot_bavo.runtime.ray_pool import RayPool

        return RayPool(workers, address=ray_address)
    return WorkerPool(workers if workers > 1 and jobs else 0, start_method=None)


def evaluate(policy: str, tasks: list[str], conditions: list[str], episodes: int, seed: int,
             output_dir: Path, workers: int = 1, videos: int = 1, trust_remote_code: bool = False,
             point_frame: str | None = None, rerun_dir: Path | None = None, executor: str = "local",
             ray_address: str | None = None) -> dict:
    """Run (or resume) the evaluation and write results.json / results.md; returns the results.
    `rerun_dir`: also write a rerun recording of every episode run there (`lerobot_bavo.viz`).
    `executor`: "local" (a `WorkerPool` of `workers` processes) or "ray" (a `RayPool`: Ray tasks on the cluster
    at `ray_address`, or on a private local Ray with `workers` CPUs)."""
    from tqdm import tqdm

    from lerobot_bavo.checkpoints import (
        CheckpointMismatchError,
        check_processor_steps,
        check_tensor_files,
        checkpoint_digest,
        load_policy_config,
    )
    from lerobot_bavo.envs.conditions import CONDITIONS
    from lerobot_bavo.envs.tasks import TASKS
    from lerobot_bavo.eval.rollout import EXPERT_POLICIES
    from lerobot_bavo.features import POINT_FRAMES

    for t in tasks:
        if t not in TASKS:
            raise SystemExit(f"bavo-eval: unknown task {t!r}; choose from {', '.join(TASKS)}")
    for c in conditions:
        if c not in CONDITIONS:
            raise SystemExit(f"bavo-eval: unknown condition {c!r}; choose from {', '.join(CONDITIONS)}")
    if policy not in EXPERT_POLICIES and not (Path(policy) / "config.json").is_file():
        raise SystemExit(f"bavo-eval: --policy {policy!r} is neither {' / '.join(EXPERT_POLICIES)} "
                         "nor a LeRobot checkpoint directory containing config.json")
    if (problem := executor_problem(executor, ray_address, workers)) is not None:
        raise SystemExit(f"bavo-eval: {problem}")
    if point_frame is not None and point_frame not in POINT_FRAMES:
        raise SystemExit(f"bavo-eval: --point-frame must be base or camera, got {point_frame!r}")
    if output_dir.exists() and not output_dir.is_dir():
        raise SystemExit(f"bavo-eval: --output-dir {output_dir} exists and is not a folder")
    settings: dict = {"seed": seed}
    if policy in EXPERT_POLICIES:
        policy_id = settings["policy"] = policy
    else:
        policy_id = settings["policy"] = str(Path(policy).resolve())
        try:  # refuse untrusted processor steps and policy types here, before any worker imports them; then
            # configs out of bounds (`lerobot_bavo.limits`) and cut-off weights, before any env or model is built
            check_processor_steps(policy, trust_remote_code=trust_remote_code)
            load_policy_config(policy)
            check_tensor_files(policy)
        except (ValueError, CheckpointMismatchError) as e:
            raise SystemExit(f"bavo-eval: {e}") from None
        settings["checkpoint_sha256"] = checkpoint_digest(policy)
    env_kwargs = env_kwargs_for_run(policy, point_frame)
    settings["point_frame"] = env_kwargs.get("point_frame", "base")

    lock = claim_output_dir(output_dir, "bavo-eval")
    try:
        return _evaluate_locked(policy, policy_id, settings, env_kwargs, tasks, conditions, episodes, seed,
                                output_dir, workers, videos, trust_remote_code, tqdm, rerun_dir, executor, ray_address)
    finally:
        lock.close()


def claim_output_dir(output_dir: Path, holder: str):
    """Create `output_dir` and take its exclusive lock (one bavo-eval run or grid per folder); returns the lock
    to close when done. Errors name the folder and say what to do."""
    from lerobot_bavo.runtime.process import LockedError, exclusive_lock

    try:
        output_dir.mkdir(parents=True, exist_ok=True)
    except OSError as e:  # e.g. a parent that is a file
        raise SystemExit(f"bavo-eval: cannot create --output-dir {output_dir}: {e.strerror}") from None
    try:
        return exclusive_lock(output_dir, holder)
    except LockedError as e:
        raise SystemExit(f"bavo-eval: {e}; wait for it or use another --output-dir") from None


def _evaluate_locked(policy, policy_id, settings, env_kwargs, tasks, conditions, episodes, seed, output_dir, workers,
                     videos, trust_remote_code, tqdm, rerun_dir=None, executor="local", ray_address=None) -> dict:
    log_path = output_dir / "episodes.jsonl"
    settings_path = output_dir / "run.json"
    if settings_path.exists():
        try:
            previous = json.loads(settings_path.read_text())
        except json.JSONDecodeError as e:
            raise SystemExit(f"bavo-eval: {settings_path} is not valid JSON ({e}); use another --output-dir") from None
        if not isinstance(previous, dict) or _identity(previous) != _identity(settings):
            raise SystemExit(f"bavo-eval: {output_dir} holds a run with different settings {previous} (now "
                             f"{settings}: another checkpoint, or the same path with other weights); use another "
                             "--output-dir")
    write_results({settings_path: json.dumps(settings)})

    done = read_episode_log(log_path)
    digest = settings.get("checkpoint_sha256")
    foreign = sorted({r["checkpoint_sha256"] for r in done.values() if r.get("checkpoint_sha256", digest) != digest})
    if foreign:
        raise SystemExit(f"bavo-eval: {log_path} holds episodes of other checkpoints (sha256 {', '.join(foreign)}; "
                         f"this one is {digest}); use another --output-dir")
    jobs = []
    for task in tasks:
        for cond in conditions:
            for i in range(episodes):
                s = seed + i
                if (task, cond, s) in done:
                    continue
                video = str(output_dir / "videos" / f"{task}_{cond}_seed{s}.mp4") if i < videos else None
                rerun = str(Path(rerun_dir) / f"{task}_{cond}_seed{s}.rrd") if rerun_dir is not None else None
                jobs.append({"policy": policy, "task": task, "condition": cond, "seed": s, "video": video, "rerun": rerun,
                             "trust_remote_code": trust_remote_code, "env_kwargs": env_kwargs,
                             "checkpoint_sha256": digest})
    if done:
        print(f"bavo-eval: resuming; {len(done)} finished episodes kept, {len(jobs)} to run")

    with open(log_path, "ab", buffering=0) as log, tqdm(total=len(jobs), desc="episodes", unit="ep") as bar:
        with _make_pool(executor, workers, jobs, ray_address) as pool:
            for record in pool.imap(_run_job, jobs):
                done[(record["task"], record["condition"], record["seed"])] = record
                append_record(log, record)
                bar.update(1)

    cells = {}
    for task in tasks:
        for cond in conditions:
            records = [done[(task, cond, seed + i)] for i in range(episodes)]
            cells[f"{task}/{cond}"] = summarize_cell(records)
    results = {"version": RESULTS_VERSION, "policy": policy_id, "tasks": tasks, "conditions": conditions,
               "episodes": episodes, "seed": seed, "cells": cells}
    table = markdown_table(results)
    write_results({output_dir / "results.json": json.dumps(results, indent=1), output_dir / "results.md": table})
    print(table)
    return results


def write_results(files: dict) -> None:
    """Write result files (path -> text or bytes) all or none (`runtime.files.write_files_atomic`); a failed
    write (a full disk) ends the run with a message and leaves the previous files as they were."""
    from lerobot_bavo.runtime.files import write_files_atomic

    try:
        write_files_atomic(files)
    except OSError as e:
        names = ", ".join(sorted({str(Path(p).name) for p in files}))
        raise SystemExit(f"bavo-eval: writing {names} in {Path(next(iter(files))).parent} failed ({e.strerror}); "
                         "the previous files are unchanged; free some space and re-run the same command: finished "
                         "episodes are kept") from None


def main(argv: list[str] | None = None) -> None:
    from lerobot_bavo.envs.tasks import TASKS
    from lerobot_bavo.features import POINT_FRAMES

    parser = argparse.ArgumentParser(prog="bavo-eval", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--policy", default=None,
                        help="LeRobot checkpoint dir (.../pretrained_model), 'expert' or 'expert-frozen-camera' "
                             "(required unless --grid)")
    parser.add_argument("--grid", type=Path, default=None, metavar="FILE.yaml",
                        help="run the grid of methods x tasks x conditions x training seeds the file lists (see "
                             "above and configs/grid_expert.yaml) instead of one --policy")
    parser.add_argument("--tasks", default=None, help="comma-separated tasks (default: all registered)")
    parser.add_argument("--conditions", default=None, help="comma-separated conditions (default clean,stage,random)")
    parser.add_argument("--episodes", type=int, default=None, help="episodes per (task, condition) (default 20)")
    parser.add_argument("--seed", type=int, default=None, help="first seed (default 1000, LeRobot's start seed)")
    parser.add_argument("--output-dir", type=Path, required=True, help="where results and videos go")
    add_executor_arguments(parser, 1, "parallel worker processes (default 1)",
                           "where episodes run: local worker processes (default) or Ray tasks")
    parser.add_argument("--videos", type=int, default=None, help="episodes recorded per cell (default 1; 0 with --grid)")
    parser.add_argument("--rerun", type=Path, default=None, metavar="DIR",
                        help="also write one rerun recording (.rrd) per episode run into DIR (view with bavo-view --rrd)")
    parser.add_argument("--trust-remote-code", action="store_true",
                        help="load processor steps and policy types that are neither LeRobot's audited ones nor "
                             "lerobot_bavo's (they run arbitrary code when loaded: only for checkpoints you trust)")
    parser.add_argument("--point-frame", choices=POINT_FRAMES, default=None,
                        help="frame of the env's point clouds when nothing records the checkpoint's (default: the "
                             "frame its training dataset records, else base); a conflicting value is refused")
    args = parser.parse_args(argv)
    if args.grid is not None:
        given = [f"--{name.replace('_', '-')}" for name in ("policy", "tasks", "conditions", "episodes", "seed",
                                                            "point_frame", "rerun") if getattr(args, name) is not None]
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
    from lerobot_bavo import register_lerobot_types
    from lerobot_bavo.checkpoints import CheckpointMismatchError, UntrustedCheckpointError

    # After the arguments are checked (`--help` and usage errors answer at once), before any worker is forked:
    # the workers inherit LeRobot's "bavo" / "maniflow" / "afar" types instead of each importing them.
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
        evaluate(args.policy, args.tasks.split(","), args.conditions.split(","), args.episodes, args.seed,
                 args.output_dir, workers=args.workers, videos=args.videos, trust_remote_code=args.trust_remote_code,
                 point_frame=args.point_frame, rerun_dir=args.rerun, executor=args.executor,
                 ray_address=args.ray_address)
    except (CheckpointMismatchError, UntrustedCheckpointError) as e:  # raised while a worker loads the policy
        raise SystemExit(f"bavo-eval: {e}") from None


if __name__ == "__main__":
    main()
