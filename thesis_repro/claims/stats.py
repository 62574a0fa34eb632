"""Statistics across training seeds: contrasts with 95 % CIs (``scipy.stats``), units, count rules, null draws.

The unit of replication is always the training seed: a :class:`Contrast` holds one value per seed for each
side (never rollouts or training episodes; those are averaged inside a seed first). Its effect is
``sign * (mean(a) - mean(b))`` (divided by ``|mean(b)|`` when ``relative``) minus ``margin``, with the 95 %
CI of a Welch test (unpaired), a one-sample t test (paired differences, or ``a`` against ``ref``), or a
Clopper-Pearson interval (``proportion``: 0/1 outcomes per seed). A contrast is *yes* when its CI lies
above 0, *no* when below, *undecided* when it spans 0. A :class:`Unit` combines contrasts (all / any);
a :class:`CountRule` turns the units' yes-fraction interval ``[yes / n, (yes + undecided) / n]`` into a
verdict: one region (reproduces / partly / does not) for the whole interval, else *inconclusive*. With
fewer than two seeds there is no CI: the point estimates give a leaning, reported as *indicative* only.

>>> c = Contrast("kl_avg - joint", a=(3.0, 3.2, 3.1), b=(1.0, 1.1, 0.9))
>>> round(c.estimate().est, 2), c.estimate().outcome
(2.1, 'yes')
>>> rule = CountRule(reproduces=0.5, partly=0.25)
>>> rule.judge([Unit("row", (c,))]).status
'reproduces'
>>> rule.judge([Unit("row", (Contrast("one seed", a=(3.0,), b=(1.0,)),))]).status
'indicative'
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from functools import lru_cache
from typing import Any

import numpy as np
from scipy import stats as st

from thesis_repro.report import DOES_NOT, INCONCLUSIVE, INDICATIVE, NOT_COMPUTED, PARTLY, REPRODUCES

YES, NO, UNDECIDED = "yes", "no", "undecided"
#: Two-sided confidence level of every interval (a contrast is "yes" at one-sided 2.5 %).
LEVEL = 0.95
#: Seeds a null draw uses at least (the design: 3 training seeds at ``small``).
NULL_SEEDS = 3


@dataclass(frozen=True)
class Estimate:
    """A contrast's directed effect (claim direction positive, margin subtracted) with its CI and seeds."""

    est: float
    lo: float
    hi: float
    n: int

    @property
    def outcome(self) -> str:
        """``yes`` (CI above 0), ``no`` (CI at or below 0), ``undecided``; point sign when there is no CI.

        A CI that ends at 0 has no room for the claimed (strictly positive) effect: a tie in every seed (0 vs 0
        successes, two learners at a task's ceiling) is ``no``, as its point estimate 0 is without a CI.

        >>> Estimate(0.0, 0.0, 0.0, 3).outcome, Estimate(0.5, -0.1, 1.1, 3).outcome, Estimate(0.0, 0.0, 0.2, 3).outcome
        ('no', 'undecided', 'undecided')
        """
        if not math.isfinite(self.est):
            return UNDECIDED
        if not (math.isfinite(self.lo) and math.isfinite(self.hi)):
            return YES if self.est > 0 else NO
        return YES if self.lo > 0 else NO if self.hi <= 0 else UNDECIDED


def _clean(x: Sequence[float] | None) -> np.ndarray | None:
    if x is None:
        return None
    a = np.asarray(x, dtype=float)
    return a[np.isfinite(a)]


def _mean(x: Sequence[float]) -> float:
    """Mean of the finite values; NaN (silently) when there are none, e.g. a diverged run's.

    >>> _mean([1.0, float("nan"), 3.0]), _mean([float("nan")])
    (2.0, nan)
    """
    a = _clean(x)
    return float(a.mean()) if a is not None and len(a) else float("nan")


@lru_cache(maxsize=4096)
def _tq(level: float, df: float) -> float:
    """Two-sided ``level`` quantile of Student's t with ``df`` degrees of freedom (``scipy.stats.t``)."""
    return float(st.t.ppf(0.5 + level / 2, df))


def _mean_ci(x: np.ndarray, level: float) -> tuple[float, float, float]:
    """Mean and t-interval of ``x`` (equal to ``scipy.stats.ttest_1samp(x, 0).confidence_interval(level)``;
    a point interval when all values are equal; NaN interval if n < 2)."""
    m = float(np.mean(x)) if x.size else float("nan")
    if x.size < 2:
        return m, float("nan"), float("nan")
    se = float(np.std(x, ddof=1)) / math.sqrt(x.size)
    if se == 0:
        return m, m, m
    h = _tq(level, x.size - 1) * se
    return m, m - h, m + h


def _welch_ci(a: np.ndarray, b: np.ndarray, level: float) -> tuple[float, float, float]:
    """Difference of means and its Welch interval (Welch-Satterthwaite df; equal to
    ``scipy.stats.ttest_ind(a, b, equal_var=False).confidence_interval(level)``)."""
    d = float(np.mean(a) - np.mean(b)) if a.size and b.size else float("nan")
    if a.size < 2 or b.size < 2:
        return d, float("nan"), float("nan")
    va, vb = float(np.var(a, ddof=1)) / a.size, float(np.var(b, ddof=1)) / b.size
    if va + vb == 0:
        return d, d, d
    df = (va + vb) ** 2 / (va**2 / (a.size - 1) + vb**2 / (b.size - 1))
    h = _tq(level, round(df, 2)) * math.sqrt(va + vb)
    return d, d - h, d + h


@dataclass(frozen=True)
class Contrast:
    """Per-seed values ``a`` against ``b`` (or against ``ref``), in the claim's direction.

    ``sign`` +1: the claim says ``a`` is larger; -1: smaller. ``paired``: ``a[i]`` and ``b[i]`` come from one
    policy (seed ``i``), e.g. its mass drop and its wind drop. ``relative``: effect divided by ``|mean(b)|``.
    ``margin``: the effect must exceed it (negative margin: non-inferiority, e.g. ``-0.1`` = "at most 10 %
    worse"). ``proportion``: ``a`` holds 0/1 outcomes per seed, compared with ``ref`` by Clopper-Pearson.
    """

    label: str
    a: tuple[float, ...]
    b: tuple[float, ...] | None = None
    sign: int = 1
    paired: bool = False
    relative: bool = False
    margin: float = 0.0
    ref: float = 0.0
    proportion: bool = False

    def directed_label(self) -> str:
        """The label of the quantity :meth:`estimate` reports: ``-(label)`` when the claim says smaller, so a
        printed effect reads as what it is (> 0 supports the claim).

        >>> Contrast("r across variants", (-0.8,), sign=-1).directed_label()
        '-(r across variants)'
        """
        return self.label if self.sign > 0 else f"-({self.label})"

    def n(self) -> int:
        """Seeds of the smaller side."""
        na = _clean(self.a).size
        return na if self.b is None else min(na, _clean(self.b).size)

    def estimate(self, level: float = LEVEL) -> Estimate:
        """The directed effect minus ``margin`` with its ``level`` CI across seeds."""
        a, b = _clean(self.a), _clean(self.b)
        if self.proportion:
            k, n = int(np.sum(a > 0.5)), int(a.size)
            if n == 0:
                return Estimate(float("nan"), float("nan"), float("nan"), 0)
            ci = st.binomtest(k, n).proportion_ci(level) if n >= 2 else None
            d, lo, hi = k / n - self.ref, *((ci.low - self.ref, ci.high - self.ref) if ci else (math.nan, math.nan))
        elif b is None:
            d, lo, hi = _mean_ci(a - self.ref, level)
        elif self.paired:
            m = min(a.size, b.size)
            d, lo, hi = _mean_ci(np.asarray(self.a, float)[:m] - np.asarray(self.b, float)[:m], level)
        else:
            d, lo, hi = _welch_ci(a, b, level)
        if self.relative and b is not None:
            scale = abs(float(np.mean(b))) if b.size else float("nan")
            d, lo, hi = (x / scale if scale > 0 else float("nan") for x in (d, lo, hi))
        if self.sign < 0:
            d, lo, hi = -d, -hi, -lo
        return Estimate(d - self.margin, lo - self.margin, hi - self.margin, self.n())

    def null_draw(self, rng: np.random.Generator, n_seeds: int = NULL_SEEDS) -> Contrast:
        """Synthetic per-seed data of this contrast's shape at its null boundary (true effect = ``margin``).

        The spread is the observed one (1 if unknown); the draw has ``max(n, n_seeds)`` seeds per side.
        """
        n = max(self.n(), n_seeds)
        a, b = _clean(self.a), _clean(self.b)
        if self.proportion:
            p = min(max(self.ref + self.sign * self.margin, 0.0), 1.0)
            return replace(self, a=tuple(float(v) for v in rng.random(n) < p))

        def sd(x: np.ndarray | None) -> float:
            s = float(np.std(x, ddof=1)) if x is not None and x.size >= 2 else 0.0
            return s if s > 0 else 1.0

        mb = float(np.mean(b)) if b is not None and b.size else 0.0
        shift = self.sign * self.margin * (abs(mb) if self.relative and mb != 0 else 1.0)
        if b is None:
            return replace(self, a=tuple(self.ref + shift + sd(a) * rng.standard_normal(n)))
        if self.paired:
            d = np.asarray(self.a, float)[: min(a.size, b.size)] - np.asarray(self.b, float)[: min(a.size, b.size)]
            bb = mb + sd(b) * rng.standard_normal(n)
            return replace(self, a=tuple(bb + shift + sd(d) * rng.standard_normal(n)), b=tuple(bb))
        bb = mb + sd(b) * rng.standard_normal(n)
        aa = mb + shift + sd(a) * rng.standard_normal(n)
        return replace(self, a=tuple(aa), b=tuple(bb))


@dataclass(frozen=True)
class Unit:
    """One row / cell / panel of a claim: its contrasts, combined ``all`` (every one yes) or ``any``."""

    label: str
    parts: tuple[Contrast, ...]
    combine: str = "all"
    #: ``any`` of ``all`` groups: when set, the unit is yes if any group has all its contrasts yes
    groups: tuple[tuple[Contrast, ...], ...] = ()

    def outcome(self, level: float = LEVEL) -> str:
        """yes / no / undecided of the combined contrasts (point signs when a contrast has no CI)."""
        if self.groups:
            inner = [_combine([c.estimate(level).outcome for c in g], "all") for g in self.groups]
            return _combine(inner, "any")
        return _combine([c.estimate(level).outcome for c in self.parts], self.combine)

    def contrasts(self) -> list[Contrast]:
        """Every contrast of the unit."""
        return [c for g in self.groups for c in g] if self.groups else list(self.parts)

    def n(self) -> int:
        """Seeds of the least-replicated contrast."""
        return min((c.n() for c in self.contrasts()), default=0)

    def null_draw(self, rng: np.random.Generator, n_seeds: int = NULL_SEEDS) -> Unit:
        """This unit with every contrast redrawn at its null boundary."""
        if self.groups:
            return replace(self, groups=tuple(tuple(c.null_draw(rng, n_seeds) for c in g) for g in self.groups))
        return replace(self, parts=tuple(c.null_draw(rng, n_seeds) for c in self.parts))

    def summary(self, level: float = LEVEL) -> dict[str, Any]:
        """JSON-ready: label, outcome, seeds and each contrast's estimate with its CI."""
        return {
            "label": self.label,
            "outcome": self.outcome(level),
            "n_seeds": self.n(),
            "contrasts": [
                {
                    "label": c.directed_label(),
                    "estimate": _r(e.est),
                    "ci": [_r(e.lo), _r(e.hi)],
                    "n": e.n,
                    "outcome": e.outcome,
                }
                for c in self.contrasts()
                for e in [c.estimate(level)]
            ],
        }


def _r(x: float) -> float | None:
    return None if not math.isfinite(x) else float(f"{x:.4g}")


def _combine(outcomes: Sequence[str], how: str) -> str:
    if not outcomes:
        return UNDECIDED
    if how == "all":
        return YES if all(o == YES for o in outcomes) else NO if NO in outcomes else UNDECIDED
    return YES if YES in outcomes else NO if all(o == NO for o in outcomes) else UNDECIDED


@dataclass(frozen=True)
class Judgement:
    """A rule's answer: status, counts of yes / undecided / no units, the yes-fraction interval, seeds."""

    status: str
    yes: int = 0
    undecided: int = 0
    no: int = 0
    n_seeds: int = 0
    leaning: str = ""  # the point-estimate region when the status is indicative
    units: list[dict[str, Any]] = field(default_factory=list)
    level: float = LEVEL  # the per-contrast confidence of the units' CIs (Bonferroni-adjusted when the rule asks)

    @property
    def n(self) -> int:
        return self.yes + self.undecided + self.no

    def statistic(self) -> dict[str, Any]:
        """The yes-fraction with its interval ``[yes / n, (yes + undecided) / n]`` (JSON-ready)."""
        if not self.n:
            return {"value": None, "ci": [None, None], "k": 0, "n": 0}
        pt = sum(1 for u in self.units if u.get("point") == YES) / self.n if self.units else None
        lo, hi = self.yes / self.n, (self.yes + self.undecided) / self.n
        return {"value": pt, "ci": [lo, hi], "k": self.yes, "undecided": self.undecided, "n": self.n}


@dataclass(frozen=True)
class CountRule:
    """Verdict from the fraction (or count, ``absolute``) of yes units: ``>= reproduces`` reproduces,
    ``>= partly`` partly, below does not; an interval spanning two regions is inconclusive.

    ``level`` is the per-contrast confidence; ``bonferroni`` divides its error by the number of units.
    """

    reproduces: float = 0.5
    partly: float | None = 0.25
    absolute: bool = False
    bonferroni: bool = False

    def region(self, x: float, n: int) -> str:
        """The status region of a yes-fraction (or count) ``x`` of ``n`` units."""
        v = x * n if self.absolute else x
        if v >= self.reproduces - 1e-12:
            return REPRODUCES
        if self.partly is not None and v >= self.partly - 1e-12:
            return PARTLY
        return DOES_NOT

    def level(self, n_units: int) -> float:
        """Per-contrast confidence level (Bonferroni-adjusted when asked)."""
        return 1 - (1 - LEVEL) / max(n_units, 1) if self.bonferroni else LEVEL

    def judge(self, units: Sequence[Unit]) -> Judgement:
        """The verdict of ``units`` under this rule (``not computed`` when there are none)."""
        if not units:
            return Judgement(NOT_COMPUTED)
        level = self.level(len(units))
        # a unit without any seed (e.g. every run of its learner diverged) is undecided, not "one seed": it
        # cannot cap the others' CIs at indicative; when no unit has a seed, every unit is undecided (the CI path)
        n_seeds = min((u.n() for u in units if u.n() > 0), default=0)
        if n_seeds == 1:
            point = [_point(u) for u in units]
            k, und, n = point.count(YES), point.count(UNDECIDED), len(units)
            rows = [{**u.summary(level), "point": p} for u, p in zip(units, point, strict=True)]
            lo, hi = self.region(k / n, n), self.region((k + und) / n, n)
            lean = lo if lo == hi else INCONCLUSIVE  # a unit without any point estimate leaves the lean open
            return Judgement(INDICATIVE, k, und, n - k - und, n_seeds, lean, rows, level)
        outcomes = [u.outcome(level) for u in units]
        yes, und = outcomes.count(YES), outcomes.count(UNDECIDED)
        n = len(units)
        lo, hi = self.region(yes / n, n), self.region((yes + und) / n, n)
        rows = [{**u.summary(level), "point": _point(u)} for u in units]
        status = lo if lo == hi else INCONCLUSIVE
        return Judgement(status, yes, und, n - yes - und, n_seeds, units=rows, level=level)


def _point(u: Unit) -> str:
    """The unit's outcome from point estimates only (no CI)."""
    pts = [replace(c, a=(_mean(c.a),), b=None if c.b is None else (_mean(c.b),)) for c in u.contrasts()]
    if u.groups:
        it = iter(pts)
        groups = tuple(tuple(next(it) for _ in g) for g in u.groups)
        return replace(u, groups=groups).outcome()
    return replace(u, parts=tuple(pts)).outcome()


def combine_groups(statuses: Sequence[str]) -> str:
    """One claim status from the statuses of its parts (groups of units, or claims a claim derives from).

    Any inconclusive part makes it inconclusive; then any indicative part indicative; all reproduce:
    reproduces; all do not: does not; otherwise partly.

    >>> combine_groups([REPRODUCES, REPRODUCES]), combine_groups([REPRODUCES, DOES_NOT])
    ('reproduces', 'partly reproduces')
    >>> combine_groups([REPRODUCES, INCONCLUSIVE])
    'inconclusive'
    """
    if not statuses or NOT_COMPUTED in statuses:
        return NOT_COMPUTED
    other = [s for s in statuses if s not in (REPRODUCES, PARTLY, DOES_NOT, INCONCLUSIVE, INDICATIVE)]
    if other:  # not judged (smoke) / not run: the claim is not judged either
        return other[0]
    if INCONCLUSIVE in statuses:
        return INCONCLUSIVE
    if INDICATIVE in statuses:
        return INDICATIVE
    if all(s == REPRODUCES for s in statuses):
        return REPRODUCES
    if all(s == DOES_NOT for s in statuses):
        return DOES_NOT
    return PARTLY


def null_pass_rate(
    groups: dict[str, Sequence[Unit]], rules: dict[str, CountRule], draws: int = 200, seed: int = 0
) -> float:
    """Fraction of null draws (every contrast at its null boundary, >= 3 seeds) judged *reproduces*.

    >>> units = {"": [Unit("u", (Contrast("a-b", a=(1.0, 1.2, 0.9), b=(0.0, 0.1, 0.2)),))]}
    >>> null_pass_rate(units, {"": CountRule(1.0, None)}) <= 0.06
    True
    """
    rng = np.random.default_rng(seed)
    passes = 0
    for _ in range(draws):
        statuses = [rules[g].judge([u.null_draw(rng) for u in us]).status for g, us in groups.items() if us]
        passes += bool(statuses) and combine_groups(statuses) == REPRODUCES
    return passes / draws
