"""`datasets/lerobot_format.py` and the LeRobot-free settings of `video_codec.py` give what LeRobot 0.6.1's
own functions give (issue 30: `bavo-collect`'s writing process no longer imports LeRobot). Each test puts one
piece beside the LeRobot function it follows; `tests/test_direct_writer.py` compares whole writer
sessions."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from _helpers import SMALL_SETTINGS

from lerobot_bavo.datasets import lerobot_format as F
from lerobot_bavo.datasets import schema as S
from lerobot_bavo.datasets import video_codec as V
from lerobot_bavo.datasets.episode_payload import codec_video_settings, encode_video, video_settings

SETTINGS = SMALL_SETTINGS


def _features() -> dict:
    return S.build_features(SETTINGS, use_videos=True, env_state_dim=14)


@pytest.mark.parametrize("codec", V.VIDEO_CODECS)
def test_encoder_settings_without_lerobot_equal_lerobots(codec):
    config = V.rgb_encoder(codec)
    assert V.encoder_record(codec) == dataclasses.asdict(config)
    assert list(V.encoder_record(codec)) == list(dataclasses.asdict(config))
    assert V.codec_options(codec) == config.get_codec_options(V.encoder_threads(codec), as_strings=True)
    assert codec_video_settings(codec, S.FPS) == video_settings(config, V.encoder_threads(codec), S.FPS)


def test_a_new_dataset_has_lerobots_info_json(tmp_path):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    for use_videos in (True, False):
        features = _features() if use_videos else S.build_features(SETTINGS, use_videos=False)
        theirs, ours = tmp_path / f"lerobot_{use_videos}", tmp_path / f"ours_{use_videos}"
        ds = LeRobotDataset.create("t/x", S.FPS, features, root=theirs, robot_type="bavo_av_aloha",
                                   use_videos=use_videos)
        ds.finalize()
        F.create_dataset(ours, S.FPS, features, use_videos=use_videos, robot_type="bavo_av_aloha")
        assert sorted(p.relative_to(ours) for p in ours.rglob("*")) == \
            sorted(p.relative_to(theirs) for p in theirs.rglob("*"))
        assert (ours / F.INFO_PATH).read_bytes() == (theirs / F.INFO_PATH).read_bytes()
    with pytest.raises(FileExistsError):
        F.create_dataset(ours, S.FPS, features, use_videos=False, robot_type=None)


def test_info_is_normalised_as_lerobots_dataset_info():
    from lerobot.datasets.utils import DatasetInfo

    raw = F.new_info(S.FPS, _features(), True, "r")
    raw.update(total_videos=3, tools=None)  # an unknown field (v2.x) and an unset optional one
    del raw["splits"]
    assert F.normalized_info(raw) == DatasetInfo.from_dict(json.loads(json.dumps(raw))).to_dict()
    raw["tools"] = [{"name": "t"}]
    assert json.dumps(F.normalized_info(raw)) == json.dumps(DatasetInfo.from_dict(dict(raw)).to_dict())


def test_arrow_schema_is_datasets_schema_and_other_features_are_refused():
    from lerobot.datasets.feature_utils import get_hf_features_from_features
    from lerobot.utils.constants import DEFAULT_FEATURES

    features = {**_features(), **DEFAULT_FEATURES}
    theirs = get_hf_features_from_features(features).arrow_schema
    ours = F.arrow_schema(features)
    assert ours.equals(theirs, check_metadata=True)
    for bad in ({"dtype": "image", "shape": (4, 4, 3)}, {"dtype": "float32", "shape": (2, 3)},
                {"dtype": "string", "shape": (1,)}):
        with pytest.raises(F.UnsupportedFeature):
            F.arrow_schema({"x": {**bad, "names": None}})


def _random_stats(rng, shape, image: bool = False) -> dict:
    lo = rng.normal(size=shape)
    stats = {"min": lo, "max": lo + rng.random(shape), "mean": rng.normal(size=shape),
             "std": rng.random(shape), "count": np.array([int(rng.integers(2, 500))])}
    for q in ("q01", "q10", "q50", "q90", "q99"):
        stats[q] = rng.normal(size=shape)
    if image:
        stats = {k: v if k == "count" else v.reshape(3, 1, 1) for k, v in stats.items()}
    return stats


def test_statistics_read_written_and_aggregated_as_lerobot_does(tmp_path):
    from lerobot.datasets.compute_stats import aggregate_stats
    from lerobot.datasets.io_utils import load_stats, write_stats

    rng = np.random.default_rng(3)
    episodes = [{"action": _random_stats(rng, (21,)),
                 "observation.images.active": _random_stats(rng, (3,), True),
                 "index": {k: v.astype(np.float32) for k, v in _random_stats(rng, (1,)).items()}}
                for _ in range(4)]
    ours = episodes[0]
    for e in episodes[1:]:
        ours = F.aggregate_stats([ours, e])
    theirs = episodes[0]
    for e in episodes[1:]:
        theirs = aggregate_stats([theirs, e])
    assert sorted(ours) == sorted(theirs)
    for key in theirs:
        assert list(ours[key]) == list(theirs[key])
        for name, value in theirs[key].items():
            assert ours[key][name].dtype == value.dtype and ours[key][name].tobytes() == value.tobytes()
    write_stats(theirs, tmp_path / "a")
    F.write_stats(theirs, tmp_path / "b")
    assert (tmp_path / "a" / F.STATS_PATH).read_bytes() == (tmp_path / "b" / F.STATS_PATH).read_bytes()
    loaded_theirs, loaded_ours = load_stats(tmp_path / "a"), F.load_stats(tmp_path / "a")
    for key in loaded_theirs:
        for name, value in loaded_theirs[key].items():
            got = loaded_ours[key][name]
            assert got.dtype == value.dtype and np.array_equal(got, value)
    assert F.load_stats(tmp_path / "none") is None
    with pytest.raises(ValueError, match="count"):
        F.aggregate_stats([{"x": {**episodes[0]["action"], "count": np.array([1, 2])}}])


def test_tasks_table_as_lerobot_writes_and_appends_it(tmp_path):
    import pandas as pd
    from lerobot.datasets.io_utils import load_tasks, write_tasks

    tasks = pd.DataFrame({"task_index": range(1)}, index=pd.Index(["first task"], name="task"))
    write_tasks(tasks, tmp_path / "a")
    F.write_tasks(tmp_path / "b", ["first task"], had_tasks=False)
    assert (tmp_path / "a" / F.TASKS_PATH).read_bytes() == (tmp_path / "b" / F.TASKS_PATH).read_bytes()
    tasks = load_tasks(tmp_path / "a")
    tasks.loc["second task"] = 1
    write_tasks(tasks, tmp_path / "a")
    F.write_tasks(tmp_path / "b", ["second task"], had_tasks=True)
    assert (tmp_path / "a" / F.TASKS_PATH).read_bytes() == (tmp_path / "b" / F.TASKS_PATH).read_bytes()
    assert F.read_tasks(tmp_path / "b") == ["first task", "second task"]


def _mp4(path: Path, n: int, seed: int) -> Path:
    rng = np.random.default_rng(seed)
    frames = rng.integers(0, 256, size=(n, 48, 64, 3), dtype=np.uint8)
    encode_video(frames, path, codec_video_settings("h264", S.FPS))
    return path


def test_video_probe_duration_and_concatenation_as_lerobots(tmp_path):
    from lerobot.datasets.video_utils import concatenate_video_files, get_video_duration_in_s, get_video_info

    a, b = _mp4(tmp_path / "a.mp4", 30, 0), _mp4(tmp_path / "b.mp4", 17, 1)
    assert F.video_info(a, V.encoder_record("h264")) == get_video_info(a, V.rgb_encoder("h264"))
    assert list(F.video_info(a, V.encoder_record("h264"))) == list(get_video_info(a, V.rgb_encoder("h264")))
    assert F.video_duration_s(b) == get_video_duration_in_s(b)
    concatenate_video_files([a, b], tmp_path / "theirs.mp4")
    F.concatenate_videos([a, b], tmp_path / "ours.mp4")
    assert (tmp_path / "ours.mp4").read_bytes() == (tmp_path / "theirs.mp4").read_bytes()


def test_card_is_lerobots(tmp_path):
    """`card.write_card` renders what LeRobot's `create_lerobot_dataset_card` renders for the same dataset."""
    from lerobot.datasets.utils import DatasetInfo, create_lerobot_dataset_card

    from lerobot_bavo.datasets.card import card_kwargs_for, write_card
    from lerobot_bavo.datasets.collection_record import CollectionRecord
    from lerobot_bavo.datasets.metadata import read_info

    root = tmp_path / "ds"
    F.create_dataset(root, S.FPS, _features(), use_videos=True, robot_type="bavo_av_aloha")
    settings = {"task": "cube_handoff", "condition": "stage", "task_description": "Hand the cube over.",
                **SETTINGS.to_dict(), "use_videos": True}
    CollectionRecord(repo_id="t/card", settings=settings, next_seed=0).save(root)
    kwargs = card_kwargs_for(root, "t/card")
    tags = kwargs.pop("tags")
    theirs = create_lerobot_dataset_card(tags=tags, dataset_info=DatasetInfo.from_dict(read_info(root)),
                                         repo_id="t/card", **kwargs)
    theirs.save(str(tmp_path / "theirs.md"))
    assert write_card(root, "t/card").read_text() == (tmp_path / "theirs.md").read_text()


def test_last_episode_row_is_lerobots_last_episode(tmp_path):
    from lerobot.datasets.io_utils import load_episodes

    root = tmp_path / "ds"
    for chunk, file, rows in ((0, 0, [0, 1]), (0, 1, [2, 3, 4])):
        path = root / F.EPISODES_PATH.format(chunk_index=chunk, file_index=file)
        writer = F.parquet_writer(path, F.episode_rows_table([{"episode_index": [0], "dataset_to_index": [0],
                                                               "tasks": [["t"]]}]).schema)
        for r in rows:  # one row group per row, as LeRobot's flushes of a buffer of one
            writer.write_table(F.episode_rows_table([{"episode_index": [r], "dataset_to_index": [10 * r],
                                                      "tasks": [["t"]]}]))
        writer.close()
    columns = ["episode_index", "dataset_to_index"]
    last = load_episodes(root)[-1]
    assert F.last_episode(root, columns) == {k: last[k] for k in columns} == {"episode_index": 4,
                                                                             "dataset_to_index": 40}


def test_read_frame_columns_joins_the_data_files_in_order(tmp_path):
    import pyarrow as pa
    import pyarrow.parquet as pq

    for chunk, file, rows in ((0, 1, [3, 4]), (0, 0, [0, 1, 2]), (1, 0, [5])):
        path = tmp_path / F.DATA_PATH.format(chunk_index=chunk, file_index=file)
        path.parent.mkdir(parents=True, exist_ok=True)
        pq.write_table(pa.table({"index": rows, "other": [0.5] * len(rows)}), path)
    table = F.read_frame_columns(tmp_path, ["index"])
    assert table.column_names == ["index"]
    assert table.column("index").to_pylist() == [0, 1, 2, 3, 4, 5]
    with pytest.raises(FileNotFoundError, match="no data files under"):
        F.read_frame_columns(tmp_path / "empty", ["index"])
