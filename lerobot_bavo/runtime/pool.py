"""The worker pool shared by `bavo-collect` and `bavo-eval`, and the per-process cache its jobs use.

Why one pattern: both commands run independent seeded episodes (a job is a small dict, its result a
small dict) in spawned worker processes that each hold an expensive, reusable set-up (a MuJoCo env with
its GL contexts, an expert recorder, a policy). Both need the same things: `init_worker` in every worker
(one BLAS/torch thread, exit with the parent), an in-process mode for tests and debugging, and a way
to keep the set-up between jobs without rebuilding it per episode.

- `WorkerPool(workers)`: `workers == 0` runs every job in the calling process (`submit` runs it at
  once; `imap` / `imap_unordered` run one job per item consumed, so results can be written as they come);
  with workers, `imap` gives results in job order and `imap_unordered` as jobs finish (`bavo-eval`: no
  record waits for a slower episode submitted before it); `workers >= 1`
  uses a `ProcessPoolExecutor` of that many processes, started with `start_method` ("spawn" by
  default: a fresh interpreter, no GL context or torch thread pool inherited from the parent; `None`
  is the platform's default, "fork" on Linux, which `bavo-eval` keeps so that a job function replaced
  in a `python -c` script reaches its workers). Each worker registers LeRobot's "bavo" / "maniflow" /
  "afar" types in its initializer (`lerobot_bavo.register_lerobot_types`) unless `light_import=True`:
  then it imports neither LeRobot nor PyTorch (seconds of CPU per worker) for jobs that never touch a
  policy, such as `bavo-collect`'s expert episodes.
- `ProcessCache`: one keyed slot per process. A job asks for the set-up of its key; a different key
  closes the old set-up and builds the new one. It is a module-level object in the job's module because
  that is the only state a pool worker keeps between jobs; it is never shared across processes.
"""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing
import os
from collections.abc import Callable, Iterable, Iterator
from typing import Any


class WorkerPool:
    """Runs jobs in `workers` spawned processes, or in this process when `workers == 0`."""

    def __init__(self, workers: int, start_method: str | None = "spawn", light_import: bool = False):
        if workers < 0:
            raise ValueError(f"workers must be >= 0, got {workers}")
        self.workers = workers
        self._executor: cf.ProcessPoolExecutor | None = None
        if workers == 0:
            from lerobot_bavo.runtime.process import limit_threads

            limit_threads()  # no exit-with-parent watch in the main process (see process.init_worker)
        else:
            from lerobot_bavo.runtime.process import init_worker

            os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
            os.environ.setdefault("OMP_NUM_THREADS", "1")
            self._executor = cf.ProcessPoolExecutor(
                max_workers=workers, mp_context=multiprocessing.get_context(start_method),
                initializer=init_worker, initargs=(os.getpid(), not light_import))

    def submit(self, fn: Callable[[dict], Any], job: dict) -> cf.Future:
        """A future of `fn(job)`; in-process, `fn` runs now and the future is already done."""
        if self._executor is not None:
            return self._executor.submit(fn, job)
        fut: cf.Future = cf.Future()
        try:
            fut.set_result(fn(job))
        except Exception as e:  # noqa: BLE001 (re-raised by fut.result(); KeyboardInterrupt propagates now)
            fut.set_exception(e)
        return fut

    def imap(self, fn: Callable[[dict], Any], jobs: Iterable[dict]) -> Iterator[Any]:
        """Results of `fn` over `jobs`, in order, each as soon as it (and those before it) finished."""
        if self._executor is not None:
            return self._executor.map(fn, jobs)
        return (fn(job) for job in jobs)

    def imap_unordered(self, fn: Callable[[dict], Any], jobs: Iterable[dict]) -> Iterator[Any]:
        """Results of `fn` over `jobs` as each finishes (any order; callers key them, e.g. by seed). Every job
        is queued at once, so a worker never waits on this process for its next one, and a result is handed
        over as soon as it exists, not after those queued before it; the first failed job's exception is
        raised and the jobs not started are cancelled. In-process: one job per result asked for."""
        if self._executor is None:
            yield from (fn(job) for job in jobs)
            return
        futures = [self._executor.submit(fn, job) for job in jobs]
        try:
            for fut in cf.as_completed(futures):
                yield fut.result()
        finally:
            for fut in futures:
                fut.cancel()

    def shutdown(self, cancel: bool = False, wait: bool = True) -> None:
        """Stop the workers; `cancel` drops queued jobs (after an error: don't run them first)."""
        if self._executor is not None:
            self._executor.shutdown(wait=wait, cancel_futures=cancel)

    def __enter__(self) -> WorkerPool:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.shutdown(cancel=exc_type is not None)


class ProcessCache:
    """One keyed set-up per process (an env, a recorder, an agent), rebuilt when the key changes."""

    def __init__(self, close: Callable[[Any], None]):
        self._close = close
        self._key: Any = None
        self._value: Any = None

    def get(self, key, build: Callable[[], Any]):
        """The set-up for `key`: the cached one, or `build()` after closing the previous one."""
        if self._value is None or self._key != key:
            self.clear()
            self._value = build()
            self._key = key
        return self._value

    def clear(self) -> None:
        if self._value is not None:
            self._close(self._value)
        self._key, self._value = None, None


EXECUTORS = ("local", "ray")  # where `bavo-eval` / `bavo-collect` run their episodes


def add_executor_arguments(parser, workers_default: int, workers_help: str, executor_help: str) -> None:
    """The `--workers`, `--executor` and `--ray-address` flags both CLIs share (same meaning, same checks)."""
    parser.add_argument(
        "--workers",
        type=int,
        default=workers_default,
        help=f"{workers_help}; with --executor ray and no --ray-address, the CPUs of the private local Ray. "
        "Many workers sharing one GPU's EGL renderer stop scaling at ~4x; software rendering per worker "
        "(docs/collect.md, 'Many cores') keeps scaling",
    )
    parser.add_argument("--executor", choices=EXECUTORS, default="local",
                        help=f"{executor_help} (needs the 'ray' extra: pip install 'lerobot_env_bavo[ray]')")
    parser.add_argument(
        "--ray-address",
        default=None,
        metavar="ADDR",
        help="with --executor ray: the Ray cluster to use (e.g. HEAD_IP:6379, or 'auto'); default: "
        "start a private local Ray with --workers CPUs",
    )


def executor_problem(executor: str, ray_address: str | None, workers: int) -> str | None:
    """What is wrong with an executor choice, as a message for the user, or None when it can run.

    One check for both CLIs (each raises it as its own error type): a known executor, `--ray-address` only
    with Ray, at least one worker on Ray, and Ray importable (else the message names the extra to install).
    Ray is imported only when it was asked for."""
    if executor not in EXECUTORS:
        return f"--executor must be one of {', '.join(EXECUTORS)}, got {executor!r}"
    if ray_address and executor != "ray":
        return "--ray-address needs --executor ray"
    if executor == "ray":
        if workers < 1:
            return f"--workers must be >= 1 with --executor ray, got {workers}"
        from lerobot_bavo.runtime.ray_pool import RayMissingError, import_ray

        try:
            import_ray()
        except RayMissingError as e:
            return str(e)
    return None
