"""Visibility ratio, CVG accounting and the task metrics (paper Sec. 3, Appendix A)."""

from __future__ import annotations

import numpy as np
import pytest

from lerobot_bavo.metrics import (
    CVG_HORIZON,
    CVGAccumulator,
    CVGEventRecord,
    aggregate_cvg,
    episode_cvg,
    event_cvg,
    joint_score,
    normalized_visibility,
    success_rate,
    task_progress_score,
)


def test_normalized_visibility():
    assert normalized_visibility(30, 120) == 0.25
    assert normalized_visibility(0, 50) == 0.0
    assert normalized_visibility(50, 50) == 1.0
    assert normalized_visibility(0, 0) == 0.0  # N_noOcc = 0 -> 0
    assert normalized_visibility(np.int64(3), np.int64(4)) == 0.75
    with pytest.raises(ValueError):
        normalized_visibility(-1, 10)
    with pytest.raises(ValueError):
        normalized_visibility(0, -1)
    with pytest.raises(ValueError):
        normalized_visibility(11, 10)
    with pytest.raises(ValueError):
        normalized_visibility(1, 0)
    with pytest.raises(TypeError):
        normalized_visibility(1.5, 10)


def test_event_cvg_frozen_camera_is_exactly_zero():
    rng = np.random.default_rng(0)
    v = rng.random(CVG_HORIZON).tolist()
    assert event_cvg(v, v) == 0.0
    assert event_cvg(v, list(v), horizon=CVG_HORIZON) == 0.0


def test_event_cvg_hand_computed():
    realized = [0.1, 0.5, 0.9, 1.0]
    frozen = [0.1, 0.1, 0.2, 0.2]
    assert event_cvg(realized, frozen, horizon=4) == pytest.approx((0 + 0.4 + 0.7 + 0.8) / 4)
    assert event_cvg(realized, frozen, horizon=4) == pytest.approx(0.475)
    # Samples beyond H do not count.
    assert event_cvg([*realized, 0.0], [*frozen, 1.0], horizon=4) == pytest.approx(0.475)
    # Negative when the camera moves to a worse view.
    assert event_cvg(frozen, realized, horizon=4) == pytest.approx(-0.475)


def test_event_cvg_truncated_window_is_none():
    assert event_cvg([0.5, 0.6, 0.7], [0.1, 0.1, 0.1], horizon=4) is None
    assert event_cvg([], [], horizon=4) is None
    assert event_cvg([0.5] * 59, [0.0] * 59) is None  # default H = 60
    assert event_cvg([0.5] * 60, [0.0] * 60) == pytest.approx(0.5)
    with pytest.raises(ValueError):
        event_cvg([0.1, 0.2], [0.1], horizon=2)
    with pytest.raises(ValueError):
        event_cvg([0.1], [0.1], horizon=0)


def test_truncated_events_excluded_from_episode_mean():
    assert episode_cvg([0.2, None, 0.4]) == pytest.approx(0.3)  # not (0.2 + 0 + 0.4) / 3
    assert episode_cvg([None, None]) is None
    assert episode_cvg([]) is None


def test_episodes_weigh_equally():
    # Episode A: three events, episode B: one event, episode C: none retained.
    ep_a = episode_cvg([0.1, 0.1, 0.1])
    ep_b = episode_cvg([0.5])
    ep_c = episode_cvg([None])
    dataset = aggregate_cvg([ep_a, ep_b, ep_c])
    assert dataset == pytest.approx((0.1 + 0.5) / 2)  # 0.3
    event_weighted = (0.1 + 0.1 + 0.1 + 0.5) / 4  # 0.2: what pooling events would give
    assert dataset != pytest.approx(event_weighted)
    assert aggregate_cvg([None, None]) is None


def test_success_rate_and_tps():
    assert success_rate([True, False, True, True]) == 75.0
    assert success_rate(np.array([1, 0])) == 50.0
    with pytest.raises(ValueError):
        success_rate([])
    assert task_progress_score([5, 0, 3]) == pytest.approx(53.333333, abs=1e-4)
    assert task_progress_score([5, 5]) == 100.0
    assert task_progress_score([np.int64(2)]) == pytest.approx(40.0)
    for bad in ([6], [-1]):
        with pytest.raises(ValueError):
            task_progress_score(bad)
    for bad in ([2.5], [True]):
        with pytest.raises(TypeError):
            task_progress_score(bad)
    with pytest.raises(ValueError):
        task_progress_score([])


def test_joint_score():
    # Table 4 convention: SR in percent, CVG in pp.
    assert joint_score(50.0, 20.0) == pytest.approx(10.0)
    assert joint_score(0.0, 32.81) == 0.0
    assert joint_score(80.0, None) is None


def test_event_record_cvg():
    rec = CVGEventRecord(index=0, start_step=10, target_name="cube", v_realized=[0.1, 0.5, 0.9, 1.0],
                         v_frozen=[0.1, 0.1, 0.2, 0.2])
    assert rec.cvg(4) == pytest.approx(0.475)
    assert rec.cvg(5) is None
    assert rec.covers(10, 4) and rec.covers(13, 4) and not rec.covers(14, 4) and not rec.covers(9, 4)


def test_accumulator_two_events_episode_ends_mid_window():
    H = 4
    acc = CVGAccumulator(horizon=H)
    # Event 0 at step 0, event 1 at step 6; the episode ends after step 7 (inside event 1's window).
    realized = {0: 0.1, 1: 0.5, 2: 0.9, 3: 1.0, 4: 0.3, 5: 0.3, 6: 0.0, 7: 0.6}
    frozen = {0: 0.1, 1: 0.1, 2: 0.2, 3: 0.2, 4: 0.9, 5: 0.9, 6: 0.0, 7: 0.1}
    for step in range(8):
        if step == 0:
            assert acc.start_event(step, "cube") == 0
        if step == 6:
            assert acc.start_event(step, "bin") == 1
        acc.record(step, realized[step], frozen[step])
    out = acc.close_episode()
    assert out["horizon"] == H
    assert out["num_events"] == 2 and out["num_retained"] == 1
    e0, e1 = out["events"]
    assert (e0["index"], e0["start_step"], e0["target"], e0["num_samples"]) == (0, 0, "cube", 4)
    assert e0["cvg"] == pytest.approx(0.475)  # steps 4, 5 fall outside its window
    assert (e1["index"], e1["start_step"], e1["target"], e1["num_samples"]) == (1, 6, "bin", 2)
    assert e1["cvg"] is None  # truncated: excluded, not padded
    assert out["episode_cvg"] == pytest.approx(0.475)
    # The accumulator is empty for the next episode.
    assert acc.close_episode() == {"horizon": H, "events": [], "num_events": 0, "num_retained": 0,
                                   "episode_cvg": None}


def test_accumulator_overlapping_windows_keep_their_own_h_steps():
    acc = CVGAccumulator(horizon=3)
    acc.start_event(0, "a")
    acc.record(0, 0.0, 0.0)
    acc.start_event(1, "b")
    assert acc.open_events(1) == [0, 1]
    # Per-event values (each event has its own frozen pose/occluder/target).
    acc.record(1, {0: 0.6, 1: 0.2}, {0: 0.0, 1: 0.2})
    acc.record(2, {0: 0.9, 1: 0.5}, {0: 0.0, 1: 0.2})
    assert acc.open_events(3) == [1]
    acc.record(3, 0.8, 0.2)  # a float applies to every open event (only event 1 here)
    out = acc.close_episode()
    assert out["events"][0]["cvg"] == pytest.approx((0 + 0.6 + 0.9) / 3)
    assert out["events"][1]["cvg"] == pytest.approx((0 + 0.3 + 0.6) / 3)
    assert out["episode_cvg"] == pytest.approx((0.5 + 0.3) / 2)


def test_accumulator_rejects_skipped_steps_and_missing_values():
    acc = CVGAccumulator(horizon=4)
    acc.start_event(5, "a")
    acc.record(3, 0.0, 0.0)  # before the window: ignored
    acc.record(5, 0.0, 0.0)
    with pytest.raises(ValueError):
        acc.record(7, 0.0, 0.0)  # step 6 was skipped
    acc = CVGAccumulator(horizon=4)
    acc.start_event(0, "a")
    with pytest.raises(KeyError):
        acc.record(0, {1: 0.0}, 0.0)
    with pytest.raises(ValueError):
        CVGAccumulator(horizon=0)


def test_wilson_interval_by_hand():
    """95 % Wilson interval: 0 of n has upper bound z^2 / (n + z^2); n of n the mirror image; 19 of 40 by
    hand."""
    from lerobot_bavo.metrics import wilson_interval

    z2 = 1.959964 ** 2
    low, high = wilson_interval(0, 20)
    assert low == 0.0 and high == pytest.approx(100 * z2 / (20 + z2))
    low, high = wilson_interval(20, 20)
    assert high == 100.0 and low == pytest.approx(100 * 20 / (20 + z2))
    # p = 0.475, n = 40: centre (p + z^2/80) / (1 + z^2/40), half z sqrt(p(1-p)/40 + z^2/6400) / (1 + z^2/40)
    centre = (0.475 + z2 / 80) / (1 + z2 / 40)
    half = 1.959964 * (0.475 * 0.525 / 40 + z2 / 6400) ** 0.5 / (1 + z2 / 40)
    assert wilson_interval(19, 40) == pytest.approx((100 * (centre - half), 100 * (centre + half)))
    assert wilson_interval(19, 40) == pytest.approx((32.94, 62.50), abs=0.01)
    with pytest.raises(ValueError):
        wilson_interval(3, 2)


def test_mcnemar_exact_p_by_hand():
    """Exact two-sided McNemar: 0 vs 5 discordant is 2 / 2^5; 1 vs 4 is 2 (1 + 5) / 2^5; a tie is 1."""
    from lerobot_bavo.metrics import mcnemar_exact_p

    assert mcnemar_exact_p(0, 5) == pytest.approx(2 / 32)
    assert mcnemar_exact_p(4, 1) == pytest.approx(12 / 32)
    assert mcnemar_exact_p(3, 3) == 1.0
    assert mcnemar_exact_p(0, 0) == 1.0
    with pytest.raises(ValueError):
        mcnemar_exact_p(-1, 2)


def test_paired_outcomes_matches_episodes_by_seed(tmp_path, capsys):
    """Episodes pair on (task, condition, seed) whatever their order; one only in A is left out."""
    import importlib.util
    import json
    from pathlib import Path

    spec = importlib.util.spec_from_file_location(
        "paired_outcomes", Path(__file__).resolve().parent.parent / "scripts" / "paired_outcomes.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    def rows(outcomes):
        return [{"task": "t", "condition": "stage", "seed": s, "success": w} for s, w in outcomes]

    a = rows([(1, True), (2, True), (3, False), (4, True)])
    b = rows([(3, True), (2, True), (1, False)])
    assert module.paired_counts(a, b) == {"stage": (3, 2, 1, 1)}
    for name, rows in (("a.jsonl", a), ("b.jsonl", b)):
        (tmp_path / name).write_text("".join(json.dumps(r) + "\n" for r in rows))
    module.main([f"{tmp_path / 'a.jsonl'}={tmp_path / 'b.jsonl'}"])
    assert "stage: 3 paired episodes, A won 2, B 2; A only 1, B only 1; McNemar exact p = 1.000" in \
        capsys.readouterr().out
    # a pair without "=" and a missing log are usage errors naming them, before any log is read
    for pair, message in ((str(tmp_path / "a.jsonl"), "want A_LOG=B_LOG"),
                          (f"{tmp_path / 'a.jsonl'}={tmp_path / 'gone.jsonl'}", "no episode log at")):
        with pytest.raises(SystemExit) as exit_info:
            module.main([pair])
        assert exit_info.value.code == 2
        assert message in capsys.readouterr().err


def test_paired_outcomes_gate_reads_the_pooled_net_change(tmp_path, capsys):
    """Two pairs pooled: Stage A only 3, B only 1 (net +2); Clean A only 0, B only 2 (net -2)."""
    import importlib.util
    import json
    from pathlib import Path

    spec = importlib.util.spec_from_file_location(
        "paired_outcomes", Path(__file__).resolve().parent.parent / "scripts" / "paired_outcomes.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)

    def write(name, outcomes):
        rows = [{"task": "t", "condition": c, "seed": s, "success": w} for c, s, w in outcomes]
        (tmp_path / name).write_text("".join(json.dumps(r) + "\n" for r in rows))
        return str(tmp_path / name)

    a1 = write("a1.jsonl", [("stage", 1, True), ("stage", 2, True), ("clean", 1, False)])
    b1 = write("b1.jsonl", [("stage", 1, False), ("stage", 2, False), ("clean", 1, True)])
    a2 = write("a2.jsonl", [("stage", 1, True), ("stage", 2, False), ("clean", 1, False)])
    b2 = write("b2.jsonl", [("stage", 1, False), ("stage", 2, True), ("clean", 1, True)])
    pairs = [f"{a1}={b1}", f"{a2}={b2}"]
    for flags, code, last in (
        (["--min-gain", "stage=2", "--max-loss", "clean=2"], 0, "gate passed"),
        (["--min-gain", "stage=3"], 1, "gate not passed: stage net 2 < +3"),
        (["--min-gain", "stage=2", "--max-loss", "clean=1"], 1, "gate not passed: clean net -2 < -1"),
        (["--min-gain", "random=0"], 1, "gate not passed: random net None < +0"),
    ):
        with pytest.raises(SystemExit) as exit_info:
            module.main(pairs + flags)
        assert exit_info.value.code == code
        assert capsys.readouterr().out.strip().splitlines()[-1] == last
    with pytest.raises(SystemExit) as exit_info:
        module.main(pairs + ["--min-gain", "stage"])
    assert exit_info.value.code == 2
    assert "expected CONDITION=COUNT" in capsys.readouterr().err
