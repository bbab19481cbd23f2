"""BAVO datasets: schema, round trip through LeRobot, LeRobot's edit tools, resume, clear errors.

Small real datasets: the scripted expert on Cube Handoff under Stage occlusion, 48 x 64 images,
32 points, episodes truncated at 30 steps (kept with `keep_failures`), written by the collector
in this process (`workers=0`).
"""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import torch
from _helpers import SMALL_SETTINGS

from lerobot_bavo.datasets import schema as S
from lerobot_bavo.datasets.collect import CollectConfig, CollectionError, Collector, collect
from lerobot_bavo.datasets.hub import check_files, load_bavo_dataset, read_sidecar
from lerobot_bavo.features import flatten_points

SETTINGS = SMALL_SETTINGS
STEPS = 30
REPO = "tester/bavo_tiny"


def _config(root: Path, episodes: int, **kw) -> CollectConfig:
    base = dict(task="cube_handoff", condition="stage", episodes=episodes, repo_id=REPO, root=root, workers=0,
                commit_every=1, settings=SETTINGS, episode_length=STEPS, keep_failures=True, progress=False)
    base.update(kw)
    return CollectConfig(**base)


@pytest.fixture(scope="module")
def dataset_root(tmp_path_factory) -> Path:
    """2 episodes (seeds 0, 1), one LeRobot writer session each (so 2 data / video / episode files)."""
    root = tmp_path_factory.mktemp("ds") / "bavo_tiny"
    summary = collect(_config(root, episodes=2))
    assert summary["episodes"] == 2 and summary["frames"] == 2 * STEPS and summary["discarded"] == 0
    return root


def _copy(root: Path, tmp_path: Path, name: str = "copy") -> Path:
    dst = tmp_path / name
    shutil.copytree(root, dst)
    return dst


# ----------------------------------------------------------------------------- schema
def test_schema_flat_layouts_and_reshape_helpers():
    feats = S.build_features(SETTINGS)
    assert all(len(ft["shape"]) == 1 for k, ft in feats.items() if k != S.OBS_IMAGE)  # no 2-D features
    assert feats[S.OBS_POINT_CLOUD]["shape"] == (32 * 6,) and feats[S.TEACHER_Z0]["shape"] == (32 * 3,)
    assert feats[S.OBS_IMAGE]["dtype"] == "video" and feats[S.OBS_IMAGE]["shape"] == (48, 64, 3)
    assert S.check_features(feats) == 32
    x = np.arange(2 * 5 * 32 * 6, dtype=np.float32).reshape(2, 5, 32 * 6)
    pc = S.unflatten_point_cloud(x, 32)
    assert pc.shape == (2, 5, 32, 6) and pc[1, 2, 3, 4] == x[1, 2, 3 * 6 + 4]
    assert S.unflatten_point_cloud(pc, 32) is pc  # already (N, 6): unchanged (env observations)
    np.testing.assert_array_equal(flatten_points(pc), x)
    import torch

    t = torch.from_numpy(x)
    assert tuple(S.unflatten_teacher(t[..., :96], 32).shape) == (2, 5, 32, 3)
    assert tuple(S.unflatten_camera_pose(torch.zeros(3, 16)).shape) == (3, 4, 4)
    with pytest.raises(ValueError, match="expected"):
        S.unflatten_point_cloud(x[..., :-1], 32)


# ----------------------------------------------------------------------------- round trip
def test_round_trip_with_delta_timestamps(dataset_root):
    """Create (collector), finalize, reload; 2 observation steps and 16 actions, as ManiFlow / A-FAR load
    them."""
    from lerobot_bavo.datasets.recording import EpisodeRecorder, episode_frames
    from lerobot_bavo.teacher import teacher_targets

    delta = {
        S.OBS_STATE: [-0.04, 0.0], S.OBS_POINT_CLOUD: [-0.04, 0.0], S.TEACHER_Z0: [-0.04, 0.0],
        S.TEACHER_ZF: [-0.04, 0.0], S.TEACHER_VALID: [-0.04, 0.0], S.OBS_IMAGE: [-0.04, 0.0],
        S.ACTION: [i / 25 for i in range(16)],
    }
    ds = load_bavo_dataset(REPO, root=dataset_root, n_points=32, delta_timestamps=delta)
    assert ds.num_episodes == 2 and len(ds) == 2 * STEPS and ds.fps == 25
    assert ds.meta.info.features.keys() == S.build_features(SETTINGS, env_state_dim=14).keys() | {
        "timestamp", "frame_index", "episode_index", "index", "task_index"}

    item = ds[0]  # first frame of episode 0: the previous observation is padding
    assert tuple(item[S.OBS_STATE].shape) == (2, 21) and tuple(item[S.ACTION].shape) == (16, 21)
    assert tuple(item[S.OBS_POINT_CLOUD].shape) == (2, 32 * 6) and tuple(item[S.TEACHER_Z0].shape) == (2, 96)
    assert tuple(item[S.OBS_IMAGE].shape) == (2, 3, 48, 64)
    assert item[f"{S.OBS_STATE}_is_pad"].tolist() == [True, False] and not item[f"{S.ACTION}_is_pad"].any()
    last = ds[STEPS - 1]  # last frame of episode 0: actions beyond the end are padding
    assert last[f"{S.ACTION}_is_pad"].sum() == 15 and last[S.TEACHER_VALID].tolist() == [0.0, 0.0]

    # The stored values are the recorded ones (episodes are deterministic per seed).
    rec = EpisodeRecorder("cube_handoff", "stage", SETTINGS, episode_length=STEPS)
    try:
        record = rec.record(seed=1)
    finally:
        rec.close()
    cols = episode_frames(record, teacher_targets(record))
    t = 7
    item = ds[STEPS + t]  # episode 1, frame 7
    assert int(item["episode_index"]) == 1 and int(item["frame_index"]) == t
    for key in (S.OBS_STATE, S.OBS_POINT_CLOUD, S.TEACHER_Z0, S.TEACHER_ZF):
        np.testing.assert_allclose(item[key][-1].numpy(), cols[key][t], atol=1e-6)
        np.testing.assert_allclose(item[key][0].numpy(), cols[key][t - 1], atol=1e-6)
    # the privileged object poses (cube, plate: xyz + wxyz each) are those of the simulator at that frame
    np.testing.assert_allclose(ds.hf_dataset[STEPS + t][S.OBS_ENV_STATE], cols[S.OBS_ENV_STATE][t], atol=1e-6)
    assert cols[S.OBS_ENV_STATE].shape == (STEPS, 14)
    np.testing.assert_allclose(np.linalg.norm(cols[S.OBS_ENV_STATE][:, 3:7], axis=1), 1.0, atol=1e-5)
    np.testing.assert_allclose(item[S.ACTION].numpy(), cols[S.ACTION][t:t + 16], atol=1e-6)
    raw = ds.hf_dataset[STEPS + t]
    assert raw[S.ANN_SEED] == 1 and raw[S.ANN_EVENT] == cols[S.ANN_EVENT][t, 0]
    np.testing.assert_allclose(np.asarray(raw[S.OBS_POINT_PIXELS]), cols[S.OBS_POINT_PIXELS][t])
    # Video frames decode (pyav) close to the recorded images (lossy video: x264 by default).
    img = (item[S.OBS_IMAGE][-1].permute(1, 2, 0).numpy() * 255.0)
    assert np.abs(img - record.rgb[t].astype(np.float64)).mean() < 12.0


def test_annotations_never_reach_a_policy(dataset_root):
    from lerobot.configs import FeatureType
    from lerobot.processor.converters import batch_to_transition
    from lerobot.utils.feature_utils import dataset_to_policy_features

    ds = load_bavo_dataset(REPO, root=dataset_root)
    pf = dataset_to_policy_features(ds.meta.features)
    assert not any(k.startswith("annotation.") for k in pf)
    assert pf[S.TEACHER_Z0].type is FeatureType.STATE and pf[S.ACTION].type is FeatureType.ACTION
    batch = {k: v for k, v in ds[3].items() if k != "task"}
    transition = batch_to_transition(batch)
    kept = set(transition["observation"]) | set(transition.get("complementary_data") or {})
    assert S.TEACHER_ZF in kept and not any(k.startswith("annotation.") for k in kept)


def test_collection_record_card_and_stats(dataset_root):
    rec = read_sidecar(dataset_root)
    assert [e["seed"] for e in rec["episodes"]] == [0, 1] and rec["discarded"] == [] and rec["complete"]
    assert rec["pending_commit"] is None and not (dataset_root / ".bavo_staging").exists()
    assert rec["settings"]["n_points"] == 32 and rec["settings"]["teacher"]["n_future"] == 15
    card = (dataset_root / "README.md").read_text()
    assert "cube_handoff" in card and "Stage Occlusion" in card and "observation.teacher.zf" in card
    assert "simulator-exact" in card and "0 unsuccessful attempts were discarded" in card
    stats = json.loads((dataset_root / "meta" / "stats.json").read_text())[S.OBS_POINT_CLOUD]
    for key in ("min", "max", "mean", "std", "q01", "q99"):
        per_point = np.asarray(stats[key]).reshape(32, 6)
        np.testing.assert_allclose(per_point, np.tile(per_point[0], (32, 1)))  # per channel, tiled
    assert np.allclose(np.asarray(stats["min"])[3:6], 0.0, atol=0.3) and np.asarray(stats["max"])[2] < 0.61


# ----------------------------------------------------------------------------- LeRobot's tools
def test_lerobot_delete_and_merge_work_on_our_datasets(dataset_root, tmp_path):
    from lerobot.datasets.dataset_tools import delete_episodes, merge_datasets

    ds = load_bavo_dataset(REPO, root=dataset_root)
    kept = delete_episodes(ds, episode_indices=[0], output_dir=tmp_path / "deleted", repo_id="tester/deleted")
    kept = load_bavo_dataset("tester/deleted", root=tmp_path / "deleted")
    assert kept.num_episodes == 1 and len(kept) == STEPS
    assert kept.hf_dataset[0][S.ANN_SEED] == 1 and kept[0][S.OBS_POINT_CLOUD].shape == (32 * 6,)

    other_root = _copy(dataset_root, tmp_path, "other")
    other = load_bavo_dataset("tester/other", root=other_root)
    merged = merge_datasets([ds, other], output_repo_id="tester/merged", output_dir=tmp_path / "merged")
    merged = load_bavo_dataset("tester/merged", root=tmp_path / "merged")
    assert merged.num_episodes == 4 and len(merged) == 4 * STEPS
    assert [merged.hf_dataset[i * STEPS][S.ANN_SEED] for i in range(4)] == [0, 1, 0, 1]
    _ = merged[3 * STEPS + 5][S.OBS_IMAGE]  # videos of the merged dataset decode


# ----------------------------------------------------------------------------- errors
def test_corrupted_or_mismatched_datasets_give_clear_errors(dataset_root, tmp_path):
    with pytest.raises(FileNotFoundError, match="no LeRobot dataset"):
        load_bavo_dataset(REPO, root=tmp_path / "nothing")
    with pytest.raises(ValueError, match=r"32 points per cloud .* but 256 were requested"):
        load_bavo_dataset(REPO, root=dataset_root, n_points=256)

    # A truncated data file (e.g. a writer killed before finalize()).
    bad = _copy(dataset_root, tmp_path, "truncated")
    data_file = sorted((bad / "data").glob("*/*.parquet"))[-1]
    data_file.write_bytes(data_file.read_bytes()[: data_file.stat().st_size // 2])
    with pytest.raises(ValueError, match=f"corrupted data file .*{data_file.name}"):
        load_bavo_dataset(REPO, root=bad)

    # Corrupted metadata.
    bad = _copy(dataset_root, tmp_path, "badinfo")
    (bad / "meta" / "info.json").write_text("{ not json")
    with pytest.raises(ValueError, match="corrupted dataset metadata .*info.json"):
        load_bavo_dataset(REPO, root=bad)

    # A video that is not a video.
    bad = _copy(dataset_root, tmp_path, "badvideo")
    video = sorted((bad / "videos").glob("*/*/*.mp4"))[0]
    video.write_bytes(b"\x00" * 1000)
    with pytest.raises(ValueError, match=f"corrupted video file .*{video.name}"):
        load_bavo_dataset(REPO, root=bad)

    def edited(name, edit):
        root = _copy(dataset_root, tmp_path, name)
        info = json.loads((root / "meta" / "info.json").read_text())
        edit(info["features"])
        (root / "meta" / "info.json").write_text(json.dumps(info))
        return root

    no_teacher = edited("noteacher", lambda f: [f.pop(k) for k in S.TEACHER_KEYS])
    with pytest.raises(ValueError, match="missing teacher cache"):
        load_bavo_dataset(REPO, root=no_teacher)
    no_pose = edited("nopose", lambda f: f.pop(S.OBS_CAMERA_POSE))
    with pytest.raises(ValueError, match="missing feature 'observation.camera_pose'"):
        load_bavo_dataset(REPO, root=no_pose)
    wrong = edited("wrongwidth", lambda f: f[S.TEACHER_ZF].update(shape=[32 * 4]))
    with pytest.raises(ValueError, match="point-aligned with the same width"):
        load_bavo_dataset(REPO, root=wrong)
    wrong = edited("wrongshape", lambda f: f[S.OBS_POINT_PIXELS].update(shape=[50]))
    with pytest.raises(ValueError, match=r"'observation.point_pixels' has shape \(50,\), expected \(64,\)"):
        load_bavo_dataset(REPO, root=wrong)
    wrong = edited("wrongdtype", lambda f: f[S.ANN_PROGRESS].update(dtype="float32"))
    with pytest.raises(ValueError, match="'annotation.progress' has dtype 'float32', expected 'int64'"):
        load_bavo_dataset(REPO, root=wrong)
    unflat = edited("twod", lambda f: f[S.OBS_POINT_CLOUD].update(shape=[32, 6]))
    with pytest.raises(ValueError, match="flat layout"):
        load_bavo_dataset(REPO, root=unflat)

    # A finished collection whose upload fails (here: offline, no login) says so and loses nothing.
    offline = _copy(dataset_root, tmp_path, "offline")
    with pytest.raises(CollectionError, match="upload .* failed.*hf auth login"):
        collect(_config(offline, episodes=2, push_to_hub=True))
    assert load_bavo_dataset(REPO, root=offline).num_episodes == 2

    # Two collections never write one dataset at the same time.
    busy = _copy(dataset_root, tmp_path, "busy")
    lock = Collector(_config(busy, episodes=3)).lock()
    try:
        with pytest.raises(CollectionError, match="another bavo-collect is writing"):
            collect(_config(busy, episodes=3))
    finally:
        lock.close()

    # Continuing a collection with other settings is refused.
    other = _copy(dataset_root, tmp_path, "settings")
    with pytest.raises(CollectionError, match="other settings .*n_points"):
        collect(_config(other, episodes=3, settings=S.ObservationSettings(48, 64, 16)))
    with pytest.raises(CollectionError, match="not a LeRobot dataset"):
        (tmp_path / "junk").mkdir()
        (tmp_path / "junk" / "file.txt").write_text("x")
        collect(_config(tmp_path / "junk", episodes=1))


# ----------------------------------------------------------------------------- resume
class _Killed(BaseException):
    """Stands in for SIGKILL: nothing after it runs (the rollback is disabled for that run)."""


def _discard_odd_seeds(real_run_job):
    """A run_job that reports odd seeds as unsuccessful (to exercise discarding)."""

    def run(job):
        summary = real_run_job(job)
        if summary["seed"] % 2:
            staging = Path(job["staging"])
            (staging / f"seed_{summary['seed']:08d}.npz").unlink(missing_ok=True)
            summary.update(success=False, kept=False)
            (staging / f"seed_{summary['seed']:08d}.json").write_text(json.dumps(summary))
        return summary

    return run


def test_an_option_recorded_only_when_used_must_match_too(tmp_path):
    """The settings check compares both sides' keys: a dataset recorded with execution noise (an entry only
    noisy records have) is not continued by a run without it, nor a human (teleop) dataset by the expert."""
    from lerobot_bavo.experts.perturbation import ExecutionNoise

    root = tmp_path / "noisy"
    collect(_config(root, 1, execution_noise=ExecutionNoise(std=0.01)))
    with pytest.raises(CollectionError, match=r"execution_noise: dataset \{'std': 0.01.*\} vs now None"):
        collect(_config(root, 2))
    record = read_sidecar(root)
    record["settings"]["source"] = "human"
    record["settings"].pop("execution_noise")
    (root / "meta" / "bavo_collection.json").write_text(json.dumps(record))
    with pytest.raises(CollectionError, match=r"source: dataset 'human' vs now None"):
        collect(_config(root, 2))


def test_resume_after_a_kill_inside_a_commit(tmp_path, monkeypatch):
    """Kill while the second writer session is half written; the next run rolls it back and finishes
    with exactly the requested episodes: unique seeds, in order, discards recorded, nothing re-run."""
    import lerobot_bavo.datasets.collect as collect_mod
    from lerobot_bavo.datasets import lerobot_format

    monkeypatch.setattr(collect_mod, "run_job", _discard_odd_seeds(collect_mod.run_job))
    root = tmp_path / "resumed"
    cfg = _config(root, episodes=4, commit_every=2, episode_length=20)

    real_table = lerobot_format.episode_table  # the writer builds each episode's rows with it
    calls = {"n": 0}

    def dying_table(*a, **kw):
        calls["n"] += 1
        if calls["n"] == 4:  # episodes 0, 1 committed; episode 2 written; die while writing episode 3
            raise _Killed()
        return real_table(*a, **kw)

    with monkeypatch.context() as m:
        m.setattr(lerobot_format, "episode_table", dying_table)
        m.setattr(Collector, "rollback", lambda self: None)
        with pytest.raises(_Killed):
            collect(cfg)
    rec = read_sidecar(root)
    assert rec["pending_commit"] == {"seeds": [4, 6], "next_seed": 7}
    assert [e["seed"] for e in rec["episodes"]] == [0, 2]
    # the half-written session left its files (not named by the committed metadata, which is unchanged)
    assert (root / "data" / "chunk-000" / "file-001.parquet").exists()
    assert json.loads((root / "meta" / "info.json").read_text())["total_episodes"] == 2

    summary = collect(cfg)
    assert summary["episodes"] == 4 and summary["attempts_this_run"] == 0  # staged episodes reused
    rec = read_sidecar(root)
    assert [e["seed"] for e in rec["episodes"]] == [0, 2, 4, 6]
    assert [e["episode_index"] for e in rec["episodes"]] == [0, 1, 2, 3]
    assert [d["seed"] for d in rec["discarded"]] == [1, 3, 5]
    ds = load_bavo_dataset(REPO, root=root)
    assert ds.num_episodes == 4 and len(ds) == 4 * 20
    seeds = [ds.hf_dataset[i * 20][S.ANN_SEED] for i in range(4)]
    assert seeds == [0, 2, 4, 6]
    assert sorted({int(s) for s in ds.hf_dataset[S.ANN_SEED]}) == [0, 2, 4, 6]
    assert "discarded" in (root / "README.md").read_text()

    # Asking for more later continues with new seeds only.
    summary = collect(_config(root, episodes=5, commit_every=2, episode_length=20))
    assert summary["episodes"] == 5 and summary["new_this_run"] == 1
    assert [e["seed"] for e in read_sidecar(root)["episodes"]] == [0, 2, 4, 6, 8]
    # Asking for fewer or as many: nothing to do.
    assert collect(_config(root, episodes=5, commit_every=2, episode_length=20))["attempts_this_run"] == 0


# ----------------------------------------------------------------------------- a learned teacher
class _PixelTeacher:
    """A stand-in learned teacher (RGB clip in, features out): answers with (u, v) normalised,
    the target time and the mean colour of the target frame, so the plumbing can be checked."""

    name = "pixel-toy"
    feature_dim = 4

    def answer(self, clip, queries):
        from lerobot_bavo.teacher import normalized_uv

        h, w = clip.image_size
        uv = normalized_uv(queries, h, w)
        frames = clip.episode_frames(queries[:, 3])
        colour = clip.episode_rgb[frames].reshape(len(queries), -1).mean(axis=1) / 255.0
        return np.column_stack([uv, queries[:, 3] / 31.0, colour]).astype(np.float32)


def test_a_learned_teacher_recomputes_the_cache_of_a_stored_dataset(dataset_root, tmp_path):
    from lerobot_bavo.datasets.teacher_cache import dataset_episode, recompute_teacher_cache
    from lerobot_bavo.teacher import Teacher, make_clip

    assert isinstance(_PixelTeacher(), Teacher)
    ds = load_bavo_dataset(REPO, root=dataset_root)
    ep = dataset_episode(ds, 1)
    assert ep.rgb.shape == (STEPS, 48, 64, 3) and ep.point_pixels.shape == (STEPS, 32, 2)
    clip = make_clip(ep, anchor=3)
    assert not clip.has_privileged_state and clip.rgb.shape == (32, 48, 64, 3)

    new = recompute_teacher_cache(
        ds, _PixelTeacher(), output_dir=tmp_path / "recached", repo_id="tester/recached"
    )
    new = load_bavo_dataset("tester/recached", root=tmp_path / "recached")
    assert new.meta.features[S.TEACHER_Z0]["shape"] == (32 * 4,)
    item = new[STEPS + 2]
    z0 = S.unflatten_teacher(item[S.TEACHER_Z0].numpy(), 32, 4)
    zf = S.unflatten_teacher(item[S.TEACHER_ZF].numpy(), 32, 4)
    np.testing.assert_allclose(z0[:, 2], 16 / 31.0) and np.testing.assert_allclose(zf[:, 2], 31 / 31.0)
    pix = S.unflatten_point_pixels(ds[STEPS + 2][S.OBS_POINT_PIXELS].numpy(), 32)
    np.testing.assert_allclose(z0[:, 0], (pix[:, 0] + 0.5) / 64, atol=1e-6)
    assert float(item[S.TEACHER_VALID]) == 1.0 and float(new[2 * STEPS - 1][S.TEACHER_VALID]) == 0.0
    assert read_sidecar(tmp_path / "recached")["settings"]["teacher"]["name"] == "pixel-toy"


@pytest.mark.parametrize("condition", ["clean", "random"])
def test_recorder_annotations_under_other_conditions(condition):
    from lerobot_bavo.datasets.recording import EpisodeRecorder, episode_frames
    from lerobot_bavo.teacher import teacher_targets

    rec = EpisodeRecorder("cube_handoff", condition, SETTINGS, episode_length=8)
    try:
        record = rec.record(seed=3)
    finally:
        rec.close()
    cols = episode_frames(record, teacher_targets(record))
    feats = S.build_features(SETTINGS)
    for key, ft in feats.items():  # exactly the dtypes and shapes LeRobot's add_frame validates
        assert cols[key].dtype == np.dtype(ft["dtype"] if ft["dtype"] != "video" else "uint8"), key
        assert cols[key].shape[1:] == tuple(ft["shape"]), key
    if condition == "clean":
        assert (cols[S.ANN_EVENT] == -1).all() and (cols[S.ANN_TARGET] == -1).all()
        assert (cols[S.ANN_VISIBILITY] == -1).all() and not cols[S.ANN_EVENT_START].any()
    else:
        assert cols[S.ANN_EVENT][0, 0] == 0 and cols[S.ANN_EVENT_START][0, 0] == 1.0
        assert cols[S.ANN_TARGET][0, 0] == 0 and 0.0 <= cols[S.ANN_VISIBILITY][0, 0] <= 0.2
        assert cols[S.ANN_ACTIVE][0, 0] == 1.0  # the expert starts recovering the view at once


def test_video_coverage_check_catches_dropped_frames(dataset_root):
    """The post-commit check compares each episode's video span with its frame count (STEPS at 25 fps)."""
    collector = Collector(_config(dataset_root, episodes=2))
    collector.verify_videos(0, [{"seed": 0, "length": STEPS}, {"seed": 1, "length": STEPS}])
    with pytest.raises(CollectionError, match=r"episode 1 \(seed 1\): video covers 1\.200 s for 31 frames"):
        collector.verify_videos(1, [{"seed": 1, "length": STEPS + 1}])


def test_training_views_keep_exactly_what_each_policy_family_reads(dataset_root, tmp_path):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from lerobot_bavo.datasets.views import make_view, removed_features, view_source

    src = LeRobotDataset(REPO, root=dataset_root, video_backend="pyav")
    bookkeeping = {"timestamp", "frame_index", "episode_index", "index", "task_index"}
    for view, keep in (("points", {S.OBS_STATE, S.ACTION, S.OBS_POINT_CLOUD, *S.TEACHER_KEYS}),
                       ("images", {S.OBS_STATE, S.ACTION, S.OBS_IMAGE}),
                       ("state", {S.OBS_STATE, S.ACTION, S.OBS_ENV_STATE})):
        out = make_view(dataset_root, view, output_root=tmp_path / view)
        assert out.repo_id == f"{REPO}_{view}"
        # the training-only labels: per point on the occluder, per frame recovering the view
        derived = {S.TEACHER_OCCLUDER, S.TEACHER_RECOVERING} if view == "points" else set()
        assert set(out.meta.features) - bookkeeping == keep | derived
        reloaded = LeRobotDataset(out.repo_id, root=tmp_path / view, video_backend="pyav")
        assert reloaded.meta.total_episodes == 2 and len(reloaded) == len(src)
        # episode metadata only about the view's features (LeRobot's modify_features keeps the dropped ones')
        columns = {c for f in (tmp_path / view / "meta" / "episodes").glob("*/*.parquet")
                   for c in pq.read_schema(f).names}
        about = {c.split("/")[1] for c in columns if c.startswith(("stats/", "videos/"))}
        assert about <= set(out.meta.features) and S.ACTION in about
        a, b = reloaded[STEPS + 3], src[STEPS + 3]  # a frame of the second episode
        for key in keep - {S.OBS_IMAGE}:
            torch.testing.assert_close(a[key], b[key])
        src_stats = json.loads((dataset_root / "meta" / "stats.json").read_text())
        out_stats = json.loads((tmp_path / view / "meta" / "stats.json").read_text())
        assert out_stats[S.OBS_STATE] == src_stats[S.OBS_STATE]
        if view == "points":  # per-channel point-cloud stats survive the copy
            assert out_stats[S.OBS_POINT_CLOUD] == src_stats[S.OBS_POINT_CLOUD]
            # the label marks the frame's cloud points inside the occluder's box at its recorded pose
            from lerobot_bavo.envs.occlusion import points_on_occluder

            xyz = b[S.OBS_POINT_CLOUD].numpy().reshape(-1, S.POINT_CHANNELS)[:, :3]
            expected = points_on_occluder(xyz, b[S.ANN_OCCLUDER_POSE].numpy())
            assert a[S.TEACHER_OCCLUDER].numpy().tolist() == expected.astype(np.float32).tolist()
            # the recovery label is the annotation, frame for frame (and the demo recovers at some frames)
            recovering = np.asarray(reloaded.hf_dataset[S.TEACHER_RECOVERING], dtype=np.float32).ravel()
            active = np.asarray(src.hf_dataset[S.ANN_ACTIVE], dtype=np.float32).ravel()
            assert recovering.tolist() == active.tolist() and 0 < active.sum() < len(active)
        with pytest.raises(FileExistsError, match="exists"):
            make_view(dataset_root, view, output_root=tmp_path / view)
        # how make_view names its default copy
        assert view_source(tmp_path / f"demo_{view}") == tmp_path / "demo"
    assert view_source(tmp_path / "demo") == tmp_path / "demo"
    assert view_source(tmp_path / "demo_pointsy") == tmp_path / "demo_pointsy"
    with pytest.raises(ValueError, match="unknown view 'depth'"):
        removed_features(src.meta.features, "depth")
    with pytest.raises(ValueError, match="needed by the 'points' view"):
        removed_features({S.OBS_STATE: {}, S.ACTION: {}}, "points")


def test_point_cloud_normalisation_is_independent_of_lerobot_edits(dataset_root, tmp_path):
    """After LeRobot's delete_episodes the point-cloud stats are rebuilt element-wise (one range per point
    slot); the policies' processor must still normalise every point per channel, with the exact range of the
    remaining frames, and independently of point order."""
    from types import SimpleNamespace

    from lerobot.datasets.dataset_tools import delete_episodes
    from lerobot.policies.factory import make_policy, make_policy_config, make_pre_post_processors

    import lerobot_bavo.policies  # noqa: F401

    ds = load_bavo_dataset(REPO, root=dataset_root)
    delete_episodes(ds, episode_indices=[0], output_dir=tmp_path / "deleted", repo_id="tester/deleted")
    edited = load_bavo_dataset("tester/deleted", root=tmp_path / "deleted")
    n = SETTINGS.n_points
    clouds = np.stack([np.asarray(edited.hf_dataset[i][S.OBS_POINT_CLOUD]) for i in range(len(edited))])
    clouds = clouds.reshape(-1, n, 6)
    lo, hi = clouds.reshape(-1, 6).min(0), clouds.reshape(-1, 6).max(0)
    edited_min = np.asarray(edited.meta.stats[S.OBS_POINT_CLOUD]["min"]).reshape(n, 6)
    assert not np.allclose(edited_min, lo[None])  # the edit really left per-slot ranges

    cfg = make_policy_config("maniflow", preset="cpu", device="cpu", dit_hidden_dim=32, dit_num_layers=1,
                             dit_num_heads=2)
    make_policy(cfg, ds_meta=SimpleNamespace(features=edited.meta.features, stats=edited.meta.stats))
    pre, _ = make_pre_post_processors(cfg, dataset_stats=edited.meta.stats)
    frame = torch.as_tensor(clouds[5])
    perm = torch.randperm(n, generator=torch.Generator().manual_seed(0))
    state = torch.zeros(21)
    out = pre({S.OBS_POINT_CLOUD: frame.reshape(-1), S.OBS_STATE: state})[S.OBS_POINT_CLOUD].reshape(n, 6)
    out_perm = pre({S.OBS_POINT_CLOUD: frame[perm].reshape(-1), S.OBS_STATE: state})[S.OBS_POINT_CLOUD]
    expected = 2 * (frame.numpy() - lo) / np.maximum(hi - lo, 1e-8) - 1
    np.testing.assert_allclose(out.numpy(), expected, atol=1e-5)
    torch.testing.assert_close(out_perm.reshape(n, 6), out[perm])


@pytest.mark.parametrize("condition", ["stage", "clean"])
def test_teacher_depth_reused_from_the_observation_is_the_segmentation_pass_depth(condition):
    """The recorder takes the teacher's depth from the observation's render instead of reading it back from
    its segmentation pass (issue 11); both passes see the same camera, state and geom groups, so the z-buffers
    must be bit-identical (occluder in view, moving arms, several frames)."""
    import types

    from lerobot_bavo.datasets.recording import EpisodeRecorder

    rec = EpisodeRecorder("cube_handoff", condition, SETTINGS, episode_length=12)
    both = []

    def view(self):
        seg, depth = self._seg.render_segmentation(self.env.data, self._camera_id, with_depth=True)
        reused = self.env.observation_depth
        both.append((depth, reused))
        return seg, reused

    rec._privileged_view = types.MethodType(view, rec)
    try:
        rec.record(seed=1)
    finally:
        rec.close()
    assert len(both) == 12
    for t, (read_back, reused) in enumerate(both):
        assert reused.dtype == read_back.dtype == np.float32
        assert np.array_equal(read_back, reused), (
            f"frame {t}: observation depth differs from the segmentation pass"
        )


# ----------------------------------------------------------------------------- the background writer
def _counting_run_job(real_run_job, calls: list, interrupt_at: int | None = None, before_interrupt=None):
    def run(job):
        calls.append(job["seed"])
        if interrupt_at is not None and len(calls) == interrupt_at:
            if before_interrupt is not None:
                before_interrupt()
            raise KeyboardInterrupt  # Ctrl+C while the main loop waits on an attempt
        return real_run_job(job)

    return run


def test_episodes_are_written_as_they_resolve_into_sessions_of_commit_every(tmp_path, monkeypatch):
    """Each kept episode is written as soon as it is resolved, before the next attempt (the attempts in flight
    keep the workers busy meanwhile), and the sessions still hold exactly --commit-every episodes each, in
    seed order."""
    import lerobot_bavo.datasets.collect as collect_mod
    from lerobot_bavo.datasets.writer import CommitSession

    events: list[tuple[str, int]] = []
    real_run_job, real_add = collect_mod.run_job, CommitSession.add

    def run_job(job):
        events.append(("attempt", job["seed"]))
        return real_run_job(job)

    def add(self, summary):
        events.append(("write", summary["seed"]))
        return real_add(self, summary)

    monkeypatch.setattr(collect_mod, "run_job", run_job)
    monkeypatch.setattr(CommitSession, "add", add)
    root = tmp_path / "streamed"
    summary = collect(_config(root, episodes=5, commit_every=2))  # in-process pool: one attempt in flight
    assert summary["episodes"] == 5
    assert events == [(kind, seed) for seed in range(5) for kind in ("attempt", "write")]
    rec = read_sidecar(root)
    commits = rec["runs"][-1]["timings"]["commits"]
    assert [[e["seed"] for e in c["episodes"]] for c in commits] == [[0, 1], [2, 3], [4]]
    assert [e["seed"] for e in rec["episodes"]] == [0, 1, 2, 3, 4]
    assert rec["pending_commit"] is None
    check_files(root)


def test_ctrl_c_with_a_writer_session_open_rolls_it_back(tmp_path, monkeypatch):
    """Ctrl+C in the main loop while the writer holds an open, uncommitted session: the session is rolled
    back, its episodes stay staged, and the next run commits them without recording them again."""
    import lerobot_bavo.datasets.collect as collect_mod
    from lerobot_bavo.datasets.writer import CommitSession

    calls: list[int] = []
    added: list[int] = []
    real_run_job, real_add = collect_mod.run_job, CommitSession.add

    def counting_add(self, summary):
        real_add(self, summary)
        added.append(summary["seed"])

    def session_holds_an_episode():  # interrupt only once the open session has an episode saved in it
        deadline = time.monotonic() + 60
        while not added and time.monotonic() < deadline:
            time.sleep(0.02)

    root = tmp_path / "interrupted"
    with monkeypatch.context() as m:
        m.setattr(CommitSession, "add", counting_add)
        m.setattr(collect_mod, "run_job", _counting_run_job(real_run_job, calls, interrupt_at=3,
                                                            before_interrupt=session_holds_an_episode))
        with pytest.raises(KeyboardInterrupt):
            collect(_config(root, episodes=4, commit_every=3))
    assert added[:1] == [0]  # seed 0 was saved into the session (not committed) when Ctrl+C came
    rec = read_sidecar(root)
    assert rec["episodes"] == [] and rec["pending_commit"] is None  # rolled back: nothing half-written stays
    staged = sorted(p.name for p in (root / ".bavo_staging").glob("seed_*.json"))
    assert staged == ["seed_00000000.json", "seed_00000001.json"]
    check_files(root)

    calls.clear()
    with monkeypatch.context() as m:
        m.setattr(collect_mod, "run_job", _counting_run_job(real_run_job, calls))
        summary = collect(_config(root, episodes=4, commit_every=3))
    assert calls == [2, 3]  # the staged episodes were reused
    assert summary["episodes"] == 4
    assert [e["seed"] for e in read_sidecar(root)["episodes"]] == [0, 1, 2, 3]
    check_files(root)



def test_mix_views_joins_the_first_episodes_of_each_view(dataset_root, tmp_path, monkeypatch):
    """scripts/mix_views.py (issue 27's condition-mix variant): Stage episode 0 + both Random-time episodes
    -> one view of 3 episodes whose frames are the sources' own, with a collection record naming the mix."""
    from _helpers import load_script
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from lerobot_bavo.datasets.metadata import SIDECAR
    from lerobot_bavo.datasets.views import make_view

    mix = load_script("scripts/mix_views.py")
    random_root = tmp_path / "bavo_random"
    assert collect(_config(random_root, episodes=2, condition="random", seed=7))["episodes"] == 2
    stage_view = tmp_path / "stage_points"
    random_view = tmp_path / "bavo_random_points"
    make_view(dataset_root, "points", output_root=stage_view)
    make_view(random_root, "points", output_root=random_view)
    (tmp_path / "stage" / "meta").mkdir(parents=True)
    shutil.copy(dataset_root / SIDECAR, tmp_path / "stage" / SIDECAR)  # the view's source record

    import datasets.config

    user_cache = tmp_path / "user_hf_cache"  # the Arrow cache of the temporary copies must not land here
    monkeypatch.setattr(datasets.config, "HF_DATASETS_CACHE", user_cache)
    out = tmp_path / "mixed_points"
    mix.main(["--output", str(out), "--source", f"{stage_view}:1", "--source", f"{random_view}:2"])
    assert not user_cache.exists() and user_cache == datasets.config.HF_DATASETS_CACHE
    joined = LeRobotDataset("local/mixed_points", root=out)
    stage = LeRobotDataset("x/stage", root=stage_view)
    rand = LeRobotDataset("x/random", root=random_view)
    assert joined.meta.total_episodes == 3 and len(joined) == 3 * STEPS
    for j, (src, i) in ((0, (stage, 0)), (STEPS + 4, (rand, 4)), (2 * STEPS + 9, (rand, STEPS + 9))):
        a, b = joined[j], src[i]
        for key in (S.OBS_POINT_CLOUD, S.ACTION, S.OBS_STATE, S.TEACHER_OCCLUDER):
            torch.testing.assert_close(a[key], b[key])
    assert [int(joined[k]["episode_index"]) for k in (0, STEPS, 2 * STEPS)] == [0, 1, 2]
    record = json.loads((tmp_path / "mixed" / SIDECAR).read_text())
    assert record["settings"]["condition"] == "stage+random"
    assert [(e["episode_index"], e["seed"]) for e in record["episodes"]] == [(0, 0), (1, 7), (2, 8)]
    assert [m["episodes"] for m in record["mixed_from"]] == [1, 2]
    with pytest.raises(SystemExit, match="exists"):
        mix.main(["--output", str(out), "--source", f"{stage_view}:1"])
    import argparse

    with pytest.raises(argparse.ArgumentTypeError, match="ROOT:EPISODES"):
        mix.parse_source("no_count")

    # A source kept for its recoveries: its other frames weigh 0.25, the rest 1 (the points view's label).
    weighted = tmp_path / "mixedw_points"
    mix.main(["--output", str(weighted), "--source", f"{stage_view}:1", "--source", f"{random_view}:2:0.25"])
    joined_w = LeRobotDataset("local/mixedw_points", root=weighted)
    assert len(joined_w) == len(joined)
    got = [float(joined_w[k][S.TEACHER_SAMPLE_WEIGHT]) for k in range(len(joined_w))]
    recovering = [float(joined[k][S.TEACHER_RECOVERING]) for k in range(len(joined))]
    expected = [1.0] * STEPS + [1.0 if r > 0.5 else 0.25 for r in recovering[STEPS:]]
    assert got == expected
    assert 0.25 in got and recovering[STEPS:].count(1.0) > 0  # both kinds of Random-time frame occur
    torch.testing.assert_close(joined_w[STEPS + 4][S.ACTION], rand[4][S.ACTION])
    record = json.loads((tmp_path / "mixedw" / SIDECAR).read_text())
    assert [m.get("outside_recovery_weight") for m in record["mixed_from"]] == [None, 0.25]


def test_mix_views_source_weights_and_frame_weights_by_hand():
    import argparse

    from _helpers import load_script

    mix = load_script("scripts/mix_views.py")
    assert mix.parse_source("a/b_points:3") == (Path("a/b_points"), 3, None)
    assert mix.parse_source("a/b_points:3:0") == (Path("a/b_points"), 3, 0.0)
    assert mix.parse_source("a/b_points:12:0.5") == (Path("a/b_points"), 12, 0.5)
    for bad in ("a:3:-1", "a:3:nan", "a:3:inf", "a:3:x", "a:0:0.5", "a:x:0.5"):
        with pytest.raises(argparse.ArgumentTypeError, match="ROOT:EPISODES"):
            mix.parse_source(bad)
    # episodes 0, 1 of an unweighted source, 2 of one weighted 0.0; recovering frames always 1
    got = mix.frame_weights(np.array([0, 0, 1, 2, 2, 2]), np.array([1.0, 0.0, 0.0, 1.0, 0.0, 0.0]),
                            np.array([1.0, 1.0, 0.0]))
    assert got.shape == (6, 1) and got.dtype == np.float32
    assert got[:, 0].tolist() == [1.0, 1.0, 1.0, 1.0, 0.0, 0.0]
    # --weigh recovery: the weighted source's recovery frames weigh its weight instead
    got = mix.frame_weights(np.array([0, 0, 1, 2, 2, 2]), np.array([1.0, 0.0, 0.0, 1.0, 0.0, 0.0]),
                            np.array([1.0, 1.0, 0.25]), weigh="recovery")
    assert got[:, 0].tolist() == [1.0, 1.0, 1.0, 0.25, 1.0, 1.0]
    # --weigh all: every frame of the weighted source, recovering or not; the others keep 1
    got = mix.frame_weights(np.array([0, 0, 1, 2, 2, 2]), np.array([1.0, 0.0, 0.0, 1.0, 0.0, 0.0]),
                            np.array([1.0, 1.0, 0.0]), weigh="all")
    assert got[:, 0].tolist() == [1.0, 1.0, 1.0, 0.0, 0.0, 0.0]
    with pytest.raises(ValueError, match="weigh"):
        mix.frame_weights(np.array([0]), np.array([0.0]), np.array([1.0]), weigh="every")
