"""Hyperparameters of the multi-domain learners (thesis §4.3.1 and Appendix A) and their resolved configs.

>>> cfg = mdl_config("kl_avg", "Walker2d", seed=0, timesteps=8192, c_a=1.0, wind=[-2.5, 2.5])
>>> cfg["n_domains"] * cfg["steps_per_domain"], cfg["batch_size"], cfg["c_a"]
(4096, 64, 1.0)
>>> mdl_config("kl_avg", "Walker2d", 0, 100, dampin=1.0)  # doctest: +ELLIPSIS
Traceback (most recent call last):
...
ValueError: unknown setting of kl_avg 'dampin'; valid setting of kl_avgs are: ...
"""

from __future__ import annotations

import copy
from typing import Any

from thesis_repro.validation import check_choice, check_nonneg, check_positive

#: Learners of this package (names as used across the kit).
ALGORITHMS: tuple[str, ...] = ("joint", "ppo-epopt", "ppo-maml-dg", "ppo-reptile-dg", "params_avg", "kl_avg")

#: Shared PPO settings: Appendix A / §4.3.1 (per domain: batch 1024, minibatch 64; joint: 4 x 1024 = 4096).
COMMON: dict[str, Any] = {
    "n_domains": 4,  # domains sampled per iteration (one worker env each)
    "steps_per_domain": 1024,  # T of Alg 3; joint merges the 4 batches into one batch of 4096
    "batch_size": 64,
    "n_epochs": 10,
    "learning_rate": 3.0e-4,
    "gamma": 0.99,
    "gae_lambda": 0.98,
    "clip_range": 0.2,
    "ent_coef": 0.0,
    "vf_coef": 0.5,
    "max_grad_norm": 0.5,
    "net_arch": [64, 64],  # tanh MLPs for policy and value
    "normalize_obs": True,  # running-mean observation filter (shared by all domain workers)
    "clip_obs": 5.0,
    "c_a": None,  # action penalty of Eq 4.12; None: the task's own (Walker2d/Hopper v5: 0.001; pendulums: none)
    "wind": None,  # [low, high]: wind xi ~ U(low, high) once per episode (chapter 4)
    "perturbation": "none",  # chapter-3 training domains: "dom" with sigma 0.2 for PPO-MDL
    "sigma": 0.0,
    "max_episode_steps": None,
    "checkpoint_every": 10,  # iterations between resumable checkpoints in the workdir
}

#: Extra settings per learner.
EXTRA: dict[str, dict[str, Any]] = {
    "joint": {},
    "ppo-epopt": {"epsilon": 0.1, "epopt_warmup": 0},  # worst eps-fraction of trajectories; warm-up iters use all
    "ppo-maml-dg": {"inner_lr": 1.0e-3, "meta_lr": 1.0e-3, "inner_epochs": 1},
    "ppo-reptile-dg": {"inner_lr": 1.0e-3, "meta_lr": 1.0e-3, "inner_epochs": 1},
    "params_avg": {"aggregate_every_epoch": True},
    # damping acts on the mean FIM (TRPO's cg_damping convention); line_search (not in the thesis) backtracks
    # the Eq 4.11 correction until the true Eq 4.7 objective is no worse than at the parameter mean.
    "kl_avg": {"aggregate_every_epoch": True, "cg_iters": 10, "damping": 0.1, "fim_states": 1024, "line_search": False},
}


def mdl_config(algo: str, env: str, seed: int, timesteps: int, **overrides: Any) -> dict[str, Any]:
    """Full resolved config of one run of learner ``algo`` (see :data:`ALGORITHMS`); unknown keys are errors."""
    check_choice(algo, ALGORITHMS, "algorithm")
    if int(seed) != seed or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    check_positive(timesteps, "timesteps")
    cfg: dict[str, Any] = {**copy.deepcopy(COMMON), **copy.deepcopy(EXTRA[algo])}
    for key, value in overrides.items():
        check_choice(key, list(cfg), f"setting of {algo}")
        cfg[key] = value
    cfg.update({"algorithm": algo, "env": env, "seed": int(seed), "timesteps": int(timesteps)})
    validate(cfg)
    return cfg


def validate(cfg: dict[str, Any]) -> None:
    """Raise ``ValueError`` for settings out of range."""
    check_choice(cfg.get("algorithm"), ALGORITHMS, "algorithm")
    for key in ("n_domains", "steps_per_domain", "batch_size", "n_epochs", "checkpoint_every"):
        if int(cfg[key]) != cfg[key] or cfg[key] < 1:
            raise ValueError(f"{key} must be a positive integer, got {cfg[key]!r}")
    if cfg["c_a"] is not None:
        check_nonneg(cfg["c_a"], "c_a")
    if cfg["wind"] is not None and (len(cfg["wind"]) != 2 or cfg["wind"][0] > cfg["wind"][1]):
        raise ValueError(f"wind must be None or [low, high] with low <= high, got {cfg['wind']!r}")
    if "epsilon" in cfg and not 0.0 < cfg["epsilon"] <= 1.0:
        raise ValueError(f"epsilon must be in (0, 1], got {cfg['epsilon']!r}")
    if "damping" in cfg:
        check_nonneg(cfg["damping"], "damping")
