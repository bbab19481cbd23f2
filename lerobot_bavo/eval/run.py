"""The evaluation library behind `bavo-eval` and `bavo-eval --grid`: the episode job, the episode log
(`episodes.jsonl`, resumable), the claim on an output folder, `evaluate` and the result files.

`eval/cli.py` (the command) and `eval/grid.py` (the grid runner) both import it; it imports neither, so
editing the command line never touches the run it starts. The command's help text (`eval/cli.py`) says what
the files hold and how resume, locking and the executors behave.
"""

from __future__ import annotations

import contextlib
import importlib.util
import json
import time
from collections.abc import Callable
from pathlib import Path

from lerobot_bavo.metrics import CELL_METRICS, cell_metrics
from lerobot_bavo.runtime.pool import ProcessCache, WorkerPool, executor_problem

RESULTS_VERSION = 1


def _close_env_agent(env_agent) -> None:
    env_agent[0].close()


_ENV_AGENT = ProcessCache(close=_close_env_agent)


def run_job(job: dict) -> dict:
    """One episode (a job of `evaluate`) in a worker process; envs and agents are cached per (policy, task,
    condition)."""
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
    values = cell_metrics([r["success"] for r in records], [r["progress"] for r in records],
                          [r.get("episode_cvg") for r in records])
    fallbacks = sum(p["fallback"] for r in records for p in r.get("placements", []))
    return {**values, "n_episodes": len(records), "occluder_fallbacks": fallbacks,
            "episodes": sorted(records, key=lambda r: r["seed"])}


def markdown_table(results: dict) -> str:
    """results.md: one row per (task, condition) cell, the `CELL_METRICS` as columns, and the mean over tasks
    per condition where there is more than one task."""
    def fmt(x):
        return "-" if x is None else f"{x:.1f}"

    def row(first, cond, values):
        return "| " + " | ".join([first, cond, *(fmt(values[k]) for k in CELL_METRICS)]) + " |"

    lines = [f"Policy: `{results['policy']}`, {results['episodes']} episodes per cell, seeds from "
             f"{results['seed']}.", "",
             "| " + " | ".join(["task", "condition", *CELL_METRICS.values()]) + " |",
             "|" + "---|" * (2 + len(CELL_METRICS))]
    cells = results["cells"]
    for task in results["tasks"]:
        for cond in results["conditions"]:
            c = cells.get(f"{task}/{cond}")
            if c:
                lines.append(row(task, cond, c))
    for cond in results["conditions"]:
        cs = [cells[f"{t}/{cond}"] for t in results["tasks"] if f"{t}/{cond}" in cells]
        if len(cs) > 1:
            means = {k: None if any(c[k] is None for c in cs) else sum(c[k] for c in cs) / len(cs)
                     for k in CELL_METRICS}
            lines.append(row("**mean**", cond, means))
    return "\n".join(lines) + "\n"


def _episode_records(complete: bytes, log_path: Path) -> list[dict]:
    """The records of complete `episodes.jsonl` lines; a line that does not parse is corruption: an error
    naming the file and the line."""
    records = []
    for number, line in enumerate(complete.decode("utf-8", errors="replace").splitlines(), start=1):
        if not line.strip():
            continue
        try:
            r = json.loads(line)
            (r["task"], r["condition"], r["seed"])
        except (json.JSONDecodeError, KeyError, TypeError) as e:
            raise SystemExit(f"bavo-eval: {log_path} line {number} is corrupt ({e}); remove that line (its "
                             "episode then runs again) or use another --output-dir") from None
        records.append(r)
    return records


def record_episodes(seeds, trace: Callable[[int], dict], output: Path | None = None) -> list[dict]:
    """`trace(seed)` for each seed, in order; with `output`, each record is appended to that JSON-lines file
    (`append_record`) as soon as its episode ends, so an interrupted probe keeps what it finished. For the
    probes in scripts/ that roll a policy out with their own logging (`run_episode(on_act=...)`); their
    records carry "task", "condition" and "seed", so `read_episode_records` reads them back."""
    records = []
    with contextlib.ExitStack() as stack:
        log = stack.enter_context(open(output, "wb", buffering=0)) if output is not None else None
        for seed in seeds:
            records.append(trace(seed))
            if log is not None:
                append_record(log, records[-1])
    return records


def read_episode_records(log_path: Path) -> list[dict]:
    """Every finished episode of a run's per-episode log, in the order written, without touching the file:
    for analysis of finished runs (tables, per-event breakdowns). Takes `episodes.jsonl` or the gzipped
    `episodes.jsonl.gz` that `scripts/grid_runs.py` commits. A torn last line (no newline) is left out, as
    `read_episode_log` would drop it; a corrupt line elsewhere is an error naming the file and the line."""
    import gzip

    data = log_path.read_bytes()
    if log_path.suffix == ".gz":
        data = gzip.decompress(data)
    return _episode_records(data[: data.rfind(b"\n") + 1], log_path)


def condition_successes(records: list[dict], condition: str, seeds=None) -> tuple[int, int]:
    """(successes, episodes) of one condition in an episode log's records (`read_episode_records`), over the
    given seeds only when `seeds` is given: the count every validation choice and gate of
    docs/results/learning_rate.md reads."""
    cell = [r for r in records if r["condition"] == condition and (seeds is None or r["seed"] in seeds)]
    return sum(bool(r["success"]) for r in cell), len(cell)


def episode_log_path(text: str) -> Path:
    """`path/to/episodes.jsonl[.gz]` -> Path, or a usage error naming it: the argparse `type` of every episode
    log the analysis scripts read (scripts/event_recovery.py, scripts/milestone_stops.py,
    scripts/paired_outcomes.py), so a mistyped path fails before any log is read."""
    import argparse

    if not Path(text).is_file():
        raise argparse.ArgumentTypeError(f"no episode log at {text}")
    return Path(text)


def labelled_episode_log(text: str) -> tuple[str, Path]:
    """`NAME=path/to/episodes.jsonl[.gz]` -> (NAME, path): `--label`'s argparse `type`."""
    import argparse

    name, sep, path = text.partition("=")
    if not sep or not name or not path:
        raise argparse.ArgumentTypeError(f"want NAME=episodes.jsonl, got {text!r}")
    return name, episode_log_path(path)


def paired_episode_logs(text: str) -> tuple[Path, Path]:
    """`A_LOG=B_LOG` -> (A, B): two runs' episode logs to pair on their shared seeds."""
    import argparse

    a_path, sep, b_path = text.partition("=")
    if not sep or not a_path or not b_path:
        raise argparse.ArgumentTypeError(f"want A_LOG=B_LOG, got {text!r}")
    return episode_log_path(a_path), episode_log_path(b_path)


def read_episode_log(log_path: Path) -> dict[tuple[str, str, int], dict]:
    """Finished episodes of `episodes.jsonl`, keyed (task, condition, seed), for resuming a run.

    Every record is written as one line ending in a newline, so a last line without one is a torn write
    (a full disk, a kill mid-write): it is dropped (the file is truncated to the last complete line) with
    a warning, and its episode runs again. A line that does not parse anywhere else is corruption: an
    error naming the file and the line."""
    import sys

    if not log_path.exists():
        return {}
    data = log_path.read_bytes()
    complete = data[: data.rfind(b"\n") + 1]
    if len(complete) < len(data):
        print(
            f"bavo-eval: warning: dropping an incomplete last line of {log_path} "
            f"({len(data) - len(complete)} "
            "bytes, a torn write); its episode runs again",
            file=sys.stderr,
        )
        with open(log_path, "r+b") as fh:
            fh.truncate(len(complete))
    return {(r["task"], r["condition"], r["seed"]): r for r in _episode_records(complete, log_path)}


def env_kwargs_for_run(policy: str, point_frame: str | None = None) -> dict:
    """The `BavoEnv` settings of a run: what the checkpoint records (`lerobot_bavo.checkpoints.env_settings`),
    with `point_frame` from the command line where nothing records it. A --point-frame that contradicts the
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
        raise SystemExit(
            f"bavo-eval: --point-frame {point_frame} conflicts with the checkpoint: point_frame: "
            f"checkpoint {recorded!r} (its training dataset's bavo_collection.json), asked {point_frame!r}"
        )
    if point_frame is not None:
        kwargs["point_frame"] = point_frame
    elif "n_points" in kwargs and recorded is None:
        kwargs["point_frame"] = "base"
        print(
            f"bavo-eval: warning: nothing on this machine records the point-cloud frame the checkpoint at "
            f"{policy} "
            "was trained on (its train_config.json names no bavo-collect dataset found here); evaluating on "
            "base-frame clouds, pass --point-frame camera for a camera-frame model",
            file=sys.stderr,
        )
    return kwargs


def checkpoint_label(policy: str, cwd: Path | None = None) -> str:
    """How results name a checkpoint folder: relative to the working directory when it lies inside it, so that
    logs committed from a project checkout name `checkpoints/...` rather than one machine's absolute path;
    absolute otherwise. Informational only: a run resumes on the checkpoint's digest (`_identity`)."""
    path = Path(policy).resolve()
    try:
        return path.relative_to((cwd or Path.cwd()).resolve()).as_posix()
    except ValueError:
        return str(path)


def _identity(settings: dict) -> tuple:
    """What must match to resume a run: seed, the checkpoint's digest (the expert's name), the point frame and
    the robot self-filter.
    The path is informational (run.json files written before the digest existed still resume)."""
    return (settings.get("seed"), settings.get("checkpoint_sha256") or settings.get("policy"),
            settings.get("point_frame", "base"), settings.get("self_filter", False))


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
        raise SystemExit(
            f"bavo-eval: writing {log.name} failed ({e.strerror}); free some space and re-run the same "
            "command: finished episodes are kept and the cut-off last line is dropped"
        ) from None




def _make_pool(executor: str, workers: int, jobs: list, ray_address: str | None, scripted: bool = False):
    """The pool episodes run in: local processes (in-process for one worker), or Ray tasks (`RayPool`; Ray is
    imported only here). Both give `imap(fn, jobs)`; Ray's results come in completion order.

    `scripted`: the policy is a scripted expert, so the local workers skip importing LeRobot and PyTorch to
    register the policy types (~3 s of CPU per worker on the 2-core machine, more when 16 start at once: the
    bulk of an expert evaluation's start-up; docs/results/costs.md)."""
    if executor == "ray" and jobs:
        from lerobot_bavo.runtime.ray_pool import RayPool

        return RayPool(workers, address=ray_address)
    return WorkerPool(workers if workers > 1 and jobs else 0, start_method=None, light_import=scripted)


def evaluate(policy: str, tasks: list[str], conditions: list[str], episodes: int, seed: int,
             output_dir: Path, workers: int = 1, videos: int = 1, trust_remote_code: bool = False,
             point_frame: str | None = None, rerun_dir: Path | None = None, executor: str = "local",
             ray_address: str | None = None) -> dict:
    """Run (or resume) the evaluation and write results.json / results.md; returns the results.
    `rerun_dir`: also write a rerun recording of every episode run there (`lerobot_bavo.viz`).
    `executor`: "local" (a `WorkerPool` of `workers` processes) or "ray" (a `RayPool`: Ray tasks on the
    cluster at `ray_address`, or on a private local Ray with `workers` CPUs)."""
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
    if videos > 0 and importlib.util.find_spec("imageio_ffmpeg") is None:
        # checked before any episode runs: the MP4 writer is only called at an episode's end, and imageio's
        # other MP4 writer (PyAV) refuses its arguments
        raise SystemExit("bavo-eval: --videos needs the imageio-ffmpeg package (a dependency of "
                         "lerobot-bavo: pip install imageio-ffmpeg), or pass --videos 0")
    settings: dict = {"seed": seed}
    if policy in EXPERT_POLICIES:
        policy_id = settings["policy"] = policy
    else:
        policy_id = settings["policy"] = checkpoint_label(policy)
        try:  # refuse untrusted processor steps and policy types here, before any worker imports them; then
            # configs out of bounds (`lerobot_bavo.limits`) and cut-off weights, before any env or model is
            # built
            check_processor_steps(policy, trust_remote_code=trust_remote_code)
            load_policy_config(policy)
            check_tensor_files(policy)
        except (ValueError, CheckpointMismatchError) as e:
            raise SystemExit(f"bavo-eval: {e}") from None
        settings["checkpoint_sha256"] = checkpoint_digest(policy)
    env_kwargs = env_kwargs_for_run(policy, point_frame)
    settings["point_frame"] = env_kwargs.get("point_frame", "base")
    if env_kwargs.get("self_filter"):  # only when on: run.json files written before the option still resume
        settings["self_filter"] = True

    lock = claim_output_dir(output_dir, "bavo-eval")
    try:
        return _evaluate_locked(
            policy,
            policy_id,
            settings,
            env_kwargs,
            tasks,
            conditions,
            episodes,
            seed,
            output_dir,
            workers,
            videos,
            trust_remote_code,
            tqdm,
            rerun_dir,
            executor,
            ray_address,
        )
    finally:
        lock.close()


def claim_output_dir(output_dir: Path, holder: str):
    """Create `output_dir` and take its exclusive lock (one bavo-eval run or grid per folder); returns the
    lock to close when done. Errors name the folder and say what to do."""
    from lerobot_bavo.runtime.process import LockedError, exclusive_lock

    try:
        output_dir.mkdir(parents=True, exist_ok=True)
    except OSError as e:  # e.g. a parent that is a file
        raise SystemExit(f"bavo-eval: cannot create --output-dir {output_dir}: {e.strerror}") from None
    try:
        return exclusive_lock(output_dir, holder)
    except LockedError as e:
        raise SystemExit(f"bavo-eval: {e}; wait for it or use another --output-dir") from None


def _evaluate_locked(
    policy,
    policy_id,
    settings,
    env_kwargs,
    tasks,
    conditions,
    episodes,
    seed,
    output_dir,
    workers,
    videos,
    trust_remote_code,
    tqdm,
    rerun_dir=None,
    executor="local",
    ray_address=None,
) -> dict:
    from lerobot_bavo.eval.rollout import EXPERT_POLICIES

    log_path = output_dir / "episodes.jsonl"
    settings_path = output_dir / "run.json"
    if settings_path.exists():
        try:
            previous = json.loads(settings_path.read_text())
        except json.JSONDecodeError as e:
            raise SystemExit(
                f"bavo-eval: {settings_path} is not valid JSON ({e}); use another --output-dir"
            ) from None
        if not isinstance(previous, dict) or _identity(previous) != _identity(settings):
            raise SystemExit(
                f"bavo-eval: {output_dir} holds a run with different settings {previous} (now "
                f"{settings}: another checkpoint, or the same path with other weights); use another "
                "--output-dir"
            )
    write_results({settings_path: json.dumps(settings)})

    done = read_episode_log(log_path)
    digest = settings.get("checkpoint_sha256")
    foreign = sorted(
        {r["checkpoint_sha256"] for r in done.values() if r.get("checkpoint_sha256", digest) != digest}
    )
    if foreign:
        raise SystemExit(
            f"bavo-eval: {log_path} holds episodes of other checkpoints (sha256 {', '.join(foreign)}; "
            f"this one is {digest}); use another --output-dir"
        )
    jobs = []
    for task in tasks:
        for cond in conditions:
            for i in range(episodes):
                s = seed + i
                if (task, cond, s) in done:
                    continue
                video = str(output_dir / "videos" / f"{task}_{cond}_seed{s}.mp4") if i < videos else None
                rerun = str(Path(rerun_dir) / f"{task}_{cond}_seed{s}.rrd") if rerun_dir is not None else None
                jobs.append(
                    {
                        "policy": policy,
                        "task": task,
                        "condition": cond,
                        "seed": s,
                        "video": video,
                        "rerun": rerun,
                        "trust_remote_code": trust_remote_code,
                        "env_kwargs": env_kwargs,
                        "checkpoint_sha256": digest,
                    }
                )
    if done:
        print(f"bavo-eval: resuming; {len(done)} finished episodes kept, {len(jobs)} to run")

    with (open(log_path, "ab", buffering=0) as log,
          tqdm(total=len(jobs), desc="episodes", unit="ep") as bar,
          _make_pool(executor, workers, jobs, ray_address, scripted=policy_id in EXPERT_POLICIES) as pool):
        # completion order: each record is logged (and so kept for a resume) as soon as its episode ends
        for record in pool.imap_unordered(run_job, jobs):
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
    write_results(
        {output_dir / "results.json": json.dumps(results, indent=1), output_dir / "results.md": table}
    )
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
        raise SystemExit(
            f"bavo-eval: writing {names} in {Path(next(iter(files))).parent} failed ({e.strerror}); "
            "the previous files are unchanged; free some space and re-run the same command: finished "
            "episodes are kept"
        ) from None
