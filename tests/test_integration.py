"""The pieces compose: any kit learner (single- or multi-domain) goes through the same cache and evaluation."""

from __future__ import annotations

import numpy as np
import pytest

from thesis_repro.cache import Job, RunCache
from thesis_repro.learners import ALGORITHMS, MULTI_DOMAIN, train_config


def test_multi_domain_learners_are_ordinary_kit_learners():
    assert set(MULTI_DOMAIN) <= set(ALGORITHMS)
    cfg = train_config("kl_avg", "Hopper", 0, 4096, perturbation="dom", sigma=0.2)
    assert cfg["algorithm"] == "kl_avg" and cfg["perturbation"] == "dom" and cfg["n_domains"] == 4
    with pytest.raises(ValueError, match="valid algorithms are: .*'kl_avg'"):
        train_config("kl-avg", "Hopper", 0, 4096)


def test_joint_trains_and_evaluates_through_the_chapter3_pipeline():
    train = train_config("joint", "InvertedPendulum", 0, 128, n_domains=2, steps_per_domain=64,
                         perturbation="dom", sigma=0.2)
    test = {"perturbation": "obs", "sigmas": [0.0, 0.5], "n_rollouts": 2, "max_episode_steps": 20}
    res = RunCache().run(Job("thesis_repro.evaluation:evaluate_job", {"train": train, "test": test}))
    assert res["returns"].shape == (2, 2)
    assert np.all(res["returns"] > 0) and np.all(res["lengths"] <= 20)
    assert res["auc"] == pytest.approx(0.5 * res["expected_return"].sum())  # Eq 3.6: dsigma * sum of eta
