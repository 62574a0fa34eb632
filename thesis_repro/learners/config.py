"""Hyperparameters as data (``config/hyperparams.yaml``) and the resolved training config of one run.

>>> cfg = train_config("ppo-16", "InvertedPendulum", seed=0, timesteps=4096, n_steps=64)
>>> cfg["net_arch"], cfg["sb3"]["n_steps"], cfg["perturbation"]
({'pi': [16, 16], 'vf': [16, 16]}, 64, 'none')
>>> train_config("ppo", "Hopper", 0, 1000, n_step=64)
Traceback (most recent call last):
...
ValueError: unknown hyperparameter of 'ppo' 'n_step'; valid hyperparameter of 'ppo's are: ...
"""

from __future__ import annotations

import copy
from functools import cache
from typing import Any

import yaml

from thesis_repro import paths
from thesis_repro.validation import check_choice, check_nonneg

PERTURBATIONS: tuple[str, ...] = ("none", "obs", "act", "env", "dom")
CLASSES: tuple[str, ...] = ("PPO", "TRPO", "DDPG", "SAC")
POLICIES: tuple[str, ...] = ("mlp", "scn")
ACTIVATIONS: tuple[str, ...] = ("tanh", "relu")

#: Run settings every config carries (besides the entry's hyperparameters); all may be overridden.
RUN_DEFAULTS: dict[str, Any] = {
    "max_episode_steps": None,  # None: the environment's own limit (1000 for the MuJoCo tasks)
    "checkpoint_every": 100_000,  # env steps between resumable checkpoints in the job's workdir
    "snapshot_every": 0,  # env steps between policy snapshots in out/snapshots (0: none)
    "curve_every": 0,  # env steps between training-curve points (0: one per PPO/TRPO batch, 1000 off-policy)
}
#: Keys that identify the run; not overridable.
IDENTITY = ("algorithm", "class", "env", "seed", "timesteps")


@cache
def _raw() -> dict[str, Any]:
    with open(paths.CONFIG / "hyperparams.yaml") as fh:
        table = yaml.safe_load(fh)
    if not isinstance(table, dict) or not table:
        raise ValueError("hyperparams.yaml must map algorithm names to entries")
    return table


def _resolve(name: str, seen: tuple[str, ...] = ()) -> dict[str, Any]:
    table = _raw()
    check_choice(name, list(table), "algorithm")
    if name in seen:
        raise ValueError(f"hyperparams.yaml: inheritance cycle {' -> '.join((*seen, name))}")
    entry = copy.deepcopy(table[name])
    base = entry.pop("base", None)
    if base is None:
        return entry
    merged = _resolve(base, (*seen, name))
    sb3 = merged.get("sb3", {})
    sb3.update(entry.pop("sb3", {}) or {})
    merged.update(entry)
    merged["sb3"] = sb3
    return merged


def algorithms() -> tuple[str, ...]:
    """Names of every entry of ``hyperparams.yaml`` (read at call time)."""
    return tuple(_raw())


#: Multi-domain learners of chapter 4 / Table 3.7 (configs from :func:`thesis_repro.mdl.mdl_config`,
#: trained by :func:`thesis_repro.mdl.train_job`); ``train_config``/``train_job`` dispatch to them.
MULTI_DOMAIN: tuple[str, ...] = tuple(n for n in algorithms() if _resolve(n).get("class") == "MultiDomain")

ALGORITHMS: tuple[str, ...] = algorithms()


def hyperparams(algo: str) -> dict[str, Any]:
    """The resolved (inheritance applied) entry of ``algo``; ``ValueError`` listing valid names if unknown."""
    return _resolve(algo)


def train_config(algo: str, env: str, seed: int, timesteps: int, **overrides: Any) -> dict[str, Any]:
    """Full resolved, JSON-plain config of one training run (the input of :func:`train_job`).

    ``overrides`` may name any top-level setting (``n_envs``, ``perturbation``, ``sigma``, ``net_arch``,
    ``snapshot_every``, ``max_episode_steps``, ...) or any key of the entry's ``sb3`` block (``n_steps``,
    ``ent_coef``, ...). A name that exists nowhere is an error, so typos never pass silently.
    """
    check_choice(algo, ALGORITHMS, "algorithm")
    if algo in MULTI_DOMAIN:
        from thesis_repro.mdl.config import mdl_config

        return mdl_config(algo, env, seed, timesteps, **overrides)
    entry = hyperparams(algo)
    if isinstance(seed, bool) or int(seed) != seed or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    if isinstance(timesteps, bool) or int(timesteps) != timesteps or timesteps <= 0:
        raise ValueError(f"timesteps must be an integer > 0, got {timesteps!r}")
    cfg: dict[str, Any] = {"algorithm": algo, "env": str(env), "seed": int(seed), "timesteps": int(timesteps)}
    cfg.update(copy.deepcopy(RUN_DEFAULTS))
    cfg.update({k: v for k, v in entry.items()})
    cfg.setdefault("sb3", {})
    top = [k for k in cfg if k not in IDENTITY and k != "sb3"]
    for key, value in overrides.items():
        if key in top:
            if isinstance(cfg[key], dict) and key != "net_arch":
                if not isinstance(value, dict) or set(value) != set(cfg[key]):
                    raise ValueError(f"override {key!r} must be a dict with keys {sorted(cfg[key])}, got {value!r}")
            cfg[key] = value
        elif key in cfg["sb3"]:
            cfg["sb3"][key] = value
        else:
            check_choice(key, sorted(top) + sorted(cfg["sb3"]), f"hyperparameter of {algo!r}")
    _validate(cfg)
    return cfg


def _validate(cfg: dict[str, Any]) -> None:
    check_choice(cfg["class"], CLASSES, "learner class")
    check_choice(cfg["perturbation"], PERTURBATIONS, "perturbation")
    cfg["sigma"] = check_nonneg(cfg["sigma"], "sigma")
    check_choice(cfg.get("policy", "mlp"), POLICIES, "policy")
    check_choice(cfg.get("activation", "tanh"), ACTIVATIONS, "activation")
    if cfg["policy"] == "scn" and cfg["class"] not in ("PPO", "TRPO"):
        raise ValueError("policy 'scn' is implemented for the on-policy classes PPO and TRPO only")
    if cfg.get("arpl") is not None and cfg["class"] != "PPO":
        raise ValueError("arpl is implemented for PPO only")
    for key in ("n_envs",):
        if int(cfg[key]) != cfg[key] or cfg[key] < 1:
            raise ValueError(f"{key} must be an integer >= 1, got {cfg[key]!r}")
    for key in ("checkpoint_every", "snapshot_every", "curve_every"):
        if int(cfg[key]) != cfg[key] or cfg[key] < 0:
            raise ValueError(f"{key} must be an integer >= 0, got {cfg[key]!r}")
    if cfg["max_episode_steps"] is not None and (int(cfg["max_episode_steps"]) < 1):
        raise ValueError(f"max_episode_steps must be None or >= 1, got {cfg['max_episode_steps']!r}")
    if cfg.get("arpl") is not None:
        check_nonneg(cfg["arpl"]["epsilon"], "arpl.epsilon")
        p = check_nonneg(cfg["arpl"]["prob"], "arpl.prob")
        if p > 1:
            raise ValueError(f"arpl.prob must be in [0, 1], got {p}")
