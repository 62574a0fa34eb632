"""Curriculum learning of Ball-in-Cup (§5.3.4, Figure 5.6): Reach → Throw → BIC vs no curriculum.

Everything is autonomous: the thesis's task cost only (no shaping, no demonstration). A *trial* is one
CMA-ES candidate, i.e. one rollout of each of the P tasks of a family, so a stage of ``k`` trials runs
``k / popsize`` generations. Every CMA-ES run starts from σ0 = ``sigma`` = 0.01, the thesis's base learner
(§5.3.2, thesis line 1113).

* A family learned *from scratch* (Reach in CL, BIC's pre-training in NC) is constructive multi-task learning
  (§5.2.3 line 1059, :func:`thesis_repro.arm.learn.mtl_refine`): CMA-ES on the Tucker factors G, U1, U2, U3
  of all P tasks at once, from a random start.
* A family learned *from a pre-trained one* is transfer multi-task RL (§5.3.4 line 1155: "the task-agnostic
  tensor is extracted and transferred to bootstrap learning the next task-category"; Algorithm 5, lines
  1068-1078; :func:`thesis_repro.arm.learn.mtl_alternate`): ``L = G ×1 U1 ×2 U2`` is extracted, each new task
  starts from the task vector (row of U3) of one random task of the previous family, and CMA-ES phases of
  ``phase_generations`` alternate "fix L, update s" / "fix s, update L" (the "periodic bumps" of Fig 5.6,
  line 1157).

Conditions (both get the same ``pretrain_trials`` before the ``bic_trials`` whose curves are compared;
thesis: 6000 + 4000 trials, line 1155):

* ``CL`` (curriculum): ``pretrain/2`` trials of MTL on Reach from scratch, ``pretrain/2`` of transfer MTL on
  Throw from Reach, then ``bic`` trials of transfer MTL on BIC from Throw.
* ``NC`` (no curriculum): ``pretrain`` trials of MTL on BIC from the same random start, then ``bic`` trials
  of the same alternation on BIC (L extracted from its own factors, each task keeping its own s).

``transfer: joint`` selects the kit's earlier procedure (Fig 5.6 at σ 0.05): every stage joint
CMA-ES on all four factors, carried from family to family including the task rows of U3.

>>> CONDITIONS, TRANSFERS
(('CL', 'NC'), ('alternate', 'joint'))
"""

from __future__ import annotations

from typing import Any

import numpy as np

from thesis_repro.arm.learn import ALGO_VERSION, evaluate_policies, mtl_alternate, mtl_refine
from thesis_repro.arm.policy import RBFPolicy
from thesis_repro.arm.tasks import SIM_VERSION, sample_tasks
from thesis_repro.arm.transfer import Tucker, hosvd
from thesis_repro.core.validation import check_choice

CONDITIONS: tuple[str, ...] = ("CL", "NC")
CURRICULUM: tuple[str, ...] = ("reach", "throw", "bic")
#: How a stage learns from a pre-trained family: Algorithm 5's L/s alternation (default) or joint CMA-ES on
#: all Tucker factors (the kit's earlier procedure).
TRANSFERS: tuple[str, ...] = ("alternate", "joint")

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
    "sigma": 0.01,
    "transfer": "alternate",
    "phase_generations": 25,
    "init_scale": 0.05,
    "l1": 1e-3,
    "l2": 1e-4,
    "seed": 0,
    "arm": {},
}


def _random_start(n_tasks: int, n_basis: int, ranks: tuple[int, int, int], scale: float, rng: np.random.Generator):
    W = np.tile(RBFPolicy(n_basis=n_basis).default_params(), (n_tasks, 1, 1))
    W[:, :n_basis] += scale * rng.normal(size=(n_tasks, n_basis, 2))
    D = n_basis + 2
    r = (min(ranks[0], D), min(ranks[1], 2), min(ranks[2], n_tasks))
    return hosvd(np.moveaxis(W, 0, 2), r)


def curriculum_job(config: dict[str, Any], workdir: Any = None) -> dict[str, Any]:
    """Cached job: one condition (``config["condition"]`` in :data:`CONDITIONS`) of Figure 5.6, one seed.

    Returns ``curve`` and ``success_curve`` (G,) over the final ``bic_trials`` (mean task cost and success
    rate of the population, over tasks), ``trials`` (G,), the pre-training curves, and the final success
    rate of the multiplied-out BIC policies; with ``transfer: alternate`` also ``phases`` (G,), the phase
    (``"s"`` or ``"L"``) of every BIC generation.
    """
    cfg = {**CURRICULUM_DEFAULTS, **config}
    condition = check_choice(cfg["condition"], CONDITIONS, "curriculum condition")
    transfer = check_choice(cfg["transfer"], TRANSFERS, "curriculum transfer")
    pop, P, seed = int(cfg["popsize"]), int(cfg["n_tasks"]), int(cfg["seed"])
    rng = np.random.default_rng([seed, 11])
    start = _random_start(P, cfg["n_basis"], tuple(cfg["ranks"]), cfg["init_scale"], rng)
    bic_tasks = sample_tasks("bic", P, rng)
    pick = np.random.default_rng([seed, 12])  # which previous-family task each new task's s starts from
    pre_gens = max(1, int(cfg["pretrain_trials"]) // pop)
    bic_gens = max(1, int(cfg["bic_trials"]) // pop)
    common = {"sigma": cfg["sigma"], "popsize": pop, "config": cfg["arm"]}

    def scratch(family: str, tasks: np.ndarray, t: Tucker, gens: int, s: int) -> Any:
        """Constructive MTL: CMA-ES on all four factors (§5.2.3)."""
        return mtl_refine(family, tasks, t, generations=gens, seed=s, l1=cfg["l1"], l2=cfg["l2"], **common)

    def transferred(family: str, tasks: np.ndarray, t: Tucker, gens: int, s: int, same_tasks: bool) -> Any:
        """Transfer MTL from the pre-trained ``t``: Algorithm 5's alternation (or, ``joint``, as from scratch)."""
        if transfer == "joint":
            return scratch(family, tasks, t, gens, s)
        U3 = t.factors[2]
        s0 = U3 if same_tasks else U3[pick.integers(0, len(U3), size=len(tasks))]
        return mtl_alternate(
            family,
            tasks,
            t,
            s0,
            generations=gens,
            phase_generations=int(cfg["phase_generations"]),
            seed=s,
            l2=cfg["l2"],
            **common,
        )

    out: dict[str, Any] = {}
    if condition == "CL":
        t = start
        for i, family in enumerate(CURRICULUM[:2]):
            tasks = sample_tasks(family, P, rng)
            gens, s = max(1, pre_gens // 2), seed * 10 + i
            res = scratch(family, tasks, t, gens, s) if i == 0 else transferred(family, tasks, t, gens, s, False)
            t = Tucker(res.core, res.factors)
            out[f"pretrain_{family}_curve"] = res.curve
            out[f"pretrain_{family}_success"] = res.success
    else:
        res = scratch("bic", bic_tasks, start, pre_gens, seed * 10)
        t = Tucker(res.core, res.factors)
        out["pretrain_bic_curve"] = res.curve
        out["pretrain_bic_success"] = res.success
    res = transferred("bic", bic_tasks, t, bic_gens, seed * 10 + 5, condition == "NC")
    final = evaluate_policies("bic", bic_tasks, res.W, cfg["arm"])
    out.update(
        curve=res.curve,
        success_curve=res.success,
        trials=pop * np.arange(1, bic_gens + 1),
        final_success=final["success"],
        final_cost=final["cost"],
        success_rate=float(final["success"].mean()),
    )
    if transfer == "alternate":
        out["phases"] = np.array(res.phases)
    return out
