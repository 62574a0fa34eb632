"""Run-cache evaluation job of the chapter-4 figures (wind / mass × friction / noise sweeps).

The figure logic that used to live here is in :mod:`thesis_repro.figures.ch4`; this job stays at its path
until the one evaluation job (:func:`thesis_repro.evaluation.evaluate_job`) accepts c_a / wind / ratios.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from thesis_repro.cache import Job, RunCache
from thesis_repro.evaluation.evaluator import BatchedEvaluator, test_seeds
from thesis_repro.learners import load_policy
from thesis_repro.mdl.envs import make_mdl_env
from thesis_repro.validation import check_choice

EVAL_KINDS: tuple[str, ...] = ("wind", "shift", "obs", "act")


def evaluate_job(config: dict[str, Any], workdir: Path) -> dict[str, Any]:
    """Testing returns ``(len(values), n_rollouts)`` of a trained run under one kind of shift.

    ``config = {"train": <train config>, "kind": wind|shift|obs|act, "values": [...], "n_rollouts": n,
    "seed": s, "c_a": c}``; "shift" values are ``{"body_mass": r, "friction": r}`` dicts (no wind).
    """
    kind = check_choice(config["kind"], EVAL_KINDS, "evaluation kind")
    policy = load_policy(RunCache().run(Job("train", config["train"])))
    train = config["train"]
    base = {"env": train["env"], "c_a": config["c_a"], "max_episode_steps": train["max_episode_steps"] or 1000}
    conds = []
    for v in config["values"]:
        if kind == "wind":
            conds.append({**base, "wind": float(v)})
        elif kind == "shift":
            conds.append({**base, "ratios": dict(v)})
        else:
            conds.append({**base, "perturbation": kind, "sigma": float(v)})
    ev = BatchedEvaluator(policy, lambda **c: make_mdl_env(**c), n_envs=16, max_episode_steps=base["max_episode_steps"])
    out = ev.run(conds, test_seeds(int(config["seed"]), int(config["n_rollouts"])))
    return {"returns": out.returns, "lengths": out.lengths}
