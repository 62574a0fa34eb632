"""Chapter-3 figure logic (thesis_repro.figures.ch3): seed selection, correlation table, frontier, budgets."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from thesis_repro.evaluation import BenchmarkResult
from thesis_repro.figures import ch3


def _result(train_return: np.ndarray, auc: np.ndarray) -> BenchmarkResult:
    res = BenchmarkResult(["a", "b", "c", "d"], ["Hopper", "Walker2d"], [0, 1], {"obs": {}})
    res.train_return = train_return
    res.auc = {"obs": auc}
    return res


def test_best_seed_picks_the_best_training_seed_per_task_and_algo():
    tr = np.array([[[1.0, 9.0]], [[5.0, 2.0]]])
    v = np.array([[[10.0, 90.0]], [[50.0, 20.0]]])
    np.testing.assert_array_equal(ch3.best_seed(tr, v), [[50.0, 90.0]])
    with pytest.raises(ValueError, match="same shape|one shape"):
        ch3.best_seed(tr, v[:, :, :1])
    with pytest.raises(ValueError, match="unknown selection"):
        ch3.select(tr, v, "median")


def test_correlation_table_signs_and_undefined_cells():
    rng = np.random.default_rng(0)
    tr = rng.normal(size=(2, 2, 4)) + np.arange(4.0) * 10  # algo d trains best
    auc = np.empty_like(tr)
    auc[:, 0] = -tr[:, 0]  # Hopper: perfectly anti-correlated
    auc[:, 1] = 7.0  # Walker2d: no spread -> undefined
    table = ch3.correlation_table(_result(tr, auc))
    hop = table[(table.env == "Hopper") & (table.test == "obs")].value.item()
    assert hop == pytest.approx(-1.0)
    assert np.isnan(table[table.env == "Walker2d"].value.item())
    assert set(table.columns) >= {"env", "test", "value", "p", "n"}
    pts = ch3.points_table(_result(tr, auc), "mean")
    assert len(pts) == 2 * 4 and np.allclose(pts[pts.env == "Hopper"].auc, -pts[pts.env == "Hopper"].train_return)


def test_training_return_at_uses_episodes_finished_by_then():
    train = {"episode_timesteps": np.array([10, 20, 30, 40]), "episode_returns": np.array([1.0, 2.0, 3.0, 4.0])}
    out = ch3.training_return_at(train, [5, 20, 40], window=2)
    assert np.isnan(out[0]) and out[1] == 1.5 and out[2] == 3.5


def test_timesteps_for_per_env_budgets():
    assert ch3.timesteps_for(100, "Hopper") == 100
    assert ch3.timesteps_for({"Hopper": 5, "default": 7}, "Hopper") == 5
    assert ch3.timesteps_for({"Hopper": 5, "default": 7}, "Walker2d") == 7
    with pytest.raises(ValueError, match="no training budget"):
        ch3.timesteps_for({"Hopper": 5}, "Walker2d")


def test_benchmark_orders_jobs_seed_env_algo():
    b = ch3.benchmark(
        ["ppo", "ppo-16"],
        ["Hopper", "InvertedPendulum"],
        [0, 1],
        {"Hopper": 300, "default": 200},
        ["obs"],
        sigmas=[0.0, 0.5],
        n_rollouts=2,
    )
    cfgs = [j.config for j in b.train_jobs]
    assert [(c["seed"], c["env"], c["algorithm"]) for c in cfgs][:4] == [
        (0, "Hopper", "ppo"),
        (0, "Hopper", "ppo-16"),
        (0, "InvertedPendulum", "ppo"),
        (0, "InvertedPendulum", "ppo-16"),
    ]
    assert {c["env"]: c["timesteps"] for c in cfgs} == {"Hopper": 300, "InvertedPendulum": 200}
    assert [j.config["train"] for j in b.eval_jobs["obs"]] == cfgs


def test_snapshot_steps_follow_iteration_boundaries():
    cfg = {"class": "PPO", "n_envs": 8, "sb3": {"n_steps": 256}, "timesteps": 10_000, "snapshot_every": 5000}
    assert ch3.snapshot_steps(cfg) == [0, 6144, 10240]  # first iteration start >= 5000 after 0, then the end
    assert ch3.snapshot_steps({**cfg, "snapshot_every": 0}) == []
    with pytest.raises(ValueError, match="on-policy"):
        ch3.snapshot_steps({**cfg, "class": "SAC"})


def test_frontier_keeps_the_pareto_optimal_variants_of_a_panel():
    trade = pd.DataFrame({"algo": ["a", "b", "c"], "train_return": [1.0, 2.0, 3.0], "auc": [3.0, 2.0, 1.0]})
    assert ch3.frontier(trade).algo.tolist() == ["a", "b", "c"]  # every variant trades one for the other
    dominant = trade.assign(auc=[1.0, 2.0, 3.0])
    assert ch3.frontier(dominant).algo.tolist() == ["c"]  # one variant is best at both
    assert ch3.frontier(trade.assign(auc=np.nan)).empty  # no finite point (a smoke run)
