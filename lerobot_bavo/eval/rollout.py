"""Agents (scripted experts or LeRobot checkpoints) and one-episode rollouts on BAVO-Bench.

A rollout returns a JSON-ready record: seed, success, deepest milestone, steps, the episode's
CVG summary (Random-time) and the occlusion events with their placements. Videos mark the
first frames after every occlusion event with a red border.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from pathlib import Path

import numpy as np

from lerobot_bavo.datasets.lerobot_private import policy_action_queue

EXPERT_POLICIES = ("expert", "expert-frozen-camera")


class ExpertAgent:
    """The privileged scripted expert (optionally with a frozen camera) as an agent."""

    def __init__(self, env, frozen_camera: bool = False):
        from lerobot_bavo.experts import make_expert

        self.expert = make_expert(env, frozen_camera=frozen_camera)

    def reset(self, seed: int | None = None) -> None:  # noqa: ARG002 (the expert draws from the env's RNG only)
        self.expert.reset()

    def act(self, obs: dict, info: dict) -> np.ndarray:
        return self.expert.act(obs, info)


class LeRobotPolicyAgent:
    """A LeRobot checkpoint (`pretrained_model` directory) driving the env, on CPU by default.

    Loading follows `lerobot-eval`: the policy config and weights from the directory, the saved
    pre/post-processors (normalisation), and LeRobot's own observation conversion
    (`preprocess_observation`), so results match `lerobot-eval --policy.path=...`. Before that,
    `lerobot_bavo.checkpoints` refuses processor steps and policy types that are neither LeRobot's audited
    ones nor ours (unless `trust_remote_code`), refuses a checkpoint whose recorded inputs (points, point
    frame, image size, object poses) differ from the env's, and after it refuses weights with missing or
    unexpected tensors: LeRobot only logs those and the policy then acts with random layers.
    """

    def __init__(self, path: str | Path, env, device: str = "cpu", trust_remote_code: bool = False):
        import torch
        from lerobot.policies.factory import make_policy, make_pre_post_processors

        from lerobot_bavo import register_lerobot_types
        from lerobot_bavo.checkpoints import (
            CheckpointMismatchError,
            check_processor_steps,
            check_tensor_files,
            check_weights_complete,
            env_settings,
            load_policy_config,
            mismatches,
        )
        from lerobot_bavo.envs.configs import BavoEnvConfig

        register_lerobot_types()  # a light worker process has not registered them yet

        path = Path(path)
        if not (path / "config.json").is_file():
            raise FileNotFoundError(f"{path} is not a LeRobot checkpoint directory (no config.json); "
                                    "pass .../checkpoints/<step>/pretrained_model")
        check_processor_steps(path, trust_remote_code=trust_remote_code)
        s = env.obs_settings
        actual = {"n_points": s.n_points, "point_frame": s.point_frame, "self_filter": s.self_filter,
                  "image_height": s.image_height,
                  "image_width": s.image_width, "environment_state": getattr(env, "environment_state", False)}
        wrong = mismatches(env_settings(path), actual)
        if wrong:
            raise CheckpointMismatchError(
                f"the checkpoint at {path} was trained on other observations than this "
                "env gives: " + "; ".join(wrong)
            )
        self._torch = torch
        cfg = load_policy_config(path)  # the config's own checks and size bounds
        check_tensor_files(path)  # a truncated model.safetensors: an error naming it, not a SafetensorError
        cfg.pretrained_path = path
        cfg.device = device
        env_cfg = BavoEnvConfig(task=env.task.name, condition=env.condition, image_height=s.image_height,
                                image_width=s.image_width, n_points=s.n_points, point_frame=s.point_frame,
                                self_filter=s.self_filter, environment_state=env.environment_state)
        self.policy = make_policy(cfg, env_cfg=env_cfg)
        check_weights_complete(self.policy, path)
        self.policy.eval()
        self.pre, self.post = make_pre_post_processors(
            policy_cfg=cfg, pretrained_path=str(path),
            preprocessor_overrides={"device_processor": {"device": device}},
        )
        self.task_description = env.task_description
        self._device = device
        self._takes_generator = "generator" in inspect.signature(self.policy.select_action).parameters
        self._generator = None
        self.last_chunk: np.ndarray | None = None  # (k, 21) joint targets predicted at the last act(), if any

    def reset(self, seed: int | None = None) -> None:
        """Clear the policy's queues; with `seed`, also fix the noise its sampler draws this episode.

        Why: a flow / diffusion policy samples each chunk from Gaussian noise. Drawn from torch's global RNG,
        an episode's actions would depend on which episodes the same worker process ran before it, so the same
        seed would not give the same episode. Policies whose `select_action` takes a `generator` (ManiFlow,
        A-FAR) get one seeded with the episode seed; others (LeRobot's own) draw from the global RNG, which is
        seeded with it instead (a worker runs one episode at a time)."""
        self.policy.reset()
        if seed is None:
            self._generator = None
        elif self._takes_generator:
            self._generator = self._torch.Generator(device=self._device).manual_seed(int(seed))
        else:
            self._generator = None
            self._torch.manual_seed(int(seed))

    def act(self, obs: dict, info: dict) -> np.ndarray:
        from lerobot.envs.utils import preprocess_observation

        batched = {k: (v[None] if isinstance(v, np.ndarray) else {kk: vv[None] for kk, vv in v.items()})
                   for k, v in obs.items()}
        batch = preprocess_observation(batched)
        batch["task"] = [self.task_description]
        batch = self.pre(batch)
        with self._torch.inference_mode():
            queue = policy_action_queue(self.policy)
            fresh = queue is not None and len(queue) == 0  # this call predicts a new chunk
            if self._generator is not None:
                action = self.policy.select_action(batch, generator=self._generator)
            else:
                action = self.policy.select_action(batch)
            queue = policy_action_queue(self.policy)
            self.last_chunk = None
            if fresh and queue is not None:  # the chunk just predicted: this action and those queued after it
                chunk = self._torch.stack([action.reshape(-1), *(a.reshape(-1) for a in queue)])
                self.last_chunk = self.post(chunk).cpu().numpy().astype(np.float64)
        action = self.post(action)
        return action.squeeze(0).cpu().numpy().astype(np.float64)


def env_kwargs_for_policy(policy: str) -> dict:
    """`BavoEnv` keyword arguments that make the env give a checkpoint the observations it was trained on:
    the point count, image size and privileged object poses its input features record, and the point frame
    where its training data records it (`lerobot_bavo.checkpoints.env_settings`). Experts need none."""
    if policy in EXPERT_POLICIES or not (Path(policy) / "config.json").is_file():
        return {}
    from lerobot_bavo.checkpoints import env_settings

    return env_settings(policy)


def make_agent(policy: str, env, trust_remote_code: bool = False):
    if policy == "expert":
        return ExpertAgent(env)
    if policy == "expert-frozen-camera":
        return ExpertAgent(env, frozen_camera=True)
    return LeRobotPolicyAgent(policy, env, trust_remote_code=trust_remote_code)


class CommandLog:
    """Wraps an agent and keeps the commands it sends, one action per step (the rollout only sees what the
    agent returns); the probes in `scripts/` read them after `run_episode`."""

    def __init__(self, agent):
        self.agent, self.commands = agent, []

    def reset(self, seed=None):
        self.commands = []
        return self.agent.reset(seed=seed)

    def act(self, obs, info):
        action = np.asarray(self.agent.act(obs, info), dtype=np.float64)
        self.commands.append(action.copy())
        return action

    def __getattr__(self, name):
        return getattr(self.agent, name)


def longest_run(flags: list[bool]) -> int:
    """Length of the longest run of True in `flags`."""
    best = run = 0
    for f in flags:
        run = run + 1 if f else 0
        best = max(best, run)
    return best


def target_hidden(info: dict, below: float = 0.5) -> bool:
    """Whether an occlusion event hides the current target this step: its visibility (the share of the
    target's sample points the camera sees, 0-1) is reported and under `below`."""
    occ = info.get("occlusion")
    return bool(occ is not None and occ["visibility"] is not None and occ["visibility"] < below)


def mark_event(frame: np.ndarray, width: int = 6) -> np.ndarray:
    """A red border around a frame (marks the frames just after an occlusion event)."""
    out = frame.copy()
    red = np.array([220, 30, 30], dtype=np.uint8)
    out[:width], out[-width:], out[:, :width], out[:, -width:] = red, red, red, red
    return out


def run_episode(env, agent, seed: int, video_path: Path | None = None, video_every: int = 2,
                mark_steps: int = 12, rerun_path: Path | None = None,
                on_step: Callable[[dict], None] | None = None,
                on_act: Callable[[dict, dict, np.ndarray], None] | None = None) -> dict:
    """Roll out one seeded episode; returns its record (and writes a video, and a rerun recording of every
    step built from the observations and `info` only (`lerobot_bavo.viz.recorder`), if asked). `on_step(info)`
    runs after every step, e.g. to show progress within an episode (`bavo-demo`); `on_act(obs, info, action)`
    runs after the agent chose each action and before the env executes it, with the env in the state the
    agent saw (the probes in scripts/ read the simulator there)."""
    obs, info = env.reset(seed=seed)
    agent.reset(seed=seed)
    frames = []
    recorder = None
    if rerun_path is not None:
        from lerobot_bavo.viz.recorder import RolloutRecorder

        recorder = RolloutRecorder(env, name=Path(rerun_path).stem)
    visibility = [_visibility(info)] if "occlusion" in info else None
    last_event_step = 0 if "occlusion" in info else None
    placements = [_event_record(info["occlusion"]["event"])] if "occlusion" in info else []

    def grab():
        frame = env.render()
        if last_event_step is not None and info["elapsed_steps"] - last_event_step < mark_steps:
            frame = mark_event(frame)
        frames.append(frame)

    if video_path is not None:
        grab()
    while True:
        action = agent.act(obs, info)
        if on_act is not None:
            on_act(obs, info, action)
        if recorder is not None:
            recorder.add(obs, info, action, getattr(agent, "last_chunk", None))
        obs, reward, terminated, truncated, info = env.step(action)
        if on_step is not None:
            on_step(info)
        if visibility is not None:
            visibility.append(_visibility(info))
        occ = info.get("occlusion")
        if occ is not None and occ["event_started"]:
            last_event_step = info["elapsed_steps"]
            placements.append(_event_record(occ["event"]))
        if video_path is not None and info["elapsed_steps"] % video_every == 0:
            grab()
        if terminated or truncated:
            break
    record = {
        "seed": int(seed),
        "success": bool(info["is_success"]),
        "progress": int(info["progress"]),
        "steps": int(info["elapsed_steps"]),
    }
    cvg = info.get("cvg")
    if cvg is not None:
        record["episode_cvg"] = cvg["episode_cvg"]
        record["events"] = cvg["events"]
    if "occlusion" in info:
        record["triggers"] = [int(t) for t in info["occlusion"]["triggers"]]
        record["num_events"] = int(info["occlusion"]["num_events"])
        record["placements"] = placements
        record["visibility"] = visibility  # V of the current target at every step 0..steps (-1: not measured)
    if recorder is not None:
        recorder.add(obs, info)
        recorder.save(rerun_path)
        record["rerun"] = str(rerun_path)
    if video_path is not None:
        import imageio.v2 as imageio

        video_path.parent.mkdir(parents=True, exist_ok=True)
        imageio.mimsave(
            video_path, frames, fps=max(1, env.metadata["render_fps"] // video_every), macro_block_size=1
        )
        record["video"] = str(video_path)
    return record


def _event_record(event: dict) -> dict:
    """An event's placement; the occluder stays at this pose (centre, wxyz quaternion) until the next
    event."""
    return {"index": int(event["index"]), "step": int(event["step"]), "target": event["target"],
            "visibility_at_start": float(event["visibility_at_start"]), "fallback": bool(event["fallback"]),
            "occluder_pos": [float(x) for x in event["occluder_pos"]],
            "occluder_quat": [round(float(x), 6) for x in event["occluder_quat"]]}


def _visibility(info: dict) -> float:
    v = info["occlusion"]["visibility"]
    return -1.0 if v is None else round(float(v), 4)
