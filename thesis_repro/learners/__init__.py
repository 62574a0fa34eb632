"""Every learner of the kit (thesis §3.2.1, §4.2, Appendix A) on Stable-Baselines3, behind one contract.

``train_config(algo, env, seed, timesteps, **overrides)`` resolves a run from ``config/hyperparams.yaml``;
``Job("train", cfg)`` trains it with :func:`train_job` (checkpoints and resumes in env steps, saves the
artefacts) and :func:`load_policy` gives the deterministic batch policy the evaluator calls.

>>> from thesis_repro.learners import ALGORITHMS, MULTI_DOMAIN, train_config
>>> "ppo-scn-16" in ALGORITHMS, "kl-avg" in MULTI_DOMAIN
(True, True)
>>> from thesis_repro.core.cache import Job
>>> job = Job("train", train_config("ppo", "Hopper", seed=0, timesteps=20_000))
"""

from thesis_repro.learners.config import (
    ALGORITHMS,
    MULTI_DOMAIN,
    algorithms,
    hyperparams,
    iteration_steps,
    n_iterations,
    train_config,
)
from thesis_repro.learners.policy_file import Policy, load_policy, snapshots
from thesis_repro.learners.train import env_seed, train_job

__all__ = [
    "ALGORITHMS",
    "MULTI_DOMAIN",
    "Policy",
    "algorithms",
    "env_seed",
    "hyperparams",
    "iteration_steps",
    "load_policy",
    "n_iterations",
    "snapshots",
    "train_config",
    "train_job",
]
