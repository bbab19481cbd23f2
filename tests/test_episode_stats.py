"""`datasets.episode_stats` gives LeRobot 0.6.1's per-episode statistics bit for bit (same keys, order,
shapes, dtypes and values), on adversarial columns and on a real recorded episode's dataset columns."""

from __future__ import annotations

import numpy as np
import pytest
from lerobot.datasets.compute_stats import compute_episode_stats as lerobot_episode_stats

from lerobot_bavo.datasets.episode_stats import compute_episode_stats, vector_stats, writer_stats_inputs


def assert_identical(ours: dict, theirs: dict) -> None:
    assert list(ours) == list(theirs)
    for feature in theirs:
        assert list(ours[feature]) == list(theirs[feature]), feature
        for key, expected in theirs[feature].items():
            got = ours[feature][key]
            assert got.dtype == expected.dtype, (feature, key, got.dtype, expected.dtype)
            assert got.shape == expected.shape, (feature, key, got.shape, expected.shape)
            # bit for bit: compare the raw bytes (so -0.0 vs 0.0 would differ)
            assert got.tobytes() == expected.tobytes(), (feature, key, got, expected)


def adversarial_columns(rng: np.random.Generator, n: int) -> dict[str, np.ndarray]:
    base = rng.normal(size=(n, 12)).astype(np.float32)
    base[:, 0] = 0.25  # constant: every bin edge is the same value
    base[:, 1] = rng.choice(np.array([-0.0, 0.0], dtype=np.float32), size=n)  # signed zeros
    base[:, 2] = rng.integers(0, 3, size=n)  # heavy ties
    base[:, 3] *= 1e6  # wide range
    base[:, 4] = 1e-12 * rng.normal(size=n)  # narrower than the 1e-10 padding
    base[:, 5] = np.where(np.arange(n) < n // 2, -1.0, 1.0)  # two clusters: empty bins in between
    return {
        "wide": base,
        "one_dim": rng.normal(size=n).astype(np.float32),  # (T,) features (LeRobot keeps dims)
        "ints": rng.integers(-5, 40, size=(n, 3)).astype(np.int64),  # float64 edges
        "int_scalar": np.full(n, 7, dtype=np.int64),
        "f64": rng.normal(size=(n, 4)),
        "flags": (rng.random(size=(n, 2)) > 0.5),
    }


@pytest.mark.parametrize("n", [2, 3, 17, 100, 431])
def test_equals_lerobot_on_adversarial_columns(n):
    rng = np.random.default_rng(n)
    cols = adversarial_columns(rng, n)
    cols, features = writer_stats_inputs(cols)
    assert_identical(compute_episode_stats(cols, features), lerobot_episode_stats(cols, features))


def test_equals_lerobot_on_a_recorded_episode():
    """Every numeric dataset column of a real (small) Stage episode, teacher targets included."""
    from lerobot_bavo.datasets import schema as S
    from lerobot_bavo.datasets.recording import EpisodeRecorder, episode_frames
    from lerobot_bavo.features import ObservationSettings
    from lerobot_bavo.teacher.simulator import teacher_targets

    recorder = EpisodeRecorder("cube_handoff", "stage", ObservationSettings(image_height=48, image_width=64,
                                                                             n_points=32), episode_length=60)
    try:
        record = recorder.record(seed=5)
    finally:
        recorder.close()
    targets = teacher_targets(
        record, n_future=S.N_FUTURE, clip_length=S.CLIP_LENGTH, anchor_index=S.ANCHOR_INDEX
    )
    cols, features = writer_stats_inputs({k: v for k, v in episode_frames(record, targets).items()
                                          if k != S.OBS_IMAGE})
    assert_identical(compute_episode_stats(cols, features), lerobot_episode_stats(cols, features))


def test_quantiles_of_a_hand_computed_case():
    """Independent of LeRobot: 0..99 has min 0, max 99, mean 49.5, and each histogram quantile lies within one
    value plus one bin (99 / 5000) of q * 100 (the order statistic it interpolates next to)."""
    x = np.arange(100, dtype=np.float32)
    s = vector_stats(x)
    assert s["min"].tolist() == [0.0] and s["max"].tolist() == [99.0] and s["count"].tolist() == [100]
    assert s["mean"].tolist() == [49.5]
    for key, q in (("q01", 0.01), ("q10", 0.10), ("q50", 0.50), ("q90", 0.90), ("q99", 0.99)):
        assert abs(float(s[key][0]) - q * 100) <= 99 / 5000 + 1e-6 + 1.0, (key, s[key])


def test_rejects_what_it_cannot_reproduce():
    with pytest.raises(ValueError, match="T >= 2"):
        vector_stats(np.zeros((1, 3), dtype=np.float32))
    with pytest.raises(ValueError, match="shape"):
        vector_stats(np.zeros((4, 2, 2), dtype=np.float32))
