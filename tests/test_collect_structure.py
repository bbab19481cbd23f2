"""The pieces `bavo-collect` is built from (issue 11): the seed scheduler, the shared worker pool and
per-process cache, the collection record, and the one module that touches LeRobot's private internals."""

from __future__ import annotations

import concurrent.futures as cf
import json
import os
from types import SimpleNamespace

import pytest

from lerobot_bavo.datasets.collect import SeedScheduler
from lerobot_bavo.datasets.collection_record import CollectionRecord, PendingCommit
from lerobot_bavo.datasets.lerobot_private import LeRobotInternalsChanged, check_private_api
from lerobot_bavo.runtime.pool import ProcessCache, WorkerPool


def _summary(seed: int, kept: bool = True) -> dict:
    return {"seed": seed, "kept": kept, "success": kept, "length": 10, "progress": 5 if kept else 2}


def test_scheduler_fills_gaps_first_and_never_attempts_more_than_needed():
    # Seeds 3 (kept) and 5 (discarded) finished before a kill; seed 2 is the first unresolved one.
    sched = SeedScheduler(next_seed=2, staged={3: _summary(3), 5: _summary(5, kept=False)})
    # 2 and 4 sit below a finished seed (gaps: the finished ones wait for them); after that, the kept seed 3
    # plus 2 attempts in flight already cover the 2 wanted episodes, so nothing more.
    assert sched.seeds_to_attempt(wanted=2, window=4) == [2, 4]
    assert sched.seeds_to_attempt(wanted=2, window=1) == [2]  # the window caps what is in flight
    assert list(sched.resolved()) == []  # nothing resolves before seed 2 has finished
    pool = WorkerPool(0)
    for seed in (2, 4):
        sched.submit(pool, lambda job: _summary(job["seed"], kept=job["seed"] != 4), {"seed": seed})
    sched.wait()
    assert sched.in_flight == {}
    assert [s["seed"] for s in sched.resolved()] == [2, 3, 4, 5]  # in seed order, each once
    assert sched.next_seed == 6 and sched.results == {}
    # Nothing staged: attempts go out one after the other up to what is wanted.
    assert SeedScheduler(next_seed=0, staged={}).seeds_to_attempt(wanted=3, window=8) == [0, 1, 2]
    with pytest.raises(RuntimeError, match="nothing in flight"):
        SeedScheduler(next_seed=0, staged={}).wait()


def test_scheduler_stops_handing_out_results_when_the_caller_stops():
    sched = SeedScheduler(next_seed=0, staged={i: _summary(i) for i in range(4)})
    it = sched.resolved()
    assert [next(it)["seed"], next(it)["seed"]] == [0, 1]
    assert sched.next_seed == 2 and sorted(sched.results) == [2, 3]  # the rest stays for the next round


def test_in_process_pool_runs_lazily_and_reports_errors_through_the_future():
    ran = []

    def job(j):
        ran.append(j["i"])
        if j["i"] == 99:
            raise ValueError("bad job")
        return j["i"] * 10

    pool = WorkerPool(0)
    results = pool.imap(job, ({"i": i} for i in range(3)))
    assert ran == []  # nothing runs before a result is asked for (results are logged as they come)
    assert next(results) == 0 and ran == [0]
    assert list(results) == [10, 20]
    fut = pool.submit(job, {"i": 99})
    assert isinstance(fut, cf.Future) and fut.done()
    with pytest.raises(ValueError, match="bad job"):
        fut.result()
    with pytest.raises(ValueError, match="workers"):
        WorkerPool(-1)


def test_light_import_pool_workers_record_without_pytorch(tmp_path, monkeypatch):
    """`bavo-collect`'s spawned workers (`light_import=True`) import neither LeRobot nor PyTorch for an expert
    job; a default pool's workers do (the package registers its LeRobot types), and the switch does not
    outlive the pool in this process's environment."""
    import os
    import sys

    (tmp_path / "light_probe.py").write_text(
        "import sys\n"
        "def probe(job):\n"
        "    import lerobot_bavo.datasets.staging  # what run_job imports\n"
        "    return 'torch' in sys.modules, 'lerobot' in sys.modules\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(tmp_path), *sys.path]))
    monkeypatch.delenv("BAVO_LIGHT_IMPORT", raising=False)
    import light_probe

    with WorkerPool(1, light_import=True) as pool:
        assert pool.submit(light_probe.probe, {}).result(timeout=120) == (False, False)
    assert "BAVO_LIGHT_IMPORT" not in os.environ
    with WorkerPool(1) as pool:
        assert pool.submit(light_probe.probe, {}).result(timeout=120) == (True, True)


def test_process_cache_rebuilds_and_closes_on_a_new_key():
    closed, built = [], []
    cache = ProcessCache(close=closed.append)

    def build(name):
        built.append(name)
        return name

    assert cache.get(("a", 1), lambda: build("A")) == "A"
    assert cache.get(("a", 1), lambda: build("A2")) == "A"  # same key: kept
    assert cache.get(("b", 1), lambda: build("B")) == "B"
    assert built == ["A", "B"] and closed == ["A"]
    cache.clear()
    assert closed == ["A", "B"]


def test_collection_record_round_trips_and_keeps_unknown_keys(tmp_path):
    (tmp_path / "meta").mkdir()
    rec = CollectionRecord(repo_id="u/x", settings={"task": "cube_handoff"}, next_seed=7,
                           pending_commit=PendingCommit([4, 6], 7), extra={"command": "bavo-collect ..."})
    rec.episodes.append({"episode_index": 0, "seed": 0, "length": 12, "recoveries": 1})
    rec.save(tmp_path)
    on_disk = json.loads((tmp_path / "meta" / "bavo_collection.json").read_text())
    assert (
        on_disk["pending_commit"] == {"seeds": [4, 6], "next_seed": 7}
        and on_disk["command"] == "bavo-collect ..."
    )
    assert on_disk["format"] == 1
    back = CollectionRecord.load(tmp_path)
    assert back == rec and back.frames == 12
    assert CollectionRecord.load(tmp_path / "nowhere") is None


def test_lerobot_private_fields_exist_and_a_missing_one_is_named(tmp_path):
    """Fails with the field's name when a LeRobot upgrade renames what lerobot_private.py touches."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    features = {"observation.state": {"dtype": "float32", "shape": (2,), "names": None}}
    ds = LeRobotDataset.create("t/private", 25, features, root=tmp_path / "ds", use_videos=False)
    try:
        check_private_api(ds)  # the installed LeRobot has every private name we use
    finally:
        ds.finalize()
    broken = SimpleNamespace(writer=SimpleNamespace(cancel_pending_videos=None, _finalized=False),
                             meta=SimpleNamespace(_metadata_buffer=[], _pq_writer=None, _finalized=False),
                             _is_finalized=False)
    with pytest.raises(LeRobotInternalsChanged, match=r"DatasetWriter\._pq_writer"):
        check_private_api(broken)


def test_workers_reuse_freed_memory_for_large_arrays():
    """`retain_freed_memory` (pool workers and bavo-collect): a second large array of the same size reuses the
    first one's pages, where glibc would otherwise map and zero new ones (one page fault per 4 KiB page)."""
    import subprocess
    import sys

    probe = (
        "import resource, sys, numpy as np\n"
        "from lerobot_bavo.runtime.process import retain_freed_memory\n"
        "ok = retain_freed_memory() if sys.argv[1] == 'retain' else True\n"
        "faults = []\n"
        "for _ in range(3):\n"
        "    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt\n"
        "    a = np.empty(64 << 20, np.uint8); a.fill(1); del a\n"
        "    faults.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)\n"
        "print(ok, faults[1], faults[2])\n")
    env = {**os.environ, "BAVO_LIGHT_IMPORT": "1"}
    out = {
        mode: subprocess.run(
            [sys.executable, "-c", probe, mode], capture_output=True, text=True, check=True, env=env
        ).stdout.split()
        for mode in ("retain", "default")
    }
    ok, second, third = out["retain"]
    if ok != "True":
        pytest.skip("mallopt not available (not glibc)")
    assert int(second) < 8 and int(third) < 8  # reused: no page of the 64 MiB is faulted in again
    # without it, every allocation of that size maps fresh pages: at least one fault per 2 MiB (huge pages)
    assert int(out["default"][1]) >= 32 and int(out["default"][2]) >= 32
