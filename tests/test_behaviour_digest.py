"""Behaviour pins: sha256 digests of short seeded rollouts, so a refactor cannot change episodes silently.

Each digest hashes, step by step, what an episode is made of: the joint positions (qpos), the
observation arrays (state, image, point cloud and its pixels), the reward, the milestone flags and
depth, the occlusion event (target, occluder pose, visibility), the expert's phase and at the end the
CVG summary. The rollouts are the seeded scripted expert on every task, a few dozen steps under every
condition, at a small image size. `bavo-eval`'s rollout records are pinned too: the expert and the
frozen-camera reference over one full CVG window under Random-time, and a whole Stage episode.

The values come from Mesa llvmpipe EGL rendering on x86-64; another renderer may differ in the
image bytes. After a deliberate behaviour change, re-pin with

    BAVO_DIGEST_PRINT=1 python -m pytest -q -s tests/test_behaviour_digest.py

and say why in the commit message.
"""

from __future__ import annotations

import hashlib
import json
import os

import numpy as np
import pytest

from lerobot_bavo.envs.bavo_env import BavoEnv
from lerobot_bavo.eval.rollout import ExpertAgent, run_episode
from lerobot_bavo.experts import make_expert

PRINT = os.environ.get("BAVO_DIGEST_PRINT") == "1"
SMALL = dict(image_height=48, image_width=64, n_points=32, render_mode=None)
STEPS = 25
SEED = 3

ROLLOUT_DIGESTS = {
    "cube_handoff/clean": "bf17f5d9c5debea525835cf2624eabaa8a6281c4b06dd11f92abc207898f9550",
    "cube_handoff/stage": "0df577e33231c5132c8dae80edb1199aa53870fca789f3d4a9837a3e97d8f47d",
    "cube_handoff/random": "b8280a9199c66f6d0eba73a1b0278ccd29d3d721f5e8e81e9eb72ed77b901749",
    "block_stacking/clean": "65a2485f90b00c6ecf12fe3be463b1505f516964dd2ebf01c0991376219bd41f",
    "block_stacking/stage": "ec83a3df0d1af92cf6cad5613a05c8e84c70b591c0f6c07754dd2f539f805d42",
    "block_stacking/random": "5a78b0796204a733a4d7b69d830ee84068783666a53608f6e571a6ef5bd73bdc",
    "drawer_stowing/clean": "6506cb2a804b3f841761620431d4afea163eb15b201409e4275b1bb53749c664",
    "drawer_stowing/stage": "926bf8bf6cac1e20af4a8ce26352bed122034a5a67f300a21e2a2cf5c6814c38",
    "drawer_stowing/random": "f2a5b357d638e598c7a64efc190d3468fa86de606f60b91ab05b72bd75932c90",
    "slide_retrieval/clean": "58172090c47e893b8fa08b92bd3bf5ec254400f133b6e0e458bd03b622c78002",
    "slide_retrieval/stage": "b72b46e3cb11372a79d41305feef0722bffaee726b741a817fdb83d3430e262a",
    "slide_retrieval/random": "f4a9c8c2df214812b4f2fb54c5bd3c4aa20eb2f606d035a02c314e732331b34c",
    "dustpan_sweeping/clean": "10f0a03b0e011ae104b18ca0f94ca4e68142f30043367fef51adde2f3bec2fec",
    "dustpan_sweeping/stage": "757361df4c34641864e3638ee19d3b4f8b896d47ccb3c22b6f558c4e7c361f08",
    "dustpan_sweeping/random": "c56dbec4e6b62754e387cac7424c7b7406f06fd2e6fcfce5e84cd4f9a8a10d69",
}
RECORD_DIGESTS = {
    "expert/random/70": "237f049e6f4b9c18b5113f975fc5a64b4747a9f4b282852c011f39bbfd71c475",
    "expert-frozen-camera/random/70": "b037e632b94744ebf8df9454f12b421351aea6ce431fb3fe294aef42f70d2846",
    "expert/stage/full": "024330072d1eebddf1c0d2d151dfab434da2e753eec20c9c56bd84725cc3d3ec",
}


class _Hash:
    def __init__(self):
        self.h = hashlib.sha256()

    def add(self, value) -> None:
        if isinstance(value, dict):
            for k in sorted(value):
                self.h.update(str(k).encode())
                self.add(value[k])
        elif isinstance(value, (list, tuple)):
            self.h.update(b"[")
            for v in value:
                self.add(v)
            self.h.update(b"]")
        elif isinstance(value, np.ndarray):
            self.h.update(str((value.dtype, value.shape)).encode())
            self.h.update(np.ascontiguousarray(value).tobytes())
        elif isinstance(value, float):
            self.h.update(np.float64(value).tobytes())
        else:
            self.h.update(repr(value).encode())

    def hexdigest(self) -> str:
        return self.h.hexdigest()


def _check(table: dict, key: str, digest: str) -> None:
    if PRINT:
        print(f"    {key!r}: {digest!r},")
        return
    assert digest == table[key], (f"behaviour changed for {key}: {digest} != pinned {table[key]} "
                                  "(re-pin with BAVO_DIGEST_PRINT=1 only if the change is deliberate)")


def _occlusion_fields(info: dict):
    occ = info.get("occlusion")
    if occ is None:
        return None
    ev = occ["event"]
    return [occ["condition"], occ["event_started"], occ["num_events"], occ["target"], occ["visibility"],
            occ["triggers"], ev["index"], ev["step"], ev["target"], ev["occluder_pos"],
            ev["visibility_at_start"], ev["fallback"]]


@pytest.mark.parametrize("key", list(ROLLOUT_DIGESTS))
def test_expert_rollout_digest(key):
    task, condition = key.split("/")
    env = BavoEnv(task=task, condition=condition, episode_length=STEPS, compute_cvg=condition != "clean",
                  environment_state=True, **SMALL)
    try:
        h = _Hash()
        obs, info = env.reset(seed=SEED)
        expert = make_expert(env, seed=SEED)
        expert.reset()
        done = False
        while True:
            h.add(env.data.qpos.copy())
            h.add({k: v for k, v in obs.items() if k != "pixels"})
            h.add(obs["pixels"]["active"])
            h.add([info["progress"], info["is_success"], info["milestones"], info["camera_pose"],
                   info["object_poses"], _occlusion_fields(info), info.get("cvg")])
            h.add(expert.phase)
            if done:
                break
            obs, reward, terminated, truncated, info = env.step(expert.act(obs, info))
            h.add([reward, terminated, truncated])
            done = terminated or truncated
        h.add([r.event for r in expert.recoveries])
    finally:
        env.close()
    _check(ROLLOUT_DIGESTS, key, h.hexdigest())


@pytest.mark.parametrize("key", list(RECORD_DIGESTS))
def test_rollout_record_digest(key):
    """`bavo-eval`'s rollout record on Cube Handoff: the expert and the frozen-camera reference over one
    full CVG window (H = 60) under Random-time Occlusion (events, their CVG, placements), and a whole
    expert episode under Stage Occlusion (all three Stage events, success)."""
    policy, condition, length = key.split("/")
    env = BavoEnv(task="cube_handoff", condition=condition, episode_length=None if length == "full" else int(length),
                  compute_cvg=condition == "random", **SMALL)
    try:
        record = run_episode(env, ExpertAgent(env, frozen_camera=policy == "expert-frozen-camera"), SEED)
    finally:
        env.close()
    if condition == "random":
        assert record["events"][0]["cvg"] is not None
    else:
        assert record["success"] and len(record["placements"]) == 3
    if policy == "expert-frozen-camera":
        assert record["episode_cvg"] == 0.0
    digest = hashlib.sha256(json.dumps(record, sort_keys=True).encode()).hexdigest()
    _check(RECORD_DIGESTS, key, digest)
