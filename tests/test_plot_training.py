"""scripts/plot_training.py: exact steps recovered from lerobot-train's rounded step counter."""

import pytest
from _helpers import load_script


def _load():
    return load_script("scripts/plot_training.py")


def _log(tmp_path, steps):
    lines = [
        "INFO 2026-11-22 08:00:00 ot_train.py:600 Creating policy",
        "Training:  10%|# | 1/10 [00:01<00:09]\r",
    ]
    for i, step in enumerate(steps):
        lines.append(
            f"INFO 2026-11-22 08:00:0{i % 10} ot_train.py:641 step:{step} smpl:8K ep:20 epch:0.{i:02d} "
            f"loss:{1.0 / (i + 1):.3f} grdn:1.0 lr:1.0e-04 updt_s:0.3 data_s:0.1 loss_fm:{0.5 / (i + 1):.3f}"
        )
    path = tmp_path / "train.log"
    path.write_text("\n".join(lines))
    return path


def test_steps_recovered_from_rounded_counter(tmp_path):
    plot = _load()
    # log_freq 250: 250, 500, 750 print exactly, then 1000 -> "1K", 1250 -> "1K", 1500 -> "2K", 2500 -> "2K"
    # (half to even).
    series = plot.parse_log(
        _log(tmp_path, ["250", "500", "750", "1K", "1K", "2K", "2K", "2K", "2K"]), log_freq=250
    )
    assert [s for s, _ in series["loss"]] == [250, 500, 750, 1000, 1250, 1500, 1750, 2000, 2250]
    assert series["loss"][1] == (500, 0.5)
    assert series["loss_fm"][3] == (1000, 0.125)
    assert "lr" in series and "epch" not in series


def test_wrong_log_freq_is_an_error(tmp_path):
    plot = _load()
    with pytest.raises(ValueError, match="log_freq"):
        plot.parse_log(_log(tmp_path, ["250", "500", "750"]), log_freq=100)


def test_log_without_metrics_is_an_error(tmp_path):
    plot = _load()
    path = tmp_path / "empty.log"
    path.write_text("nothing here\n")
    with pytest.raises(ValueError, match="no `lerobot-train` metric lines"):
        plot.parse_log(path, log_freq=10)
