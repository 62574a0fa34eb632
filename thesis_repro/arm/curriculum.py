"""Curriculum learning of Ball-in-Cup (§5.3.4, Figure 5.6): Reach → Throw → BIC vs no curriculum.

Everything is autonomous: the thesis's task cost only (no shaping, no demonstration). Each stage is
constructive multi-task learning (:func:`thesis_repro.arm.learn.mtl_refine`: CMA-ES on the Tucker factors
G, U1, U2, U3 of all P tasks of a family at once). A *trial* is one CMA-ES candidate, i.e. one rollout of
each of the P tasks, so a stage of ``k`` trials runs ``k / popsize`` generations.

* ``CL`` (curriculum): ``pretrain/2`` trials of MTL on Reach from a random start, then ``pretrain/2`` on
  Throw starting from the Reach factors, then ``bic`` trials on BIC starting from the Throw factors
  (the factors, including the task-specific U3 rows, are carried from family to family).
* ``NC`` (no curriculum): ``pretrain`` trials of MTL on BIC from the same random start, then ``bic`` more.

Both get the same pre-training budget; the curves of the final ``bic`` trials are compared (thesis:
6000 + 4000 trials).

>>> CONDITIONS
('CL', 'NC')
"""

from __future__ import annotations

from typing import Any

import numpy as np

from thesis_repro.arm.learn import ALGO_VERSION
from thesis_repro.arm.tasks import SIM_VERSION
from thesis_repro.validation import check_choice

CONDITIONS: tuple[str, ...] = ("CL", "NC")
CURRICULUM: tuple[str, ...] = ("reach", "throw", "bic")

#: Defaults of :func:`curriculum_job`.
CURRICULUM_DEFAULTS: dict[str, Any] = {
    "sim_version": SIM_VERSION,
    "algo_version": ALGO_VERSION,
    "n_tasks": 16,
    "n_basis": 10,
    "ranks": [8, 2, 8],
    "pretrain_trials": 6000,
    "bic_trials": 4000,
    "popsize": 16,
    "sigma": 0.05,
    "init_scale": 0.05,
    "l1": 1e-3,
    "l2": 1e-4,
    "seed": 0,
    "arm": {},
}


def _random_start(n_tasks: int, n_basis: int, ranks: tuple[int, int, int], scale: float, rng: np.random.Generator):
    from thesis_repro.arm.policy import RBFPolicy
    from thesis_repro.arm.transfer import hosvd

    W = np.tile(RBFPolicy(n_basis=n_basis).default_params(), (n_tasks, 1, 1))
    W[:, :n_basis] += scale * rng.normal(size=(n_tasks, n_basis, 2))
    D = n_basis + 2
    r = (min(ranks[0], D), min(ranks[1], 2), min(ranks[2], n_tasks))
    return hosvd(np.moveaxis(W, 0, 2), r)


def curriculum_job(config: dict[str, Any], workdir: Any = None) -> dict[str, Any]:
    """Cached job: one condition (``config["condition"]`` in :data:`CONDITIONS`) of Figure 5.6, one seed.

    Returns ``curve`` and ``success_curve`` (G,) over the final ``bic_trials`` (mean task cost and success
    rate of the population, over tasks), ``trials`` (G,), the pre-training curves, and the final success
    rate of the multiplied-out BIC policies.
    """
    from thesis_repro.arm.learn import evaluate_policies, mtl_refine
    from thesis_repro.arm.tasks import sample_tasks
    from thesis_repro.arm.transfer import Tucker

    cfg = {**CURRICULUM_DEFAULTS, **config}
    condition = check_choice(cfg["condition"], CONDITIONS, "curriculum condition")
    pop, P, seed = int(cfg["popsize"]), int(cfg["n_tasks"]), int(cfg["seed"])
    rng = np.random.default_rng([seed, 11])
    start = _random_start(P, cfg["n_basis"], tuple(cfg["ranks"]), cfg["init_scale"], rng)
    bic_tasks = sample_tasks("bic", P, rng)
    pre_gens = max(1, int(cfg["pretrain_trials"]) // pop)
    bic_gens = max(1, int(cfg["bic_trials"]) // pop)
    common = {"sigma": cfg["sigma"], "l1": cfg["l1"], "l2": cfg["l2"], "popsize": pop, "config": cfg["arm"]}
    out: dict[str, Any] = {}
    if condition == "CL":
        t = start
        for i, family in enumerate(CURRICULUM[:2]):
            tasks = sample_tasks(family, P, rng)
            res = mtl_refine(family, tasks, t, generations=max(1, pre_gens // 2), seed=seed * 10 + i, **common)
            t = Tucker(res.core, res.factors)
            out[f"pretrain_{family}_curve"] = res.curve
            out[f"pretrain_{family}_success"] = res.success
    else:
        res = mtl_refine("bic", bic_tasks, start, generations=pre_gens, seed=seed * 10, **common)
        t = Tucker(res.core, res.factors)
        out["pretrain_bic_curve"] = res.curve
        out["pretrain_bic_success"] = res.success
    res = mtl_refine("bic", bic_tasks, t, generations=bic_gens, seed=seed * 10 + 5, **common)
    final = evaluate_policies("bic", bic_tasks, res.W, cfg["arm"])
    out.update(
        curve=res.curve,
        success_curve=res.success,
        trials=pop * np.arange(1, bic_gens + 1),
        final_success=final["success"],
        final_cost=final["cost"],
        success_rate=float(final["success"].mean()),
    )
    return out
