"""Hostile inputs and faults (issue 16): untrusted and mismatched checkpoints, torn logs, orphaned workers,
lock bypass, and small argument / file errors. Each test reproduces the fault and checks the fix."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

N_POINTS = 32


# ----------------------------------------------------------------------------- a small real checkpoint
def _save_checkpoint(path: Path, n_points: int = N_POINTS) -> Path:
    """A tiny ManiFlow checkpoint written the way lerobot-train writes one (config, weights, processors)."""
    from lerobot.policies.factory import make_policy, make_policy_config, make_pre_post_processors

    import lerobot_bavo.policies  # noqa: F401

    features = {
        "observation.point_cloud": {"dtype": "float32", "shape": (n_points * 6,), "names": None},
        "observation.state": {"dtype": "float32", "shape": (21,), "names": None},
        "action": {"dtype": "float32", "shape": (21,), "names": None},
    }
    stats = {k: {"min": np.full(f["shape"], -1.0, np.float32), "max": np.full(f["shape"], 1.0, np.float32)}
             for k, f in features.items()}
    cfg = make_policy_config("maniflow", preset="cpu_fast", device="cpu", points_per_step=0, dit_hidden_dim=32,
                             dit_num_layers=1, dit_num_heads=2, point_encoder_hidden_dims=(16,), point_feature_dim=16,
                             state_feature_dim=8, time_embed_hidden_dim=16, time_freq_dim=16)
    policy = make_policy(cfg, ds_meta=SimpleNamespace(features=features, stats=stats))
    pre, post = make_pre_post_processors(cfg, dataset_stats=stats)
    policy.save_pretrained(path)
    pre.save_pretrained(path)
    post.save_pretrained(path)
    return path


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory) -> Path:
    return _save_checkpoint(tmp_path_factory.mktemp("ckpt") / "pretrained_model")


def _copy(src: Path, dst: Path) -> Path:
    import shutil

    shutil.copytree(src, dst)
    return dst


def _cli(name: str) -> list[str]:
    exe = Path(sys.executable).with_name(name)
    return [str(exe)]


def _env() -> dict:
    return dict(os.environ, HF_HUB_OFFLINE="1", OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1",
                MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"))


# ----------------------------------------------------------------------------- 1. untrusted checkpoint
def test_a_checkpoint_with_a_popen_step_is_refused_before_it_runs(checkpoint, tmp_path):
    """The exact attack: a preprocessor step {"class": "subprocess.Popen", "config": {"args": [...]}}."""
    from lerobot_bavo.checkpoints import UntrustedCheckpointError, check_processor_steps
    from lerobot_bavo.envs.bavo_env import BavoEnv
    from lerobot_bavo.eval.rollout import LeRobotPolicyAgent

    evil = _copy(checkpoint, tmp_path / "evil")
    marker = tmp_path / "pwned"
    pre = json.loads((evil / "policy_preprocessor.json").read_text())
    pre["steps"].insert(0, {"class": "subprocess.Popen", "config": {"args": ["touch", str(marker)]}})
    (evil / "policy_preprocessor.json").write_text(json.dumps(pre))

    proc = subprocess.run(_cli("bavo-eval") + ["--policy", str(evil), "--tasks", "cube_handoff", "--conditions",
                                               "clean", "--episodes", "1", "--output-dir", str(tmp_path / "out")],
                          capture_output=True, text=True, timeout=300, env=_env())
    assert proc.returncode != 0
    assert "subprocess.Popen" in proc.stderr and "--trust-remote-code" in proc.stderr
    env = BavoEnv("cube_handoff", "clean", image_height=32, image_width=32, n_points=N_POINTS, render_mode=None)
    try:
        with pytest.raises(UntrustedCheckpointError, match="subprocess.Popen"):
            LeRobotPolicyAgent(evil, env)
    finally:
        env.close()
    time.sleep(0.5)
    assert not marker.exists(), "the checkpoint's command ran"
    check_processor_steps(evil, trust_remote_code=True)  # the explicit opt-in lets it through
    check_processor_steps(checkpoint)  # LeRobot's and our own steps are trusted

    # other spellings of the same attack
    for step in ({"registry_name": "not_a_registered_step"}, {"class": "os.system"},
                 {"class": "lerobot_bavo.checkpoints.checkpoint_digest"}, {"config": {}}):
        pre_bad = json.loads((checkpoint / "policy_preprocessor.json").read_text())
        pre_bad["steps"].append(step)
        (evil / "policy_preprocessor.json").write_text(json.dumps(pre_bad))
        with pytest.raises(UntrustedCheckpointError, match="step"):
            check_processor_steps(evil)


# ----------------------------------------------------------------------------- 2. mismatched / partial checkpoints
def test_mismatched_and_partial_checkpoints_are_refused_with_the_reason(checkpoint, tmp_path):
    from safetensors.torch import load_file, save_file

    from lerobot_bavo.checkpoints import CheckpointMismatchError, checkpoint_digest, env_settings
    from lerobot_bavo.envs.bavo_env import BavoEnv
    from lerobot_bavo.eval.rollout import LeRobotPolicyAgent, env_kwargs_for_policy

    # bavo-eval builds its env from what the checkpoint records
    assert env_settings(checkpoint) == {"n_points": N_POINTS, "environment_state": False}
    assert env_kwargs_for_policy(str(checkpoint)) == {"n_points": N_POINTS, "environment_state": False}
    wrong = BavoEnv("cube_handoff", "clean", image_height=32, image_width=32, n_points=64, render_mode=None)
    try:
        with pytest.raises(CheckpointMismatchError, match="n_points: checkpoint 32, env 64"):
            LeRobotPolicyAgent(checkpoint, wrong)
    finally:
        wrong.close()

    # a ManiFlow fed another point count (e.g. by lerobot-eval --env.n_points) names the feature
    from lerobot.policies.factory import make_pre_post_processors
    from lerobot.configs.policies import PreTrainedConfig

    cfg = PreTrainedConfig.from_pretrained(checkpoint)
    pre, _ = make_pre_post_processors(cfg, pretrained_path=str(checkpoint))
    with pytest.raises(ValueError, match="observation.point_cloud.*trained on"):
        pre({"observation.point_cloud": torch.zeros(1, 64, 6), "observation.state": torch.zeros(1, 21)})

    # a tensor missing from model.safetensors: an error, not a silent SR 0
    partial = _copy(checkpoint, tmp_path / "partial")
    weights = load_file(str(partial / "model.safetensors"))
    dropped = sorted(weights)[0]
    del weights[dropped]
    save_file(weights, str(partial / "model.safetensors"))
    env = BavoEnv("cube_handoff", "clean", image_height=32, image_width=32, n_points=N_POINTS, render_mode=None)
    try:
        with pytest.raises(CheckpointMismatchError, match="1 missing tensor"):
            LeRobotPolicyAgent(partial, env)
        agent = LeRobotPolicyAgent(checkpoint, env)  # the complete one loads and acts
        obs, info = env.reset(seed=0)
        assert np.isfinite(agent.act(obs, info)).all()
    finally:
        env.close()

    # resume is keyed on the files' digest: a replaced checkpoint at the same path is refused
    from lerobot_bavo.eval.cli import evaluate

    assert checkpoint_digest(partial) != checkpoint_digest(checkpoint)
    same_path = _copy(checkpoint, tmp_path / "same_path")
    out = tmp_path / "eval"
    out.mkdir()
    (out / "run.json").write_text(json.dumps({"seed": 1000, "policy": str(same_path.resolve()),
                                              "checkpoint_sha256": checkpoint_digest(partial)}))
    with pytest.raises(SystemExit, match="different settings"):
        evaluate(str(same_path), ["cube_handoff"], ["clean"], 1, 1000, out)


# ----------------------------------------------------------------------------- 3. torn episodes.jsonl
def test_a_torn_last_log_line_is_dropped_and_a_corrupt_middle_line_is_named(tmp_path, capsys):
    from lerobot_bavo.eval.cli import read_episode_log

    log = tmp_path / "episodes.jsonl"
    records = [{"task": "cube_handoff", "condition": "clean", "seed": s, "success": True} for s in (0, 1)]

    class FullDisk:
        """A file whose device fills after `room` bytes: the write stops mid-line, as with ENOSPC."""

        def __init__(self, path: Path, room: int):
            self.fh, self.room = open(path, "w"), room

        def write(self, text: str) -> None:
            if len(text) > self.room:
                self.fh.write(text[: self.room])
                self.fh.close()
                raise OSError(28, "No space left on device")
            self.room -= len(text)
            self.fh.write(text)

    first = json.dumps(records[0]) + "\n"
    disk = FullDisk(log, room=len(first) + 10)
    disk.write(first)
    with pytest.raises(OSError, match="No space"):
        disk.write(json.dumps(records[1]) + "\n")
    assert not log.read_text().endswith("\n")
    done = read_episode_log(log)
    assert list(done) == [("cube_handoff", "clean", 0)]
    assert "incomplete last line" in capsys.readouterr().err
    assert log.read_text() == first  # truncated to the last complete record; appends continue cleanly

    log.write_text(first + "{not json\n" + json.dumps(records[1]) + "\n")
    with pytest.raises(SystemExit, match=r"episodes.jsonl line 2 is corrupt"):
        read_episode_log(log)


# ----------------------------------------------------------------------------- 5. locks
def test_locks_hold_across_symlinked_spellings_and_for_bavo_eval(tmp_path):
    from lerobot_bavo.datasets.collect import CollectConfig, CollectionError, Collector
    from lerobot_bavo.datasets import schema as S
    from lerobot_bavo.eval.cli import evaluate
    from lerobot_bavo.runtime.process import LockedError, exclusive_lock

    real = tmp_path / "datasets" / "bavo_x"
    real.mkdir(parents=True)
    link = tmp_path / "link_to_x"
    link.symlink_to(real)
    cfg = dict(task="cube_handoff", condition="stage", episodes=1, repo_id="t/x", workers=0,
               settings=S.DatasetSettings(32, 32, n_points=8), progress=False)
    held = Collector(CollectConfig(root=real, **cfg))._lock()
    try:
        with pytest.raises(CollectionError, match="another bavo-collect is writing"):
            Collector(CollectConfig(root=link, **cfg))._lock()
    finally:
        held.close()
    Collector(CollectConfig(root=link, **cfg))._lock().close()  # free again once released

    out = tmp_path / "eval"
    held = exclusive_lock(out, "bavo-eval")
    try:
        with pytest.raises(SystemExit, match="another bavo-eval is writing"):
            evaluate("expert", ["cube_handoff"], ["clean"], 1, 0, out)
        with pytest.raises(LockedError):
            exclusive_lock(tmp_path / "." / "eval", "bavo-eval")
    finally:
        held.close()


# ----------------------------------------------------------------------------- 6. small items
def test_bad_arguments_and_files_give_clear_errors(tmp_path, capsys):
    from lerobot_bavo.datasets.collect import main as collect_main
    from lerobot_bavo.eval.cli import main as eval_main

    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    base = ["--policy", "expert", "--tasks", "cube_handoff", "--conditions", "clean"]
    for extra, message in ((["--seed", "-5"], "--seed must be >= 0"), (["--workers", "-3"], "--workers must be >= 1"),
                           (["--videos", "-1"], "--videos must be >= 0")):
        with pytest.raises(SystemExit):
            eval_main(base + ["--output-dir", str(tmp_path / "o")] + extra)
        assert message in capsys.readouterr().err
    with pytest.raises(SystemExit, match="is not a folder"):
        eval_main(base + ["--output-dir", str(a_file)])
    for extra, message in ((["--root", str(a_file)], "is not a folder"), (["--seed", "-5"], "--seed must be >= 0"),
                           (["--workers", "-3"], "--workers must be >= 0")):
        with pytest.raises(SystemExit):
            collect_main(["--task", "cube_handoff", "--episodes", "1", "--repo-id", "t/x"] + extra)
        assert message in capsys.readouterr().err


def test_env_stops_after_the_episode_ends_and_renders_nothing_without_a_render_mode():
    from lerobot_bavo.envs.bavo_env import BavoEnv
    from lerobot_bavo.sim import constants as C

    env = BavoEnv("cube_handoff", "clean", image_height=32, image_width=32, n_points=8, render_mode=None,
                  episode_length=2)
    try:
        env.reset(seed=0)
        assert env.render() is None
        home = np.asarray(C.HOME_ACTION)
        env.step(home)
        _, _, terminated, truncated, _ = env.step(home)
        assert truncated and not terminated
        with pytest.raises(RuntimeError, match="call reset"):
            env.step(home)
        env.reset(seed=0)
        env.step(home)  # a reset starts a new episode
    finally:
        env.close()


def test_bad_dataset_metadata_and_nan_are_named(tmp_path):
    from lerobot_bavo.datasets.hub import read_info, read_sidecar, read_stats
    from lerobot_bavo.policies.maniflow.processor_maniflow import make_maniflow_pre_post_processors
    from lerobot_bavo.policies import ManiFlowConfig
    from lerobot.configs import FeatureType, PolicyFeature

    meta = tmp_path / "meta"
    meta.mkdir()
    (meta / "stats.json").write_text("{not json")
    with pytest.raises(ValueError, match=r"stats.json: not valid JSON"):
        read_stats(tmp_path)
    (meta / "stats.json").write_text(json.dumps({"observation.state": {"min": [float("nan"), 0.0], "max": [1.0, 1.0]}}))
    with pytest.raises(ValueError, match=r"NaN in \['observation.state.min'\]"):
        read_stats(tmp_path)
    (meta / "info.json").write_text(json.dumps({"codebase_version": "v3.0", "features": None}))
    with pytest.raises(ValueError, match=r"info.json: no 'features' object"):
        read_info(tmp_path)
    (tmp_path / "bavo_collect.json").write_text(json.dumps({"episodes": []}))
    from lerobot_bavo.datasets.hub import SIDECAR

    (tmp_path / SIDECAR).write_text(json.dumps({"episodes": []}))
    with pytest.raises(ValueError, match=f"{SIDECAR}: no 'settings' object"):
        read_sidecar(tmp_path)

    cfg = ManiFlowConfig(preset="cpu_fast", device="cpu", points_per_step=0, input_features={
        "observation.point_cloud": PolicyFeature(FeatureType.STATE, (8 * 6,)),
        "observation.state": PolicyFeature(FeatureType.STATE, (21,))},
        output_features={"action": PolicyFeature(FeatureType.ACTION, (21,))})
    stats = {"observation.state": {"min": torch.full((21,), float("nan")), "max": torch.ones(21)},
             "action": {"min": -torch.ones(21), "max": torch.ones(21)}}
    with pytest.raises(ValueError, match="NaN in \\['observation.state.min'\\]"):
        make_maniflow_pre_post_processors(cfg, stats)


def test_afar_refuses_nan_teacher_features():
    from lerobot.configs import FeatureType, PolicyFeature

    from lerobot_bavo.policies import AfarConfig, AfarPolicy

    cfg = AfarConfig(preset="cpu_fast", device="cpu", points_per_step=0, dit_hidden_dim=32, dit_num_layers=1,
                     dit_num_heads=2, input_features={
                         "observation.point_cloud": PolicyFeature(FeatureType.STATE, (8, 6)),
                         "observation.state": PolicyFeature(FeatureType.STATE, (21,))},
                     output_features={"action": PolicyFeature(FeatureType.ACTION, (21,))})
    policy = AfarPolicy(cfg)
    policy.train()
    batch = {"observation.point_cloud": torch.rand(2, 2, 8, 6), "observation.state": torch.rand(2, 2, 21),
             "action": torch.rand(2, 16, 21), "observation.teacher.z0": torch.full((2, 2, 8, 3), float("nan")),
             "observation.teacher.zf": torch.zeros(2, 2, 8, 3)}
    with pytest.raises(ValueError, match="teacher.z0' holds NaN"):
        policy.forward(batch)


# ----------------------------------------------------------------------------- 4. kill -9 leaves no orphans
def _children(pid: int) -> set[int]:
    out = subprocess.run(["ps", "-o", "pid=", "--ppid", str(pid)], capture_output=True, text=True).stdout
    return {int(p) for p in out.split()}


def _is_worker(pid: int) -> bool:
    try:
        return "spawn_main" in Path(f"/proc/{pid}/cmdline").read_text() or "fork" in Path(f"/proc/{pid}/cmdline").read_text()
    except OSError:
        return False


def _watching(pid: int) -> bool:
    from lerobot_bavo.runtime.process import WATCH_THREAD_NAME

    try:
        return any((t / "comm").read_text().strip() == WATCH_THREAD_NAME for t in Path(f"/proc/{pid}/task").iterdir())
    except OSError:
        return False


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    stat = Path(f"/proc/{pid}/stat")
    return stat.exists() and stat.read_text().split()[2] != "Z"


@pytest.mark.slow
@pytest.mark.parametrize("tool", ["bavo-collect", "bavo-eval"])
def test_kill_9_leaves_no_worker_behind(tool, tmp_path):
    args = {
        "bavo-collect": ["--task", "cube_handoff", "--episodes", "4", "--repo-id", "t/kill", "--root",
                         str(tmp_path / "ds"), "--workers", "2", "--no-progress"],
        "bavo-eval": ["--policy", "expert", "--tasks", "cube_handoff", "--conditions", "stage", "--episodes", "4",
                      "--workers", "2", "--videos", "0", "--output-dir", str(tmp_path / "eval")],
    }[tool]
    proc = subprocess.Popen(_cli(tool) + args, env=_env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.time() + 120
        workers: set[int] = set()
        while time.time() < deadline and len(workers) < 2:  # pool workers (+ the resource tracker) are up
            time.sleep(1.0)
            workers = _children(proc.pid)
        assert len(workers) >= 2, f"{tool} started no workers"
        # A spawned worker imports for a while before its initializer (which starts the watch) runs; wait until
        # every worker runs its watch thread (named bavo-watch), i.e. it is set up and working on episodes.
        deadline = time.time() + 240
        while time.time() < deadline and sum(_watching(p) for p in _children(proc.pid) if _is_worker(p)) < 2:
            time.sleep(1.0)
        time.sleep(2.0)
        workers = _children(proc.pid)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        deadline = time.time() + 5.0
        while time.time() < deadline and any(_alive(p) for p in workers):
            time.sleep(0.2)
        survivors = [p for p in workers if _alive(p)]
        assert not survivors, f"{tool}: children {survivors} outlived their parent by more than 5 s"
    finally:
        if proc.poll() is None:
            proc.kill()
        for p in _children(proc.pid):
            os.kill(p, signal.SIGKILL)
