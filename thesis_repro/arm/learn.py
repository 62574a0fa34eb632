"""CMA-ES with batched evaluation, source-task learning and constructive multi-task learning (§5.2.3, §5.3).

The core is :func:`~thesis_repro.arm.cma.cma_lockstep` (:mod:`thesis_repro.arm.cma`): ``n`` CMA-ES instances
whose populations are evaluated by ONE call per generation. For the arm this means one vectorised ``simulate``
call per generation for ``n × popsize`` rollouts.

Learning curves are arrays ``(n, generations)`` of the mean task cost of each generation's population
(the rollouts actually executed), so the *total cost of learning* is the sum of all rollout costs:
``popsize * curve.sum(axis=1)``.

Source tasks. The thesis learned its source tasks "with supervised demonstration followed by MTL RL
refinement". We have no demonstrations, so the automatic equivalent used here is:

1. per source task, CMA-ES (σ0 = ``sigma``, 0.1 by default) from the zero-trajectory policy on the
   simulator's shaped cost (``ArmConfig(shaped=True)``: Eq 5.12 + a dense ball-to-target distance term),
2. the Tucker factors of the stacked solutions (HOSVD, Algorithm 4) as the MTL initial condition,
3. constructive MTL refinement: CMA-ES on the flat vector of (G, U1, U2, U3) for all source tasks at
   once, cost = mean shaped cost + ``l1 * |U3|_1 + l2 * (|G|² + |U1|² + |U2|²)``; a task keeps its
   refined policy only if that is not worse than its stage-1 policy.

Two run-cache jobs: :func:`source_job` (the source tasks) and :func:`solve_task` (one task alone, Fig 5.3).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from thesis_repro.arm.cma import CMAResult, cma_lockstep
from thesis_repro.arm.policy import RBFPolicy
from thesis_repro.arm.tasks import SIM_VERSION, check_family, sample_tasks, simulate, validate_tasks
from thesis_repro.arm.transfer import Subspace, Tucker, hosvd


# ------------------------------------------------------------------------------------ the arm
def _arm_config(config: dict[str, Any] | None, shaped: bool) -> dict[str, Any]:
    cfg = dict(config or {})
    cfg["shaped"] = bool(shaped)
    return cfg


def arm_objective(
    family: str,
    tasks: np.ndarray,
    *,
    shaped: bool = False,
    config: dict[str, Any] | None = None,
) -> Callable[[np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """``f(W (n, pop, D, A)) -> (fitness, task_cost, success)`` each (n, pop) for the ``n`` tasks (n, k).

    All ``n × pop`` rollouts go through ONE ``simulate`` call. ``fitness`` is the shaped cost of the
    simulator when ``shaped`` (a dense ball-to-target distance term), else the thesis's task cost.

    >>> from thesis_repro.arm import sample_tasks
    >>> f = arm_objective("reach", sample_tasks("reach", 2, np.random.default_rng(0)))
    >>> [a.shape for a in f(np.zeros((2, 5, 8, 2)))]
    [(2, 5), (2, 5), (2, 5)]
    """
    tasks = validate_tasks(family, tasks)
    cfg = _arm_config(config, shaped)

    def f(W: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        W = np.asarray(W, dtype=float)
        n, pop = W.shape[:2]
        if n != len(tasks):
            raise ValueError(f"W has {n} task rows but the objective has {len(tasks)} tasks")
        rows = np.repeat(tasks, pop, axis=0)
        r = simulate(family, rows, W.reshape(n * pop, *W.shape[2:]), config=cfg)
        shape = (n, pop)
        return r.cost.reshape(shape), r.task_cost.reshape(shape), r.success.reshape(shape).astype(float)

    return f


def evaluate_policies(family: str, tasks: np.ndarray, W: np.ndarray, config: dict[str, Any] | None = None) -> dict:
    """Task cost and success of one policy per task (``W`` (n, D, A)): the 'at convergence' numbers."""
    _, cost, success = arm_objective(family, tasks, config=config)(np.asarray(W)[:, None])
    return {"cost": cost[:, 0], "success": success[:, 0]}


def learn_independent(
    family: str,
    tasks: np.ndarray,
    W0: np.ndarray,
    *,
    generations: int,
    sigma: float = 0.01,
    popsize: int | None = None,
    shaped: bool = False,
    l2: float = 0.0,
    seed: int = 0,
    config: dict[str, Any] | None = None,
) -> tuple[np.ndarray, CMAResult]:
    """CMA-ES on the full ``W`` of every task independently (lockstep, batched): Scratch and Direct.

    ``W0`` (n, D, A) initial policies. Returns the final ``W`` (n, D, A) and the :class:`CMAResult`.
    """
    W0 = np.asarray(W0, dtype=float)
    n, D, A = W0.shape
    f = arm_objective(family, tasks, shaped=shaped, config=config)

    def evaluate(X: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        W = X.reshape(n, X.shape[1], D, A)
        fit, cost, succ = f(W)
        return fit + l2 * (X**2).sum(-1), cost, succ

    res = cma_lockstep(evaluate, W0.reshape(n, D * A), sigma, generations, popsize=popsize, seed=seed)
    return res.x.reshape(n, D, A), res


@dataclass
class MTLResult:
    """Constructive MTL outcome: the factors, the multiplied-out policies and the learning curve."""

    core: np.ndarray
    factors: list[np.ndarray]
    W: np.ndarray  # (P, D, A)
    curve: np.ndarray  # (G,) mean task cost over tasks and population
    success: np.ndarray  # (G,)
    popsize: int


def _unpack(theta: np.ndarray, shapes: list[tuple[int, ...]]) -> list[np.ndarray]:
    parts, i = [], 0
    for shp in shapes:
        size = int(np.prod(shp))
        parts.append(theta[..., i : i + size].reshape(*theta.shape[:-1], *shp))
        i += size
    return parts


def mtl_refine(
    family: str,
    tasks: np.ndarray,
    W: Any,
    ranks: tuple[int, int, int] | None = None,
    *,
    generations: int,
    sigma: float = 0.01,
    l1: float = 1e-3,
    l2: float = 1e-3,
    popsize: int | None = None,
    shaped: bool = False,
    seed: int = 0,
    config: dict[str, Any] | None = None,
) -> MTLResult:
    """Constructive multi-task learning (§5.2.3): CMA-ES on (G, U1, U2, U3) for all P tasks at once.

    The initial condition is the HOSVD of the stacked ``W`` (P, D, A) (Algorithm 5, "MTL initial
    condition") with ``ranks``, or ``W`` is already a :class:`~thesis_repro.arm.transfer.Tucker` (factors
    transferred from another family, as in the curriculum). The fitness of a factor vector is the mean over
    tasks of the cost of its multiplied-out policies + ``l1 |U3|_1 + l2 (|G|² + |U1|² + |U2|²)``. One
    ``simulate`` call per generation (pop × P).
    """
    if isinstance(W, Tucker):
        t = W
    else:
        if ranks is None:
            raise ValueError("mtl_refine needs ranks (r1, r2, r3) to factorise W")
        t = hosvd(np.moveaxis(np.asarray(W, dtype=float), 0, 2), ranks)
    if t.factors[2].shape[0] != len(tasks):
        raise ValueError(f"U3 has {t.factors[2].shape[0]} task rows but there are {len(tasks)} tasks")
    shapes = [t.core.shape, *(u.shape for u in t.factors)]
    theta0 = np.concatenate([t.core.ravel(), *(u.ravel() for u in t.factors)])
    f = arm_objective(family, tasks, shaped=shaped, config=config)

    def evaluate(X: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        G, U1, U2, U3 = _unpack(X[0], shapes)  # (pop, ...)
        Wp = np.einsum("bijk,bdi,baj,bpk->pbda", G, U1, U2, U3)  # (P, pop, D, A)
        fit, cost, succ = f(Wp)
        sq = (G**2).sum(axis=(1, 2, 3)) + (U1**2).sum((1, 2)) + (U2**2).sum((1, 2))
        reg = l1 * np.abs(U3).sum(axis=(1, 2)) + l2 * sq
        return (fit.mean(0) + reg)[None], cost.mean(0)[None], succ.mean(0)[None]

    res = cma_lockstep(evaluate, theta0[None], sigma, generations, popsize=popsize, seed=seed)
    G, U1, U2, U3 = _unpack(res.x[0], shapes)
    Wp = np.einsum("ijk,di,aj,pk->pda", G, U1, U2, U3)
    return MTLResult(
        core=G, factors=[U1, U2, U3], W=Wp, curve=res.curve[0], success=res.success[0], popsize=res.popsize
    )


@dataclass
class AlternateMTLResult(MTLResult):
    """:func:`mtl_alternate`'s outcome: an :class:`MTLResult` (``factors[2]`` = the task vectors S (P, K))
    plus the phase (``"s"`` or ``"L"``) of every generation of the curve."""

    phases: list[str]


def mtl_alternate(
    family: str,
    tasks: np.ndarray,
    model: Any,
    s0: np.ndarray,
    *,
    generations: int,
    phase_generations: int,
    sigma: float = 0.01,
    l2: float = 1e-4,
    popsize: int | None = None,
    seed: int = 0,
    config: dict[str, Any] | None = None,
) -> AlternateMTLResult:
    """Transfer multi-task RL (Algorithm 5 for a family of P tasks, §5.2.3 / §5.3.4): alternate s and L.

    The task-agnostic tensor ``L = G ×1 U1 ×2 U2`` (D, A, K) is extracted from ``model`` (a
    :class:`~thesis_repro.arm.transfer.Tucker`; its U3 is dropped) and shared by the P tasks; task ``p``'s
    policy is ``W_p = L ×3 s_p`` with ``s0`` (P, K) the initial task vectors. Phases of
    ``phase_generations`` CMA-ES generations alternate, starting with s ("fix L and update s", then "fix s
    and update L"), until ``generations`` are used (the last phase may be shorter); every phase is a fresh
    CMA-ES with σ0 = ``sigma``.

    * s-phase: one CMA-ES per task on its ``s_p`` (lockstep; with L fixed the tasks are independent),
      fitness = cost_p + ``l2 |W_p|²``;
    * L-phase: one CMA-ES on the factors (G, U1, U2) of L (the kit's tensor reading of Algorithm 5, as
      :func:`thesis_repro.arm.transfer.alternate`), fitness = mean over tasks of cost_p + ``l2 |W_p|²``.

    Either way a generation is ``popsize`` rollouts of every task (one ``simulate`` call). The curve is
    the mean task cost of the population over tasks, per generation.
    """
    if phase_generations < 1:
        raise ValueError(f"phase_generations must be >= 1, got {phase_generations}")
    if generations < 1:
        raise ValueError(f"generations must be >= 1, got {generations}")
    G, U1, U2 = model.core, model.factors[0], model.factors[1]
    s = np.array(s0, dtype=float)
    P = len(tasks)
    if s.shape != (P, G.shape[2]):
        raise ValueError(f"s0 must have shape (P, K) = {(P, G.shape[2])}, got {s.shape}")
    sub = Subspace("tensor", [G.shape, U1.shape, U2.shape], np.concatenate([G.ravel(), U1.ravel(), U2.ravel()]), s)
    theta = sub.theta0.copy()
    f = arm_objective(family, tasks, config=config)
    curves, succs, phases = [], [], []
    done, k = 0, 0
    while done < generations:
        gens = min(phase_generations, generations - done)
        phase = "s" if k % 2 == 0 else "L"
        if phase == "s":
            L = sub.latent(theta)  # (D, A, K)

            def evaluate(X: np.ndarray, L: np.ndarray = L) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
                W = np.einsum("dak,npk->npda", L, X)  # (P, pop, D, A)
                fit, cost, succ = f(W)
                return fit + l2 * (W**2).sum(axis=(-2, -1)), cost, succ

            res = cma_lockstep(evaluate, s, sigma, gens, popsize=popsize, seed=seed * 1000 + k)
            s = res.x
        else:
            s_fixed = s

            def evaluate(X: np.ndarray, s_fixed: np.ndarray = s_fixed) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
                W = np.einsum("bdak,pk->pbda", sub.latent(X[0]), s_fixed)  # (P, pop, D, A)
                fit, cost, succ = f(W)
                fit = fit + l2 * (W**2).sum(axis=(-2, -1))
                return fit.mean(0)[None], cost.mean(0)[None], succ.mean(0)[None]

            res = cma_lockstep(evaluate, theta[None], sigma, gens, popsize=popsize, seed=seed * 1000 + k)
            theta = res.x[0]
        curves.append(res.curve.mean(0))
        succs.append(res.success.mean(0))
        phases.extend([phase] * gens)
        done += gens
        k += 1
    G, U1, U2 = _unpack(theta, sub.shapes)
    L = np.einsum("ijk,di,aj->dak", G, U1, U2)
    return AlternateMTLResult(
        core=G,
        factors=[U1, U2, s],
        W=np.einsum("dak,pk->pda", L, s),
        curve=np.concatenate(curves),
        success=np.concatenate(succs),
        popsize=res.popsize,
        phases=phases,
    )


# ------------------------------------------------------------------------------ cached jobs
#: Bump when a change to this package's learning code alters results (part of every job config).
ALGO_VERSION: int = 1

#: Defaults of :func:`source_job` (every key may be overridden by the job config).
SOURCE_DEFAULTS: dict[str, Any] = {
    "sim_version": SIM_VERSION,
    "algo_version": ALGO_VERSION,
    "n_tasks": 16,
    "n_basis": 10,
    "seed": 0,
    "sigma": 0.1,
    "generations": 200,
    "popsize": 16,
    "mtl_generations": 50,
    "mtl_sigma": 0.01,
    "ranks": [8, 2, 8],
    "l1": 1e-3,
    "l2": 1e-4,
    "arm": {},
}


def source_config(family: str, **overrides: Any) -> dict[str, Any]:
    """Full config of the source-task job of ``family`` (``SOURCE_DEFAULTS`` + overrides)."""
    check_family(family)
    for k in overrides:
        if k not in SOURCE_DEFAULTS:
            raise ValueError(f"unknown source setting {k!r}; valid settings are: {', '.join(SOURCE_DEFAULTS)}")
    return {"family": family, **SOURCE_DEFAULTS, **overrides}


def source_job(config: dict[str, Any], workdir: Any = None) -> dict[str, Any]:
    """Learn a family of source tasks automatically (module docstring) and return their policies.

    Stage 1: CMA-ES per task from the zero-trajectory policy (σ = ``sigma``) on the simulator's shaped
    cost (our stand-in for the thesis's demonstrations). Stage 2: constructive MTL refinement of the
    Tucker factors (σ = ``mtl_sigma``) on the same cost. Returns ``W`` (P, D, A), ``tasks`` (P, k), the
    curves and the final task cost/success of every source task (thesis cost, unshaped).
    """
    cfg = {**SOURCE_DEFAULTS, **config}
    family, P = cfg["family"], int(cfg["n_tasks"])
    rng = np.random.default_rng(cfg["seed"])
    tasks = sample_tasks(family, P, rng)
    pol = RBFPolicy(n_basis=cfg["n_basis"])
    W0 = np.tile(pol.default_params(), (P, 1, 1))
    W, res = learn_independent(
        family,
        tasks,
        W0,
        generations=cfg["generations"],
        sigma=cfg["sigma"],
        popsize=cfg["popsize"],
        shaped=True,
        seed=cfg["seed"],
        config=cfg["arm"],
    )
    stage1 = evaluate_policies(family, tasks, W, cfg["arm"])
    out: dict[str, Any] = {
        "tasks": tasks,
        "curve": res.curve.mean(0),
        "success_curve": res.success.mean(0),
        "stage1_success": stage1["success"],
        "stage1_cost": stage1["cost"],
    }
    if cfg["mtl_generations"] > 0:
        D = W.shape[1]
        r1, r2, r3 = cfg["ranks"]
        mtl = mtl_refine(
            family,
            tasks,
            W,
            (min(r1, D), min(r2, 2), min(r3, P)),
            generations=cfg["mtl_generations"],
            sigma=cfg["mtl_sigma"],
            l1=cfg["l1"],
            l2=cfg["l2"],
            popsize=cfg["popsize"],
            shaped=True,
            seed=cfg["seed"] + 1,
            config=cfg["arm"],
        )
        final = evaluate_policies(family, tasks, mtl.W, cfg["arm"])
        # keep the refined policies only where they are not worse (MTL with truncated ranks can lose a task)
        better = final["cost"] <= stage1["cost"]
        W = np.where(better[:, None, None], mtl.W, W)
        out.update(mtl_curve=mtl.curve, mtl_success_curve=mtl.success)
    final = evaluate_policies(family, tasks, W, cfg["arm"])
    out.update(W=W, success=final["success"], cost=final["cost"], success_rate=float(final["success"].mean()))
    return out


def solve_task(config: dict[str, Any], workdir: Path) -> dict[str, Any]:
    """Run-cache job: CMA-ES (``thesis_repro.arm.learn.learn_independent``) on ONE task, then a recorded rollout.

    ``config``: ``family``, ``task`` (list of task parameters), ``n_basis``, ``generations``, ``sigma``,
    ``popsize`` (``None`` = CMA default), ``shaped`` (bool), ``seed``. The search starts from the policy
    with zero RBF weights and unit PD gains. Returns the final ``W``, learning curves, the recorded
    trajectory of the final mean policy (``ee``, ``ball``, ``taut``) and its ``cost``/``success``.
    """
    family = check_family(config["family"])
    task = np.asarray(config["task"], dtype=float)[None]
    pol = RBFPolicy(n_basis=int(config["n_basis"]))
    W0 = pol.default_params()[None]
    W, res = learn_independent(
        family,
        task,
        W0,
        generations=int(config["generations"]),
        sigma=float(config["sigma"]),
        popsize=config.get("popsize"),
        shaped=bool(config["shaped"]),
        seed=int(config["seed"]),
    )
    r = simulate(family, task, W, record=True)
    return {
        "W": W[0],
        "curve": res.curve[0],
        "success_curve": res.success[0],
        "popsize": int(res.popsize),
        "ee": r.ee[0],
        "ball": r.ball[0] if r.ball is not None else np.zeros((0, 2)),
        "taut": r.taut[0],
        "hit_step": int(r.hit_step[0]),
        "cost": float(r.task_cost[0]),
        "success": bool(r.success[0]),
    }
