"""The training wall time a shipped checkpoint's card states (`scripts/ship_checkpoint.py`), read from the
lerobot-train log: hand-made logs with known segment times."""

from __future__ import annotations

import pytest
from _helpers import load_script

training_wall_min = load_script("scripts/ship_checkpoint.py").training_wall_min


def _line(stamp: str, text: str) -> str:
    return f"INFO 2026-11-{stamp} ot_train.py:597 {text}\n"


# a run stopped after its step-1000 checkpoint (its steps 1000-1150 were lost), then resumed from 1000
RESUMED = (
    _line("26 10:00:00", "Start offline training on a fixed dataset")
    + "Training:  10%| 500/5000 [05:00<45:00]\n"
    + _line("26 10:05:00", "Checkpoint policy after step 500")
    + _line("26 10:10:00", "Checkpoint policy after step 1000")
    + _line("26 10:11:30", "step:1K smpl:128K")
    + _line("26 11:00:00", "Start offline training on a fixed dataset")
    + _line("26 11:06:00", "Checkpoint policy after step 1500")
    + _line("26 11:12:30", "Checkpoint policy after step 2000")
)


@pytest.mark.parametrize(("step", "minutes"), [(500, 5.0), (1000, 10.0), (1500, 16.0), (2000, 22.5)])
def test_segments_count_from_their_start_to_the_last_kept_checkpoint(step, minutes):
    assert training_wall_min(RESUMED, step) == pytest.approx(minutes)


def test_a_step_never_saved_has_no_wall_time():
    assert training_wall_min(RESUMED, 2500) is None
    assert training_wall_min("", 1000) is None


def test_a_segment_stopped_before_its_first_checkpoint_adds_nothing():
    log = (_line("26 10:00:00", "Start offline training") + _line("26 10:20:00", "step:200 smpl:25K")
           + _line("26 11:00:00", "Start offline training")
           + _line("26 11:07:00", "Checkpoint policy after step 500"))
    assert training_wall_min(log, 500) == pytest.approx(7.0)


def test_a_run_across_midnight():
    log = (_line("26 23:58:00", "Start offline training")
           + _line("27 00:02:30", "Checkpoint policy after step 500"))
    assert training_wall_min(log, 500) == pytest.approx(4.5)


def test_the_cards_of_joined_data_variants_point_to_the_variant_commands():
    """A checkpoint trained on a joined view (`scripts/mix_views.py`) names where the variant's commands are,
    not the recipe's single-collection command (self-filtered variants' cards once named DATA=dartsf512)."""
    from pathlib import Path

    cards = sorted(Path(__file__).resolve().parents[1].glob("checkpoints/*/README.md"))
    joined = [c for c in cards if "`scripts/mix_views.py` joined" in c.read_text()]
    assert joined, "no shipped checkpoint of a joined data variant"
    for card_file in joined:
        text = card_file.read_text()
        assert "Variants and baselines beside the recipe" in text, card_file
        assert "DATA=dartsf512" not in text, card_file


def test_the_card_names_the_preset_flags_that_differ_from_the_preset():
    """A model of the `cpu` preset with a narrower MLP (a size that fits 7 MB in float16) needs
    `--policy.dit_mlp_ratio=3.5` to be rebuilt from the card's command; the preset's own sizes need none. A
    training setting a preset fills (A-FAR's fusion-gate lr multiplier, 10 in `cpu_fast`) is named the same
    way when a run changed it."""
    preset_flags = load_script("scripts/ship_checkpoint.py").preset_flags
    cpu = {"type": "afar", "preset": "cpu", "dit_hidden_dim": 192, "dit_num_layers": 3, "dit_num_heads": 4,
           "time_embed_hidden_dim": 256, "point_encoder_hidden_dims": [64, 128, 256, 512],
           "dit_mlp_ratio": 4.0}
    assert preset_flags(cpu) == []
    assert preset_flags({**cpu, "dit_mlp_ratio": 3.5}) == ["--policy.dit_mlp_ratio=3.5"]
    assert preset_flags({**cpu, "point_encoder_hidden_dims": [64, 128]}) == [
        "--policy.point_encoder_hidden_dims=[64,128]"]
    assert preset_flags({**cpu, "type": "maniflow", "preset": "cpu_fast"}) == [  # cpu's sizes on cpu_fast
        "--policy.point_encoder_hidden_dims=[64,128,256,512]", "--policy.dit_hidden_dim=192",
        "--policy.time_embed_hidden_dim=256"]
    fast = {**cpu, "preset": "cpu_fast", "point_encoder_hidden_dims": [64, 128], "dit_hidden_dim": 128,
            "time_embed_hidden_dim": 128, "fusion_gate_lr_scale": 10.0}
    assert preset_flags(fast) == []
    assert preset_flags({**fast, "fusion_gate_lr_scale": 1.0}) == ["--policy.fusion_gate_lr_scale=1.0"]


def test_a_joined_source_kept_for_its_recoveries_says_so_on_the_card():
    """`mix_views.py --source ROOT:N:WEIGHT` records the weight in the view's `mixed_from`; the card's data
    sentence names it, and names nothing for an unweighted source."""
    ship = load_script("scripts/ship_checkpoint.py")
    assert ship.weighted({"root": "r", "episodes": 100, "condition": "stage"}) == ""
    random_source = {"condition": "random", "outside_recovery_weight": 0.0}
    assert "weigh 0.0 in the action losses" in ship.weighted(random_source)
    assert "recoveries' frames weigh 0.5" in ship.weighted({"condition": "random", "recovery_weight": 0.5})
    assert ship.weighted({"condition": "random", "all_frames_weight": 0.0}, [*range(14)]) == (
        "; every frame weighs 0.0 in action dims 0-13 of the action losses, 1 in the others")
    text = ship.mixed_data_text({"episodes": 200, "frames": 97071, "mixed_from": [
        {"root": "s", "episodes": 100, "condition": "stage"},
        {"root": "r", "episodes": 100, "condition": "random", "outside_recovery_weight": 0.0}]}, "")
    assert "(stage)" in text and "(random; frames outside the view recoveries weigh 0.0" in text
    data = {"episodes": 200, "frames": 97071, "mixed_from": [
        {"root": "r", "episodes": 100, "condition": "random", "recovery_weight": 0.0}]}
    camera_only = ship.mixed_data_text(data, "", {"sample_weights": True, "loss_weight_dims": [*range(14)]})
    assert "recoveries' frames weigh 0.0 in action dims 0-13 of the action losses, 1 in" in camera_only
    unused = ship.mixed_data_text(data, "", {"sample_weights": False})
    assert "weights unused" in unused and "weigh 0.0" not in unused
    assert ship.dims_text([0, 1, 2, 5, 7, 8]) == "0-2, 5, 7-8"


def test_temporal_ensembling_is_written_into_the_shipped_config_and_card(tmp_path):
    """`--temporal-ensemble-coeff` with `--n-action-steps` re-ships a checkpoint whose config turns ACT's
    ensembling on and whose card says so; chunks that would not overlap, or none executed, are refused
    before anything is written. `--task` names the task for the card, as on a fresh clone (no training data,
    no evaluation)."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    repo = Path(__file__).resolve().parents[1]
    base = [sys.executable, str(repo / "scripts/ship_checkpoint.py"), "--checkpoint",
            str(repo / "checkpoints/afar_cube_handoff_sf"), "--step", "004000", "--point-frame", "base",
            "--task", "cube_handoff"]
    out = tmp_path / "te"
    ensemble = ["--n-action-steps", "4", "--temporal-ensemble-coeff", "0.01"]
    subprocess.run([*base, *ensemble, "--output", str(out)], check=True, capture_output=True, cwd=repo)
    config = json.loads((out / "config.json").read_text())
    assert (config["n_action_steps"], config["temporal_ensemble_coeff"]) == (4, 0.01)
    card = " ".join((out / "README.md").read_text().split())
    assert "a new one every 4 steps" in card and "temporal ensemble (ACT's, coefficient 0.01" in card
    no_overlap = ["--temporal-ensemble-coeff", "0.01", "--n-action-steps", "15"]
    refused = subprocess.run([*base, *no_overlap, "--output", str(tmp_path / "no")], capture_output=True,
                             text=True, cwd=repo)
    assert refused.returncode != 0
    assert "`n_action_steps` must be < horizon - n_obs_steps + 1 = 15" in refused.stderr
    zero = subprocess.run([*base, "--n-action-steps", "0", "--output", str(tmp_path / "zero")],
                          capture_output=True, text=True, cwd=repo)
    assert zero.returncode != 0 and "--n-action-steps must be >= 1" in zero.stderr
    assert not (tmp_path / "no").exists() and not (tmp_path / "zero").exists()  # refused before any write


def test_action_smoothing_is_written_into_the_shipped_config_and_card(tmp_path):
    """`--smoothed-action-dims 14-20 --action-smoothing-alpha 0.25` re-ships a checkpoint whose config
    low-passes the camera arm's commands and whose card says so; a gripper dim, a bad gain or one flag alone
    is refused before anything is written."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    ship = load_script("scripts/ship_checkpoint.py")
    assert ship.dims_arg("14-20") == tuple(range(14, 21))
    assert ship.dims_arg("0-2,5") == (0, 1, 2, 5)
    repo = Path(__file__).resolve().parents[1]
    base = [sys.executable, str(repo / "scripts/ship_checkpoint.py"), "--checkpoint",
            str(repo / "checkpoints/afar_cube_handoff_sf"), "--step", "004000", "--point-frame", "base",
            "--task", "cube_handoff"]
    out = tmp_path / "lp"
    subprocess.run([*base, "--smoothed-action-dims", "14-20", "--action-smoothing-alpha", "0.25",
                    "--output", str(out)], check=True, capture_output=True, cwd=repo)
    config = json.loads((out / "config.json").read_text())
    assert (config["smoothed_action_dims"], config["action_smoothing_alpha"]) == (list(range(14, 21)), 0.25)
    card = " ".join((out / "README.md").read_text().split())
    assert "action dims 14-20 low-pass filtered at inference (a_t = a_(t-1) + 0.25" in card
    for flags, message in ((["--smoothed-action-dims", "13-14", "--action-smoothing-alpha", "0.25"],
                            "[13] are also `binary_action_dims`"),
                           (["--smoothed-action-dims", "14", "--action-smoothing-alpha", "2"],
                            "must be in (0, 1]"),
                           (["--smoothed-action-dims", "14"], "go together")):
        refused = subprocess.run([*base, *flags, "--output", str(tmp_path / "no")], capture_output=True,
                                 text=True, cwd=repo)
        assert refused.returncode != 0 and message in refused.stderr
        assert not (tmp_path / "no").exists()


def test_a_checkpoint_without_its_training_config_is_refused_before_any_write(tmp_path):
    """The card is written from `train_config.json`; a folder without it (a hand-copied `pretrained_model`)
    is refused with the missing file's name, and `--output` is not created."""
    import shutil
    import subprocess
    import sys
    from pathlib import Path

    repo = Path(__file__).resolve().parents[1]
    src = tmp_path / "copied"
    shutil.copytree(repo / "checkpoints/afar_cube_handoff_sf", src)
    (src / "train_config.json").unlink()
    command = [sys.executable, str(repo / "scripts/ship_checkpoint.py"), "--checkpoint", str(src), "--step",
               "004000", "--point-frame", "base", "--task", "cube_handoff", "--output", str(tmp_path / "out")]
    refused = subprocess.run(command, capture_output=True, text=True, cwd=repo)
    assert refused.returncode != 0
    assert "train_config.json is missing" in refused.stderr
    assert not (tmp_path / "out").exists()


def test_a_fine_tune_card_names_its_start_and_its_episodes():
    """A fine-tune's card command starts from the checkpoint it was fine-tuned from (`--policy.path`), not
    from a policy type and preset it never trained from scratch, and names the episodes it read, with a run of
    consecutive indices written as a `seq` a shell expands (hand-written cases)."""
    ship = load_script("scripts/ship_checkpoint.py")
    assert ship.episodes_text(list(range(400))) == '"[$(seq -s, 0 399)]"'
    assert ship.episodes_text([7, 0, 1, 2, 5, 6]) == "[0,1,2,5,6,7]"
    assert ship.episodes_text([3, 9]) == "[3,9]"
    scratch = {"policy": {"type": "afar", "preset": "cpu_fast"}, "dataset": {"repo_id": "x"}}
    assert ship.start_flags(scratch) == ("--policy.type=afar --policy.preset=cpu_fast", "")
    fine = {"policy": {"type": "afar", "preset": "cpu_fast", "pretrained_path": "checkpoints/a"},
            "dataset": {"repo_id": "x", "episodes": list(range(10))}}
    assert ship.start_flags(fine) == ("--policy.path=checkpoints/a", ' --dataset.episodes="[$(seq -s, 0 9)]"')
