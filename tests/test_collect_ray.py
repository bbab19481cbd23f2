"""`bavo-collect --executor ray` (issue 15): a Ray collection writes the same dataset as a local one, a Ray
worker killed mid-episode is retried with nothing lost or duplicated, a killed-and-resumed Ray collection
finishes the same dataset, and bad executor settings are refused.

The episodes are the ones `test_collect_content.py` pins (2 Cube Handoff Stage episodes, seeds 0 and 1, 30
steps, 48 x 64 images, 32 points, images in the parquet files), compared per column with its digest helper,
against both a local collection and the pinned reference digests. The Ray tests share one private local Ray
(`ray.init(num_cpus=2)`, loopback only) and are skipped where Ray (the optional 'ray' extra) is missing. About
60 s on 2 cores.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import pytest
from test_collect_content import (
    REFERENCE_COLUMNS,
    REFERENCE_STATS,
    SETTINGS,
    STEPS,
    dataset_digests,
)
from test_ray_executor import (
    clear_marks,
    marked_starts,
    needs_ray,
    start_killer,
    start_local_ray,
)

from lerobot_bavo.datasets import collect as collect_module
from lerobot_bavo.datasets.collect import CollectConfig, collect
from lerobot_bavo.datasets.staging import ship_job

MARKS_ENV = "BAVO_TEST_COLLECT_MARKS"



def marked_ship_job(job: dict) -> dict:
    """The real Ray collection job, after marking `<seed>.<pid>` in $BAVO_TEST_COLLECT_MARKS and a short pause
    (so a test can kill the worker while the episode is in progress)."""
    (Path(os.environ[MARKS_ENV]) / f"{job['seed']}.{os.getpid()}").touch()
    time.sleep(0.5)
    return ship_job(job)


def _config(root: Path, episodes: int = 2, **kw) -> CollectConfig:
    return CollectConfig(
        task="cube_handoff",
        condition="stage",
        episodes=episodes,
        repo_id="tester/bavo_ray",
        root=root,
        commit_every=1,
        settings=SETTINGS,
        episode_length=STEPS,
        keep_failures=True,
        use_videos=False,
        progress=False,
        **kw,
    )


@pytest.fixture(scope="module")
def local_ray(tmp_path_factory):
    yield from start_local_ray(tmp_path_factory, MARKS_ENV)


@pytest.fixture(scope="module")
def local_dataset(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("local") / "bavo_ray"
    collect(_config(root, workers=0))
    return root


def _episode_seeds(root: Path) -> list[int]:
    import json

    return [e["seed"] for e in json.loads((root / "meta" / "bavo_collection.json").read_text())["episodes"]]


@needs_ray
def test_ray_collection_is_identical_to_local(local_ray, local_dataset, tmp_path):
    root = tmp_path / "bavo_ray"
    summary = collect(_config(root, workers=2, executor="ray"))
    assert summary["episodes"] == 2 and summary["attempts_this_run"] == 2
    columns, stats = dataset_digests(root)
    assert (columns, stats) == dataset_digests(local_dataset)
    assert columns == REFERENCE_COLUMNS and stats == REFERENCE_STATS
    assert _episode_seeds(root) == [0, 1]
    assert not (root / ".bavo_staging").exists()


@pytest.mark.slow  # ~60 s on 2 cores; the local executor's kill tests run by default
@needs_ray
def test_a_killed_ray_worker_loses_and_duplicates_nothing(local_ray, local_dataset, tmp_path, monkeypatch):
    """SIGKILL the Ray worker recording seed 1 mid-episode: Ray runs it again in another worker; the dataset
    has seeds 0 and 1 once each and is identical to the local one."""
    _, marks = local_ray
    clear_marks(marks)
    monkeypatch.setattr(collect_module, "ship_job", marked_ship_job)
    victim = 1
    killer, killed = start_killer(marks, victim)
    root = tmp_path / "bavo_ray"
    summary = collect(_config(root, workers=2, executor="ray"))
    killer.join(timeout=5)
    assert killed, "the victim episode never started"
    started = marked_starts(marks)
    assert len(started[victim]) == 2 and killed[0] in started[victim], started  # killed once, run again
    assert len(started[0]) == 1
    assert summary["episodes"] == 2 and summary["attempts_this_run"] == 2
    assert _episode_seeds(root) == [0, 1]
    assert dataset_digests(root) == dataset_digests(local_dataset)


@pytest.mark.slow
@needs_ray
def test_ray_collection_resumes_a_local_one(local_ray, local_dataset, tmp_path):
    """One episode collected locally, then the same command for two on Ray records only the second."""
    root = tmp_path / "bavo_ray"
    collect(_config(root, workers=0, episodes=1))
    summary = collect(_config(root, workers=2, executor="ray"))
    assert summary["new_this_run"] == 1 and summary["attempts_this_run"] == 1
    assert _episode_seeds(root) == [0, 1]
    assert dataset_digests(root) == dataset_digests(local_dataset)


def test_bad_executor_settings_are_refused(tmp_path, monkeypatch):
    with pytest.raises(ValueError, match="--executor must be one of local, ray, got 'dask'"):
        _config(tmp_path / "a", executor="dask")
    with pytest.raises(ValueError, match="--ray-address needs --executor ray"):
        _config(tmp_path / "a", ray_address="127.0.0.1:6379")
    monkeypatch.setitem(__import__("sys").modules, "ray", None)  # as if Ray were not installed
    with pytest.raises(ValueError, match=r"--executor ray needs Ray, the optional 'ray' extra: pip install "):
        _config(tmp_path / "a", executor="ray")
    assert not (tmp_path / "a").exists()


def test_cli_executor_flags(tmp_path, capsys):
    args = [
        "--task",
        "cube_handoff",
        "--episodes",
        "1",
        "--repo-id",
        "tester/x",
        "--root",
        str(tmp_path / "x"),
    ]
    assert (
        collect_module.build_parser()
        .parse_args(args + ["--executor", "ray", "--ray-address", "auto"])
        .executor
        == "ray"
    )
    assert collect_module.main(args + ["--ray-address", "127.0.0.1:6379"]) == 2
    assert "bavo-collect: error: --ray-address needs --executor ray" in capsys.readouterr().err
    assert collect_module.main(args + ["--executor", "ray", "--workers", "0"]) == 2
    assert "--workers must be >= 1 with --executor ray, got 0" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()
