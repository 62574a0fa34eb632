"""Target-task learning strategies of §5.3.2-5.3.3 and the competitors' closed-loop policies.

Transfer strategies (all on our RBF-PD policy, CMA-ES with the same population and budget):

* ``scratch``: CMA-ES on ``W`` from the zero-trajectory policy (PD gains 1);
* ``direct``: warm start from one randomly chosen learned source policy, then CMA-ES on ``W``;
* ``matrix``: SVD of the ``DA × P`` source matrix, then Algorithm 5 (alternating ``s`` / ``L``);
* ``tensor``: HOSVD of the ``D × A × P`` source tensor, then Algorithm 5 (the thesis's method).

Competitors (§5.3.3), each with its own policy class, its own source tasks learned the same automatic
way (CMA-ES on the shaped cost), and an ELLA-style transfer: the basis ``L`` (n_params × K) is the SVD
of the stacked source parameter vectors and the target learns ``s`` and ``L`` by alternating CMA-ES
(the same Algorithm 5 machinery as ``matrix``; ELLA's own second-order updates need a gradient model
we do not have for CMA-ES policy search):

* ``ella``: linear policy per actuator on ``[x_t,i, ẋ_t,i, t, 1]``;
* ``rbf-ella``: linear on a 5×5×5 Gaussian RBF tiling of ``(x_t,i, ẋ_t,i, t)`` per actuator (125 features);
* ``fcnn``: ``[x_t, ẋ_t, t] → 8 ReLU → 2`` accelerations.

``simulate`` (tasks.py) accepts RBF-PD policies only; :func:`closed_loop_simulate` runs the same
simulator with ``a_t = controller(t, pos, vel)`` (see its docstring).

>>> pol = ClosedLoopPolicy("fcnn")
>>> pol.n_params, pol.action(np.zeros((3, pol.n_params)), 0, np.zeros((3, 2)), np.zeros((3, 2))).shape
(66, (3, 2))
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from thesis_repro.arm.cma import CMAResult, cma_lockstep
from thesis_repro.arm.learn import SOURCE_DEFAULTS, arm_objective, evaluate_policies, learn_independent
from thesis_repro.arm.policy import RBFPolicy
from thesis_repro.arm.tasks import sample_tasks, simulate, validate_tasks
from thesis_repro.arm.transfer import alternate, make_subspace
from thesis_repro.core.cache import Job, RunCache
from thesis_repro.core.validation import check_choice

TRANSFER: tuple[str, ...] = ("scratch", "direct", "matrix", "tensor")
COMPETITORS: tuple[str, ...] = ("ella", "rbf-ella", "fcnn")
STRATEGIES: tuple[str, ...] = TRANSFER + COMPETITORS
POLICY_CLASSES: tuple[str, ...] = COMPETITORS


def closed_loop_simulate(
    family: str,
    task_params: np.ndarray,
    controller: Callable[[int, np.ndarray, np.ndarray], np.ndarray],
    B: int,
    config: dict[str, Any] | None = None,
) -> Any:
    """``tasks.simulate`` with the action ``a_t = controller(t, pos (B, 2), vel (B, 2))`` for B rollouts.

    Physics, costs and success are the simulator's (``tasks.simulate(..., controller=...)``).
    """
    dummy = np.zeros((B, 3, 2))
    dummy[:, 1:] = 1.0
    return simulate(family, task_params, dummy, config=config, controller=controller)


class ClosedLoopPolicy:
    """A competitor's policy class: ``kind`` in :data:`POLICY_CLASSES`, batched over B parameter vectors.

    Inputs are normalised: ``t`` by the episode duration, positions by ``pos_scale`` m, velocities by
    ``vel_scale`` m/s; outputs are accelerations scaled by ``acc_scale`` m/s².
    """

    def __init__(
        self,
        kind: str,
        horizon: int = 100,
        dt: float = 0.02,
        tiles: int = 5,
        hidden: int = 8,
        pos_scale: float = 0.3,
        vel_scale: float = 2.0,
        acc_scale: float = 20.0,
    ) -> None:
        self.kind = check_choice(kind, POLICY_CLASSES, "policy class")
        self.horizon, self.dt, self.tiles, self.hidden = int(horizon), float(dt), int(tiles), int(hidden)
        self.pos_scale, self.vel_scale, self.acc_scale = pos_scale, vel_scale, acc_scale
        self.centres = np.linspace(-1.0, 1.0, self.tiles)
        self.width = 2.0 / max(self.tiles - 1, 1)

    @property
    def n_params(self) -> int:
        if self.kind == "ella":
            return 4 * 2
        if self.kind == "rbf-ella":
            return self.tiles**3 * 2
        return 5 * self.hidden + self.hidden + self.hidden * 2 + 2

    def _inputs(self, t: int, pos: np.ndarray, vel: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        tau = 2.0 * t / self.horizon - 1.0  # in [-1, 1]
        return pos / self.pos_scale, vel / self.vel_scale, tau

    def action(self, theta: np.ndarray, t: int, pos: np.ndarray, vel: np.ndarray) -> np.ndarray:
        """Accelerations (B, 2) for parameters ``theta`` (B, n_params) at control step ``t``."""
        x, v, tau = self._inputs(t, pos, vel)
        B = len(theta)
        if self.kind == "ella":
            w = theta.reshape(B, 4, 2)
            out = w[:, 0] * x + w[:, 1] * v + w[:, 2] * tau + w[:, 3]
        elif self.kind == "rbf-ella":
            w = theta.reshape(B, self.tiles**3, 2)
            c, s = self.centres, self.width
            fx = np.exp(-0.5 * ((x[..., None] - c) / s) ** 2)  # (B, 2, tiles)
            fv = np.exp(-0.5 * ((v[..., None] - c) / s) ** 2)
            ft = np.exp(-0.5 * ((tau - c) / s) ** 2)  # (tiles,)
            feats = np.einsum("bai,baj,k->baijk", fx, fv, ft).reshape(B, 2, -1)  # per actuator (B, 2, tiles³)
            out = np.einsum("baf,bfa->ba", feats, w)
        else:
            h = self.hidden
            inp = np.concatenate([x, v, np.full((B, 1), tau)], axis=1)  # (B, 5)
            W1 = theta[:, : 5 * h].reshape(B, 5, h)
            b1 = theta[:, 5 * h : 6 * h]
            W2 = theta[:, 6 * h : 8 * h].reshape(B, h, 2)
            b2 = theta[:, 8 * h :]
            hid = np.maximum(np.einsum("bi,bih->bh", inp, W1) + b1, 0.0)
            out = np.einsum("bh,bha->ba", hid, W2) + b2
        return self.acc_scale * out

    def init_params(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """Initial parameters (n, n_params): zeros for the linear classes, small random weights for FCNN."""
        if self.kind != "fcnn":
            return np.zeros((n, self.n_params))
        return 0.3 * rng.normal(size=(n, self.n_params))


def closed_loop_objective(
    family: str, tasks: np.ndarray, pol: ClosedLoopPolicy, *, shaped: bool = False, config: dict | None = None
) -> Callable[[np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """``f(theta (n, pop, n_params)) -> (fitness, task_cost, success)`` (n, pop), one simulator call."""
    tasks = validate_tasks(family, tasks)
    cfg = {**(config or {}), "shaped": bool(shaped)}

    def f(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        n, pop = theta.shape[:2]
        flat = theta.reshape(n * pop, -1)
        r = closed_loop_simulate(
            family, np.repeat(tasks, pop, axis=0), lambda t, p, v: pol.action(flat, t, p, v), n * pop, cfg
        )
        return r.cost.reshape(n, pop), r.task_cost.reshape(n, pop), r.success.reshape(n, pop).astype(float)

    return f


def learn_closed_loop_sources(
    family: str,
    tasks: np.ndarray,
    kind: str,
    *,
    generations: int,
    sigma: float,
    popsize: int,
    seed: int,
    config: dict | None = None,
) -> tuple[np.ndarray, CMAResult]:
    """A competitor's source tasks: CMA-ES per task on the shaped cost from its initial parameters."""
    pol = ClosedLoopPolicy(kind)
    f = closed_loop_objective(family, tasks, pol, shaped=True, config=config)
    x0 = pol.init_params(np.random.default_rng(seed), len(tasks))
    res = cma_lockstep(f, x0, sigma, generations, popsize=popsize, seed=seed)
    return res.x, res


#: Defaults of :func:`target_job` (transfer budget: ``rounds × 2 × phase_generations`` CMA-ES generations).
TARGET_DEFAULTS: dict[str, Any] = {
    "n_targets": 50,
    "seed": 0,
    "rounds": 2,
    "phase_generations": 25,
    "popsize": 12,
    "sigma": 0.01,
    "ranks": [6, 2, 6],
    "l2": 1e-4,
}


def learn_target(
    strategy: str,
    family: str,
    targets: np.ndarray,
    sources: np.ndarray,
    *,
    rounds: int,
    phase_generations: int,
    popsize: int,
    sigma: float = 0.01,
    ranks: tuple[int, int, int] = (6, 2, 6),
    l2: float = 1e-4,
    seed: int = 0,
    n_basis: int = 10,
    config: dict | None = None,
) -> dict[str, Any]:
    """Learn ``n`` target tasks of ``family`` with ``strategy`` (one of :data:`STRATEGIES`), batched.

    ``sources`` are the learned source policies: ``W`` (P, D, A) for the RBF-PD strategies, flat
    parameters (P, n_params) of the competitor's own class otherwise. Every strategy gets the same budget
    (``rounds × 2 × phase_generations`` generations of ``popsize``). Returns the curves (n, G), the
    final cost/success of the CMA-ES means and the total cost of learning (n,).
    """
    check_choice(strategy, STRATEGIES, "strategy")
    n = len(targets)
    rng = np.random.default_rng(seed)
    generations = rounds * 2 * phase_generations
    if strategy in ("scratch", "direct"):
        if strategy == "scratch":
            W0 = np.tile(RBFPolicy(n_basis=n_basis).default_params(), (n, 1, 1))
        else:
            W0 = np.asarray(sources)[rng.integers(0, len(sources), size=n)]
        W, res = learn_independent(
            family, targets, W0, generations=generations, sigma=sigma, popsize=popsize, l2=l2, seed=seed, config=config
        )
        curve, success = res.curve, res.success
        final = evaluate_policies(family, targets, W, config)
    else:
        if strategy in ("matrix", "tensor"):
            tensor = np.moveaxis(np.asarray(sources), 0, 2)  # (D, A, P)
            objective = arm_objective(family, targets, config=config)
        else:
            pol = ClosedLoopPolicy(strategy)
            tensor = np.asarray(sources).T[:, None, :]  # (n_params, 1, P)
            f = closed_loop_objective(family, targets, pol, config=config)

            def objective(W: np.ndarray, f=f) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
                return f(W[..., 0])

        D, A, P = tensor.shape
        kind = "tensor" if strategy == "tensor" else "matrix"
        r = (min(ranks[0], D), min(ranks[1], A), min(ranks[2], P)) if kind == "tensor" else (D, A, min(ranks[2], P))
        sub = make_subspace(tensor, kind, r)
        res = alternate(
            objective,
            sub,
            n,
            rounds=rounds,
            generations=phase_generations,
            sigma_s=sigma,
            sigma_L=sigma,
            l2=l2,
            popsize=popsize,
            seed=seed,
        )
        curve, success = res.curve, res.success
        _, cost, succ = objective(res.W[:, None])
        final = {"cost": cost[:, 0], "success": succ[:, 0]}
    return {
        "curve": curve,
        "success_curve": success,
        "final_cost": np.asarray(final["cost"], dtype=float),
        "final_success": np.asarray(final["success"], dtype=float),
        "total_cost": popsize * curve.sum(axis=1),
        "trials": popsize * np.arange(1, curve.shape[1] + 1),
    }


def target_job(config: dict[str, Any], workdir: Any = None) -> dict[str, Any]:
    """Cached job: learn ``n_targets`` tasks of ``config["target"]`` with ``config["strategy"]``.

    ``config["source"]`` is the source config (:func:`thesis_repro.arm.learn.source_config`); its job is
    run (or loaded) through the run cache. For competitors, the source tasks are re-learned with the
    competitor's policy class (:func:`learn_closed_loop_sources`, same tasks, same budget).
    """
    cfg = {**TARGET_DEFAULTS, **config}
    strategy = check_choice(cfg["strategy"], STRATEGIES, "strategy")
    src_cfg = cfg["source"]
    arm = src_cfg.get("arm", {})
    if strategy in COMPETITORS:
        src = RunCache.current().run(Job("arm-competitor-source", {**src_cfg, "policy": strategy}))
        sources = src["theta"]
    else:
        sources = RunCache.current().run(Job("arm-source", src_cfg))["W"]
    targets = sample_tasks(cfg["target"], cfg["n_targets"], np.random.default_rng([cfg["seed"], 7]))
    out = learn_target(
        strategy,
        cfg["target"],
        targets,
        sources,
        rounds=cfg["rounds"],
        phase_generations=cfg["phase_generations"],
        popsize=cfg["popsize"],
        sigma=cfg["sigma"],
        ranks=tuple(cfg["ranks"]),
        l2=cfg["l2"],
        seed=cfg["seed"],
        n_basis=src_cfg.get("n_basis", 10),
        config=arm,
    )
    out["success_rate"] = float(out["final_success"].mean())
    out["mean_total_cost"] = float(out["total_cost"].mean())
    return out


def target_dependencies(config: Mapping[str, Any]) -> dict[str, Job]:
    """The source job a ``target_job`` config loads through the run cache (the ``arm-target`` kind's hook).

    >>> [j.kind for j in target_dependencies({"source": {"family": "reach"}, "strategy": "fcnn"}).values()]
    ['arm-competitor-source']
    """
    src = config.get("source")
    if not isinstance(src, Mapping):
        return {}
    if config.get("strategy") in COMPETITORS:
        return {"source": Job("arm-competitor-source", {**src, "policy": config["strategy"]})}
    return {"source": Job("arm-source", src)}


def competitor_source_job(config: dict[str, Any], workdir: Any = None) -> dict[str, Any]:
    """Cached job: the source tasks of a source config, learned with a competitor's policy class."""
    cfg = {**SOURCE_DEFAULTS, **config}
    tasks = sample_tasks(cfg["family"], int(cfg["n_tasks"]), np.random.default_rng(cfg["seed"]))
    theta, res = learn_closed_loop_sources(
        cfg["family"],
        tasks,
        cfg["policy"],
        generations=cfg["generations"] + cfg["mtl_generations"],
        sigma=cfg["sigma"],
        popsize=cfg["popsize"],
        seed=cfg["seed"],
        config=cfg["arm"],
    )
    f = closed_loop_objective(cfg["family"], tasks, ClosedLoopPolicy(cfg["policy"]), config=cfg["arm"])
    _, cost, succ = f(theta[:, None])
    return {
        "theta": theta,
        "tasks": tasks,
        "curve": res.curve.mean(0),
        "success": succ[:, 0],
        "success_rate": float(succ.mean()),
        "cost": cost[:, 0],
    }
