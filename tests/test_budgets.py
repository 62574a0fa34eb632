"""Learning-curve statistics behind the trained-regime budgets (thesis_repro.budgets)."""

from __future__ import annotations

import numpy as np
import pytest

from thesis_repro import budgets
from thesis_repro.__main__ import main


def test_thesis_training_returns_are_table_3_3a():
    ret = budgets.thesis_training_returns()
    assert ret == {
        ("ppo", "Walker2d"): 3128.6,
        ("ppo-obsnoise", "Walker2d"): 1424.0,
        ("ppo-actnoise", "Walker2d"): 2694.8,
        ("ppo-envnoise", "Walker2d"): 3261.3,
        ("ppo-mdl", "Walker2d"): 2445.3,
    }


def test_curve_stats_on_a_saturating_and_a_linear_curve():
    t = np.arange(1, 1001) * 1000  # episodes ending every 1000 steps of a 1M budget
    flat = budgets.curve_stats(t, np.minimum(t / 100.0, 2000.0), 1e6)
    assert flat["final"] == pytest.approx(2000.0) and flat["half"] == pytest.approx(2000.0) and flat["gain"] == 0
    lin = budgets.curve_stats(t, t / 100.0, 1e6)
    assert lin["final"] == pytest.approx(np.mean(np.arange(901, 1001) * 10.0))
    assert lin["half"] == pytest.approx(np.mean(np.arange(401, 501) * 10.0))
    assert lin["gain"] == pytest.approx((9505 - 4505) / 9505)
    assert np.isnan(budgets.curve_stats(t[:10], t[:10] / 100.0, 1e6)["final"])  # no episode late in the budget


def test_judge_uses_the_thesis_return_where_given_else_the_plateau():
    assert budgets.judge(0.7 * 3128.6, 0.5, 3128.6) == "trained"
    assert budgets.judge(0.69 * 3128.6, 0.0, 3128.6) == "still learning"
    assert budgets.judge(500.0, 0.1, None) == "trained"
    assert budgets.judge(500.0, 0.11, None) == "still learning"
    assert budgets.judge(500.0, float("nan"), None) == "still learning"


def test_budgets_command_lists_untrained_runs_and_rejects_bad_scales(capsys):
    assert main(["budgets", "--scale", "smoke", "--figures", "3.3"]) == 0
    out = capsys.readouterr().out
    assert "InvertedPendulum" in out and "not trained yet" in out
    assert main(["budgets", "--scale", "huge"]) == 2
    assert "smoke" in capsys.readouterr().err
