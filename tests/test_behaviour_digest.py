"""Behaviour pins: sha256 digests of short seeded rollouts, so a refactor cannot change episodes silently.

Each digest hashes, step by step, what an episode is made of: the joint positions (qpos), the
observation arrays (state, image, point cloud and its pixels), the reward, the milestone flags and
depth, the occlusion event (target, occluder pose, visibility), the expert's phase and at the end the
CVG summary. The rollouts are the seeded scripted expert on every task, a few dozen steps under every
condition, at a small image size. `bavo-eval`'s rollout records are pinned too: the expert and the
frozen-camera reference over one full CVG window under Random-time, and a whole Stage episode.

The values come from Mesa llvmpipe EGL rendering on x86-64 with OpenBLAS's Haswell (AVX2 + FMA)
kernels, which tests/conftest.py selects (OPENBLAS_CORETYPE): OpenBLAS otherwise picks kernels by CPU, and
the SkylakeX and Zen families round the experts' small matrix products differently in the last bit, which
changed every digest between an Intel AVX-512 and an AMD machine. Another renderer may differ in the image
bytes. After a deliberate behaviour change, re-pin with

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
    "cube_handoff/clean": "90999b0331c515f41dbc4336511af652eec89e9ebed81829a6384e8191ab4e19",
    "cube_handoff/stage": "6c6834ae5afcde089d3869033e42dd9d4094f59aeac7def99b7aa2832a992ee9",
    "cube_handoff/random": "e3f066fd7d7b365558f8c1fce98f50b2aab4763248a2082c87f14f11384394fd",
    "block_stacking/clean": "ebd5ef413d3636c14f2b6b9a5402cc0bbb97ec5e8a62c1998a291f0fdaa524e2",
    "block_stacking/stage": "daf246d8b4bbad90e8da6c6eb6c195c0232cc0b057d552a0d18115a67d76a5a1",
    "block_stacking/random": "2f10508c903d5fcde6e08680719566fba0c1c8741ff60fc169df29571b025644",
    "drawer_stowing/clean": "eecc433bb3a9869ae39671749b0d0d52a4e315b848d7b475c214065e70a2dc35",
    "drawer_stowing/stage": "e75412044f7fe671a5a4064c8a4e9b4a5762d3cb84a7b97d280b08b54205da34",
    "drawer_stowing/random": "eadee7b685fd255ed85edd16ee1f56db4a22e5aac28d90a52972c04b0892d415",
    # Two accepted values, from the same code: the first pinned on the earlier machines, the second measured
    # on an AMD EPYC machine without AVX-512 (2026-11-28), where only this episode's bytes differ (the other
    # 17 pins hold). Not isolated: on the AMD machine neither llvmpipe's vector width (LP_NATIVE_VECTOR_WIDTH
    # 128 against its 256) nor NumPy's AVX2 / FMA3 dispatch (NPY_DISABLE_CPU_FEATURES) changes any byte of
    # this episode, so what is left is code only an AVX-512 machine runs (NumPy's AVX512_SKX loops, LLVM's
    # AVX-512 code in llvmpipe): check there with NPY_DISABLE_CPU_FEATURES="AVX512F AVX512_SKX".
    "slide_retrieval/clean": ("8ded6e4aa35184639d96282fa3ff3a7c0f857e74ffa01354a41c492b5b9cc44a",
                              "893d67dd12f399484bbaf259b39d4879d684d86c3f7b7a1dbca32cf473579b6f"),
    "slide_retrieval/stage": "8a7abeaf7bc0ed735a2d9ab2c5adf6d2a182192321f09b98773a1da967ddcce8",
    "slide_retrieval/random": "d6559ecfb68ca45e1f4307df91ee0c2eb3172be385f187577db9903ce6c0c762",
    "dustpan_sweeping/clean": "e33893126575c440151be675322e272affc639c6eee29b67e4e66b73f95f9a28",
    "dustpan_sweeping/stage": "812eb6dc7227203ffa791ff56d6b7088cb9c9fd23a26de7ea98c1a7c7a71e4dd",
    "dustpan_sweeping/random": "391b26501ad858b252a84e534a6ed3bfa006c1c3ec22f8e9bb22f7228d660b9e",
}
RECORD_DIGESTS = {
    "expert/random/70": "237f049e6f4b9c18b5113f975fc5a64b4747a9f4b282852c011f39bbfd71c475",
    "expert-frozen-camera/random/70": "b037e632b94744ebf8df9454f12b421351aea6ce431fb3fe294aef42f70d2846",
    "expert/stage/full": "703c290d546aca8a0079847d9fbf6bddd33d9b195879d7ddf5244ba3d5b01849",
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
    pinned = table[key] if isinstance(table[key], tuple) else (table[key],)  # a tuple: one per CPU family
    assert digest in pinned, (f"behaviour changed for {key}: {digest} not in pinned {pinned} "
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
    env = BavoEnv(
        task="cube_handoff",
        condition=condition,
        episode_length=None if length == "full" else int(length),
        compute_cvg=condition == "random",
        **SMALL,
    )
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
