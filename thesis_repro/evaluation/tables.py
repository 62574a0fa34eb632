"""Statistics of the chapter-3 tables (thesis Tables 3.3-3.7, Figs 3.5-3.6), on tidy frames.

* A table **cell** is ``mean ± std`` over every (training seed × testing rollout) sample of one
  (task, test, method), as the thesis averages "over 12 training seeds × 20 testing seeds"; ``std`` is the
  corrected sample standard deviation (``ddof=1``, the one Welch's test uses) and ``n`` the sample count.
* **Bolding** (captions of Tables 3.4-3.7, e.g. thesis l. 647: "the results of the best-performing
  algorithm, as well as algorithms that are not significantly different are highlighted in boldface.
  Welch's t-test with p < 0.05 is used"): per row, the cell with the highest mean, plus every cell whose
  two-sided Welch p-value against it is ``>= alpha``. ``alpha`` is read from
  ``data/thesis/chapter3_settings.csv`` (:func:`significance_level`).
* The thesis prints mean ± std, not its samples, so **its** bolding is derived with the same rule from its
  numbers by :func:`welch_p_from_stats` with ``n = 12 × 20 = 240`` per cell (:func:`thesis_n`; the
  setting rows ``n_train_seeds`` × ``n_test_seeds``), assuming its std is over those 240 samples.
* **Normalised AUC change** (Figs 3.5, 3.6): the thesis does not define its normalisation. We use
  ``(AUC_method − AUC_baseline) / |AUC_baseline|`` per (task, test) (``how="baseline"``: the change relative
  to the baseline, so tasks with returns of different size weigh alike; positive = better than the
  baseline), or ``(AUC_method − AUC_baseline) / max_m |AUC_m|`` over the methods of the row (``how="max"``),
  then average over tasks.

* **Confidence intervals across training seeds** (the training seed is the unit of replication,
  never the testing rollout): per seed, the mean over its rollouts; then the two-sided t-interval of the mean
  over the seeds (:func:`t_interval`, ``scipy.stats.t.interval`` with ``n_seeds − 1`` degrees of freedom, level
  :data:`CI_LEVEL`) — :func:`seed_ci` for table cells, :func:`seed_change_ci` for the bars of Figs 3.5/3.6,
  :func:`t_errorbar` for the bands of the curve figures. With one seed there is no interval (NaN bounds).

Frames are tidy: samples ``env, test, method, value`` (one row per sample; ``seed`` for the intervals), cells
``env, test, method, mean, std, n`` (the thesis CSVs have the same columns but ``n``).

>>> import pandas as pd
>>> s = pd.DataFrame({"env": "Hopper", "test": "obs", "method": ["a"] * 3 + ["b"] * 3,
...                   "value": [1.0, 2.0, 3.0, 10.0, 11.0, 12.0]})
>>> c = cells(s)
>>> c[["method", "mean", "std", "n"]].values.tolist()
[['a', 2.0, 1.0, 3], ['b', 11.0, 1.0, 3]]
>>> bold(c)["bold"].tolist()          # b is best; a differs significantly (p ~ 5e-4)
[False, True]
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import cache

import numpy as np
import pandas as pd
from scipy import stats

from thesis_repro.core import thesis_numbers
from thesis_repro.core.validation import check_choice

#: Columns that identify one row of a chapter-3 table (a testing condition).
ROW: tuple[str, ...] = ("env", "test")
#: Normalisations of the AUC change (see the module docstring).
NORMALISATIONS: tuple[str, ...] = ("baseline", "max")
#: Confidence level of the intervals across training seeds.
CI_LEVEL: float = 0.95


@cache
def _settings() -> dict[str, float]:
    frame = thesis_numbers.load("chapter3_settings")
    rows = frame[frame["condition"] == "all"]
    return {r.parameter: float(r.value) for r in rows.itertuples()}


def significance_level() -> float:
    """The thesis's significance level for bolding (``welch_p_value`` in ``chapter3_settings.csv``).

    >>> significance_level()
    0.05
    """
    return _settings()["welch_p_value"]


def thesis_n() -> int:
    """Samples behind one thesis cell: training seeds × testing rollouts (Sec 3.2.2).

    >>> thesis_n()
    240
    """
    s = _settings()
    return int(s["n_train_seeds"] * s["n_test_seeds"])


def mean_std(values: Sequence[float] | np.ndarray) -> tuple[float, float, int]:
    """``(mean, std, n)`` of all finite values (any shape, e.g. seeds × rollouts); ``std`` uses ``ddof=1``.

    ``std`` is NaN for fewer than two values; an empty input raises ``ValueError``.

    >>> mean_std([[1.0, 3.0], [5.0, 7.0]])
    (4.0, 2.581988897471611, 4)
    """
    v = np.asarray(values, dtype=float).ravel()
    v = v[np.isfinite(v)]
    if v.size == 0:
        raise ValueError("mean_std needs at least one finite value")
    std = float(v.std(ddof=1)) if v.size > 1 else float("nan")
    return float(v.mean()), std, int(v.size)


def _degenerate(m1: float, s1: float, m2: float, s2: float) -> float | None:
    """p for two zero-variance samples (SciPy gives NaN or a warning): 1 if equal means, else 0."""
    if s1 == 0.0 and s2 == 0.0:
        return 1.0 if m1 == m2 else 0.0
    return None


def pm_text(mean: float, spread: float) -> str:
    """A display cell: ``"mean ± spread"`` (one decimal), ``"mean"`` when ``spread`` is NaN, ``""`` when ``mean`` is.

    >>> pm_text(800.0, 248.44), pm_text(700.0, float("nan")), pm_text(float("nan"), 1.0)
    ('800.0 ± 248.4', '700.0', '')
    """
    if not np.isfinite(mean):
        return ""
    return f"{mean:.1f} ± {spread:.1f}" if np.isfinite(spread) else f"{mean:.1f}"


def welch_p(a: Sequence[float] | np.ndarray, b: Sequence[float] | np.ndarray) -> float:
    """Two-sided Welch p-value of two samples (``scipy.stats.ttest_ind(a, b, equal_var=False)``).

    NaN if a sample has fewer than two finite values; two constant samples give 1 (equal) or 0 (different).

    >>> round(welch_p([1.0, 2.0, 3.0, 4.0, 5.0], [2.0, 4.0, 6.0, 9.0]), 4)
    0.2397
    """
    x, y = (np.asarray(v, dtype=float).ravel() for v in (a, b))
    x, y = x[np.isfinite(x)], y[np.isfinite(y)]
    if x.size < 2 or y.size < 2:
        return float("nan")
    p = _degenerate(x.mean(), x.std(), y.mean(), y.std())
    if p is not None:
        return p
    return float(stats.ttest_ind(x, y, equal_var=False).pvalue)


def welch_p_from_stats(m1: float, s1: float, n1: int, m2: float, s2: float, n2: int) -> float:
    """Two-sided Welch p-value from ``mean, std (ddof=1), n`` of two samples (``ttest_ind_from_stats``).

    >>> round(welch_p_from_stats(3.0, 1.5811, 5, 5.25, 2.9861, 4), 3)
    0.24
    """
    if n1 < 2 or n2 < 2 or not (np.isfinite(s1) and np.isfinite(s2)):
        return float("nan")
    p = _degenerate(m1, s1, m2, s2)
    if p is not None:
        return p
    res = stats.ttest_ind_from_stats(m1, s1, n1, m2, s2, n2, equal_var=False)
    return float(res.pvalue)


def cells(samples: pd.DataFrame, value: str = "value", by: Sequence[str] = (*ROW, "method")) -> pd.DataFrame:
    """Cells ``by + (mean, std, n)`` of a tidy sample frame (one row per seed × rollout sample).

    Rows keep the order in which each group first appears.
    """
    missing = [c for c in (*by, value) if c not in samples.columns]
    if missing:
        raise ValueError(f"sample frame lacks columns {missing}; it has {list(samples.columns)}")
    rows = []
    for key, group in samples.groupby(list(by), sort=False):
        m, s, n = mean_std(group[value].to_numpy())
        rows.append({**dict(zip(by, key, strict=True)), "mean": m, "std": s, "n": n})
    return pd.DataFrame(rows, columns=[*by, "mean", "std", "n"])


def bold_row(
    means: Sequence[float], stds: Sequence[float], ns: Sequence[int], alpha: float | None = None
) -> np.ndarray:
    """Bold mask of one row: the best mean, plus every cell not significantly different from it.

    A cell is "not significantly different" when its Welch p-value against the best cell is ``>= alpha``
    (default :func:`significance_level`). A p-value that cannot be computed (fewer than two samples)
    does not bold the cell. Higher is better; NaN means (cells not run) are never bold.

    >>> bold_row([10.0, 9.0, 2.0], [1.0, 1.0, 1.0], [240, 240, 240]).tolist()
    [True, False, False]
    >>> bold_row([10.0, 9.9, 2.0], [1.0, 1.0, 1.0], [240, 240, 240]).tolist()
    [True, True, False]
    """
    alpha = significance_level() if alpha is None else float(alpha)
    m, s, n = (np.asarray(x, dtype=float) for x in (means, stds, ns))
    if not (m.shape == s.shape == n.shape) or m.ndim != 1:
        raise ValueError(f"means, stds and ns must be 1-D of one length, got {m.shape}, {s.shape}, {n.shape}")
    out = np.zeros(m.shape, dtype=bool)
    if not np.isfinite(m).any():
        return out
    best = int(np.nanargmax(m))
    for i in range(m.size):
        if i == best:
            out[i] = True
        elif np.isfinite(m[i]):
            p = welch_p_from_stats(m[best], s[best], int(n[best]), m[i], s[i], int(n[i]))
            out[i] = bool(np.isfinite(p) and p >= alpha)
    return out


def bold(table: pd.DataFrame, alpha: float | None = None, n: int | None = None) -> pd.DataFrame:
    """``table`` (cells ``env, test, method, mean, std[, n]``) with a boolean ``bold`` column per row.

    ``n`` fills a missing ``n`` column (e.g. :func:`thesis_n` for the thesis's CSVs).

    >>> t = thesis_numbers.thesis_table("table3_4", env="Walker2d", test="obs")
    >>> bold(t, n=thesis_n()).query("bold").method.tolist()
    ['sac']
    """
    t = table.copy()
    if "n" not in t.columns:
        if n is None:
            raise ValueError("the table has no 'n' column; pass n= (the samples behind each cell)")
        t["n"] = int(n)
    t["bold"] = False
    for _, idx in t.groupby(list(ROW), sort=False).groups.items():
        rows = t.loc[idx]
        t.loc[idx, "bold"] = bold_row(rows["mean"], rows["std"], rows["n"], alpha)
    return t


def best(table: pd.DataFrame) -> pd.DataFrame:
    """The method with the highest mean in each row: columns ``env, test, method``.

    >>> best(thesis_numbers.thesis_table("table3_4", env="Hopper")).method.tolist()
    ['trpo', 'sac', 'sac', 'ppo']
    """
    ok = table.dropna(subset=["mean"])
    idx = ok.groupby(list(ROW), sort=False)["mean"].idxmax()
    return ok.loc[idx.to_numpy(), [*ROW, "method"]].reset_index(drop=True)


def bold_agreement(ours: pd.DataFrame, thesis: pd.DataFrame) -> dict[str, int]:
    """How far our bolding agrees with the thesis's, over the (row, method) cells both have.

    Both frames carry ``env, test, method, mean, bold`` (from :func:`bold`; compare them on the same methods).
    Returns ``cells`` (cells compared), ``same`` (bold in both or in neither), ``bold_both``,
    ``bold_thesis`` and ``bold_ours`` (bold cells per source among the compared), and ``rows`` /
    ``best_same`` (rows whose best method is the same).

    >>> a = pd.DataFrame({"env": "H", "test": "obs", "method": ["x", "y"], "bold": [True, False], "mean": [2, 1]})
    >>> b = a.assign(bold=[True, True])
    >>> bold_agreement(a, b)["same"]
    1
    """
    keys = [*ROW, "method"]
    for name, frame in (("ours", ours), ("thesis", thesis)):
        missing = [c for c in (*keys, "mean", "bold") if c not in frame.columns]
        if missing:
            raise ValueError(f"{name} lacks columns {missing}; run bold() on it first")
    m = ours[[*keys, "mean", "bold"]].merge(thesis[[*keys, "mean", "bold"]], on=keys, suffixes=("_ours", "_thesis"))
    m = m.dropna(subset=["mean_ours", "mean_thesis"])
    rows = m[list(ROW)].drop_duplicates()
    b_ours = best(m.rename(columns={"mean_ours": "mean"})[[*keys, "mean"]])
    b_thesis = best(m.rename(columns={"mean_thesis": "mean"})[[*keys, "mean"]])
    same_best = b_ours.merge(b_thesis, on=list(ROW), suffixes=("_o", "_t"))
    return {
        "cells": int(len(m)),
        "same": int((m["bold_ours"] == m["bold_thesis"]).sum()),
        "bold_both": int((m["bold_ours"] & m["bold_thesis"]).sum()),
        "bold_thesis": int(m["bold_thesis"].sum()),
        "bold_ours": int(m["bold_ours"].sum()),
        "rows": int(len(rows)),
        "best_same": int((same_best["method_o"] == same_best["method_t"]).sum()),
    }


def auc_change(table: pd.DataFrame, baseline: str, how: str = "baseline") -> pd.DataFrame:
    """Change in normalised AUC of every method vs ``baseline``, per row: ``env, test, method, change``.

    ``how="baseline"``: ``(m − b) / |b|``; ``how="max"``: ``(m − b) / max |AUC|`` over the row's methods
    (the baseline's own row is dropped). Rows without the baseline are dropped.

    >>> t = pd.DataFrame({"env": "H", "test": "obs", "method": ["ppo", "x", "y"], "mean": [100.0, 150.0, 50.0]})
    >>> auc_change(t, "ppo").change.tolist()
    [0.5, -0.5]
    >>> auc_change(t, "ppo", how="max").change.round(3).tolist()
    [0.333, -0.333]
    """
    check_choice(how, NORMALISATIONS, "normalisation")
    base = table[table["method"] == baseline][[*ROW, "mean"]].rename(columns={"mean": "base"})
    if base.empty:
        raise ValueError(f"baseline {baseline!r} is not in the table; methods are {sorted(set(table['method']))}")
    t = table.merge(base, on=list(ROW))
    if how == "baseline":
        scale = t["base"].abs()
    else:
        scale = t.groupby(list(ROW))["mean"].transform(lambda x: x.abs().max())
    t["change"] = (t["mean"] - t["base"]) / scale.where(scale > 0)
    return t[t["method"] != baseline][[*ROW, "method", "change"]].reset_index(drop=True)


def mean_change(changes: pd.DataFrame) -> pd.DataFrame:
    """Average :func:`auc_change` over tasks (the bars of Figs 3.5, 3.6): ``test, method, change, n_envs``.

    >>> c = pd.DataFrame({"env": ["A", "B"], "test": "obs", "method": "x", "change": [0.5, -0.1]})
    >>> mean_change(c).values.tolist()
    [['obs', 'x', 0.2, 2]]
    """
    g = changes.dropna(subset=["change"]).groupby(["test", "method"], sort=False)["change"]
    return g.agg(change="mean", n_envs="count").reset_index()


# ---------------------------------------------------------------- confidence intervals across training seeds
def t_interval(values: Sequence[float] | np.ndarray, level: float = CI_LEVEL) -> tuple[float, float, float, int]:
    """``(mean, lo, hi, n)``: the two-sided ``level`` t-interval of the mean of the finite ``values`` (one value
    per training seed), ``scipy.stats.t.interval(level, n - 1, loc=mean, scale=sem)``.

    ``lo``/``hi`` are NaN for fewer than two values (one seed: no interval); equal values give ``lo = hi = mean``.
    An empty input raises ``ValueError``.

    >>> m, lo, hi, n = t_interval([700.0, 800.0, 900.0])   # mean 800, sem 57.7, t(0.975, 2) = 4.303
    >>> m, round(lo, 1), round(hi, 1), n
    (800.0, 551.6, 1048.4, 3)
    >>> t_interval([812.0])
    (812.0, nan, nan, 1)
    """
    v = np.asarray(values, dtype=float).ravel()
    v = v[np.isfinite(v)]
    if v.size == 0:
        raise ValueError("t_interval needs at least one finite value")
    m = float(v.mean())
    if v.size < 2:
        return m, float("nan"), float("nan"), 1
    sem = float(stats.sem(v))
    if sem == 0.0:
        return m, m, m, int(v.size)
    lo, hi = stats.t.interval(level, v.size - 1, loc=m, scale=sem)
    return m, float(lo), float(hi), int(v.size)


def t_errorbar(values: Sequence[float] | np.ndarray) -> tuple[float, float]:
    """``(lo, hi)`` of :func:`t_interval` at :data:`CI_LEVEL`: a seaborn ``errorbar=`` callable for per-seed
    values (a band over training seeds; seaborn draws none where a point has a single value).

    >>> [round(x, 1) for x in t_errorbar([700.0, 800.0, 900.0])]
    [551.6, 1048.4]
    """
    _, lo, hi, _ = t_interval(values)
    return lo, hi


def seed_means(
    samples: pd.DataFrame, value: str = "value", by: Sequence[str] = (*ROW, "method"), seed: str = "seed"
) -> pd.DataFrame:
    """Per training seed, the mean of ``value`` over its samples (testing rollouts): columns ``by + seed + value``.

    >>> s = pd.DataFrame({"method": "a", "seed": [0, 0, 1, 1], "value": [1.0, 3.0, 5.0, 9.0]})
    >>> seed_means(s, by=["method"]).values.tolist()
    [['a', 0, 2.0], ['a', 1, 7.0]]
    """
    keys = [*by, seed]
    missing = [c for c in (*keys, value) if c not in samples.columns]
    if missing:
        raise ValueError(f"sample frame lacks columns {missing}; it has {list(samples.columns)}")
    return samples.groupby(keys, as_index=False, sort=False)[value].mean()[[*keys, value]]


def _ci_frame(per_seed: pd.DataFrame, value: str, by: Sequence[str], level: float) -> pd.DataFrame:
    rows = []
    for key, group in per_seed.groupby(list(by), sort=False):
        m, lo, hi, n = t_interval(group[value].to_numpy(), level)
        rows.append({**dict(zip(by, key, strict=True)), "seed_mean": m, "ci_lo": lo, "ci_hi": hi, "n_seeds": n})
    return pd.DataFrame(rows, columns=[*by, "seed_mean", "ci_lo", "ci_hi", "n_seeds"])


def seed_ci(
    samples: pd.DataFrame,
    value: str = "value",
    by: Sequence[str] = (*ROW, "method"),
    seed: str = "seed",
    level: float = CI_LEVEL,
) -> pd.DataFrame:
    """Per cell (``by``): the mean over training seeds of each seed's mean over its rollouts and the ``level``
    t-interval of that mean across seeds: columns ``by + (seed_mean, ci_lo, ci_hi, n_seeds)``.

    One seed: ``n_seeds = 1`` and NaN bounds (no interval). Rows keep their order of first appearance.

    >>> s = pd.DataFrame({"env": "Hopper", "test": "obs", "method": "ppo", "seed": [0, 0, 1, 1, 2, 2],
    ...                   "value": [690.0, 710.0, 780.0, 820.0, 900.0, 900.0]})   # seed means 700, 800, 900
    >>> seed_ci(s).round(1)[["seed_mean", "ci_lo", "ci_hi", "n_seeds"]].values.tolist()
    [[800.0, 551.6, 1048.4, 3.0]]
    >>> seed_ci(s[s.seed == 0])[["seed_mean", "ci_lo", "n_seeds"]].values.tolist()   # one seed: no interval
    [[700.0, nan, 1.0]]
    """
    return _ci_frame(seed_means(samples, value, by, seed), value, list(by), level)


def seed_change(samples: pd.DataFrame, baseline: str, how: str = "baseline", seed: str = "seed") -> pd.DataFrame:
    """Per training seed, the change of :func:`auc_change` computed on that seed's runs: ``env, test, method,
    seed, change``.

    Seed ``s`` of a method is compared with seed ``s`` of the baseline (seeds are paired by index, so the spread
    across seeds carries both learners' seed variation); the normaliser is the pooled one of :func:`auc_change`
    (``|baseline mean|`` or the row's largest ``|mean|`` over all seeds), a fixed scale per task, so the mean
    over seeds of this change equals :func:`auc_change` on the pooled cells (equal rollouts per seed).

    >>> s = pd.DataFrame({"env": "H", "test": "obs", "method": ["ppo", "ppo", "x", "x"], "seed": [0, 1, 0, 1],
    ...                   "value": [100.0, 100.0, 140.0, 160.0]})
    >>> seed_change(s, "ppo")[["seed", "change"]].values.tolist()
    [[0.0, 0.4], [1.0, 0.6]]
    """
    check_choice(how, NORMALISATIONS, "normalisation")
    per = seed_means(samples, "value", (*ROW, "method"), seed)
    pooled = per.groupby([*ROW, "method"], as_index=False, sort=False)["value"].mean()
    base_pooled = pooled[pooled["method"] == baseline][[*ROW, "value"]].rename(columns={"value": "scale"})
    if base_pooled.empty:
        raise ValueError(f"baseline {baseline!r} is not in the samples; methods are {sorted(set(per['method']))}")
    if how == "baseline":
        scale = base_pooled.assign(scale=base_pooled["scale"].abs())
    else:
        scale = pooled.assign(scale=pooled["value"].abs()).groupby(list(ROW), as_index=False)["scale"].max()
    base = per[per["method"] == baseline][[*ROW, seed, "value"]].rename(columns={"value": "base"})
    t = per[per["method"] != baseline].merge(base, on=[*ROW, seed]).merge(scale, on=list(ROW))
    t["change"] = (t["value"] - t["base"]) / t["scale"].where(t["scale"] > 0)
    return t[[*ROW, "method", seed, "change"]].rename(columns={seed: "seed"}).reset_index(drop=True)


def seed_change_ci(
    samples: pd.DataFrame, baseline: str, how: str = "baseline", level: float = CI_LEVEL
) -> pd.DataFrame:
    """The bars of Figs 3.5/3.6 per training seed and their interval: per seed, :func:`seed_change` averaged over
    the tasks (as :func:`mean_change`); then the ``level`` t-interval over seeds. Columns ``test, method,
    seed_mean, ci_lo, ci_hi, n_seeds`` (one seed: NaN bounds).

    >>> s = pd.DataFrame({"env": "H", "test": "obs", "method": ["ppo"] * 3 + ["x"] * 3, "seed": [0, 1, 2] * 2,
    ...                   "value": [100.0, 100.0, 100.0, 140.0, 150.0, 160.0]})
    >>> seed_change_ci(s, "ppo").round(3).values.tolist()
    [['obs', 'x', 0.5, 0.252, 0.748, 3]]
    """
    ch = seed_change(samples, baseline, how).dropna(subset=["change"])
    per_seed = ch.groupby(["test", "method", "seed"], as_index=False, sort=False)["change"].mean()
    return _ci_frame(per_seed, "change", ["test", "method"], level)


def ci_label(n_seeds: Sequence[int] | np.ndarray | int, level: float = CI_LEVEL) -> str:
    """What a page's intervals are, for a caption: the level and the number of training seeds behind them.

    >>> ci_label([3, 3])
    '95 % CI of the mean across 3 training seeds (t-interval over per-seed means)'
    >>> ci_label(1)
    '1 training seed: no confidence interval'
    >>> ci_label([1, 3])
    '95 % CI of the mean across 1-3 training seeds (t-interval over per-seed means; seeds per cell in parentheses)'
    """
    n = np.atleast_1d(np.asarray(n_seeds, dtype=float))
    n = n[np.isfinite(n)].astype(int)
    if n.size == 0 or n.max() < 2:
        return "1 training seed: no confidence interval"
    what = f"{level:.0%}".replace("%", " %") + " CI of the mean across"
    if n.min() == n.max():
        return f"{what} {n.max()} training seeds (t-interval over per-seed means)"
    return f"{what} {n.min()}-{n.max()} training seeds (t-interval over per-seed means; seeds per cell in parentheses)"


def fmt_ci(mean: float, lo: float, hi: float, n_seeds: int, digits: int | None = None) -> str:
    """A compact interval cell: ``"mean [lo, hi] (n_seeds)"``, or ``"mean (1 seed)"`` without an interval;
    ``""`` for a NaN mean (cell not run). ``digits`` decimals; by default 0 from ``|mean| >= 100``, else 1.

    >>> fmt_ci(812.4, 640.0, 984.6, 3), fmt_ci(81.24, float("nan"), float("nan"), 1)
    ('812 [640, 985] (3)', '81.2 (1 seed)')
    >>> fmt_ci(0.1234, 0.05, 0.2, 3, digits=3)
    '0.123 [0.050, 0.200] (3)'
    """
    if not np.isfinite(mean):
        return ""
    d = (0 if abs(mean) >= 100 else 1) if digits is None else int(digits)
    if not (np.isfinite(lo) and np.isfinite(hi)):
        return f"{mean:.{d}f} ({int(n_seeds)} seed{'s' if int(n_seeds) != 1 else ''})"
    return f"{mean:.{d}f} [{lo:.{d}f}, {hi:.{d}f}] ({int(n_seeds)})"
