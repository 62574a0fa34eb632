"""Multi-domain learners of chapters 3-4: joint (PPO-MDL), EPOpt, MAML-DG, Reptile-DG, params_avg, kl_avg.

The aggregation math (Eq 4.6-4.11) lives in :mod:`thesis_repro.mdl.aggregate`; the SB3-based trainers in
:mod:`thesis_repro.mdl.train` (``train_job(config, workdir)``, the run-cache contract of the kit).
"""

from thesis_repro.mdl.aggregate import (
    GaussianPolicy,
    PolicyView,
    fisher_matrix,
    fisher_vector_product,
    kl_avg,
    kl_avg_dense,
    mean_kl,
    params_avg,
)
from thesis_repro.mdl.config import ALGORITHMS, mdl_config
from thesis_repro.mdl.train import MultiDomainTrainer, load_policy, train_job

__all__ = [
    "ALGORITHMS",
    "MultiDomainTrainer",
    "load_policy",
    "mdl_config",
    "train_job",
    "GaussianPolicy",
    "PolicyView",
    "fisher_matrix",
    "fisher_vector_product",
    "kl_avg",
    "kl_avg_dense",
    "mean_kl",
    "params_avg",
]
