"""Chapter-3 generalisation metrics (thesis §3.2.2): testing return, expected testing return, AUC.

Axis convention of the kit's result arrays (so ``scipy``/rliable-style aggregation applies directly):
``(training seeds, tasks, algorithms/variants, sigmas, testing rollouts)``; a metric reduces the trailing
axes, e.g. :func:`expected_return` removes the rollout axis and :func:`auc` the sigma axis, leaving
``(training seeds, tasks, algorithms)``.

>>> auc([100.0, 80.0, 40.0], [0.0, 0.2, 0.4])  # 0.2 * (100 + 80 + 40)
44.0
>>> pareto_frontier([1.0, 2.0, 3.0], [3.0, 1.0, 2.0]).tolist()
[0, 2]
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy import stats

ArrayLike = np.ndarray | Sequence[float] | Sequence[Sequence[float]]


def sigma_step(sigmas: Sequence[float] | np.ndarray) -> float:
    """Grid step ``Δσ = σ₂ − σ₁`` of a uniform, strictly increasing, non-negative grid of ≥ 2 scales.

    >>> sigma_step([0.0, 0.1, 0.2])
    0.1
    """
    s = np.asarray(sigmas, dtype=float)
    if s.ndim != 1 or s.size < 2:
        raise ValueError(f"the sigma grid needs at least 2 points in a 1-D list, got {s.tolist()}")
    if not np.all(np.isfinite(s)) or np.any(s < 0):
        raise ValueError(f"sigmas must be finite and >= 0, got {s.tolist()}")
    steps = np.diff(s)
    if np.any(steps <= 0):
        raise ValueError(f"sigmas must be strictly increasing, got {s.tolist()}")
    if not np.allclose(steps, steps[0], rtol=1e-6, atol=1e-9):
        raise ValueError(f"Eq. 3.6 needs a uniform sigma grid (constant step), got steps {steps.tolist()}")
    return float(s[1] - s[0])


def auc(returns_by_sigma: ArrayLike, sigmas: Sequence[float] | np.ndarray, axis: int = -1) -> np.ndarray | float:
    """Area under the testing-return curve, Eq. 3.6: ``AUC = Σₙ Δσ · η_{σₙ}`` with ``Δσ = σ₂ − σ₁``.

    ``returns_by_sigma`` holds (expected) testing returns with the sigma axis at ``axis`` (default: last);
    every other axis is kept. Because the AUC is linear, the AUC of the expected-return curve equals the
    mean of per-rollout AUCs.

    >>> auc([[100.0, 80.0, 40.0], [10.0, 10.0, 10.0]], [0.0, 0.2, 0.4]).round(6).tolist()
    [44.0, 6.0]
    """
    step = sigma_step(sigmas)
    r = np.asarray(returns_by_sigma, dtype=float)
    if r.ndim == 0 or r.shape[axis] != len(sigmas):
        raise ValueError(f"returns have shape {r.shape}; axis {axis} must have one entry per sigma ({len(sigmas)})")
    out = step * r.sum(axis=axis)
    return float(out) if np.ndim(out) == 0 else out


def expected_return(returns: ArrayLike, axis: int | tuple[int, ...] = -1) -> np.ndarray | float:
    """Expected testing return (Eq. 3.3/3.4): the mean over testing rollouts (and domains) along ``axis``.

    >>> expected_return([[1.0, 3.0], [2.0, 2.0]]).tolist()
    [2.0, 2.0]
    """
    r = np.asarray(returns, dtype=float)
    if r.size == 0:
        raise ValueError("expected_return of an empty array")
    out = r.mean(axis=axis)
    return float(out) if np.ndim(out) == 0 else out


def correlation(train_return: ArrayLike, test_auc: ArrayLike) -> tuple[float, float]:
    """Pearson ``(r, p-value)`` of testing AUC vs training return across variants (Fig. 3.3c).

    >>> r, p = correlation([1.0, 2.0, 3.0, 4.0], [4.0, 3.0, 2.5, 1.0])
    >>> round(r, 3)
    -0.981
    """
    x, y = np.asarray(train_return, dtype=float).ravel(), np.asarray(test_auc, dtype=float).ravel()
    if x.shape != y.shape:
        raise ValueError(f"train_return and test_auc need one value per variant each, got {x.size} and {y.size}")
    if x.size < 3:
        raise ValueError(f"a correlation needs at least 3 variants, got {x.size}")
    if np.ptp(x) == 0 or np.ptp(y) == 0:
        raise ValueError("correlation is undefined when training returns or testing AUCs are all equal")
    res = stats.pearsonr(x, y)
    return float(res.statistic), float(res.pvalue)


def pareto_frontier(train_return: ArrayLike, test_auc: ArrayLike) -> np.ndarray:
    """Indices of the points not dominated in both training return and testing AUC (both maximised).

    A point is dominated if another is at least as good in both and strictly better in one. The indices
    are sorted by increasing training return (so by decreasing testing AUC), ready to draw the frontier.

    >>> pareto_frontier([1.0, 2.0, 2.0, 0.5], [2.0, 1.0, 0.5, 1.0]).tolist()
    [0, 1]
    """
    x, y = np.asarray(train_return, dtype=float).ravel(), np.asarray(test_auc, dtype=float).ravel()
    if x.shape != y.shape or x.size == 0:
        raise ValueError(f"need the same, non-zero number of points, got {x.size} and {y.size}")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        raise ValueError("pareto_frontier needs finite values")
    ge = (x[None, :] >= x[:, None]) & (y[None, :] >= y[:, None])  # ge[i, j]: j at least as good as i
    gt = (x[None, :] > x[:, None]) | (y[None, :] > y[:, None])
    dominated = (ge & gt).any(axis=1)
    keep = np.flatnonzero(~dominated)
    return keep[np.lexsort((-y[keep], x[keep]))]
