"""`lerobot_private.arrow_episode_tables`: LeRobot's writer gets the same episode tables, and writes the same
parquet bytes, when it builds them directly in Arrow instead of through `datasets.Dataset.from_dict` (issue
11)."""

from __future__ import annotations

import io

import datasets
import numpy as np
import pyarrow.parquet as pq
import pytest

from lerobot_bavo.datasets import lerobot_private
from lerobot_bavo.datasets.lerobot_private import (
    arrow_episode_tables,
    arrow_table_of,
    skip_noop_image_embedding,
)

FEATURES = datasets.Features({
    "observation.point_cloud": datasets.List(datasets.Value("float32"), length=12),
    "observation.teacher.valid": datasets.Value("float32"),
    "annotation.progress": datasets.Value("int64"),
    "timestamp": datasets.Value("float32"),
})


def _columns(n: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    cloud = rng.normal(size=(n, 12)).astype(np.float32)
    cloud[1, 3] = np.nan  # NaN and signed zero are values, not nulls, on both paths
    cloud[2, 0] = -0.0
    return {
        "observation.point_cloud": cloud,
        "observation.teacher.valid": (rng.random(n) > 0.5).astype(np.float32),
        "annotation.progress": rng.integers(0, 6, n),
        "timestamp": np.arange(n, dtype=np.float32) / 25,
    }


def _parquet_bytes(table) -> bytes:
    buf = io.BytesIO()
    writer = pq.ParquetWriter(buf, schema=table.schema, compression="snappy", use_dictionary=True)
    writer.write_table(table)
    writer.close()
    return buf.getvalue()


@pytest.mark.parametrize("timestamps", ["float32", "float64"])
def test_direct_table_equals_from_dict_and_writes_the_same_bytes(timestamps):
    cols = _columns(40, np.random.default_rng(0))
    if timestamps == "float64":  # as LeRobot hands them over for a float32 feature: cast as datasets casts
        cols["timestamp"] = np.random.default_rng(3).normal(size=40) * 1e3
    theirs = datasets.Dataset.from_dict(cols, features=FEATURES, split="train").with_format("arrow")[:]
    ours = arrow_table_of(cols, FEATURES)
    assert ours.schema.equals(theirs.schema, check_metadata=True)
    assert _parquet_bytes(ours) == _parquet_bytes(theirs)


@pytest.mark.parametrize("change", ["dtype", "width", "missing", "extra", "list", "string", "empty"])
def test_anything_else_takes_datasets_own_path(change):
    cols = _columns(10, np.random.default_rng(1))
    features = FEATURES
    if change == "dtype":
        cols["annotation.progress"] = cols["annotation.progress"].astype(np.float64)  # datasets would cast
    elif change == "width":
        cols["observation.point_cloud"] = cols["observation.point_cloud"][:, :6]
    elif change == "missing":
        del cols["annotation.progress"]
    elif change == "extra":
        cols["other"] = np.zeros(10)
    elif change == "list":
        cols["annotation.progress"] = list(cols["annotation.progress"])
    elif change == "empty":
        cols = {k: v[:0] for k, v in cols.items()}
    else:
        features = datasets.Features({**FEATURES, "task": datasets.Value("string")})
        cols["task"] = np.array(["t"] * 10)
    assert arrow_table_of(cols, features) is None


def test_lerobot_writes_the_same_files_with_direct_tables(tmp_path, monkeypatch):
    """Two episodes of BAVO-like columns through LeRobot's writer with and without the replacement: every
    data and episode-metadata file is the same bytes, and the replacement did build the tables."""
    import lerobot.datasets.dataset_writer as writer_mod
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    features = {
        "observation.images.active": {
            "dtype": "video",
            "shape": (24, 32, 3),
            "names": ["height", "width", "channels"],
        },
        "observation.point_cloud": {"dtype": "float32", "shape": (12,), "names": None},
        "observation.teacher.valid": {"dtype": "float32", "shape": (1,), "names": None},
        "annotation.progress": {"dtype": "int64", "shape": (1,), "names": None},
    }
    built = []
    real = lerobot_private.arrow_table_of
    monkeypatch.setattr(lerobot_private, "arrow_table_of", lambda m, f: built.append(real(m, f)) or built[-1])

    def write(root, direct: bool):
        rng = np.random.default_rng(7)
        ds = LeRobotDataset.create(
            "t/arrow",
            25,
            features,
            root=root,
            use_videos=True,
            streaming_encoding=True,
            encoder_queue_maxsize=64,
            video_backend="pyav",
        )
        # bavo-collect's writer skips LeRobot's no-op image embedding pass either way (it would write the
        # datasets fingerprint of each episode's in-memory table into the file)
        with arrow_episode_tables() if direct else skip_noop_image_embedding():
            assert (writer_mod.datasets is not datasets) == direct
            for n in (30, 17):
                cols = _columns(n, rng)
                for t in range(n):
                    ds.add_frame(
                        {
                            "observation.images.active": rng.integers(0, 255, (24, 32, 3), dtype=np.uint8),
                            "observation.point_cloud": cols["observation.point_cloud"][t],
                            "observation.teacher.valid": cols["observation.teacher.valid"][t : t + 1],
                            "annotation.progress": cols["annotation.progress"][t : t + 1],
                            "task": "t",
                        }
                    )
                ds.save_episode()
        ds.finalize()
        return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*.parquet"))}

    theirs = write(tmp_path / "lerobot", direct=False)
    assert built == []
    ours = write(tmp_path / "ours", direct=True)
    assert writer_mod.datasets is datasets  # restored after the block
    assert len(built) == 2 and all(t is not None for t in built)  # both episodes took the direct path
    assert sorted(ours) == sorted(theirs) and any(k.startswith("data/") for k in ours)
    for name in theirs:
        assert ours[name] == theirs[name], name
