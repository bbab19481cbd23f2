"""The environment every collection / evaluation worker gets: one thread, headless GL, the GPU driver's
wait policy (sleep, not spin) and one rasteriser thread for Mesa's software renderer, each only where the
user has not chosen one."""

from __future__ import annotations

import os
import sys

import pytest

from lerobot_bavo.runtime import process
from lerobot_bavo.runtime.ray_pool import worker_env_vars


@pytest.fixture
def clean_env(monkeypatch):
    for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MUJOCO_GL", "__GL_YIELD", "LP_NUM_THREADS"):
        monkeypatch.delenv(name, raising=False)
    torch = sys.modules.get("torch")  # limit_threads sets a loaded torch to one thread: give it back
    threads = torch.get_num_threads() if torch is not None else None
    yield monkeypatch
    if torch is not None:
        torch.set_num_threads(threads)


def test_local_workers_sleep_while_waiting_for_the_gpu_unless_told_otherwise(clean_env):
    process.limit_threads()
    assert os.environ["__GL_YIELD"] == "USLEEP"
    assert os.environ["OMP_NUM_THREADS"] == "1" and os.environ["MUJOCO_GL"] == "egl"
    clean_env.setenv("__GL_YIELD", "NOTHING")
    process.limit_threads()
    assert os.environ["__GL_YIELD"] == "NOTHING"


def test_ray_workers_get_the_same_wait_policy(clean_env):
    assert worker_env_vars()["__GL_YIELD"] == "USLEEP"
    clean_env.setenv("__GL_YIELD", "NOTHING")
    assert worker_env_vars()["__GL_YIELD"] == "NOTHING"


def test_software_rendering_keeps_one_rasteriser_thread_per_worker_unless_told_otherwise(clean_env):
    process.limit_threads()
    assert os.environ["LP_NUM_THREADS"] == "1"
    assert worker_env_vars()["LP_NUM_THREADS"] == "1"
    clean_env.setenv("LP_NUM_THREADS", "4")
    process.limit_threads()
    assert os.environ["LP_NUM_THREADS"] == "4" and worker_env_vars()["LP_NUM_THREADS"] == "4"
