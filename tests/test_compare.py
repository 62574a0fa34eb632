"""A comparison a reader can read: your agent against the plain learners and the best of the rest (highlighted,
the others faded), the shipped learners' training budgets, and a paired test against any named learner."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from thesis_repro.book import agent
from thesis_repro.cli.commands import main

ROOT = Path(__file__).resolve().parents[1]
LAYER = ROOT / "data" / "reference"
pytestmark = pytest.mark.xdist_group("compare")  # one worker scores the module's agent once


@pytest.fixture(scope="module")
def comparison(tmp_path_factory):
    """An untrained PPO on InvertedPendulum beside the shipped learners (scale small), scored once."""
    if not (LAYER / "evaluate").is_dir():
        pytest.skip("no shipped evaluations (data/reference/evaluate)")
    from stable_baselines3 import PPO

    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("THESIS_REPRO_REFERENCE", str(LAYER))
        mp.setenv("THESIS_REPRO_DATA", str(tmp_path_factory.mktemp("runs")))
        model = PPO("MlpPolicy", "InvertedPendulum-v5", n_steps=64, batch_size=32, seed=0, device="cpu")
        scores = agent.score_model(model, "InvertedPendulum", "small", progress=False)
        yield agent.compare_with_shipped(scores, timesteps=64)


def test_budgets_are_shown_beside_the_aucs(comparison):
    wide = comparison.wide()
    assert wide.loc["your agent", "train steps"] == "64"
    assert wide.loc["ppo", "train steps"] == "200k"  # the shipped InvertedPendulum runs' budget


def test_the_figure_highlights_the_plain_learners_and_the_best_other(comparison):
    best = comparison.best_other()
    assert best is not None and best not in agent.PLAIN
    legend = [t.get_text() for t in comparison.figure.legends[0].get_texts()]
    assert legend[0] == "your agent (64 steps)"
    assert [t.split(" ")[0] for t in legend[1:6]] == [*agent.PLAIN, best]
    assert legend[-1].startswith("others (") and legend[-1].endswith(", faded)")
    faded = [ln for ln in comparison.figure.axes[0].get_lines() if ln.get_alpha() == 0.35]
    assert len(faded) == len(comparison.learners) - 5


def test_a_paired_test_against_a_named_learner(comparison):
    v = comparison.versus("ppo")
    assert list(v["test"]) == ["obs", "act", "env", "dom"]
    a = comparison.aucs
    for r in v.itertuples():
        mine = a[(a["method"] == "your agent") & (a["test"] == r.test)].groupby("rollout")["value"].mean()
        theirs = a[(a["method"] == "ppo") & (a["test"] == r.test)].groupby("rollout")["value"].mean()
        assert r.difference == pytest.approx(float((mine - theirs).mean()))
        assert r.ci_lo < r.difference < r.ci_hi and r.rollouts == 10
        assert np.isnan(r.welch_p)  # one training seed of yours: no Welch test across seeds
    text = comparison.versus_text("ppo")
    assert text.startswith("your agent minus ppo, testing AUC paired by rollout (95 % CI over rollouts):")
    with pytest.raises(ValueError, match="^unknown learner 'ppo2'; valid learners are: 'ppo', 'trpo'"):
        comparison.versus("ppo2")


def test_score_versus_on_the_command_line_in_80_columns(tmp_path, monkeypatch, capsys):
    if not (LAYER / "evaluate").is_dir():
        pytest.skip("no shipped evaluations (data/reference/evaluate)")
    from stable_baselines3 import PPO

    monkeypatch.setenv("THESIS_REPRO_REFERENCE", str(LAYER))
    monkeypatch.setenv("COLUMNS", "80")
    PPO("MlpPolicy", "InvertedPendulum-v5", n_steps=64, batch_size=32, seed=0, device="cpu").save(tmp_path / "m.zip")
    argv = ["score", str(tmp_path / "m.zip"), "--task", "InvertedPendulum", "--scale", "small", "--versus", "sac"]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "your agent minus sac, testing AUC paired by rollout" in out and "train steps" in out
    assert all(len(line) <= 80 for line in out.splitlines()), max(out.splitlines(), key=len)
    assert "AUC (thesis Eq 3.6): the area under testing return vs σ" in out
    assert "ppo-reptile-dg" in out and "your agent" in out
    assert main([*argv[:-1], "sac2"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith("error: unknown learner 'sac2'; valid learners are: 'ppo'")
    assert main([*argv, "--no-compare"]) == 2
    assert capsys.readouterr().err.startswith("error: --figure and --versus show the comparison; drop --no-compare")
