"""The pieces compose: any kit learner (single- or multi-domain) goes through the same cache and evaluation."""

from __future__ import annotations

import numpy as np
import pytest

from thesis_repro.core.cache import Job, RunCache
from thesis_repro.learners import ALGORITHMS, MULTI_DOMAIN, train_config


def test_multi_domain_learners_are_ordinary_kit_learners():
    assert set(MULTI_DOMAIN) <= set(ALGORITHMS)
    cfg = train_config("kl-avg", "Hopper", 0, 4096, perturbation="dom", sigma=0.2)
    assert cfg["algorithm"] == "kl-avg" and cfg["perturbation"] == "dom" and cfg["n_envs"] == 4
    assert cfg["class"] == "SubPolicyAggregation" and train_config("joint", "Hopper", 0, 1)["class"] == "PPO"
    with pytest.raises(ValueError, match="valid algorithms are: .*'kl-avg'"):
        train_config("kl_avg", "Hopper", 0, 4096)


def test_joint_trains_and_evaluates_through_the_chapter3_pipeline():
    train = train_config("joint", "InvertedPendulum", 0, 128, n_envs=2, n_steps=64, perturbation="dom", sigma=0.2)
    test = {"perturbation": "obs", "sigmas": [0.0, 0.5], "n_rollouts": 2, "max_episode_steps": 20}
    res = RunCache().run(Job("evaluate", {"train": train, "test": test}))
    assert res["returns"].shape == (2, 2)
    assert np.all(res["returns"] > 0) and np.all(res["lengths"] <= 20)
    assert res["auc"] == pytest.approx(0.5 * res["expected_return"].sum())  # Eq 3.6: dsigma * sum of eta


def test_chapter4_run_evaluates_under_wind_and_its_own_action_penalty():
    """One evaluation job for every learner: a wind sweep is a list of fixed-wind ``ratios``; c_a follows training."""
    train = train_config("kl-avg", "Hopper", 0, 64, n_envs=2, n_steps=32, batch_size=32, n_epochs=1,
                         c_a=1.0, wind=[-0.5, 0.5], max_episode_steps=20)  # fmt: skip
    test = {"perturbation": "none", "ratios": [{"wind": -3.0}, {"wind": 3.0}], "n_rollouts": 2, "max_episode_steps": 20}
    res = RunCache().run(Job("evaluate", {"train": train, "test": test}))
    assert res["returns"].shape == (2, 2) and res["auc"] is None
    cheap = RunCache().run(Job("evaluate", {"train": train, "test": {**test, "c_a": 0.0}}))
    assert np.all(cheap["returns"] > res["returns"])  # the same episodes without the action penalty earn more
