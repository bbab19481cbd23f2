"""Hostile inputs and faults (issue 16): untrusted and mismatched checkpoints, torn logs, orphaned workers,
lock bypass, and small argument / file errors. Each test reproduces the fault and checks the fix."""

from __future__ import annotations

import contextlib
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
    cfg = make_policy_config(
        "maniflow",
        preset="cpu_fast",
        device="cpu",
        points_per_step=0,
        dit_hidden_dim=32,
        dit_num_layers=1,
        dit_num_heads=2,
        point_encoder_hidden_dims=(16,),
        point_feature_dim=16,
        state_feature_dim=8,
        time_embed_hidden_dim=16,
        time_freq_dim=16,
    )
    policy = make_policy(cfg, ds_meta=SimpleNamespace(features=features, stats=stats))
    pre, post = make_pre_post_processors(cfg, dataset_stats=stats)
    policy.save_pretrained(path)
    pre.save_pretrained(path)
    post.save_pretrained(path)
    return path


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory) -> Path:
    return _save_checkpoint(tmp_path_factory.mktemp("ckpt") / "pretrained_model")


def _small_env(**overrides):
    """A Cube Handoff env with small observations (32 x 32 images, N_POINTS points, no rendering), closed on
    exit: `with _small_env() as env: ...`."""
    from lerobot_bavo.envs.bavo_env import BavoEnv

    kwargs = dict(image_height=32, image_width=32, n_points=N_POINTS, render_mode=None)
    kwargs.update(overrides)
    return contextlib.closing(BavoEnv("cube_handoff", "clean", **kwargs))


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
    from lerobot_bavo.eval.rollout import LeRobotPolicyAgent

    evil = _copy(checkpoint, tmp_path / "evil")
    marker = tmp_path / "pwned"
    pre = json.loads((evil / "policy_preprocessor.json").read_text())
    pre["steps"].insert(0, {"class": "subprocess.Popen", "config": {"args": ["touch", str(marker)]}})
    (evil / "policy_preprocessor.json").write_text(json.dumps(pre))

    proc = subprocess.run(
        _cli("bavo-eval")
        + [
            "--policy",
            str(evil),
            "--tasks",
            "cube_handoff",
            "--conditions",
            "clean",
            "--episodes",
            "1",
            "--output-dir",
            str(tmp_path / "out"),
        ],
        capture_output=True,
        text=True,
        timeout=300,
        env=_env(),
    )
    assert proc.returncode != 0
    assert "subprocess.Popen" in proc.stderr and "--trust-remote-code" in proc.stderr
    with _small_env() as env, pytest.raises(UntrustedCheckpointError, match="subprocess.Popen"):
        LeRobotPolicyAgent(evil, env)
    time.sleep(0.5)
    assert not marker.exists(), "the checkpoint's command ran"
    check_processor_steps(evil, trust_remote_code=True)  # the explicit opt-in lets it through
    check_processor_steps(checkpoint)  # LeRobot's and our own steps are trusted

    # other spellings of the same attack: unknown names, non-step classes, a registered step told to run Hub
    # code (LeRobot's action tokenizer defaults to trust_remote_code=True), a state file outside the folder
    for step in (
        {"registry_name": "not_a_registered_step"},
        {"class": "os.system"},
        {"class": "lerobot_bavo.checkpoints.checkpoint_digest"},
        {"config": {}},
        {"registry_name": "action_tokenizer_processor", "config": {"action_tokenizer_name": "evil/tok"}},
        {
            "registry_name": "tokenizer_processor",
            "config": {"tokenizer_name": "x", "trust_remote_code": True},
        },
        {"registry_name": "reward_classifier_processor", "config": {"pretrained_path": "evil/classifier"}},
        {"registry_name": "normalizer_processor", "state_file": "../../elsewhere.safetensors"},
    ):
        pre_bad = json.loads((checkpoint / "policy_preprocessor.json").read_text())
        pre_bad["steps"].append(step)
        (evil / "policy_preprocessor.json").write_text(json.dumps(pre_bad))
        with pytest.raises(UntrustedCheckpointError, match="step"):
            check_processor_steps(evil)

    # policy types: unregistered, registered but loading Hub code when built, a PEFT adapter
    (evil / "policy_preprocessor.json").write_text((checkpoint / "policy_preprocessor.json").read_text())
    base_cfg = json.loads((checkpoint / "config.json").read_text())
    for change, message in (
        ({"type": "no_such_policy"}, "not a registered"),
        ({"type": "pi0_fast"}, "'pi0_fast' is not audited"),
        ({"use_peft": True}, "use_peft"),
    ):
        (evil / "config.json").write_text(json.dumps({**base_cfg, **change}))
        with pytest.raises(UntrustedCheckpointError, match=message):
            check_processor_steps(evil)
        check_processor_steps(evil, trust_remote_code=True)


def test_the_reward_models_hub_processor_steps_are_refused_once_registered(checkpoint, tmp_path):
    """LeRobot's reward models register two steps that load a Hub processor with trust_remote_code=True
    (`robometer_encoder`, `topreward_encoder`), but only once `lerobot.rewards` is imported: with them
    registered, a checkpoint naming either is refused for what it loads, not as an unknown step."""
    import lerobot.rewards  # noqa: F401  (registers the two steps)
    from lerobot.processor import ProcessorStepRegistry

    from lerobot_bavo.checkpoints import UntrustedCheckpointError, check_processor_steps

    evil = _copy(checkpoint, tmp_path / "evil")
    pre = json.loads((checkpoint / "policy_preprocessor.json").read_text())
    for name, config in (("robometer_encoder", {"pretrained_path": "evil/model"}),
                         ("topreward_encoder", {"vlm_name": "evil/vlm"})):
        assert name in ProcessorStepRegistry.list()
        bad = dict(pre, steps=[*pre["steps"], {"registry_name": name, "config": config}])
        (evil / "policy_preprocessor.json").write_text(json.dumps(bad))
        with pytest.raises(UntrustedCheckpointError, match=f"'{name}' loads a model or tokenizer .* Hub"):
            check_processor_steps(evil)


def test_every_registered_step_that_loads_from_the_hub_is_refused():
    """HUB_LOADING_STEPS is a list read from LeRobot's sources; this keeps it complete if LeRobot changes.

    A step is registered when its module is imported, and what the process has imported depends on the tests
    that ran before (the reward models' steps come only with `lerobot.rewards`): so every LeRobot module whose
    source registers a step is imported here first."""
    import importlib
    import inspect

    import lerobot
    from lerobot.processor import ProcessorStepRegistry

    import lerobot_bavo.policies  # noqa: F401
    from lerobot_bavo.checkpoints import HUB_LOADING_STEPS

    root = Path(lerobot.__file__).parent
    registering = [p for p in sorted(root.rglob("*.py")) if "ProcessorStepRegistry.register" in p.read_text()]
    assert len(registering) > 10, registering  # LeRobot 0.6.1 has 31 such modules
    for path in registering:
        importlib.import_module(".".join(("lerobot", *path.relative_to(root).with_suffix("").parts)))

    loading = {
        name
        for name in ProcessorStepRegistry.list()
        if any(
            w in inspect.getsource(ProcessorStepRegistry.get(name))
            for w in ("from_pretrained", "hf_hub_download")
        )
    }
    assert loading <= HUB_LOADING_STEPS, (
        f"registered steps that load from the Hub but are not refused: {loading - HUB_LOADING_STEPS}"
    )


# ----------------------------------------------------------------------------- 2. mismatched / partial
# checkpoints
def test_mismatched_and_partial_checkpoints_are_refused_with_the_reason(checkpoint, tmp_path):
    from safetensors.torch import load_file, save_file

    from lerobot_bavo.checkpoints import CheckpointMismatchError, checkpoint_digest, env_settings
    from lerobot_bavo.eval.rollout import LeRobotPolicyAgent, env_kwargs_for_policy

    # bavo-eval builds its env from what the checkpoint records
    assert env_settings(checkpoint) == {"n_points": N_POINTS, "environment_state": False}
    assert env_kwargs_for_policy(str(checkpoint)) == {"n_points": N_POINTS, "environment_state": False}

    # an ACT made for 96 x 128 images: bavo-eval's env renders 96 x 128; an env at 240 x 320 is refused
    # (config.json alone: the check runs before anything is loaded)
    act = tmp_path / "act"
    act.mkdir()
    (act / "config.json").write_text(json.dumps({"type": "act", "input_features": {
        "observation.images.active": {"type": "VISUAL", "shape": [3, 96, 128]},
        "observation.state": {"type": "STATE", "shape": [21]}}}))
    assert env_settings(act) == {"image_height": 96, "image_width": 128, "environment_state": False}
    with (
        _small_env(image_height=240, image_width=320, n_points=8) as big,
        pytest.raises(
            CheckpointMismatchError,
            match=r"image_height: checkpoint 96, env 240; image_width: checkpoint 128, env 320",
        ),
    ):
        LeRobotPolicyAgent(act, big)
    (act / "config.json").write_text(json.dumps({"type": "act", "input_features": {
        "observation.point_cloud": {"type": "STATE", "shape": [100]}}}))
    with pytest.raises(
        CheckpointMismatchError, match=r"config.json: observation.point_cloud shape \[100\] is not N x 6"
    ):
        env_settings(act)
    with (
        _small_env(n_points=64) as wrong,
        pytest.raises(CheckpointMismatchError, match="n_points: checkpoint 32, env 64"),
    ):
        LeRobotPolicyAgent(checkpoint, wrong)

    # a ManiFlow fed another point count (e.g. by lerobot-eval --env.n_points) names the feature
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.policies.factory import make_pre_post_processors

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
    with _small_env() as env:
        with pytest.raises(CheckpointMismatchError, match="1 missing tensor"):
            LeRobotPolicyAgent(partial, env)
        weights = load_file(str(checkpoint / "model.safetensors"))
        weights["extra.weight"] = torch.zeros(2)
        save_file(weights, str(partial / "model.safetensors"))
        with pytest.raises(CheckpointMismatchError, match=r"1 unexpected \['extra.weight'\]"):
            LeRobotPolicyAgent(partial, env)
        invalid = _copy(checkpoint, tmp_path / "invalid")  # a value the config's own check refuses: named
        config = json.loads((invalid / "config.json").read_text())
        config["n_action_steps"] = config["horizon"]
        (invalid / "config.json").write_text(json.dumps(config))
        with pytest.raises(
            CheckpointMismatchError, match=r"because: `n_action_steps` must be in \[1, horizon"
        ):
            LeRobotPolicyAgent(invalid, env)
        agent = LeRobotPolicyAgent(checkpoint, env)  # the complete one loads and acts
        obs, info = env.reset(seed=0)
        assert np.isfinite(agent.act(obs, info)).all()

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

    # ... while the same files at another path resume (the key is the digest, not the path); a record of
    # another checkpoint in the log is refused even without run.json
    record = {"task": "cube_handoff", "condition": "clean", "seed": 1000, "success": False, "progress": 1,
              "steps": 800, "checkpoint_sha256": checkpoint_digest(checkpoint)}
    (out / "run.json").write_text(json.dumps({"seed": 1000, "policy": str(checkpoint.resolve()),
                                              "checkpoint_sha256": checkpoint_digest(checkpoint)}))
    (out / "episodes.jsonl").write_text(json.dumps(record) + "\n")
    results = evaluate(str(same_path), ["cube_handoff"], ["clean"], 1, 1000, out)  # no episode left to run
    assert results["cells"]["cube_handoff/clean"]["n_episodes"] == 1
    (out / "run.json").unlink()
    (out / "episodes.jsonl").write_text(
        json.dumps({**record, "checkpoint_sha256": checkpoint_digest(partial)}) + "\n"
    )
    with pytest.raises(SystemExit, match="episodes of other checkpoints"):
        evaluate(str(same_path), ["cube_handoff"], ["clean"], 1, 1000, out)


def test_the_point_frame_comes_from_the_training_data_and_a_conflict_is_refused(checkpoint, tmp_path, capsys):
    """A model trained on camera-frame clouds must not be scored on base-frame clouds."""
    from lerobot_bavo.checkpoints import CheckpointMismatchError, env_settings
    from lerobot_bavo.eval.cli import env_kwargs_for_run
    from lerobot_bavo.eval.rollout import LeRobotPolicyAgent

    # lerobot-train wrote train_config.json naming the `points` view; its source holds the bavo-collect record
    source = tmp_path / "datasets" / "bavo_x"
    (source / "meta").mkdir(parents=True)
    (source / "meta" / "bavo_collection.json").write_text(json.dumps({"settings": {"point_frame": "camera"}}))
    cam = _copy(checkpoint, tmp_path / "cam")
    (cam / "train_config.json").write_text(
        json.dumps(
            {"dataset": {"repo_id": "t/bavo_x_points", "root": str(tmp_path / "datasets" / "bavo_x_points")}}
        )
    )
    assert env_settings(cam)["point_frame"] == "camera"
    assert env_kwargs_for_run(str(cam))["point_frame"] == "camera"
    with pytest.raises(
        SystemExit, match="--point-frame base conflicts with the checkpoint: point_frame: checkpoint 'camera'"
    ):
        env_kwargs_for_run(str(cam), "base")
    with (
        _small_env() as env,
        pytest.raises(CheckpointMismatchError, match="point_frame: checkpoint 'camera', env 'base'"),
    ):
        LeRobotPolicyAgent(cam, env)
    # nothing records it: base, with a warning that says how to change it
    assert env_kwargs_for_run(str(checkpoint))["point_frame"] == "base"
    assert "pass --point-frame camera" in capsys.readouterr().err
    assert env_kwargs_for_run(str(checkpoint), "camera")["point_frame"] == "camera"


def test_a_checkpoint_without_its_data_carries_its_point_frame(checkpoint, tmp_path):
    """A shipped / Hub checkpoint has no training dataset beside it: its own bavo_inputs.json says the frame,
    wins over train_config.json, and a broken record is an error naming the file."""
    from lerobot_bavo.checkpoints import (
        INPUTS_RECORD,
        CheckpointMismatchError,
        env_settings,
        recorded_cloud_settings,
        write_inputs_record,
    )

    cam = _copy(checkpoint, tmp_path / "cam")
    assert recorded_cloud_settings(cam) is None  # nothing on this machine records it
    write_inputs_record(cam, "camera")
    assert recorded_cloud_settings(cam)["point_frame"] == "camera"
    assert env_settings(cam)["point_frame"] == "camera"
    (cam / INPUTS_RECORD).write_text('{"point_frame": "world"}')
    with pytest.raises(
        CheckpointMismatchError, match="bavo_inputs.json: point_frame must be 'base' or 'camera'"
    ):
        recorded_cloud_settings(cam)
    (cam / INPUTS_RECORD).write_text("{not json")
    with pytest.raises(CheckpointMismatchError, match="bavo_inputs.json is not a valid inputs record"):
        recorded_cloud_settings(cam)
    with pytest.raises(ValueError, match="point_frame must be"):
        write_inputs_record(cam, "world")


def test_the_shipped_checkpoint_records_its_point_frame():
    from lerobot_bavo.checkpoints import recorded_cloud_settings

    shipped = Path(__file__).resolve().parents[1] / "checkpoints" / "afar_cube_handoff"
    # bavo-collect's default, what its data was collected in
    assert recorded_cloud_settings(shipped)["point_frame"] == "base"


# ----------------------------------------------------------------------------- 3. torn episodes.jsonl
def test_a_torn_last_log_line_is_dropped_and_a_corrupt_middle_line_is_named(tmp_path, capsys):
    from lerobot_bavo.eval.cli import read_episode_log

    log = tmp_path / "episodes.jsonl"
    records = [{"task": "cube_handoff", "condition": "clean", "seed": s, "success": True} for s in (0, 1)]

    class FullDisk:
        """A file whose device fills after `room` bytes: the write stops mid-line, as with ENOSPC."""

        def __init__(self, path: Path, room: int):
            self.fh, self.room = open(path, "w"), room  # noqa: SIM115  (closed by close(), like a log file)

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


def test_reading_a_log_for_analysis_leaves_a_torn_line_in_place_and_reads_gzip(tmp_path):
    """Tables and breakdowns read finished runs, perhaps while bavo-eval still appends to one: the
    analysis reader leaves out a torn last line without truncating the file, reads the committed .gz form,
    and names a corrupt line as the resuming reader does."""
    import gzip

    from lerobot_bavo.eval.run import read_episode_records

    records = [{"task": "cube_handoff", "condition": "stage", "seed": s, "success": s == 1} for s in (3, 1)]
    complete = "".join(json.dumps(r) + "\n" for r in records)
    log = tmp_path / "episodes.jsonl"
    log.write_text(complete + '{"task": "cube_ha')
    assert read_episode_records(log) == records  # in the order written
    assert log.read_text() == complete + '{"task": "cube_ha'  # untouched

    packed = tmp_path / "episodes.jsonl.gz"
    packed.write_bytes(gzip.compress(complete.encode()))
    assert read_episode_records(packed) == records

    log.write_text(complete + '{"task": "cube_handoff"}\n')  # no condition / seed: not an episode record
    with pytest.raises(SystemExit, match=r"episodes.jsonl line 3 is corrupt"):
        read_episode_records(log)


# A bavo-eval run whose episodes are fake and fast (the write path, resume and lock are the real ones):
# `python -c FAKE_EVAL <seconds per episode> <bavo-eval arguments>`.
FAKE_EVAL = """
import resource, signal, sys, time
from lerobot_bavo.eval import cli, run
def fake_run_job(job):
    time.sleep(float(sys.argv[1]))
    return {"task": job["task"], "condition": job["condition"], "seed": job["seed"], "success": True,
            "progress": 5, "steps": 300, "padding": "x" * 200}
run.run_job = fake_run_job
limit = int(sys.argv[2])
if limit:  # the disk fills after `limit` bytes: writes past it fail with EFBIG, as with ENOSPC
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
cli.main(sys.argv[3:])
"""


def _fake_eval(
    seconds: float, limit: int, args: list[str], **kw
) -> subprocess.CompletedProcess | subprocess.Popen:
    cmd = [
        sys.executable,
        "-c",
        FAKE_EVAL,
        str(seconds),
        str(limit),
        "--policy",
        "expert",
        "--tasks",
        "cube_handoff",
        "--conditions",
        "clean",
        "--videos",
        "0",
        *args,
    ]
    if kw.pop("background", False):
        return subprocess.Popen(cmd, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    return subprocess.run(cmd, env=_env(), capture_output=True, text=True, timeout=300)


def test_a_full_disk_tears_the_log_and_the_rerun_drops_the_torn_line(tmp_path):
    """bavo-eval's own writes, with the file size limited so the second record is cut mid-line."""
    out = tmp_path / "eval"
    line = len(json.dumps({"task": "cube_handoff", "condition": "clean", "seed": 1000, "success": True,
                           "progress": 5, "steps": 300, "padding": "x" * 200, "wall_s": 0.0})) + 1
    full = _fake_eval(0, line + 40, ["--episodes", "3", "--output-dir", str(out)])
    assert full.returncode != 0 and "episodes.jsonl failed (File too large); free some space" in full.stderr
    assert "Traceback" not in full.stderr
    torn = (out / "episodes.jsonl").read_bytes()
    assert torn.count(b"\n") == 1 and not torn.endswith(b"\n")  # one record, then a torn one

    rerun = _fake_eval(0, 0, ["--episodes", "3", "--output-dir", str(out)])
    assert rerun.returncode == 0, rerun.stderr
    assert f"dropping an incomplete last line of {out / 'episodes.jsonl'}" in rerun.stderr
    assert "1 finished episodes kept, 2 to run" in rerun.stdout
    lines = (out / "episodes.jsonl").read_text().splitlines()
    assert sorted(json.loads(x)["seed"] for x in lines) == [1000, 1001, 1002]
    assert json.loads((out / "results.json").read_text())["cells"]["cube_handoff/clean"]["n_episodes"] == 3


def test_two_bavo_eval_runs_on_one_folder(tmp_path):
    """A second run on the same folder (here through a symlink) is refused while the first writes; the first
    finishes with each episode once."""
    from lerobot_bavo.eval.cli import main as eval_main

    out = tmp_path / "eval"
    link = tmp_path / "link"
    link.symlink_to(out, target_is_directory=True)
    first = _fake_eval(0.5, 0, ["--episodes", "6", "--output-dir", str(out)], background=True)
    try:
        deadline = time.time() + 120
        while time.time() < deadline and not (out / "run.json").exists() and first.poll() is None:
            time.sleep(0.2)
        assert (out / "run.json").exists(), first.communicate()[1]
        for spelling in (out, link):
            with pytest.raises(SystemExit, match=f"another bavo-eval is writing {out.resolve()}"):
                eval_main(
                    [
                        "--policy",
                        "expert",
                        "--tasks",
                        "cube_handoff",
                        "--conditions",
                        "clean",
                        "--episodes",
                        "6",
                        "--videos",
                        "0",
                        "--output-dir",
                        str(spelling),
                    ]
                )
        stdout, stderr = first.communicate(timeout=120)
        assert first.returncode == 0, stderr
    finally:
        if first.poll() is None:
            first.kill()
    seeds = [json.loads(x)["seed"] for x in (out / "episodes.jsonl").read_text().splitlines()]
    assert sorted(seeds) == list(range(1000, 1006))


# ----------------------------------------------------------------------------- 5. locks
def test_locks_hold_across_symlinked_spellings_and_for_bavo_eval(tmp_path):
    from lerobot_bavo.datasets import schema as S
    from lerobot_bavo.datasets.collect import CollectConfig, CollectionError, Collector
    from lerobot_bavo.eval.cli import evaluate
    from lerobot_bavo.runtime.process import LockedError, exclusive_lock

    real = tmp_path / "datasets" / "bavo_x"
    real.mkdir(parents=True)
    link = tmp_path / "link_to_x"
    link.symlink_to(real)
    cfg = dict(task="cube_handoff", condition="stage", episodes=1, repo_id="t/x", workers=0,
               settings=S.ObservationSettings(32, 32, n_points=8), progress=False)
    held = Collector(CollectConfig(root=real, **cfg)).lock()
    try:
        with pytest.raises(CollectionError, match="another bavo-collect is writing"):
            Collector(CollectConfig(root=link, **cfg)).lock()
    finally:
        held.close()
    Collector(CollectConfig(root=link, **cfg)).lock().close()  # free again once released

    out = tmp_path / "eval"
    held = exclusive_lock(out, "bavo-eval")
    try:
        with pytest.raises(SystemExit, match="another bavo-eval is writing"):
            evaluate("expert", ["cube_handoff"], ["clean"], 1, 0, out)
        with pytest.raises(LockedError):
            exclusive_lock(tmp_path / "." / "eval", "bavo-eval")
    finally:
        held.close()
    # a released lock leaves no file beside the folders, and closing twice is harmless
    held.close()
    assert not list(tmp_path.glob(".*.lock")) and not list((tmp_path / "datasets").glob(".*.lock"))
    with exclusive_lock(out, "bavo-eval"):  # and the folder can be claimed again
        assert (tmp_path / ".eval.bavo-eval.lock").exists()
    assert not (tmp_path / ".eval.bavo-eval.lock").exists()


# ----------------------------------------------------------------------------- 6. small items
def test_bad_arguments_and_files_give_clear_errors(tmp_path, capsys):
    from lerobot_bavo.datasets.collect import main as collect_main
    from lerobot_bavo.eval.cli import main as eval_main

    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    base = ["--policy", "expert", "--tasks", "cube_handoff", "--conditions", "clean"]
    for extra, message in (
        (["--seed", "-5"], "--seed must be >= 0"),
        (["--workers", "-3"], "--workers must be >= 1"),
        (["--videos", "-1"], "--videos must be >= 0"),
    ):
        with pytest.raises(SystemExit):
            eval_main(base + ["--output-dir", str(tmp_path / "o")] + extra)
        assert message in capsys.readouterr().err
    with pytest.raises(SystemExit, match="is not a folder"):
        eval_main(base + ["--output-dir", str(a_file)])
    collect_args = ["--task", "cube_handoff", "--episodes", "1", "--repo-id", "t/x"]
    with pytest.raises(SystemExit):
        collect_main(collect_args + ["--root", str(a_file)])
    assert "is not a folder" in capsys.readouterr().err
    # the flags CollectConfig checks (in one place): exit status 2 with the message, as for every config error
    for extra, message in ((["--seed", "-5"], "--seed must be >= 0"),
                           (["--workers", "-3"], "--workers must be >= 0")):
        assert collect_main(collect_args + extra) == 2
        assert message in capsys.readouterr().err


def test_env_stops_after_the_episode_ends_and_renders_nothing_without_a_render_mode():
    from lerobot_bavo.sim import constants as C

    with _small_env(n_points=8, episode_length=2) as env:
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


def test_bad_dataset_metadata_and_nan_are_named(tmp_path):
    from lerobot.configs import FeatureType, PolicyFeature

    from lerobot_bavo.datasets.hub import read_info, read_sidecar, read_stats
    from lerobot_bavo.policies import ManiFlowConfig
    from lerobot_bavo.policies.maniflow.processor_maniflow import make_maniflow_pre_post_processors

    meta = tmp_path / "meta"
    meta.mkdir()
    (meta / "stats.json").write_text("{not json")
    with pytest.raises(ValueError, match=r"stats.json: not valid JSON"):
        read_stats(tmp_path)
    (meta / "stats.json").write_text(
        json.dumps({"observation.state": {"min": [float("nan"), 0.0], "max": [1.0, 1.0]}})
    )
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


def test_bavo_collect_names_the_broken_metadata_file_of_the_dataset_it_continues(tmp_path, capsys):
    """Resuming a dataset whose stats.json is not JSON, whose info.json has features: null, or whose
    collection record has no settings: one line naming the file (before: JSONDecodeError / TypeError /
    KeyError: 'settings' tracebacks)."""
    from lerobot_bavo.datasets import schema as S
    from lerobot_bavo.datasets.collect import CollectConfig, Collector
    from lerobot_bavo.datasets.collect import main as collect_main
    from lerobot_bavo.datasets.hub import SIDECAR

    root = tmp_path / "ds"
    args = [
        "--task",
        "cube_handoff",
        "--episodes",
        "1",
        "--repo-id",
        "t/x",
        "--root",
        str(root),
        "--workers",
        "0",
        "--image-height",
        "32",
        "--image-width",
        "32",
        "--n-points",
        "8",
        "--no-progress",
    ]
    Collector(
        CollectConfig(
            task="cube_handoff",
            condition="stage",
            episodes=1,
            repo_id="t/x",
            root=root,
            workers=0,
            # empty dataset
            settings=S.ObservationSettings(32, 32, n_points=8),
            progress=False,
        )
    ).open()
    good = {name: (root / name).read_text() for name in ("meta/info.json", str(SIDECAR))}
    for name, text, message in (
            ("meta/stats.json", "{not json", "stats.json: not valid JSON"),
            ("meta/info.json", json.dumps({**json.loads(good["meta/info.json"]), "features": None}),
             "info.json: no 'features' object"),
            (str(SIDECAR), json.dumps({"episodes": []}), f"{SIDECAR.name}: no 'settings' object")):
        (root / name).write_text(text)
        assert collect_main(args) == 2
        err = capsys.readouterr().err
        assert message in err and str(root) in err and "Traceback" not in err
        (root / name).unlink()
        if name in good:
            (root / name).write_text(good[name])


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
    batch = {
        "observation.point_cloud": torch.rand(2, 2, 8, 6),
        "observation.state": torch.rand(2, 2, 21),
        "action": torch.rand(2, 16, 21),
        "observation.teacher.z0": torch.full((2, 2, 8, 3), float("nan")),
        "observation.teacher.zf": torch.zeros(2, 2, 8, 3),
    }
    with pytest.raises(ValueError, match="teacher.z0' holds NaN"):
        policy.forward(batch)


# ----------------------------------------------------------------------------- 4. kill -9 leaves no orphans
def _children(pid: int) -> set[int]:
    out = subprocess.run(["ps", "-o", "pid=", "--ppid", str(pid)], capture_output=True, text=True).stdout
    return {int(p) for p in out.split()}


def _watching(pid: int) -> bool:
    from lerobot_bavo.runtime.process import WATCH_THREAD_NAME

    try:
        return any(
            (t / "comm").read_text().strip() == WATCH_THREAD_NAME for t in Path(f"/proc/{pid}/task").iterdir()
        )
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
        "bavo-collect": [
            "--task",
            "cube_handoff",
            "--episodes",
            "20",
            "--repo-id",
            "t/kill",
            "--root",
            str(tmp_path / "ds"),
            "--workers",
            "2",
            "--no-progress",
        ],
        "bavo-eval": [
            "--policy",
            "expert",
            "--tasks",
            "cube_handoff",
            "--conditions",
            "stage",
            "--episodes",
            "20",
            "--workers",
            "2",
            "--videos",
            "0",
            "--output-dir",
            str(tmp_path / "eval"),
        ],
    }[tool]
    proc = subprocess.Popen(
        _cli(tool) + args, env=_env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    try:
        deadline = time.time() + 120
        workers: set[int] = set()
        while time.time() < deadline and len(workers) < 2:  # pool workers (+ the resource tracker) are up
            time.sleep(1.0)
            workers = _children(proc.pid)
        assert len(workers) >= 2, f"{tool} started no workers"
        # A spawned worker imports for a while before its initializer (which starts the watch) runs; wait
        # until every worker runs its watch thread (named bavo-watch), i.e. it is set up and working on
        # episodes. (bavo-eval's workers are forked, bavo-collect's spawned: their command lines tell
        # nothing.)
        deadline = time.time() + 240
        while time.time() < deadline and sum(_watching(p) for p in _children(proc.pid)) < 2:
            time.sleep(1.0)
        time.sleep(2.0)
        workers = _children(proc.pid)
        assert sum(_watching(p) for p in workers) >= 2, f"{tool}: its workers never started their watch"
        assert proc.poll() is None, f"{tool} ended before it could be killed (exit {proc.returncode})"
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
