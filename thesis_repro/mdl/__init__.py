"""Aggregation math of multi-domain learning (thesis §4.2, Eq 4.6-4.11 and the exact Eq 4.7 minimiser).

The learners that use it (joint, EPOpt, MAML-DG, Reptile-DG and Alg 3 with params_avg / kl_avg / kl_exact)
are SB3 algorithms in :mod:`thesis_repro.learners.multidomain`, trained by the kit's one ``"train"`` job.
"""

from thesis_repro.mdl.aggregate import (
    FisherProducts,
    GaussianPolicy,
    MLPSpec,
    PolicyView,
    eq47_kls,
    eq47_objective,
    fisher_matrix,
    fisher_vector_product,
    kl_avg,
    kl_avg_dense,
    mean_kl,
    params_avg,
)
from thesis_repro.mdl.exact import kl_exact

__all__ = [
    "FisherProducts",
    "GaussianPolicy",
    "MLPSpec",
    "PolicyView",
    "eq47_kls",
    "eq47_objective",
    "fisher_matrix",
    "fisher_vector_product",
    "kl_avg",
    "kl_avg_dense",
    "kl_exact",
    "mean_kl",
    "params_avg",
]
