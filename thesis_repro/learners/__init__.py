"""Chapter-3 single-domain learners (thesis §3.2.1, Appendix A) on Stable-Baselines3.

>>> from thesis_repro.learners import ALGORITHMS, train_config
>>> "ppo-scn-16" in ALGORITHMS
True
>>> from thesis_repro.cache import Job
>>> job = Job("thesis_repro.learners:train_job", train_config("ppo", "Hopper", seed=0, timesteps=20_000))
"""

from thesis_repro.learners.config import (
    ALGORITHMS,
    MULTI_DOMAIN,
    PERTURBATIONS,
    algorithms,
    hyperparams,
    train_config,
)
from thesis_repro.learners.policy import Policy, load_policy, snapshots


def train_job(config, workdir, **kwargs):  # noqa: ANN001,ANN201 - thin lazy alias, see learners.train.train_job
    """Train one run: :func:`thesis_repro.learners.train.train_job`, or for the multi-domain learners
    (``MULTI_DOMAIN``: joint, params_avg, kl_avg, ppo-epopt, ppo-maml-dg, ppo-reptile-dg)
    :func:`thesis_repro.mdl.train.train_job`. Imports lazily (keeps ``import learners`` light)."""
    if config.get("algorithm") in MULTI_DOMAIN:
        from thesis_repro.mdl.train import train_job as _mdl_train_job

        return _mdl_train_job(config, workdir, **kwargs)
    from thesis_repro.learners.train import train_job as _train_job

    return _train_job(config, workdir, **kwargs)


__all__ = [
    "ALGORITHMS",
    "MULTI_DOMAIN",
    "PERTURBATIONS",
    "Policy",
    "algorithms",
    "hyperparams",
    "load_policy",
    "snapshots",
    "train_config",
    "train_job",
]
