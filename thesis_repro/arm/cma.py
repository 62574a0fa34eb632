"""CMA-ES in lock-step: ``n`` independent CMA-ES instances (one per task, from the ``cma`` package, ask/tell)
advance generation by generation together, and the populations of all of them are evaluated by ONE call of
``evaluate(X)`` with ``X`` of shape ``(n, popsize, dim)`` (:func:`cma_lockstep`).

>>> import numpy as np
>>> res = cma_lockstep(lambda X: ((X - 1.0) ** 2).sum(-1), np.zeros((3, 4)), 0.5, generations=60, seed=1)
>>> bool(np.allclose(res.x, 1.0, atol=0.05)), res.curve.shape
(True, (3, 60))
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from thesis_repro.core.validation import check_positive

#: ``evaluate(X (n, pop, dim))`` returns either ``fitness`` or ``(fitness, cost, success)``, each ``(n, pop)``.
Evaluate = Callable[[np.ndarray], Any]


@dataclass
class CMAResult:
    """Outcome of :func:`cma_lockstep` for ``n`` problems over ``G`` generations.

    ``x`` (n, dim) final CMA-ES means; ``curve`` (n, G) mean population cost per generation;
    ``success`` (n, G) fraction of the population that succeeded; ``best`` (n, G) best cost so far;
    ``popsize`` rollouts per problem per generation.
    """

    x: np.ndarray
    curve: np.ndarray
    success: np.ndarray
    best: np.ndarray
    popsize: int

    @property
    def trials(self) -> np.ndarray:
        """Cumulative rollouts per problem at the end of each generation, shape (G,)."""
        return self.popsize * np.arange(1, self.curve.shape[1] + 1)

    @property
    def total_cost(self) -> np.ndarray:
        """Total cost of learning per problem: the sum of the costs of all rollouts executed, shape (n,)."""
        return self.popsize * self.curve.sum(axis=1)


def default_popsize(dim: int) -> int:
    """CMA-ES default population ``4 + floor(3 ln dim)``."""
    return 4 + int(3 * np.log(max(dim, 1)))


def _split(out: Any, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    if isinstance(out, tuple):
        fit, cost, succ = (np.asarray(o, dtype=float).reshape(shape) for o in out)
    else:
        fit = np.asarray(out, dtype=float).reshape(shape)
        cost, succ = fit, np.zeros(shape)
    return fit, cost, succ


def cma_lockstep(
    evaluate: Evaluate,
    x0: np.ndarray,
    sigma0: float,
    generations: int,
    popsize: int | None = None,
    seed: int = 0,
) -> CMAResult:
    """Run ``n = len(x0)`` CMA-ES instances in lockstep; each generation is ONE ``evaluate`` call.

    ``evaluate(X)`` gets ``X`` (n, popsize, dim) and returns ``fitness`` (minimised) or the triple
    ``(fitness, cost, success)`` where ``cost``/``success`` (the unregularised task cost, 0/1 success)
    are what the learning curves record.

    >>> r = cma_lockstep(lambda X: (X ** 2).sum(-1), np.ones((2, 3)), 0.3, generations=5, popsize=6)
    >>> r.curve.shape, r.trials.tolist()[:2]
    ((2, 5), [6, 12])
    """
    import cma  # local: the cma package takes seconds to import (start-up time of every arm module)

    x0 = np.atleast_2d(np.asarray(x0, dtype=float))
    n, dim = x0.shape
    check_positive(sigma0, "sigma0")
    if generations < 1:
        raise ValueError(f"generations must be >= 1, got {generations}")
    pop = int(popsize or default_popsize(dim))
    if pop < 2:
        raise ValueError(f"popsize must be >= 2, got {pop}")
    rng = np.random.default_rng(seed)
    opts = {"popsize": pop, "verbose": -9, "CMA_diagonal": dim > 150}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if dim == 1:  # cma refuses 1-D problems; carry a dummy coordinate that the caller never sees
            x0 = np.concatenate([x0, np.zeros((n, 1))], axis=1)
        es = [
            cma.CMAEvolutionStrategy(x0[i], sigma0, {**opts, "seed": int(rng.integers(1, 2**31 - 1))}) for i in range(n)
        ]
    curve = np.zeros((n, generations))
    success = np.zeros((n, generations))
    best = np.zeros((n, generations))
    best_so_far = np.full(n, np.inf)
    for g in range(generations):
        X = np.stack([np.asarray(e.ask()) for e in es])[:, :, :dim]
        fit, cost, succ = _split(evaluate(X), (n, pop))
        fit = np.where(np.isfinite(fit), fit, 1e12)
        with warnings.catch_warnings():
            # cma's diagonal decoding notes a sample far out in one coordinate and damps its update itself; the
            # note is advice, not an error, and it came in dozens per run (Fig 5.6's curriculum)
            warnings.filterwarnings("ignore", message="elements of z2", category=UserWarning)
            for i, e in enumerate(es):
                e.tell(list(np.concatenate([X[i], np.zeros((pop, e.N - dim))], axis=1)), fit[i].tolist())
        curve[:, g] = cost.mean(axis=1)
        success[:, g] = succ.mean(axis=1)
        best_so_far = np.minimum(best_so_far, cost.min(axis=1))
        best[:, g] = best_so_far
    x = np.stack([np.asarray(e.mean)[:dim] for e in es])
    return CMAResult(x=x, curve=curve, success=success, best=best, popsize=pop)
