"""`scripts/seed_spread.py`: the binomial variance of an SR and the between-seed variance on hand-computed
cases, and the ratio it prints from hand-made grid runs."""

import json

import pytest
from _helpers import load_script


def write_run(root, method, seed, wins_by_condition, episodes=40):
    folder = root / method / seed / "cube_handoff"
    folder.mkdir(parents=True)
    lines = [json.dumps({"task": "cube_handoff", "condition": c, "seed": 2000 + i, "success": i < wins})
             for c, wins in wins_by_condition.items() for i in range(episodes)]
    (folder / "episodes.jsonl").write_text("\n".join(lines) + "\n")


def test_binomial_variance_and_seed_spread_by_hand():
    spread = load_script("scripts/seed_spread.py")
    assert spread.binomial_variance(0.5, 40) == pytest.approx(0.25 / 40)
    assert spread.binomial_variance(0.0, 40) == 0.0
    # 0.5, 0.6, 0.7: mean 0.6, sample variance ((-0.1)^2 + 0 + 0.1^2) / 2 = 0.01, binomial 0.24 / 40 = 0.006
    mean, observed, binomial = spread.seed_spread([0.5, 0.6, 0.7], 40)
    assert (mean, observed, binomial) == pytest.approx((0.6, 0.01, 0.006))
    with pytest.raises(ValueError, match="two training seeds"):
        spread.seed_spread([0.5], 40)
    with pytest.raises(ValueError, match="one episode"):
        spread.binomial_variance(0.5, 0)


def test_the_ratio_sums_over_methods_and_skips_incomplete_ones(tmp_path, capsys):
    spread = load_script("scripts/seed_spread.py")
    # method a: Stage 20, 24, 28 of 40 (0.5, 0.6, 0.7); method b: Stage 24 of 40 three times (variance 0)
    for seed, wins in zip(("s1000", "s1001", "s1002"), (20, 24, 28)):
        write_run(tmp_path, "a", seed, {"stage": wins})
        write_run(tmp_path, "b", seed, {"stage": 24})
    write_run(tmp_path, "c", "s1000", {"stage": 40})  # one seed only: not read
    spread.main(["--runs", str(tmp_path), "--task", "cube_handoff"])
    out = capsys.readouterr().out
    assert "| a | stage | 60.0 | 10.0 | 7.7 |" in out
    assert "| b | stage | 60.0 | 0.0 | 7.7 |" in out
    assert "| c |" not in out
    # (0.01 + 0) / (0.006 + 0.006) = 0.83
    assert "stage: 2 methods; SD between seeds 7.1 points, binomial 7.7; variance ratio 0.83" in out
    assert "clean: no method with all of s1000, s1001, s1002" in out
