"""`bavo-view` (lerobot_bavo.viz): the .rrd of a dataset episode and of a `bavo-eval` episode, read back with
rerun's own reader (`rerun.experimental.RrdReader`; rerun 0.33 has no `rerun.dataframe`), and LeRobot's own
tools (`lerobot-info`, `lerobot-dataset-viz`) on a BAVO dataset.

Data: a 2-episode Stage dataset (48 x 64 images, 32 points, 30 steps, as in test_datasets.py) and a real
1-episode `bavo-eval` run of the scripted expert (Cube Handoff, Stage, default image size).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest

from lerobot_bavo.datasets import schema as S
from lerobot_bavo.viz import entities as E

REPO = Path(__file__).resolve().parents[1]
SETTINGS = S.ObservationSettings(image_height=48, image_width=64, n_points=32)
STEPS = 30
REPO_ID = "tester/bavo_view"


# ----------------------------------------------------------------------------- reading an .rrd back
class Rrd:
    """Everything in an .rrd, per entity path: its archetypes and, per frame_index, its component values."""

    def __init__(self, path: Path):
        from rerun.experimental import RrdReader

        self.archetypes: dict[str, set[str]] = defaultdict(set)
        self.static: dict[str, dict[str, object]] = defaultdict(dict)
        self.frames: dict[str, dict[int, dict[str, object]]] = defaultdict(lambda: defaultdict(dict))
        for chunk in RrdReader(path).stream().to_chunks():
            path_ = chunk.entity_path.lstrip("/")
            rb = chunk.to_record_batch()
            for f in rb.schema:
                meta = f.metadata or {}
                if b"rerun:archetype" in meta:
                    self.archetypes[path_].add(meta[b"rerun:archetype"].decode().rsplit(".", 1)[-1])
            data = [f.name for f in rb.schema if (f.metadata or {}).get(b"rerun:kind") == b"data"]
            if "frame_index" not in rb.schema.names:
                for name in data:
                    self.static[path_][name] = rb.column(name)[0].as_py()
                continue
            frames = rb.column("frame_index").to_pylist()
            for name in data:
                values = rb.column(name).to_pylist()
                for k, v in zip(frames, values, strict=True):
                    if v is not None:
                        self.frames[path_][k][name] = v

    def at(self, path: str, k: int, component: str):
        return self.frames[path][k][component]


def _mat3(values) -> np.ndarray:
    """rerun's Mat3x3 is stored column-major."""
    return np.asarray(values, dtype=np.float64).reshape(3, 3).T


def _rgba(values) -> np.ndarray:
    """Rgba32 (0xRRGGBBAA integers) -> (n, 3) floats in [0, 1]."""
    c = np.asarray(values, dtype=np.uint64)
    return np.stack([(c >> 24) & 255, (c >> 16) & 255, (c >> 8) & 255], axis=1) / 255.0


# ----------------------------------------------------------------------------- a dataset episode
@pytest.fixture(scope="module")
def dataset_root(tmp_path_factory) -> Path:
    from lerobot_bavo.datasets.collect import CollectConfig, collect

    root = tmp_path_factory.mktemp("ds") / "bavo_view"
    cfg = CollectConfig(
        task="cube_handoff",
        condition="stage",
        episodes=2,
        repo_id=REPO_ID,
        root=root,
        workers=0,
        commit_every=2,
        settings=SETTINGS,
        episode_length=STEPS,
        keep_failures=True,
        progress=False,
    )
    assert collect(cfg)["episodes"] == 2
    return root


@pytest.fixture(scope="module")
def dataset_rrd(dataset_root, tmp_path_factory) -> Path:
    from lerobot_bavo.viz.cli import main

    out = tmp_path_factory.mktemp("view") / "ep1.rrd"
    assert main(["--root", str(dataset_root), "--episode", "1", "--save", str(out), "--teacher",
                 "--relation-point", "3"]) == 0
    return out


def test_dataset_episode_rrd_entities_cloud_and_camera(dataset_root, dataset_rrd):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    rrd = Rrd(dataset_rrd)
    expected = {
        "world": {"ViewCoordinates"},
        E.CLOUD: {"Points3D"},
        E.CAMERA: {"Transform3D"},
        E.PINHOLE: {"Pinhole"},
        E.RGB: {"EncodedImage"},
        E.CAMERA_PATH: {"LineStrips3D"},
        E.OCCLUDER: {"Boxes3D"},
        E.TEACHER_QUERIES: {"Arrows3D"},
        E.RELATION: {"Points3D"},
        E.VISIBILITY: {"Scalars", "SeriesLines"},
        E.PROGRESS: {"Scalars", "SeriesLines"},
        E.RECOVERING: {"Scalars", "SeriesLines"},
        E.EVENT_MARKERS: {"Scalars", "SeriesPoints"},
        E.EVENTS: {"TextLog"},
        **{f"{E.MILESTONES}/m{i}": {"Scalars", "SeriesLines"} for i in range(1, 6)},
    }
    for path, archetypes in expected.items():
        assert archetypes <= rrd.archetypes[path], (path, rrd.archetypes.get(path))
    assert "world/policy" not in "".join(rrd.archetypes)  # datasets have no predicted chunks

    ds = LeRobotDataset(REPO_ID, root=dataset_root, episodes=[1])
    start = int(ds.meta.episodes[1]["dataset_from_index"])
    assert sorted(rrd.frames[E.CLOUD]) == list(range(STEPS))
    for k in (0, 7, STEPS - 1):
        item = ds[k]
        assert int(item["episode_index"]) == 1 and int(item["index"]) == start + k
        cloud = S.unflatten_point_cloud(item[S.OBS_POINT_CLOUD].numpy(), SETTINGS.n_points)
        # the cloud of frame k is the dataset's cloud of frame k (xyz exactly, colours to 8 bits)
        np.testing.assert_array_equal(
            np.asarray(rrd.at(E.CLOUD, k, "Points3D:positions"), np.float32), cloud[:, :3]
        )
        np.testing.assert_allclose(
            _rgba(rrd.at(E.CLOUD, k, "Points3D:colors")), cloud[:, 3:], atol=0.5 / 255 + 1e-6
        )
        # the camera transform of frame k is observation.camera_pose
        pose = S.unflatten_camera_pose(item[S.OBS_CAMERA_POSE].numpy()).astype(np.float64)
        np.testing.assert_allclose(rrd.at(E.CAMERA, k, "Transform3D:translation")[0], pose[:3, 3], atol=1e-6)
        np.testing.assert_allclose(
            _mat3(rrd.at(E.CAMERA, k, "Transform3D:mat3x3")[0]), pose[:3, :3], atol=1e-6
        )
        # the camera path so far ends at the camera
        path = np.asarray(rrd.at(E.CAMERA_PATH, k, "LineStrips3D:strips")[0])
        assert path.shape == (k + 1, 3) and np.allclose(path[-1], pose[:3, 3], atol=1e-6)
        # the occluder box at the recorded pose (Stage: an occluder from the first frame on)
        occ = item[S.ANN_OCCLUDER_POSE].numpy()
        np.testing.assert_allclose(rrd.at(E.OCCLUDER, k, "Boxes3D:centers")[0], occ[:3], atol=1e-6)
        xyzw = np.asarray(rrd.at(E.OCCLUDER, k, "Boxes3D:quaternions")[0])
        assert abs(abs(np.dot(xyzw, np.r_[occ[4:7], occ[3]] / np.linalg.norm(occ[3:7]))) - 1) < 1e-5
        # the teacher's queries start at the cloud's points (z0 is the camera-frame cloud, moved back to the
        # base)
        np.testing.assert_allclose(rrd.at(E.TEACHER_QUERIES, k, "Arrows3D:origins"), cloud[:, :3], atol=1e-4)
        v = float(item[S.ANN_VISIBILITY])
        assert rrd.at(E.VISIBILITY, k, "Scalars:scalars") == pytest.approx([v], abs=1e-6)
        assert rrd.at(E.PROGRESS, k, "Scalars:scalars") == [float(item[S.ANN_PROGRESS])]
    # the event at reset is a marker and a log line; the Pinhole holds the dataset's intrinsics
    assert 0 in rrd.frames[E.EVENT_MARKERS] and "occlusion event 0" in rrd.at(E.EVENTS, 0, "TextLog:text")[0]
    res = rrd.static[E.PINHOLE]["Pinhole:resolution"]
    assert list(res[0]) == [SETTINGS.image_width, SETTINGS.image_height]


def test_a_dataset_without_occluder_poses_is_continued_and_viewed(dataset_root, tmp_path):
    """Datasets collected before `annotation.occluder_pose` existed: `bavo-collect` continues them without the
    column, and `bavo-view` shows them without the occluder box."""
    import shutil

    from lerobot.datasets.dataset_tools import remove_feature
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from lerobot_bavo.datasets.collect import CollectConfig, collect
    from lerobot_bavo.viz.cli import main

    old = tmp_path / "old"
    remove_feature(
        LeRobotDataset(REPO_ID, root=dataset_root), [S.ANN_OCCLUDER_POSE], output_dir=old, repo_id=REPO_ID
    )
    shutil.copy(dataset_root / "meta" / "bavo_collection.json", old / "meta" / "bavo_collection.json")
    cfg = CollectConfig(
        task="cube_handoff",
        condition="stage",
        episodes=3,
        repo_id=REPO_ID,
        root=old,
        workers=0,
        commit_every=1,
        settings=SETTINGS,
        episode_length=STEPS,
        keep_failures=True,
        progress=False,
    )
    assert collect(cfg)["episodes"] == 3
    ds = LeRobotDataset(REPO_ID, root=old)
    assert ds.meta.total_episodes == 3 and S.ANN_OCCLUDER_POSE not in ds.meta.features
    assert (
        main(["--root", str(old), "--episode", "2", "--save", str(tmp_path / "old.rrd"), "--no-images"]) == 0
    )
    rrd = Rrd(tmp_path / "old.rrd")
    assert E.OCCLUDER not in rrd.archetypes and sorted(rrd.frames[E.CLOUD]) == list(range(STEPS))


def test_viewer_imports_stay_light():
    """bavo-view reads the package's own keys and constants; importing it must not import PyTorch or LeRobot
    (that alone would take longer than showing an episode)."""
    # bavo-view's imports stay light: no PyTorch
    code = ("import sys, lerobot_bavo.viz.cli, lerobot_bavo.viz.episode, lerobot_bavo.viz.log; "
            "print('torch' in sys.modules or 'lerobot' in sys.modules)")
    env = dict(os.environ, BAVO_LIGHT_IMPORT="1", PYTHONPATH=str(REPO))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=env)
    assert out.returncode == 0 and out.stdout.strip() == "False", out.stdout + out.stderr


def test_pure_helpers():
    from lerobot_bavo.viz.episode import diverging_colors, milestones_from_progress, relation_row

    flags = milestones_from_progress(np.array([0, 2, 5]))
    assert flags.tolist() == [[False] * 5, [True, True, False, False, False], [True] * 5]
    rng = np.random.default_rng(0)
    z0, zf = rng.normal(size=(6, 3)), rng.normal(size=(6, 3))
    import torch

    from lerobot_bavo.teacher.relations import teacher_relations

    R, dR = teacher_relations(torch.tensor(z0), torch.tensor(zf))
    r, dr = relation_row(z0, zf, 2)
    np.testing.assert_allclose(r, R[2].numpy(), atol=1e-9)
    np.testing.assert_allclose(dr, dR[2].numpy(), atol=1e-9)
    c = diverging_colors(np.array([-1.0, 0.0, 1.0]))
    assert c[1].tolist() == [255, 255, 255] and c[0, 2] > c[0, 0] and c[2, 0] > c[2, 2]


def test_cli_arguments(dataset_root, tmp_path):
    from lerobot_bavo.viz.cli import build_parser, main

    text = build_parser().format_help()
    for flag in ("--save", "--web", "--spawn", "--root", "--repo-id", "--episode", "--rrd", "--teacher",
                 "--relation-point"):
        assert flag in text
    with pytest.raises(SystemExit):
        main(["--episode", "0"])  # no source
    with pytest.raises(SystemExit):
        main(["--root", str(dataset_root), "--web", "--spawn"])
    with pytest.raises(SystemExit):
        main(["--root", str(dataset_root), "--relation-point", "32", "--save", str(tmp_path / "x.rrd")])
    assert main(["--root", str(dataset_root), "--episode", "5", "--save", str(tmp_path / "y.rrd")]) == 2
    # --last-frame: frames 0..K only; the teacher's answers at K + 15 still use the camera pose of K + 15
    assert main(["--root", str(dataset_root), "--last-frame", "4", "--teacher", "--no-images",
                 "--save", str(tmp_path / "z.rrd")]) == 0
    rrd = Rrd(tmp_path / "z.rrd")
    assert sorted(rrd.frames[E.CLOUD]) == sorted(rrd.frames[E.TEACHER_QUERIES]) == [0, 1, 2, 3, 4]
    assert E.RGB not in rrd.archetypes


def test_lerobot_info_and_dataset_viz_work_on_a_bavo_dataset(dataset_root, tmp_path):
    """LeRobot's own CLIs on our installs: no torchcodec traceback (system FFmpeg), `lerobot-dataset-viz`
    saves an .rrd of a BAVO episode (it needs lerobot[viz], a dependency of this package)."""
    bindir = Path(sys.executable).parent
    env = dict(os.environ, HF_HUB_OFFLINE="1", OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    info = subprocess.run(
        [str(bindir / "lerobot-info")], capture_output=True, text=True, timeout=300, env=env
    )
    assert info.returncode == 0, info.stderr[-3000:]
    assert "LeRobot version: 0.6.1" in info.stdout and "FFmpeg version: N/A" not in info.stdout
    assert "Traceback" not in info.stderr and "libtorchcodec" not in info.stderr
    viz = subprocess.run(
        [
            str(bindir / "lerobot-dataset-viz"),
            "--repo-id",
            REPO_ID,
            "--root",
            str(dataset_root),
            "--episode-index",
            "0",
            "--save",
            "1",
            "--output-dir",
            str(tmp_path),
            "--num-workers",
            "0",
        ],
        capture_output=True,
        text=True,
        timeout=300,
        env=env,
    )
    assert viz.returncode == 0, viz.stderr[-3000:]
    assert "Traceback" not in viz.stderr
    saved = list(tmp_path.glob("*.rrd"))
    assert len(saved) == 1 and saved[0].stat().st_size > 10_000
    # why bavo-view exists
    assert "Points3D" not in "".join(a for s in Rrd(saved[0]).archetypes.values() for a in s)


# ----------------------------------------------------------------------------- a bavo-eval episode
@pytest.fixture(scope="module")
def eval_run(tmp_path_factory):
    from lerobot_bavo.eval.cli import main

    out = tmp_path_factory.mktemp("eval")
    main(
        [
            "--policy",
            "expert",
            "--tasks",
            "cube_handoff",
            "--conditions",
            "stage",
            "--episodes",
            "1",
            "--seed",
            "0",
            "--output-dir",
            str(out),
            "--videos",
            "0",
            "--rerun",
            str(out / "videos"),
        ]
    )
    record = json.loads((out / "episodes.jsonl").read_text().splitlines()[0])
    return out, record


def test_eval_episode_rrd_matches_the_rollout(eval_run):
    from lerobot_bavo.envs.bavo_env import BavoEnv

    out, record = eval_run
    path = out / "videos" / "cube_handoff_stage_seed0.rrd"
    assert record["rerun"] == str(path) and path.is_file()
    rrd = Rrd(path)
    for p, archetypes in {
        E.CLOUD: {"Points3D"},
        E.CAMERA: {"Transform3D"},
        E.PINHOLE: {"Pinhole"},
        E.RGB: {"EncodedImage"},
        E.OCCLUDER: {"Boxes3D"},
        E.CAMERA_PATH: {"LineStrips3D"},
        E.VISIBILITY: {"Scalars"},
        E.PROGRESS: {"Scalars"},
        f"{E.MILESTONES}/m5": {"Scalars"},
        E.EVENT_MARKERS: {"Scalars", "SeriesPoints"},
        E.EVENTS: {"TextLog"},
    }.items():
        assert archetypes <= rrd.archetypes[p], (p, rrd.archetypes.get(p))
    T = record["steps"] + 1  # every observation, the final one included
    assert sorted(rrd.frames[E.CLOUD]) == list(range(T))
    # the record carries what the viewer draws: per-step visibility and every placement's pose
    assert len(record["visibility"]) == T
    for k in (0, T // 2, T - 1):
        assert rrd.at(E.VISIBILITY, k, "Scalars:scalars") == pytest.approx(
            [record["visibility"][k]], abs=1e-4
        )
    placements = record["placements"]
    assert [p["step"] for p in placements] == sorted(rrd.frames[E.EVENT_MARKERS])
    for p, nxt in zip(placements, placements[1:] + [None], strict=True):
        for k in (p["step"], (nxt["step"] - 1) if nxt else T - 1):  # the panel stays put until the next event
            np.testing.assert_allclose(
                rrd.at(E.OCCLUDER, k, "Boxes3D:centers")[0], p["occluder_pos"], atol=1e-5
            )
            w, x, y, z = p["occluder_quat"]
            assert abs(abs(np.dot(rrd.at(E.OCCLUDER, k, "Boxes3D:quaternions")[0], [x, y, z, w])) - 1) < 1e-4
    assert rrd.at(E.MILESTONES + "/m5", T - 1, "Scalars:scalars") == [1.0]  # the expert succeeds
    # frame 0 is the reset observation of the seed (checked here by resetting a fresh env; the viewer never
    # does)
    env = BavoEnv("cube_handoff", "stage", render_mode=None)
    try:
        obs, info = env.reset(seed=0)
    finally:
        env.close()
    np.testing.assert_array_equal(np.asarray(rrd.at(E.CLOUD, 0, "Points3D:positions"), np.float32),
                                  obs["point_cloud"][:, :3])
    np.testing.assert_allclose(
        rrd.at(E.CAMERA, 0, "Transform3D:translation")[0], info["camera_pose"][:3, 3], atol=1e-6
    )
    np.testing.assert_allclose(
        _mat3(rrd.at(E.CAMERA, 0, "Transform3D:mat3x3")[0]), info["camera_pose"][:3, :3], atol=1e-6
    )


def test_eval_rrd_has_the_policys_predicted_chunks(tmp_path):
    """A LeRobot checkpoint (the shipped A-FAR) rolled out by bavo-eval's `run_episode` for two chunks: a
    chunk of n_action_steps (12 shipped) joint targets at frames 0 and n: the actions then sent, and the
    grippers' paths."""
    from lerobot_bavo.demo import SHIPPED_CHECKPOINT
    from lerobot_bavo.envs.bavo_env import BavoEnv
    from lerobot_bavo.eval.rollout import env_kwargs_for_policy, make_agent, run_episode

    n_action_steps = json.loads((SHIPPED_CHECKPOINT / "config.json").read_text())["n_action_steps"]
    env = BavoEnv("cube_handoff", "stage", render_mode=None, episode_length=2 * n_action_steps,
                  **env_kwargs_for_policy(str(SHIPPED_CHECKPOINT)))
    try:
        agent = make_agent(str(SHIPPED_CHECKPOINT), env)
        sent = []
        act = agent.act

        def spy(obs, info):
            sent.append(act(obs, info))
            return sent[-1]

        agent.act = spy
        record = run_episode(env, agent, seed=1000, rerun_path=tmp_path / "afar.rrd")
    finally:
        env.close()
    n = agent.policy.config.n_action_steps
    rrd = Rrd(tmp_path / "afar.rrd")
    assert "Tensor" in rrd.archetypes[E.CHUNK]
    assert sorted(rrd.frames[E.CHUNK]) == list(range(0, record["steps"], n))
    for k in rrd.frames[E.CHUNK]:
        tensor = rrd.at(E.CHUNK, k, "Tensor:data")[0]
        chunk = np.asarray(tensor["buffer"], dtype=np.float32).reshape(tensor["shape"])
        assert chunk.shape == (n, 21)
        # the chunk is what was then sent
        np.testing.assert_allclose(chunk, np.stack(sent[k:k + n]), atol=1e-5)
        for arm in ("left", "right", "camera"):
            assert np.asarray(rrd.at(f"{E.CHUNK_PATH}/{arm}", k, "LineStrips3D:strips")[0]).shape == (n, 3)
