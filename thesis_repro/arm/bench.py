"""Simulator benchmark of chapter 5's arm (``make bench``'s ``arm`` line): vectorised vs looped rollouts.

:func:`bench_arm` times population rollouts of the vectorised simulator against a per-policy Python
loop over the same simulator (ratio measured in one run), and the wall time of one CMA-ES generation
(``cma.CMAEvolutionStrategy`` ask → one batched ``simulate`` → tell) at the CMA default population for
the ``D·A`` policy parameters.

>>> r = bench_arm(n_rollouts=64, loop_rollouts=4, cma_generations=2)
>>> sorted(k for k in r if k.endswith("per_s")), r["speedup"] > 1
(['loop_rollouts_per_s', 'vectorised_rollouts_per_s'], True)
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from thesis_repro.arm.policy import RBFPolicy
from thesis_repro.arm.tasks import ArmConfig, check_family, sample_tasks, simulate


def _random_population(rng: np.random.Generator, B: int, n_basis: int) -> np.ndarray:
    W = np.zeros((B, n_basis + 2, 2))
    W[:, :n_basis] = rng.normal(0.0, 0.3, (B, n_basis, 2))
    W[:, n_basis:] = 1.0 + rng.normal(0.0, 0.1, (B, 2, 2))
    return W


def bench_arm(
    family: str = "bic",
    n_rollouts: int = 2000,
    loop_rollouts: int = 40,
    n_basis: int = 10,
    cma_generations: int = 10,
    repeats: int = 2,
    seed: int = 0,
) -> dict[str, Any]:
    """Rollouts/s of ``simulate`` on a population of ``n_rollouts`` at once vs one policy at a time.

    Rates are the best of ``repeats`` timings each. Returns ``vectorised_rollouts_per_s``,
    ``loop_rollouts_per_s``, ``speedup`` (their ratio),
    ``cma_popsize``, ``cma_generation_s`` (mean wall time of one ask/simulate/tell generation on one task)
    and the settings used.
    """
    import cma  # local: the cma package takes seconds to import; only the benchmark's timing needs it

    check_family(family)
    if min(n_rollouts, loop_rollouts, cma_generations, repeats) < 1:
        raise ValueError("n_rollouts, loop_rollouts, cma_generations and repeats must be >= 1")
    rng = np.random.default_rng(seed)
    tasks = sample_tasks(family, n_rollouts, rng)
    W = _random_population(rng, n_rollouts, n_basis)
    simulate(family, tasks[:8], W[:8])  # warm-up
    vec = loop = 0.0
    for _ in range(repeats):  # best of `repeats` for both (the machine is shared)
        t0 = time.perf_counter()
        simulate(family, tasks, W)
        vec = max(vec, n_rollouts / (time.perf_counter() - t0))
        t0 = time.perf_counter()
        for i in range(loop_rollouts):
            simulate(family, tasks[i], W[i])
        loop = max(loop, loop_rollouts / (time.perf_counter() - t0))

    pol = RBFPolicy(n_basis=n_basis, horizon=ArmConfig().horizon, dt=ArmConfig().dt)
    es = cma.CMAEvolutionStrategy(pol.get_params(), 0.01, {"seed": seed + 1, "verbose": -9})
    t0 = time.perf_counter()
    for _ in range(cma_generations):
        X = np.asarray(es.ask())
        es.tell(list(X), simulate(family, tasks[0], pol.unflatten(X)).cost.tolist())
    gen = (time.perf_counter() - t0) / cma_generations
    return {
        "family": family,
        "n_rollouts": n_rollouts,
        "loop_rollouts": loop_rollouts,
        "horizon": ArmConfig().horizon,
        "vectorised_rollouts_per_s": vec,
        "loop_rollouts_per_s": loop,
        "speedup": vec / loop,
        "cma_popsize": int(es.popsize),
        "cma_n_params": pol.n_params,
        "cma_generation_s": gen,
    }
