"""Statistics across training seeds: contrasts with 95 % CIs (``scipy.stats``), units, count rules, null draws.

One file on purpose (over 600 lines): the frozen judging code (:data:`thesis_repro.claims.design.ENGINE`) takes
definitions from both of its halves (v1's contrasts, CIs and count rules; v2's margins and pooled tests, which
judge v1's :class:`Contrast` and :class:`Unit` with v1's private helpers ``_mean``, ``_mean_ci``, ``_combine``,
``_point``), so no seam separates frozen code from the rest: a split would only spread the frozen definitions
over two files, one importing the other's private helpers.

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
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field, fields, replace
from functools import lru_cache
from typing import Any

import numpy as np
from scipy import stats as st

from thesis_repro.claims.report import (
    AT_LEAST_PARTLY,
    AT_MOST_PARTLY,
    DOES_NOT,
    INCONCLUSIVE,
    INDICATIVE,
    NOT_COMPUTED,
    PARTLY,
    REPRODUCES,
)

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
    #: what one unit of the v2 margin means (:func:`contrast_scale`): ``value`` (a fraction of the reference
    #: side's mean), ``r`` (a correlation: in r, intervals through Fisher z), ``share`` (absolute)
    kind: str = "value"
    #: design v3: the side whose mean a margin is a fraction of (``b``, the reference learner; ``a`` where the
    #: claim's margin is stated as a fraction of ``a``'s value, e.g. 25 % of the centre's return)
    scale_by: str = "b"

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


@dataclass(frozen=True)
class _EstimatedOnce(Contrast):
    """A :class:`Contrast` whose :meth:`estimate` (per level) and :meth:`n` are computed once (pure functions of its
    fields): a judge reads each several times, and the null draws judge thousands of contrasts."""

    def estimate(self, level: float = LEVEL) -> Estimate:
        memo = self.__dict__.setdefault("_estimates", {})
        if level not in memo:
            memo[level] = super().estimate(level)
        return memo[level]

    def n(self) -> int:
        if "_n" not in self.__dict__:
            self.__dict__["_n"] = super().n()
        return self.__dict__["_n"]


def estimated_once(u: Unit) -> Unit:
    """``u`` with each contrast an :class:`_EstimatedOnce` (its null draws are too): judged exactly as ``u``.

    >>> u = Unit("u", (Contrast("a-b", a=(1.0, 1.2, 0.9), b=(0.0, 0.1, 0.2)),))
    >>> estimated_once(u).summary() == u.summary()
    True
    """

    def once(c: Contrast) -> Contrast:
        return _EstimatedOnce(**{f.name: getattr(c, f.name) for f in fields(c)})

    if u.groups:
        return replace(u, groups=tuple(tuple(once(c) for c in g) for g in u.groups))
    return replace(u, parts=tuple(once(c) for c in u.parts))


def null_pass_rate(
    groups: dict[str, Sequence[Unit]], rules: dict[str, CountRule], draws: int = 200, seed: int = 0
) -> float:
    """Fraction of null draws (every contrast at its null boundary, >= 3 seeds) judged *reproduces*.

    >>> units = {"": [Unit("u", (Contrast("a-b", a=(1.0, 1.2, 0.9), b=(0.0, 0.1, 0.2)),))]}
    >>> null_pass_rate(units, {"": CountRule(1.0, None)}) <= 0.06
    True
    """
    rng = np.random.default_rng(seed)
    groups = {g: [estimated_once(u) for u in us] for g, us in groups.items()}
    passes = 0
    for _ in range(draws):
        statuses = [rules[g].judge([u.null_draw(rng) for u in us]).status for g, us in groups.items() if us]
        passes += bool(statuses) and combine_groups(statuses) == REPRODUCES
    return passes / draws


# ---------------------------------------------------------------- design v2: margins, bounds, pooled tests
_REGION = {DOES_NOT: 0, PARTLY: 1, REPRODUCES: 2}
_BOUNDS = {(2, 2): REPRODUCES, (1, 1): PARTLY, (0, 0): DOES_NOT, (1, 2): AT_LEAST_PARTLY, (0, 1): AT_MOST_PARTLY}
KINDS = ("value", "r", "share")
_Z_CLIP = 0.999999


def bounded_label(low: str, high: str) -> str:
    """The v2 label of an interval of regions ``[low, high]``: the region itself, *at least partly* (partly or
    reproduces), *at most partly* (does not or partly), *inconclusive* only when it spans all three.

    >>> bounded_label(DOES_NOT, PARTLY), bounded_label(PARTLY, REPRODUCES), bounded_label(DOES_NOT, REPRODUCES)
    ('at most partly', 'at least partly', 'inconclusive')
    """
    return _BOUNDS.get((_REGION[low], _REGION[high]), INCONCLUSIVE)


def label_bounds(label: str) -> tuple[int, int]:
    """The region interval of a v2 label (0 does not, 1 partly, 2 reproduces).

    >>> label_bounds(AT_MOST_PARTLY), label_bounds(INCONCLUSIVE)
    ((0, 1), (0, 2))
    """
    for k, v in _BOUNDS.items():
        if v == label:
            return k
    return (0, 2)


def combine_bounded(statuses: Sequence[str]) -> str:
    """v2's :func:`combine_groups`: a claim holds when every part holds, so its lower region combines the parts'
    lower bounds and its upper region their upper bounds (all reproduce: reproduces; all do not: does not; else
    partly). A clearly failing part is no longer hidden by an undecided one.

    >>> combine_bounded([DOES_NOT, INCONCLUSIVE]), combine_bounded([REPRODUCES, AT_LEAST_PARTLY])
    ('at most partly', 'at least partly')
    >>> combine_bounded([REPRODUCES, REPRODUCES]), combine_bounded([DOES_NOT, DOES_NOT])
    ('reproduces', 'does not reproduce')
    """
    if not statuses or NOT_COMPUTED in statuses:
        return NOT_COMPUTED
    judged = (REPRODUCES, PARTLY, DOES_NOT, INCONCLUSIVE, INDICATIVE, AT_LEAST_PARTLY, AT_MOST_PARTLY)
    other = [s for s in statuses if s not in judged]
    if other:
        return other[0]
    if INDICATIVE in statuses:
        return INDICATIVE
    b = [label_bounds(s) for s in statuses]

    def comb(xs: list[int]) -> int:
        return 2 if all(x == 2 for x in xs) else 0 if all(x == 0 for x in xs) else 1

    return _BOUNDS.get((comb([x[0] for x in b]), comb([x[1] for x in b])), INCONCLUSIVE)


def contrast_scale(c: Contrast) -> float:
    """What a v2 margin of 1 means for ``c``: 1 for correlations, shares and relative contrasts; otherwise the
    reference side's mean magnitude (``|mean(b)|``, else ``|ref|``, else ``|mean(a)|``), so a margin of 0.05 is
    5 % of the compared learner's value on that task.

    >>> contrast_scale(Contrast("a - b", (10.0, 12.0), (200.0, 220.0)))
    210.0
    >>> contrast_scale(Contrast("r", (-0.5, -0.6), kind="r"))
    1.0
    """
    if c.kind in ("r", "share") or c.relative or c.proportion:
        return 1.0
    for side in (c.b, None if c.ref == 0 else (c.ref,), c.a):
        m = abs(_mean(side)) if side is not None and len(side) else float("nan")
        if math.isfinite(m) and m > 0:
            return m
    return 1.0


def _z(x: np.ndarray) -> np.ndarray:
    return np.arctanh(np.clip(x, -_Z_CLIP, _Z_CLIP))


def estimate_v2(c: Contrast, level: float = LEVEL) -> Estimate:
    """:meth:`Contrast.estimate` with correlations through Fisher z: the t-interval of ``atanh(r)`` across seeds,
    mapped back with ``tanh`` (so it stays inside [-1, 1]); every other kind as v1.

    >>> e = estimate_v2(Contrast("r", (-0.9, -0.95, -0.99), sign=-1, kind="r"))
    >>> -1 <= e.lo <= e.hi <= 1, e.outcome
    (True, 'yes')
    """
    if c.kind != "r" or c.b is not None:
        return c.estimate(level)
    a = _clean(c.a)
    z = _z(a) - math.atanh(c.ref)
    m, lo, hi = _mean_ci(z, level)
    d, lo, hi = (math.tanh(x) if math.isfinite(x) else x for x in (m, lo, hi))
    if c.sign < 0:
        d, lo, hi = -d, -hi, -lo
    return Estimate(d - c.margin, lo - c.margin, hi - c.margin, a.size)


def unit_margin(c: Contrast, margin: float) -> float:
    """The smallest effect of interest of one contrast, in its own units: ``margin`` x :func:`contrast_scale`; 0
    for a contrast whose v1 rule already states a bound (``c.margin`` != 0: non-inferiority)."""
    return 0.0 if c.margin != 0 else margin * contrast_scale(c)


def outcome_v2(e: Estimate, delta: float) -> str:
    """A contrast's v2 outcome with smallest effect of interest ``delta`` (>= 0): *yes* when the CI lies above 0
    and reaches ``delta``; *no* when it excludes effects of size ``delta`` in the claim's direction (hi <
    ``delta``; with ``delta`` 0, hi <= 0 as in v1); *undecided* otherwise. Point signs without a CI.

    >>> outcome_v2(Estimate(0.02, -0.01, 0.05, 3), 0.1), outcome_v2(Estimate(0.3, 0.1, 0.5, 3), 0.1)
    ('no', 'yes')
    >>> outcome_v2(Estimate(0.05, -0.2, 0.3, 3), 0.1), outcome_v2(Estimate(0.05, 0.01, 0.08, 3), 0.1)
    ('undecided', 'no')
    """
    if not math.isfinite(e.est):
        return UNDECIDED
    if not (math.isfinite(e.lo) and math.isfinite(e.hi)):
        return YES if e.est > 0 else NO
    if e.hi < delta or e.hi <= 0:
        return NO
    return YES if e.lo > 0 else UNDECIDED


def unit_outcome_v2(u: Unit, margin: float, level: float = LEVEL) -> str:
    """A unit's v2 outcome: its contrasts' :func:`outcome_v2` combined as in v1 (all / any / any of all)."""

    def one(c: Contrast) -> str:
        return outcome_v2(estimate_v2(c, level), unit_margin(c, margin))

    if u.groups:
        return _combine([_combine([one(c) for c in g], "all") for g in u.groups], "any")
    return _combine([one(c) for c in u.parts], u.combine)


def unit_summary_v2(u: Unit, margin: float, level: float = LEVEL) -> dict[str, Any]:
    """JSON-ready v2 unit: label, outcome, seeds, each contrast's estimate, CI and margin in its own units."""
    rows = []
    for c in u.contrasts():
        e = estimate_v2(c, level)
        rows.append(
            {
                "label": c.directed_label(),
                "estimate": _r(e.est),
                "ci": [_r(e.lo), _r(e.hi)],
                "margin": _r(unit_margin(c, margin)),
                "n": e.n,
                "outcome": outcome_v2(e, unit_margin(c, margin)),
            }
        )
    return {"label": u.label, "outcome": unit_outcome_v2(u, margin, level), "n_seeds": u.n(), "contrasts": rows}


def judge_count_v2(rule: CountRule, units: Sequence[Unit], margin: float, summaries: bool = False) -> Judgement:
    """A count (or *each*: ``reproduces`` 1) rule under v2: units' :func:`unit_outcome_v2`, the yes-share
    interval ``[yes / n, (yes + undecided) / n]`` and :func:`bounded_label` of its two regions (``summaries``:
    with each unit's JSON summary).

    >>> us = [Unit(str(i), (Contrast("a-b", a=(1.0, 1.1, 0.9), b=(1.0, 1.05, 0.95)),)) for i in range(4)]
    >>> judge_count_v2(CountRule(0.5, 0.25), us, 0.5).status
    'does not reproduce'
    """
    if not units:
        return Judgement(NOT_COMPUTED)
    level = rule.level(len(units))
    n_seeds = min((u.n() for u in units if u.n() > 0), default=0)
    if n_seeds == 1:
        j = rule.judge(units)
        return j
    outcomes = [unit_outcome_v2(u, margin, level) for u in units]
    yes, und, n = outcomes.count(YES), outcomes.count(UNDECIDED), len(units)
    low, high = rule.region(yes / n, n), rule.region((yes + und) / n, n)
    rows = [{**unit_summary_v2(u, margin, level), "point": _point(u)} for u in units] if summaries else []
    status = bounded_label(low, high) if rule.partly is not None else (low if low == high else INCONCLUSIVE)
    return Judgement(status, yes, und, n - yes - und, n_seeds, units=rows, level=level)


def seed_effects(c: Contrast) -> np.ndarray:
    """Per training seed, the contrast's directed effect in margin units (divided by :func:`contrast_scale`;
    Fisher z for correlations), v1 bound subtracted; ``a`` and ``b`` paired by seed index, NaN where missing."""
    a = np.asarray(c.a, float)
    if c.proportion:
        d = (a > 0.5).astype(float) - c.ref
    elif c.kind == "r" and c.b is None:
        d = _z(a) - math.atanh(c.ref)
    elif c.b is None:
        d = a - c.ref
    else:
        b = np.asarray(c.b, float)
        m = min(a.size, b.size)
        d = a[:m] - b[:m]
    scale = abs(_mean(c.b)) if c.relative and c.b is not None else contrast_scale(c)
    d = c.sign * d / (scale if scale > 0 else float("nan"))
    return d - (math.atanh(c.margin) if c.kind == "r" and c.b is None else c.margin)


def unit_seed_effects(u: Unit) -> np.ndarray:
    """Per seed, a unit's effect: the weakest contrast for ``all``, the strongest for ``any`` (groups: the best
    group's weakest)."""

    if not u.groups and len(u.parts) == 1:
        return seed_effects(u.parts[0])

    def stack(cs: Sequence[Contrast]) -> np.ndarray:
        es = [seed_effects(c) for c in cs]
        n = max((e.size for e in es), default=0)
        return np.array([np.pad(e, (0, n - e.size), constant_values=np.nan) for e in es])

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        if u.groups:
            inner = [np.nanmin(stack(g), axis=0) for g in u.groups]
            n = max(x.size for x in inner)
            return np.nanmax(np.array([np.pad(x, (0, n - x.size), constant_values=np.nan) for x in inner]), axis=0)
        s = stack(u.parts)
        return np.nanmin(s, axis=0) if u.combine == "all" else np.nanmax(s, axis=0)


@dataclass(frozen=True)
class Pooled:
    """A pooled effect over a claim's units (tasks as fixed effects): mean across units of each seed's effect,
    then a t-interval across seeds; ``kind`` r: in Fisher z, reported back in r. ``p_yes``/``p_no``: one-sided
    p-values of "effect <= 0" and "effect >= margin"."""

    est: float
    lo: float
    hi: float
    n: int
    margin: float
    kind: str
    p_yes: float
    p_no: float
    units: int

    def outcome(self, alpha: float = (1 - LEVEL) / 2) -> str:
        """yes / no / undecided at one-sided ``alpha`` (0.025 = the 95 % CI's; Holm passes a smaller one)."""
        if not math.isfinite(self.est):
            return UNDECIDED
        if self.n < 2:
            return YES if self.est > 0 else NO
        if self.p_no < alpha or (self.margin == 0 and self.hi <= 0):
            return NO
        return YES if self.p_yes < alpha else UNDECIDED

    def shown(self, sign: int) -> tuple[float, float, float]:
        """Estimate and CI with the claim's own sign (an r reads as r, not as the directed effect)."""
        f = math.tanh if self.kind == "r" else (lambda x: x)
        pts = [f(x) if math.isfinite(x) else x for x in (self.est, self.lo, self.hi)]
        if sign < 0:
            return -pts[0], -pts[2], -pts[1]
        return pts[0], pts[1], pts[2]


def pooled(units: Sequence[Unit], margin: float, level: float = LEVEL) -> Pooled:
    """:class:`Pooled` of ``units`` with smallest effect of interest ``margin`` (in margin units; r for
    correlations). Per seed, units missing that seed are left out of its mean.

    >>> us = [Unit(t, (Contrast("r", (0.7, 0.8, 0.75), sign=-1, kind="r"),)) for t in "abcde"]
    >>> p = pooled(us, 0.1)
    >>> p.outcome(), round(p.shown(-1)[0], 2)
    ('no', 0.75)
    """
    kinds = {c.kind for u in units for c in u.contrasts()}
    kind = "r" if kinds == {"r"} else "value"
    rows = [unit_seed_effects(u) for u in units]
    n = max((r.size for r in rows), default=0)
    grid = np.full((len(rows), n), np.nan)
    for i, r in enumerate(rows):
        grid[i, : r.size] = r
    ok = np.isfinite(grid)
    count = ok.sum(axis=0)
    per_seed = np.where(count > 0, np.where(ok, grid, 0.0).sum(axis=0) / np.maximum(count, 1), np.nan)
    x = per_seed[np.isfinite(per_seed)] if n else np.array([])
    delta = math.atanh(min(margin, _Z_CLIP)) if kind == "r" else margin
    m, lo, hi = _mean_ci(x, level)
    if x.size >= 2:
        se = float(np.std(x, ddof=1)) / math.sqrt(x.size)
        if se > 0:
            p_yes = float(st.t.sf(m / se, x.size - 1))
            p_no = float(st.t.cdf((m - delta) / se, x.size - 1))
        else:
            p_yes, p_no = float(m <= 0), float(m >= delta)
    else:
        p_yes = p_no = float("nan")
    return Pooled(m, lo, hi, int(x.size), delta, kind, p_yes, p_no, len(units))


def holm(pvalues: Sequence[float], alpha: float = (1 - LEVEL) / 2) -> list[bool]:
    """Holm's step-down over a family: which hypotheses are rejected at family-wise ``alpha``.

    >>> holm([0.001, 0.02, 0.012]), holm([0.001, 0.02, 0.013])
    ([True, True, True], [True, False, False])
    """
    order = sorted(range(len(pvalues)), key=lambda i: pvalues[i] if math.isfinite(pvalues[i]) else 2.0)
    out = [False] * len(pvalues)
    m = len(pvalues)
    for rank, i in enumerate(order):
        if not (math.isfinite(pvalues[i]) and pvalues[i] < alpha / (m - rank)):
            break
        out[i] = True
    return out
