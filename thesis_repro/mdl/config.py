"""Resolved configs of the multi-domain learners (hyperparameters: ``config/hyperparams.yaml``, class MultiDomain).

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


def _entries() -> dict[str, dict[str, Any]]:
    """The multi-domain entries of ``config/hyperparams.yaml`` (class ``MultiDomain``), inheritance applied."""
    from thesis_repro.learners.config import algorithms, hyperparams

    out = {}
    for name in algorithms():
        entry = hyperparams(name)
        if entry.get("class") == "MultiDomain":
            entry.pop("class")
            entry.pop("sb3", None)
            out[name] = entry
    return out


#: Learners of this package (names as used across the kit), in the order of ``hyperparams.yaml``.
ALGORITHMS: tuple[str, ...] = tuple(_entries())


def mdl_config(algo: str, env: str, seed: int, timesteps: int, **overrides: Any) -> dict[str, Any]:
    """Full resolved config of one run of learner ``algo`` (see :data:`ALGORITHMS`); unknown keys are errors."""
    check_choice(algo, ALGORITHMS, "algorithm")
    if int(seed) != seed or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    check_positive(timesteps, "timesteps")
    cfg: dict[str, Any] = copy.deepcopy(_entries()[algo])
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
