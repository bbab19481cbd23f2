"""`bavo-collect`: scripted-expert demonstrations -> a LeRobot v3.0 dataset with cached teacher targets.

    bavo-collect --task cube_handoff --condition stage --episodes 100 --repo-id <user>/bavo_cube_handoff \\
        [--root DIR] [--workers 2] [--executor {local,ray} [--ray-address ADDR]] [--push-to-hub]

How it works:
- Episodes are keyed by seed: attempt k uses seed `--seed` + k for the env (layout, occlusion
  schedule) and the expert (timing jitter). The dataset holds the first `--episodes` successful
  seeds, in seed order; unsuccessful attempts are discarded and counted.
- Worker processes (`--workers`, spawn, one env + expert + renderer each, one BLAS thread, no LeRobot or
  PyTorch import: `WorkerPool(light_import=True)`) record an episode, compute its teacher targets,
  build everything about it that depends only on the episode (`episode_payload.py`: the active camera's mp4,
  encoded exactly as LeRobot's streaming encoder would with this run's codec settings, and the per-episode
  statistics) and stage it as `<root>/.bavo_staging/seed_*.mp4` and `seed_*.npz` plus a `seed_*.json` marker
  written last (atomic renames). The pool starts first, with one warm-up job per worker (`staging.warm_job`:
  build the recorder), so the workers' set-up runs beside this process's own.
  Workers and this process keep freed memory for reuse (`runtime.process.retain_freed_memory`).
- The main process is the only writer of the dataset, and does only what must be serial: it appends each
  kept episode as soon as it and every lower seed are resolved (`writer.StreamingWriter`); every
  `--commit-every` episodes form one writer session (the episodes in seed order), and only then are they
  recorded in `meta/bavo_collection.json` (the collection record). With video (the workers encode every
  mp4) the sessions are `direct_writer.DirectWriterSession`: the files LeRobot 0.6.1's writer makes, written
  without importing LeRobot or PyTorch (`lerobot_format.py`; the data pages' encoding is the one difference,
  see there), ~0.1 s of CPU against a worker's ~5 s per episode (docs/results/costs.md); without video,
  LeRobot's own writer (`writer.WriterSession`: `LeRobotDataset.resume`, the episodes, `finalize()`).
- Resume: re-running the same command continues where a killed run stopped. LeRobot keeps its
  parquet writers open until `finalize()`, so a kill inside a commit leaves unreadable files. Each
  commit therefore first snapshots `meta/info.json`, `meta/stats.json`, `meta/tasks.parquet` and
  the list of data / video / episode files (a resumed LeRobot writer only ever adds new files)
  and marks the commit pending in the record; a pending commit found at start-up is rolled back
  (new files deleted, metadata restored) and redone from the staged episodes, which are deleted
  only after the record says they are committed. Finished episodes are never lost or duplicated.
- The active camera is stored as video (`video_codec.py`): x264 for a new dataset (GOP 2, CRF 20, one thread,
  SSE4.2 SIMD: the same quality as LeRobot's SVT-AV1 for several times less CPU, and reproducible bytes),
  `--vcodec libsvtav1` for LeRobot's AV1 (what earlier versions wrote); a dataset being continued keeps its
  own codec.
- At the end: exact per-channel point-cloud statistics (`hub.retile_point_cloud_stats`, read back from every
  data file; with local workers, which are idle by then, the channels are split between them:
  `Collector._point_cloud_stats`), the dataset card (README.md), and optionally `push_to_hub` (needs
  `hf auth login`).

Where each job lives: this module has the CLI and the run (`Collector`, `SeedScheduler`); `collect_config.py`
the run's settings (`CollectConfig`); `session.py` the dataset-session API every writer of a dataset uses
(`DatasetSession`: lock, open, stage, commit, finish; `bavo-teleop` too); `staging.py` records and stages one
episode (the worker side), with `episode_payload.py` (its video and statistics); `writer.py` is the writer
side (a commit's writer session, fed episode by episode; LeRobot's writer) and `direct_writer.py` the same
without LeRobot; `collection_record.py` is the record; `transaction.py` snapshots and rolls back a writer
session; `lerobot_private.py` holds every use of LeRobot's private internals; `runtime/pool.py` is the worker
pool `bavo-eval` uses too.
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import functools
import json
import logging
import os
import shlex
import sys
import time
from pathlib import Path

import numpy as np

from lerobot_bavo.datasets import schema as S
from lerobot_bavo.datasets.collect_config import (  # noqa: F401  (offered here too, where they were first)
    STAGING,
    CollectConfig,
    CollectionError,
)
from lerobot_bavo.datasets.episode_payload import codec_video_settings
from lerobot_bavo.datasets.session import DatasetSession
from lerobot_bavo.datasets.staging import receive_shipped, run_job, ship_job, warm_job
from lerobot_bavo.datasets.video_codec import VIDEO_CODECS, quiet_libav
from lerobot_bavo.datasets.writer import StreamingWriter, WriterSession
from lerobot_bavo.experts.perturbation import ExecutionNoise
from lerobot_bavo.features import POINT_FRAMES, ObservationSettings
from lerobot_bavo.runtime.pool import WorkerPool, add_executor_arguments

logger = logging.getLogger("bavo-collect")

# ================================================================== main side
class SeedScheduler:
    """Which seeds to attempt next, and the finished attempts in seed order.

    Attempts finish out of order (several workers); the dataset holds episodes in seed order. So a
    finished attempt waits in `results` until every lower seed is resolved, and no more attempts are in
    flight than could still be needed (finished-and-kept plus in-flight covers what is wanted), except
    to fill a gap below a finished seed.
    """

    def __init__(self, next_seed: int, staged: dict[int, dict], receive=None):
        self.next_seed = next_seed  # the first seed not yet resolved
        self.results: dict[int, dict] = dict(staged)  # finished, not yet resolved
        self.in_flight: dict[cf.Future, int] = {}
        # a job's result -> its summary (Ray: writes the shipped files); None: the result
        self.receive = receive

    def resolved(self):
        """Finished summaries in seed order, each removed as it is handed out (stop whenever you like)."""
        while self.next_seed in self.results:
            summary = self.results.pop(self.next_seed)
            self.next_seed += 1
            yield summary

    def seeds_to_attempt(self, wanted: int, window: int) -> list[int]:
        """Seeds to submit now: at most `window` in flight, and no more than `wanted` kept episodes need."""
        seeds: list[int] = []
        busy = set(self.in_flight.values())
        ahead = sum(1 for r in self.results.values() if r["kept"])
        seed = self.next_seed
        while len(self.in_flight) + len(seeds) < window:
            while seed in self.results or seed in busy:
                seed += 1
            gap = bool(self.results) and seed < max(self.results)  # staged results wait for this seed
            if not gap and ahead + len(self.in_flight) + len(seeds) >= wanted:
                break
            seeds.append(seed)
            seed += 1
        return seeds

    def submit(self, pool: WorkerPool, fn, job: dict) -> None:
        self.in_flight[pool.submit(fn, job)] = job["seed"]

    def wait(self) -> None:
        """Block until at least one attempt in flight finishes; a worker's exception propagates here."""
        if not self.in_flight:
            if self.next_seed in self.results:
                return
            raise CollectionError("internal error: nothing in flight and nothing to resolve")
        done, _ = cf.wait(list(self.in_flight), return_when=cf.FIRST_COMPLETED)
        for fut in done:
            seed = self.in_flight.pop(fut)
            result = fut.result()
            self.results[seed] = result if self.receive is None else self.receive(result)


class Collector(DatasetSession):
    """One `bavo-collect` run on one dataset folder (see the module docstring): the dataset session plus the
    worker pool, the seed scheduler and the streaming writer."""

    def run(self) -> dict:
        lock = self.lock()
        try:
            return self._run()
        finally:
            lock.close()

    def _run(self) -> dict:
        cfg = self.cfg
        t_start = time.perf_counter()
        early_pool = None
        if cfg.executor == "local" and cfg.workers > 0:
            # Start the workers' set-up now, beside this process's own (LeRobot import, dataset open)
            early_pool = self._pool()
            for _ in range(cfg.workers):
                early_pool.submit(warm_job, self._job(seed=-1))
        try:
            return self._run_with(early_pool, t_start)
        finally:
            if early_pool is not None:
                early_pool.shutdown(cancel=True, wait=False)

    def _run_with(self, early_pool, t_start: float) -> dict:
        cfg = self.cfg
        self.open()
        requested = cfg.episodes
        committed = len(self.record.episodes)
        on_ray = cfg.executor == "ray"
        sched = SeedScheduler(
            self.record.next_seed,
            self.scan_staging(self.record.next_seed),
            receive=(lambda shipped: receive_shipped(shipped, self.staging)) if on_ray else None,
        )
        job_fn = ship_job if on_ray else run_job
        run_stats = {
            "started": time.strftime("%Y-%m-%d %H:%M:%S"),
            "requested": requested,
            "committed_before": committed,
            "workers": cfg.workers,
            "executor": cfg.executor,
            "attempts": 0,
            "reused_staged": len(sched.results),
        }
        timings: dict[str, list] = {}
        needed = requested - committed
        discarded = len(self.record.discarded)
        max_discards = int(cfg.max_discard_ratio * requested) + 10
        bar = _progress(total=requested, initial=committed, enabled=cfg.progress)
        bar.set_postfix(discarded=discarded)
        pool = (early_pool or self._pool()) if needed > 0 else None
        window = pool.max_in_flight if on_ray and pool is not None else max(1, 2 * cfg.workers)
        writer = StreamingWriter(self._session_opener(timings, t_start), needed, cfg.commit_every) \
            if needed > 0 else None
        try:
            while writer is not None and writer.written < needed:
                for summary in sched.resolved():  # finished attempts, in seed order
                    writer.put(summary)  # a kept episode is written now; its session commits at its last one
                    if summary["kept"]:
                        bar.update(1)
                    else:
                        discarded += 1
                        self._check_discards(discarded, max_discards, committed + writer.written, bar)
                    if writer.written >= needed:
                        break
                if writer.written >= needed:
                    break
                for seed in sched.seeds_to_attempt(wanted=needed - writer.written, window=window):
                    sched.submit(pool, job_fn, self._job(seed))
                    run_stats["attempts"] += 1
                sched.wait()
            if writer is not None:
                writer.finish()
            point_cloud_stats = self._point_cloud_stats(pool)
        except BaseException:
            if writer is not None:
                writer.abort()  # rolls back a session that has not reached its commit point
            raise
        finally:
            bar.close()
            if pool is not None:
                pool.shutdown(cancel=True, wait=False)
        run_stats["timings"] = timings
        return self.finish(run_stats, time.perf_counter() - t_start, point_cloud_stats)

    def _point_cloud_stats(self, pool) -> dict | None:
        """The dataset's per-channel point-cloud statistics (`hub.point_cloud_channel_stats`, read back from
        every data file at the end of each run), the channels split between the local workers, idle by now:
        the same values as in one process, bit for bit (a channel's statistics depend on its values only),
        and none of that work in this process. None (`finish` computes them here) without local workers."""
        from lerobot_bavo.datasets.hub import merge_channel_stats, point_cloud_stats_job

        if pool is None or self.cfg.executor != "local" or self.cfg.workers < 2:
            return None
        parts = np.array_split(np.arange(S.POINT_CHANNELS), min(self.cfg.workers, S.POINT_CHANNELS))
        futures = [pool.submit(point_cloud_stats_job, {"root": str(self.root), "channels": part.tolist()})
                   for part in parts]
        return merge_channel_stats([f.result() for f in futures])

    def _pool(self):
        """Where episodes run: `WorkerPool` (local processes) or `RayPool` (Ray tasks; at most 2 x the
        cluster's CPUs in flight). Ray is imported only for --executor ray."""
        if self.cfg.executor == "ray":
            from lerobot_bavo.runtime.ray_pool import RayPool

            return RayPool(self.cfg.workers, address=self.cfg.ray_address)
        # expert episodes: no LeRobot / PyTorch in workers
        return WorkerPool(self.cfg.workers, light_import=True)

    def _session_opener(self, timings: dict, t_start: float):
        """What opens each writer session: `DirectWriterSession` (the files LeRobot's writer makes, written
        without importing LeRobot) when the workers encode every episode's mp4 (a dataset with video);
        LeRobot's writer (`WriterSession`) otherwise (a dataset without video)."""
        if self._video is not None:
            from lerobot_bavo.datasets.direct_writer import DirectWriterSession

            return functools.partial(DirectWriterSession, self, timings, t_start)
        from lerobot_bavo.envs.tasks import TASKS

        max_frames = self.cfg.episode_length or TASKS.lookup(self.cfg.task).max_episode_steps
        return functools.partial(WriterSession, self, max_frames, timings, t_start)

    def _job(self, seed: int) -> dict:
        cfg = self.cfg
        return {"task": cfg.task, "condition": cfg.condition, "settings": cfg.settings.to_dict(),
                "episode_length": cfg.episode_length, "keep_failures": cfg.keep_failures, "seed": seed,
                "staging": str(self.staging),
                "video": self._video if seed >= 0 else None,
                "execution_noise": cfg.execution_noise.to_dict() if cfg.execution_noise.enabled else None,
                "events_outside_contacts": cfg.events_outside_contacts, "decoy_panels": cfg.decoy_panels,
                "square_grasps": cfg.square_grasps}

    @functools.cached_property
    def _video(self) -> dict | None:
        """The encoder settings a worker encodes the active camera's mp4 with (`episode_payload`): this run's
        codec as the LeRobot writer uses it (known once the dataset is open); None without video."""
        if not self.cfg.use_videos:
            return None
        return codec_video_settings(self.video_codec, S.FPS)

    def _check_discards(self, total: int, limit: int, kept: int, bar) -> None:
        bar.set_postfix(discarded=total)
        if total > limit:
            raise CollectionError(
                f"{total} unsuccessful expert episodes for {kept} kept: the expert for {self.cfg.task!r} "
                "under "
                f"{self.cfg.condition!r} fails too often; aborting"
            )


def _progress(total: int, initial: int, enabled: bool):
    from tqdm import tqdm

    return tqdm(
        total=total, initial=initial, unit="ep", desc="episodes", disable=not enabled, dynamic_ncols=True
    )


def collect(cfg: CollectConfig) -> dict:
    """Run (or continue) a collection; returns a summary dict."""
    return Collector(cfg).run()


# ================================================================== CLI
def build_parser() -> argparse.ArgumentParser:
    from lerobot_bavo.envs.conditions import CONDITIONS

    p = argparse.ArgumentParser(prog="bavo-collect", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", required=True, help="benchmark task, e.g. cube_handoff")
    p.add_argument("--condition", default="stage", choices=tuple(CONDITIONS),
                   help="visibility condition (the paper trains on stage)")
    p.add_argument("--episodes", type=int, required=True, help="successful episodes wanted")
    p.add_argument("--repo-id", required=True, help="<user>/<name>, e.g. me/bavo_cube_handoff")
    p.add_argument(
        "--root", type=Path, default=None, help="local dataset folder (default $HF_LEROBOT_HOME/<repo-id>)"
    )
    add_executor_arguments(
        p,
        2,
        "worker processes (0: in this process)",
        "where episode rollouts run: local worker processes (default) or Ray tasks, this process "
        "staying the only dataset writer",
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the first attempt")
    p.add_argument("--commit-every", type=int, default=10, help="episodes per dataset write session")
    default = ObservationSettings()  # the observation defaults, in one place
    p.add_argument("--image-height", type=int, default=default.image_height)
    p.add_argument("--image-width", type=int, default=default.image_width)
    p.add_argument("--n-points", type=int, default=default.n_points)
    p.add_argument("--point-frame", default="base", choices=POINT_FRAMES)
    p.add_argument("--self-filter", action="store_true",
                   help="drop the robot's own body (its three arms) from the point cloud before sampling it, "
                        "as real robots do with their model and joint state; recorded with the dataset, and "
                        "bavo-eval gives a policy trained on it the same cloud. Default: off (the paper's "
                        "cloud)")
    p.add_argument(
        "--episode-length", type=int, default=None, help="control-step limit (default: the task's)"
    )
    p.add_argument(
        "--vcodec",
        default=None,
        choices=VIDEO_CODECS,
        help="codec of the active camera's video: h264 (x264, GOP 2, CRF 20, preset faster; the default "
        "for a new dataset: the same quality as AV1 for several times less CPU) or libsvtav1 (LeRobot's "
        "default "
        "AV1: GOP 2, CRF 30, preset 12; what bavo-collect wrote before). Default: h264 for a new "
        "dataset, the dataset's own codec when continuing one",
    )
    p.add_argument("--keep-failures", action="store_true", help="keep unsuccessful episodes (debugging only)")
    p.add_argument(
        "--execution-noise",
        type=float,
        default=0.0,
        metavar="RAD",
        help="DART-style demonstrations: execute the expert's arm joint targets plus a slowly varying "
        "random offset of this standard deviation in radians (AR(1), correlation 0.9 per step; "
        "grippers and camera untouched) while recording its clean targets, so the data show "
        "corrections back to the plan. 0 (default): off. The cube_handoff runs used 0.01",
    )
    p.add_argument("--execution-noise-clean-contacts", action="store_true",
                   help="with --execution-noise: no noise during the expert's approach/grasp/release phases "
                        "(its `contact_phases`)")
    p.add_argument("--events-outside-contacts", action="store_true",
                   help="an occlusion event that falls due while the expert is in one of its approach/grasp/"
                        "release phases (its `contact_phases`) waits until that phase is over, so no "
                        "demonstration has an interrupted grasp or release. A data variant for occluded "
                        "conditions (docs/results/random_time.md); evaluation never holds events. "
                        "Default: off")
    p.add_argument("--decoy-panels", type=int, default=0, metavar="N",
                   help="add N decoy panels: copies of the occluder, re-drawn at every occlusion event "
                        "where they leave the current target visible, so that a panel in the cloud stops "
                        "telling where the target is (the occluder shortcut). A data variant for occluded "
                        "conditions (docs/results/decoy_panels.md); the benchmark never has decoys. "
                        "Default: 0")
    p.add_argument("--square-grasps", action="store_true",
                   help="the scripted expert grasps square to the table's axes (wrist yaw 0) instead of "
                        "turning to the object's faces, and the closing fingers turn the object. A data "
                        "variant (docs/results/learning_rate.md); cube_handoff only. Default: off")
    p.add_argument(
        "--push-to-hub", action="store_true", help="upload when done (needs `hf auth login`)"
    )
    p.add_argument("--private", action="store_true", help="create the Hub repository private")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    return p


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.root is not None and args.root.exists() and not args.root.is_dir():
        parser.error(f"--root {args.root} exists and is not a folder")
    if args.root is not None:
        parent = next((p for p in args.root.absolute().parents if p.exists()), None)
        if parent is not None and not parent.is_dir():
            parser.error(f"--root {args.root}: {parent} is not a folder")
    argv_text = " ".join(shlex.quote(a) for a in (sys.argv[1:] if argv is None else argv))
    # the flags' checks are CollectConfig's (and ObservationSettings'): one place, reported as usage errors
    try:
        cfg = CollectConfig(
            task=args.task,
            condition=args.condition,
            episodes=args.episodes,
            repo_id=args.repo_id,
            root=args.root,
            workers=args.workers,
            executor=args.executor,
            ray_address=args.ray_address,
            seed=args.seed,
            commit_every=args.commit_every,
            settings=ObservationSettings(
                args.image_height, args.image_width, args.n_points, args.point_frame,
                self_filter=args.self_filter,
            ),
            episode_length=args.episode_length,
            keep_failures=args.keep_failures,
            video_codec=args.vcodec,
            execution_noise=ExecutionNoise(
                std=args.execution_noise, clean_contacts=args.execution_noise_clean_contacts
            ),
            events_outside_contacts=args.events_outside_contacts,
            decoy_panels=args.decoy_panels,
            square_grasps=args.square_grasps,
            push_to_hub=args.push_to_hub,
            private=True if args.private else None,
            progress=not args.no_progress,
            command=f"bavo-collect {argv_text}",
        )
    except ValueError as e:
        print(f"bavo-collect: error: {e}", file=sys.stderr)
        return 2
    os.environ.setdefault("SVT_LOG", "1")  # SVT-AV1 (--vcodec libsvtav1): errors only
    quiet_libav()
    from lerobot_bavo.runtime.process import retain_freed_memory

    retain_freed_memory()  # this process reads every staged episode (~110-310 MB each) back: reuse the pages
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    for noisy in ("lerobot", "datasets", "libav", "huggingface_hub"):
        logging.getLogger(noisy).setLevel(logging.WARNING)
    try:
        summary = collect(cfg)
    except (CollectionError, ValueError) as e:
        print(f"bavo-collect: error: {e}", file=sys.stderr)
        return 2
    print(json.dumps(summary, indent=1))
    print(
        f"kept {summary['episodes']} episodes ({summary['frames']} frames), discarded {summary['discarded']} "
        f"unsuccessful attempts; dataset at {summary['root']}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
