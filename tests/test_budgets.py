"""Learning-curve statistics behind the trained-regime budgets (thesis_repro.runs.budgets)."""

from __future__ import annotations

import numpy as np
import pytest

from thesis_repro.cli.commands import main
from thesis_repro.runs import budgets


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
    bump = budgets.curve_stats(t, np.where(t <= 5e5, t / 100.0, 1000.0), 1e6)  # rises to 5,000, drops to 1,000
    assert bump["peak"] == pytest.approx(np.mean(np.arange(401, 501) * 10.0)) and bump["final"] == 1000.0


def test_extrapolation_and_judgement():
    # log-linear: +500 per doubling, 1M -> 4M is two doublings
    assert budgets.extrapolate(1500.0, 1000.0, 1e6, 4e6) == 2500.0
    assert budgets.extrapolate(1500.0, 1000.0, 2e6, 4e6) == 2000.0
    assert budgets.extrapolate(1500.0, 1600.0, 1e6, 4e6) == 1500.0  # a falling curve is not extrapolated down
    assert budgets.extrapolate(1500.0, 1000.0, 4e6, 4e6) == 1500.0
    # the thesis's own training return wins where it exists (Table 3.3a)
    assert budgets.training_verdict(0.7 * 3128.6, 0.0, 1e6, 3128.6) == (pytest.approx(0.7), "trained")
    assert budgets.training_verdict(0.69 * 3128.6, 2000.0, 1e6, 3128.6)[1] == "still learning"
    # else the extrapolated 4e6 return: at 1M, 1000 after 833.3 at 500k -> 1000 + 2 * 166.7 = 1333.3 at 4M
    assert budgets.training_verdict(1000.0, 2500.0 / 3, 1e6, None) == (pytest.approx(0.75), "trained")
    assert budgets.training_verdict(1000.0, 600.0, 1e6, None) == (pytest.approx(1000 / 1800), "still learning")
    assert budgets.training_verdict(float("nan"), 1.0, 1e6, None)[1] == "still learning"
    # a run that collapsed (PPO) is judged against its own peak, not against a flat extrapolation
    assert budgets.training_verdict(2839.0, 5142.0, 1e6, None, peak=8000.0) == (
        pytest.approx(2839 / 8000),
        "fell from its peak",
    )
    assert budgets.training_verdict(7900.0, 8100.0, 1e6, None, peak=8200.0) == (pytest.approx(7900 / 8200), "trained")
    assert budgets.training_verdict(1500.0, 1000.0, 1e6, None, peak=1600.0)[0] == pytest.approx(
        0.6
    )  # extrapolation larger
    # a bounded task: the extrapolation stops at the largest possible return (InvertedDoublePendulum: 10/step)
    assert budgets.training_verdict(9191.0, 6308.0, 1e6, None, ceiling=10_000.0) == (pytest.approx(0.9191), "trained")
    assert budgets.THESIS_STEPS == 4_000_000


def test_budgets_command_lists_untrained_runs_and_rejects_bad_scales(capsys):
    assert main(["budgets", "--scale", "smoke", "--figures", "3.3"]) == 0
    out = capsys.readouterr().out
    assert "InvertedPendulum" in out and "not trained yet" in out
    assert main(["budgets", "--scale", "huge"]) == 2
    assert "smoke" in capsys.readouterr().err
