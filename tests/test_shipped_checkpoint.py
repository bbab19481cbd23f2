"""The checkpoints shipped in `checkpoints/<method>_<task>` (`afar_cube_handoff_sf` is the demo's policy)
load in both evaluators and act: smoke tests (finite actions for a few steps), not SR assertions; SR is
in each model card and docs/results/table.md."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from lerobot_bavo.demo import SHIPPED_CHECKPOINT


def test_shipped_checkpoint_is_complete_small_and_documented():
    names = {p.name for p in SHIPPED_CHECKPOINT.iterdir()}
    assert {"config.json", "model.safetensors", "policy_preprocessor.json", "policy_postprocessor.json",
            "README.md", "train_config.json"} <= names
    assert sum(p.stat().st_size for p in SHIPPED_CHECKPOINT.iterdir()) <= 7_000_000  # inference weights only
    cfg = json.loads((SHIPPED_CHECKPOINT / "config.json").read_text())
    assert cfg["type"] == "afar" and not any(
        k.startswith("observation.teacher") for k in cfg["input_features"]
    )
    card = (SHIPPED_CHECKPOINT / "README.md").read_text()
    assert "bavo-eval" in card and "hf upload" in card and "SR (%)" in card


def test_loading_the_config_leaves_no_temporary_file(tmp_path, monkeypatch):
    """LeRobot's `PreTrainedConfig.from_pretrained` writes a `tmpXXXX.json` it never removes; our loader
    gives it a private folder and deletes that."""
    import tempfile

    from lerobot_bavo.checkpoints import load_policy_config

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    assert load_policy_config(SHIPPED_CHECKPOINT).type == "afar"
    assert list(tmp_path.glob("*.json")) == []  # (torch may make its own cache folder here: not ours)


def test_shipped_checkpoint_acts_in_bavo_eval_agent_under_stage_occlusion():
    from lerobot_bavo.envs.bavo_env import BavoEnv
    from lerobot_bavo.eval.rollout import env_kwargs_for_policy, make_agent

    env = BavoEnv("cube_handoff", "stage", render_mode=None, **env_kwargs_for_policy(str(SHIPPED_CHECKPOINT)))
    try:
        agent = make_agent(str(SHIPPED_CHECKPOINT), env)
        obs, info = env.reset(seed=1000)
        agent.reset()
        start = obs["agent_pos"].copy()
        for _ in range(10):
            action = agent.act(obs, info)
            assert action.shape == (21,) and np.isfinite(action).all()
            obs, _, terminated, truncated, info = env.step(action)
            assert not (terminated or truncated)
        assert not np.allclose(obs["agent_pos"], start)  # it moves
    finally:
        env.close()


@pytest.mark.parametrize(("folder", "inference_flags"), [
    (SHIPPED_CHECKPOINT.name, []),
    ("maniflow_block_stacking", []),
    (SHIPPED_CHECKPOINT.name, ["--policy.temporal_ensemble_coeff=0.01", "--policy.n_action_steps=4"]),
])
def test_shipped_checkpoint_runs_in_lerobot_eval(tmp_path, folder, inference_flags):
    """`lerobot-eval --policy.path=checkpoints/<method>_<task>[_sf]` on its own task with the cloud flags its
    card names (two of the shipped folders: both policy types, two tasks, the self-filtered demo policy and a
    plain cloud; every folder loads through the same code path as in the test above), and once with temporal
    ensembling turned on from the command line (docs/training.md)."""
    from lerobot_bavo.eval.rollout import env_kwargs_for_policy

    checkpoint = SHIPPED_CHECKPOINT.parent / folder
    task = method_and_task(checkpoint)[1]
    cloud = env_kwargs_for_policy(str(checkpoint))
    cloud_flags = [f"--env.n_points={cloud['n_points']}",
                   f"--env.self_filter={str(cloud['self_filter']).lower()}"]
    exe = Path(sys.executable).with_name("lerobot-eval")
    env = dict(os.environ, HF_HUB_OFFLINE="1", OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1",
               MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"))
    proc = subprocess.run(
        [
            str(exe),
            f"--policy.path={checkpoint}",
            "--policy.device=cpu",
            "--env.type=bavo",
            f"--env.task={task}",
            "--env.condition=stage",
            "--env.episode_length=8",
            *cloud_flags,
            "--eval.n_episodes=1",
            "--eval.batch_size=1",
            "--eval.use_async_envs=false",
            f"--output_dir={tmp_path / 'eval'}",
            *inference_flags,
        ],
        capture_output=True,
        text=True,
        timeout=600,
        env=env,
        cwd=tmp_path,
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    info = json.loads((tmp_path / "eval" / "eval_info.json").read_text())
    assert info["overall"]["n_episodes"] == 1
    for flag in inference_flags:  # the run's printed config holds the setting it was given
        name, value = flag.removeprefix("--policy.").split("=")
        assert f"'{name}': {value}" in proc.stdout + proc.stderr


def test_a_learned_policy_episode_depends_only_on_its_seed():
    """Same seed, same episode: the sampler's noise is seeded with the episode seed, so an episode does not
    depend on what the same process ran before it (it did when the noise came from torch's global RNG), and
    the noise does matter (another noise seed, other actions from the same state)."""
    from lerobot_bavo.envs.bavo_env import BavoEnv
    from lerobot_bavo.eval.rollout import env_kwargs_for_policy, make_agent, run_episode

    env = BavoEnv("cube_handoff", "stage", render_mode=None, episode_length=6,
                  **env_kwargs_for_policy(str(SHIPPED_CHECKPOINT)))
    try:
        agent = make_agent(str(SHIPPED_CHECKPOINT), env)
        sent = []
        act = agent.act
        agent.act = lambda obs, info: sent.append(act(obs, info)) or sent[-1]

        def actions(seed):
            sent.clear()
            run_episode(env, agent, seed=seed)
            return np.stack(sent)

        first = actions(1000)
        actions(1001)
        np.testing.assert_array_equal(actions(1000), first)  # after another episode in the same process

        obs, info = env.reset(seed=1000)
        agent.reset(seed=1000)
        assert np.array_equal(act(obs, info), first[0])
        obs, info = env.reset(seed=1000)
        agent.reset(seed=7)  # same state, other noise
        assert not np.allclose(act(obs, info), first[0])
    finally:
        env.close()


SHIPPED = sorted(p for p in (Path(__file__).resolve().parent.parent / "checkpoints").iterdir() if p.is_dir())


# data variants beside the recipe (docs/training.md): 50 (100) Stage + 50 (100) Random-time demonstrations;
# self-filtered clouds (sf); the self-filtered 100 + 100 at 1.5x and 2x the recipe's budget (b1.5x, b2x) and
# with the larger shippable model (cpu_mlp3.5: `PRESET=cpu --policy.dit_mlp_ratio=3.5`, float16); the
# Stage-only self-filtered recipe fine-tuned on the self-filtered 100 + 100 (ft); the self-filtered 100 + 100
# with the Random-time episodes kept for their view recoveries only (ro: their other frames weighted 0), and
# with their recoveries teaching the camera arm only (rc: the arms' dims of their recovery frames weighted 0),
# and with all their frames teaching the camera arm only (ca: the arms' dims of every Random-time frame
# weighted 0); the Stage-only self-filtered recipe at half and twice its samples (sf_half, sf_b2x); the
# self-filtered 200 Stage + 200 Random-time at the recipe's samples, twice and four times them
# (mixsr400sf[_b2x|_b4x], the 2x one at peak lr 1e-3: mixsr400sf_b2x_lr1e3), and with 200 more Stage
# demonstrations (mixs400r200sf_b2x_lr1e3), the Random-time camera commands weighing 0.25
# (mixsr400sfcw25_b2x_lr1e3), the Random-time recovery frames weighing 0.25 (mixsr400sfrw25_b2x_lr1e3) or
# occluder dropout sparing the recovery frames (mixsr400sfodr_b2x_lr1e3), or the Random-time camera commands
# weighing 0.25 outside their recoveries (mixsr400sfco25_b2x_lr1e3), and the 400 + 200 one fine-tuned on its
# Stage episodes (mixs400r200sf_b2x_lr1e3_ftstage) or on square-grasp Stage demonstrations (..._ftsquare);
# the self-filtered recipe with decoy panels (sfdc1), at peak lr 1e-3 (sf_lr1e3), and at peak lr 1e-3 on
# square-grasp Stage demonstrations (sfsq_lr1e3)
DATA_VARIANTS = ("mixsr", "mixsr200", "mixsr200sf", "mixsr200sf_b1.5x", "mixsr200sf_b2x",
                 "mixsr200sf_cpu_mlp3.5", "mixsr200sf_ft", "mixsr150sf", "mixsr200sfro", "mixsr200sfrc",
                 "mixsr200sfca", "mixsroc200sf", "mixsr400sf", "mixsr400sf_b2x", "mixsr400sf_b2x_lr1e3",
                 "mixsr400sf_b4x", "mixs400r200sf_b2x_lr1e3", "mixs400r200sf_b2x_lr1e3_ftstage",
                 "mixs400r200sf_b2x_lr1e3_ftsquare",
                 "mixs400r200sfgate1_b2x_lr1e3", "mixsr400sfcw25_b2x_lr1e3", "mixsr400sfrw25_b2x_lr1e3",
                 "mixsr400sfodr_b2x_lr1e3", "mixsr400sfco25_b2x_lr1e3", "sf", "sf_b2x", "sf_half", "sfdc1",
                 "sf_lr1e3", "sfsq_lr1e3")


def method_and_task(folder: Path) -> tuple[str, str]:
    """`checkpoints/<method>_<task>` (training seed 1000) or `<method>_<task>_s<seed>` (another training seed,
    as `scripts/train_task.sh recipe` names it), each with an optional data variant's suffix before the
    seed."""
    variants = "|".join(map(re.escape, DATA_VARIANTS))
    match = re.fullmatch(rf"([a-z]+)_([a-z_]+?)(?:_(?:{variants}))?(?:_s\d+)?", folder.name)
    assert match, folder.name
    return match.group(1), match.group(2)


def test_every_task_has_its_checkpoint_folder_named_method_task():
    from lerobot_bavo.envs.tasks import TASKS

    for folder in SHIPPED:
        method, task = method_and_task(folder)
        assert method in ("afar", "maniflow") and task in TASKS, folder.name


@pytest.mark.parametrize("folder", SHIPPED, ids=lambda p: p.name)
def test_each_shipped_checkpoint_is_small_documented_and_acts_in_its_task(folder):
    """Every `checkpoints/<method>_<task>`: at most 7 MB, a card naming its method and task with measured
    results, and `bavo-eval`'s agent drives its own task's env with finite actions."""
    from lerobot_bavo.envs.bavo_env import BavoEnv
    from lerobot_bavo.eval.rollout import env_kwargs_for_policy, make_agent

    method, task = method_and_task(folder)
    assert sum(p.stat().st_size for p in folder.iterdir()) <= 7_000_000
    cfg = json.loads((folder / "config.json").read_text())
    assert cfg["type"] == method
    card = (folder / "README.md").read_text()
    assert f"--tasks {task}" in card and "SR (%)" in card and "2000-2039" in card
    env = BavoEnv(task, "stage", render_mode=None, **env_kwargs_for_policy(str(folder)))
    try:
        agent = make_agent(str(folder), env)
        obs, info = env.reset(seed=1000)
        agent.reset()
        for _ in range(3):
            action = agent.act(obs, info)
            assert action.shape == (21,) and np.isfinite(action).all()
            obs, _, _, _, info = env.step(action)
    finally:
        env.close()
