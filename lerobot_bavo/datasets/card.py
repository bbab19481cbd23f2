"""Dataset card (README.md locally, the card on the Hub) of a BAVO-Bench demonstration dataset.

The text is LeRobot's own card template (`create_lerobot_dataset_card`, which also embeds
`meta/info.json`) with our description: task, condition, features (teacher semantics included),
how the data was made (command, seeds, counts kept / discarded) and how to load it.
"""

from __future__ import annotations

from pathlib import Path

from lerobot_bavo.datasets import schema as S
from lerobot_bavo.datasets.metadata import read_info, read_sidecar
from lerobot_bavo.datasets.video_codec import recorded_video_codec
from lerobot_bavo.envs.conditions import CONDITIONS

PAPER = ("Recovering the View: Benchmarking Physical Active Vision for Occlusion Recovery in Robotic "
         "Manipulation (BAVO-Bench / A-FAR), arXiv 2609.37292")


_CODEC_NAMES = {"h264": "H.264 (x264)", "libsvtav1": "AV1 (SVT-AV1)"}


def _image_storage(settings: dict) -> str:
    """How the active image is stored: "video, <codec>" (see `video_codec.py`) or "image" (PNG in the
    parquet)."""
    codec = recorded_video_codec(settings)
    return "image" if codec is None else f"video, {_CODEC_NAMES.get(codec, codec)}"


def _feature_rows(settings: dict) -> list[str]:
    n = settings["n_points"]
    h, w = settings["image_height"], settings["image_width"]
    frame = (
        "base (robot-base / world, table top at z = 0)"
        if settings["point_frame"] == "base"
        else "active-camera (OpenCV)"
    )
    return [
        "| key | shape | dtype | meaning |",
        "|---|---|---|---|",
        f"| `{S.OBS_STATE}` | (21,) | float32 | joint state: left arm 6 + gripper, right arm 6 + gripper, "
        "camera arm 7 (rad; grippers 0 closed .. 1 open) |",
        f"| `{S.ACTION}` | (21,) | float32 | absolute joint targets (same order) sent after this frame's "
        "observation; 25 Hz |",
        f"| `{S.OBS_IMAGE}` | ({h}, {w}, 3) | {_image_storage(settings)} | active-camera RGB (the camera "
        "rides on the 7-DoF camera arm) |",
        f"| `{S.OBS_POINT_CLOUD}` | ({n * 6},) | float32 | ({n}, 6) row-major: xyz in the {frame} frame (m) "
        f"+ rgb in [0, 1]; {n} farthest-point samples of the workspace crop |",
        f"| `{S.OBS_POINT_PIXELS}` | ({n * 2},) | float32 | ({n}, 2) row-major: source pixel (u = column, v "
        "= row) of each point; -1 for an empty view |",
        f"| `{S.OBS_CAMERA_POSE}` | (16,) | float32 | T_B<-C (4 x 4 row-major): camera-to-base transform, "
        "OpenCV camera axes (x right, y down, z forward) |",
        f"| `{S.TEACHER_Z0}` | ({n * 3},) | float32 | ({n}, 3): 4D-teacher answer to q0 = (u, v, t, t, t) "
        "for every point: the point in the camera frame of t (m) |",
        f"| `{S.TEACHER_ZF}` | ({n * 3},) | float32 | ({n}, 3): answer to qF = (u, v, t, t+15, t+15): where "
        "that surface point is 15 steps (0.6 s) later, in the camera frame of t+15 |",
        f"| `{S.TEACHER_VISIBLE}` | ({n},) | float32 | 1 if the point is still the first surface along its "
        "ray at t+15 (not occluded, inside the image) |",
        f"| `{S.TEACHER_VALID}` | (1,) | float32 | 1 if frame t+15 exists; 0 in the last 15 frames, where "
        "t+15 is clamped to the last frame |",
        f"| `{S.ANN_PROGRESS}` | (1,) | int64 | milestone depth 0..5 reached so far (5 = success) |",
        f"| `{S.ANN_EVENT}` | (1,) | int64 | index of the current occlusion event (-1: none) |",
        f"| `{S.ANN_EVENT_START}` | (1,) | float32 | 1 at the frame an occlusion event starts |",
        f"| `{S.ANN_ACTIVE}` | (1,) | float32 | 1 while the demonstrator recovers the view after an event |",
        f"| `{S.ANN_TARGET}` | (1,) | int64 | stage index s of the occluded target (`stage_targets[s]`), -1: "
        "none |",
        f"| `{S.ANN_VISIBILITY}` | (1,) | float32 | visible fraction V of the current target (privileged "
        "render), -1 under Clean |",
        f"| `{S.ANN_SEED}` | (1,) | int64 | episode seed (env layout, occlusion schedule, expert timing) |",
        f"| `{S.ANN_SOURCE}` | (1,) | int64 | demonstrator: 0 = scripted expert, 1 = human (browser "
        "teleoperation) |",
        f"| `{S.ANN_OCCLUDER_POSE}` | (7,) | float32 | occluder panel centre (m, base frame) + wxyz "
        "quaternion; 0: none |",
    ]


def card_description(sidecar: dict, repo_id: str) -> str:
    """Markdown body describing the dataset, from the collection record `meta/bavo_collection.json`."""
    st = sidecar["settings"]
    kept = sidecar.get("episodes", [])
    discarded = sidecar.get("discarded", [])
    seeds = [e["seed"] for e in kept]
    frames = sum(e["length"] for e in kept)
    stage_targets = st.get("stage_targets") or []
    condition = CONDITIONS.get(st["condition"])
    condition_text = (
        condition.description if condition is not None and condition.description else st["condition"]
    )
    lines = [
        f"# BAVO-Bench demonstrations: `{st['task']}` under {st['condition']} occlusion",
        "",
        f"Task: *{st.get('task_description', st['task'])}* Condition: {condition_text}",
        "",
        f"Stage targets (`annotation.occlusion_target` indexes them): "
        f"{', '.join(f'{i}: {t}' for i, t in enumerate(stage_targets))}.",
        "",
        "Bimanual manipulation with physical active vision: two 6-DoF arms with parallel grippers and a "
        "7-DoF camera "
        "arm carrying the only (RGB-D) camera, simulated in MuJoCo by "
        "lerobot-bavo (distribution `lerobot_env_bavo`, a LeRobot plugin). "
        f"Paper: {PAPER}.",
        "",
        "## Contents",
        "",
        f"- {len(kept)} "
        + ("scripted-expert episodes (unsuccessful ones kept: --keep-failures), " if st.get("keep_failures")
           else "successful scripted-expert episodes, ")
        + f"{frames} frames at {st.get('fps', S.FPS)} fps "
        f"(seeds {min(seeds) if seeds else '-'}..{max(seeds) if seeds else '-'}); "
        f"{len(discarded)} unsuccessful attempts were discarded"
        + (
            f" (seeds "
            f"{', '.join(str(d['seed']) for d in discarded[:20])}{' ...' if len(discarded) > 20 else ''})."
            if discarded
            else "."
        ),
        *(
            [
                f"- DART-style execution noise: the env executed the expert's arm joint targets plus an "
                "AR(1) offset "
                f"(std {st['execution_noise']['std']} rad, correlation "
                f"{st['execution_noise']['correlation']} per step; "
                "grippers and camera untouched"
                + (
                    "; none in the expert's contact phases"
                    if st["execution_noise"].get("clean_contacts")
                    else ""
                )
                + "); `action` holds the expert's clean targets."
            ]
            if st.get("execution_noise")
            else []
        ),
        *(
            ["- Occlusion events that fell due during the expert's approach, grasp or release phases waited "
             "until the phase was over (`--events-outside-contacts`): no demonstration has an interrupted "
             "grasp or release."]
            if st.get("events_outside_contacts")
            else []
        ),
        *(
            [f"- {st['decoy_panels']} decoy panel(s) in the scene (`--decoy-panels`): copies of the "
             "occluder, re-drawn at every occlusion event where they leave the current target visible. A "
             "data variant; the benchmark has none."]
            if st.get("decoy_panels")
            else []
        ),
        *(
            ["- The expert grasped square to the table's axes (`--square-grasps`: wrist yaw 0, the closing "
             "fingers turn the object) instead of turning to the object's faces. A data variant."]
            if st.get("square_grasps")
            else []
        ),
        f"- Observation: {st['image_height']} x {st['image_width']} RGB, {st['n_points']} points per cloud, "
        f"vertical field of view {st['fovy']} deg (intrinsics f = H / (2 tan(fovy / 2)), principal point at "
        "the image centre).",
        "- Array features are stored flat (LeRobot's edit tools do not handle 2-D features): reshape with "
        "`lerobot_bavo.datasets.schema.unflatten_point_cloud(x, N)` etc. The `observation.point_cloud` "
        "statistics in "
        "`meta/stats.json` are per channel (xyz rgb over all points), tiled to the flat layout.",
        "",
        "## Features",
        "",
        *_feature_rows(st),
        "",
        "`annotation.*` columns are for analysis only: LeRobot never passes them to a policy. "
        "`observation.teacher.*` "
        "are training targets for A-FAR; the policies remove them from their inputs, so evaluation does not "
        "need them.",
        "",
        "## The 4D teacher targets",
        "",
        "A-FAR distils relations among point-aligned features of a 4D teacher queried D4RT-style with "
        "q = (u, v, t_src, t_tgt, t_cam) on a 32-frame clip around each frame t (anchor index 16, future "
        "index 31, "
        "Delta t = 15; paper App. B), at the source pixels of the frame's point cloud. D4RT/OpenD4RT weights "
        "cannot be "
        "obtained offline, so these targets come from the **simulator-exact teacher**: the exact answer D4RT "
        "is trained "
        "to predict. The seen surface point is back-projected from depth, attached to the body seen at that "
        "pixel "
        "(segmentation), moved rigidly with that body from t to t_tgt and expressed in the camera frame of "
        "t_cam "
        "(metres, OpenCV axes). Relations (paper Eq. 4) are computed from `z0`/`zf` in the loss. Near the "
        "episode end "
        "the clip is clamped (future frames repeat the last frame) and `observation.teacher.valid` is 0.",
        "",
        "## How it was made",
        "",
        "```bash",
        sidecar.get(
            "command",
            f"bavo-collect --task {st['task']} --condition {st['condition']} --episodes {len(kept)} "
            f"--repo-id {repo_id}",
        ),
        "```",
        "",
        "Episodes are seeded (`annotation.episode_seed`): the seed fixes the object layout, the occlusion "
        "schedule "
        "and the expert's timing jitter. Only successful episodes (milestone M5 reached) are kept, in seed "
        "order. "
        "Demonstration seeds start at "
        f"{st.get('base_seed', 0)}; `bavo-eval` / `lerobot-eval` seeds start at 1000.",
        "",
        "## Loading",
        "",
        "```python",
        "from lerobot.datasets.lerobot_dataset import LeRobotDataset",
        f"ds = LeRobotDataset(\"{repo_id}\", video_backend=\"pyav\",",
        "                    delta_timestamps={\"observation.state\": [-0.04, 0.0], "
        "\"observation.point_cloud\": [-0.04, 0.0],",
        "                                      \"action\": [i / 25 for i in range(16)]})",
        "```",
        "",
        "Offline: `HF_HUB_OFFLINE=1` and `LeRobotDataset(repo_id, root=<local folder>)`; "
        "`lerobot_bavo.datasets.load_bavo_dataset` adds schema and file checks. Training: "
        f"`lerobot-train --dataset.repo_id={repo_id} --dataset.video_backend=pyav --policy.type=afar ...`.",
    ]
    return "\n".join(lines)


def card_kwargs_for(root: str | Path, repo_id: str) -> dict:
    """Keyword arguments for LeRobot's `push_to_hub` / `create_lerobot_dataset_card`."""
    sidecar = read_sidecar(root)
    if sidecar is None:
        raise ValueError(
            f"{root} has no collection record (meta/bavo_collection.json): not made by bavo-collect"
        )
    st = sidecar["settings"]
    return {
        "tags": [
            "bavo-bench",
            "active-vision",
            "occlusion",
            "bimanual",
            "simulation",
            st["task"],
            f"{st['condition']}-occlusion",
        ],
        "dataset_description": card_description(sidecar, repo_id),
        "license": "apache-2.0",
        "paper": PAPER,
    }


def write_card(root: str | Path, repo_id: str) -> Path:
    """Render the card with LeRobot's template and save it as `<root>/README.md`: what LeRobot's
    `create_lerobot_dataset_card(tags, dataset_info, repo_id=..., **card_kwargs_for(...))` renders, built
    here with `huggingface_hub` and LeRobot's template file so that `bavo-collect`'s writing process never
    imports LeRobot (its dataset modules import PyTorch; `tests/test_lerobot_format.py` compares the two)."""
    import json

    from huggingface_hub import DatasetCard, DatasetCardData

    from lerobot_bavo.datasets.lerobot_format import card_template, normalized_info

    root = Path(root)
    kwargs = card_kwargs_for(root, repo_id)
    tags = kwargs.pop("tags")
    info = normalized_info(read_info(root))
    kwargs["dataset_structure"] = (
        f"[meta/info.json](meta/info.json):\n```json\n{json.dumps(info, indent=4)}\n```\n")
    card_data = DatasetCardData(license=kwargs.get("license"), tags=["LeRobot", *tags],
                                task_categories=["robotics"],
                                configs=[{"config_name": "default", "data_files": "data/*/*.parquet"}])
    card = DatasetCard.from_template(card_data=card_data, template_str=card_template(), repo_id=repo_id,
                                     **kwargs)
    path = root / "README.md"
    card.save(str(path))
    return path
