"""`RayPool`: the `WorkerPool` interface (`imap` over job dicts) on Ray, for `--executor ray`.

Imported only for `--executor ray`: `--executor local` never imports Ray. Ray is an optional extra
(`pip install lerobot_env_bavo[ray]`); without it `RayPool` raises `RayMissingError` naming the extra.

- Every job is one Ray task (one CPU) of `_call(fn, job)`. Ray keeps its worker processes between tasks
  of the same job, so the job module's `ProcessCache` (env, policy) is reused across episodes in a Ray
  worker exactly as in a local pool worker; `fn` must be a module-level function of an importable module
  (or defined in `__main__`, which Ray ships by value).
- `submit(fn, job)` gives a `concurrent.futures.Future` instead (`WorkerPool.submit`'s interface), for
  `bavo-collect`, which waits on its futures itself; `shutdown` cancels those not finished.
- Results come back as they finish, in any order (`imap` callers key them by (task, condition, seed)).
  At most `2 x` the cluster's CPUs are in flight, so a stopped run leaves little work queued, and jobs
  start in about their given order (episodes of one cell together: its env stays cached).
- A worker process lost mid-job (killed, OOM, its node gone) is retried by Ray (`max_retries`); an
  exception raised by `fn` itself is not retried and is re-raised by `imap` as that exception's type.
- `RayPool(workers, address)` connects to the cluster at `address` (`ray start --head` prints it; "auto"
  finds a local one) or, with no address, starts a private local Ray with `workers` CPUs, stopped again
  by `shutdown` (no address given and RAY_ADDRESS set: that cluster). If Ray is already initialised in this
  process (tests, notebooks), it is used as it is. When this pool initialises Ray, every worker gets one BLAS
  / OpenMP thread and headless GL (a local Ray's workers inherit them from the environment Ray starts with, a
  cluster's through the job's `runtime_env`), and a local Ray's workers get this package's source folder on
  PYTHONPATH, so a source checkout runs unchanged; cluster nodes need the package installed (README, "Running
  on a Ray cluster"). A private Ray's workers run at nice 0 like a local pool's (Ray's default is 15:
  `RAY_worker_niceness`; a cluster's is set where it is started, `RAY_worker_niceness=0 ray start ...`). A
  private Ray sends no usage statistics (`RAY_USAGE_STATS_ENABLED=0`; it shortens its start).
"""

from __future__ import annotations

import concurrent.futures as cf
import os
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

from lerobot_bavo.runtime.process import WORKER_ENV_DEFAULTS

MAX_RETRIES = 3
# Ray's config: the nice value of its worker processes (default 15)
WORKER_NICENESS_VAR = "RAY_worker_niceness"
USAGE_STATS_VAR = "RAY_USAGE_STATS_ENABLED"  # Ray's switch for its usage-statistics report (default on)
EXTRA_HINT = "pip install 'lerobot_env_bavo[ray]'"


class RayMissingError(ImportError):
    """`--executor ray` without Ray installed."""


def import_ray():
    try:
        import ray
    except ImportError as e:
        raise RayMissingError(
            f"--executor ray needs Ray, the optional 'ray' extra: {EXTRA_HINT} ({e})"
        ) from None
    return ray


def worker_env_vars() -> dict[str, str]:
    """Environment of every Ray worker this pool starts: one BLAS / OpenMP thread (2-core machines: the
    variables must be set before numpy loads, hence not in the task), headless GL, and this package's source
    folder ahead of the driver's PYTHONPATH; the GL wait and software-rendering thread settings as
    `process.limit_threads` gives local workers. (A Ray worker registers LeRobot's types only when a job
    loads a checkpoint: `import lerobot_bavo` is light.)"""
    source = str(Path(__file__).resolve().parents[2])
    path = [source] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p and p != source]
    return {"OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS", "1"),
            **{name: os.environ.get(name, value) for name, value in WORKER_ENV_DEFAULTS},
            "PYTHONPATH": os.pathsep.join(path)}


_THREADS_LIMITED = False


def _call(fn: Callable[[dict], Any], job: dict) -> Any:
    """The body of every Ray task: `fn(job)` after limiting threads once per worker process."""
    global _THREADS_LIMITED
    if not _THREADS_LIMITED:
        from lerobot_bavo.runtime.process import limit_threads

        limit_threads()
        _THREADS_LIMITED = True
    return fn(job)


class RayPool:
    """Runs jobs as Ray tasks; `with RayPool(workers, address) as pool: for r in pool.imap(fn, jobs): ...`."""

    def __init__(self, workers: int = 1, address: str | None = None, max_retries: int = MAX_RETRIES):
        if workers < 1:
            raise ValueError(f"workers must be >= 1, got {workers}")
        ray = self._ray = import_ray()
        self._owns_ray = not ray.is_initialized()
        if self._owns_ray:
            kwargs: dict[str, Any] = {"include_dashboard": False, "logging_level": "WARNING"}
            address = address or os.environ.get("RAY_ADDRESS") or None
            env = worker_env_vars()
            # a cluster: its nodes have the package installed; threads and GL through the runtime_env
            if address:
                env.pop("PYTHONPATH")
                ray.init(address=address, runtime_env={"env_vars": env}, **kwargs)
            else:  # a private Ray on this machine, `workers` CPUs, loopback only; its workers inherit this
                # process's environment when Ray starts (faster than a runtime_env to the first task, as the
                # prestarted workers are used; docs/results/costs.md)
                saved = dict(os.environ)
                os.environ.update(env)
                # Ray starts its workers at nice 15 by default: beside any other load on a 2-core machine (a
                # training, the collection writer) the episodes then crawl; a local pool's workers run at the
                # caller's priority, so these do too
                os.environ.setdefault(WORKER_NICENESS_VAR, "0")
                # A private, loopback-only Ray reports no usage statistics: the report's set-up was a large
                # part of ray.init on 2 cores (docs/results/costs.md)
                os.environ.setdefault(USAGE_STATS_VAR, "0")
                try:
                    ray.init(num_cpus=workers, _node_ip_address="127.0.0.1", **kwargs)
                finally:
                    os.environ.clear()
                    os.environ.update(saved)
        self._remote = ray.remote(num_cpus=1, max_retries=max_retries)(_call)
        cpus = int(ray.cluster_resources().get("CPU", workers))
        self.max_in_flight = max(2, 2 * cpus)
        self._pending: list = []  # imap's refs in flight
        # submit's (ref, future) pairs not yet seen finished (shutdown cancels them)
        self._submitted: list = []

    def submit(self, fn: Callable[[dict], Any], job: dict) -> cf.Future:
        """A `concurrent.futures.Future` of `fn(job)` run as a Ray task (`WorkerPool.submit`'s interface, for
        `bavo-collect`); a lost worker is retried as in `imap`, an exception of `fn` is the future's
        exception."""
        ref = self._remote.remote(fn, job)
        future = ref.future()
        self._submitted = [(r, f) for r, f in self._submitted if not f.done()] + [(ref, future)]
        return future

    def imap(self, fn: Callable[[dict], Any], jobs: Iterable[dict]) -> Iterator[Any]:
        """Results of `fn` over `jobs` as each finishes (any order); the first failed job's exception is
        raised (the remaining ones are cancelled)."""
        ray = self._ray
        jobs = iter(jobs)
        fn_ref = ray.put(fn)
        exhausted = False
        try:
            while True:
                while not exhausted and len(self._pending) < self.max_in_flight:
                    job = next(jobs, None)
                    if job is None:
                        exhausted = True
                    else:
                        self._pending.append(self._remote.remote(fn_ref, job))
                if not self._pending:
                    return
                ready, self._pending = ray.wait(self._pending, num_returns=1)
                for ref in ready:
                    yield ray.get(ref)
        finally:
            self.cancel()

    imap_unordered = imap  # Ray's results always come in completion order (`WorkerPool`'s name for that)

    def cancel(self) -> None:
        for ref in self._pending:
            self._ray.cancel(ref, force=True)
        self._pending = []

    def shutdown(self, cancel: bool = False, wait: bool = True) -> None:  # noqa: ARG002 (WorkerPool's signature)
        self.cancel()
        for ref, future in self._submitted:
            if not future.done():
                self._ray.cancel(ref, force=True)
        self._submitted = []
        if self._owns_ray and self._ray.is_initialized():
            self._ray.shutdown()

    def __enter__(self) -> RayPool:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.shutdown(cancel=exc_type is not None)
