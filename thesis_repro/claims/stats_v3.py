"""Design v3's statistics: seed-keyed one-sided tests, margins tested linearly, compound units tested as such.

Pure functions over design v2's :class:`~thesis_repro.claims.stats.Contrast` and
:class:`~thesis_repro.claims.stats.Unit` (v2's own code stays as frozen). What v3 changes, and why
(``book/deviations.md`` lists each change with the verdicts it moves):

- **Seed-keyed.** Every per-seed value carries its training seed (:mod:`thesis_repro.claims.seeds`); two sides are
  joined by seed, and a pooled test averages each seed over the units that hold it. A missing value is a missing
  seed, never a shift.
- **Margins tested linearly.** A margin that is a fraction of a learner's mean (``m x |mean(b)|``) is tested as the
  linear contrast ``sign * (a - b) - t * s * b`` (Fieller's device: ``s`` the sign of ``b``'s mean), whose null is
  exact, instead of dividing by the noisy mean of ``b`` (a biased ratio).
- **Two one-sided p-values per contrast**: ``p_yes`` for H0 "effect <= its v1 bound", ``p_no`` for H0 "effect >=
  the margin"; a unit's combine is an intersection-union test (``all``: the largest ``p_yes``, Bonferroni over
  the parts for ``p_no``) or its mirror (``any``).
- **Pooled compound units** are pooled part by part (a *slot*: the same contrast across units) and combined as
  above, instead of taking each seed's minimum over noisy contrasts (biased low).
- **Multiplicity** in count claims: Holm across a group's units, both for *yes* and for *no*; an *each* claim's
  *yes* needs every unit (intersection-union, no adjustment), its *no* is Holm-adjusted.

>>> from thesis_repro.claims.seeds import Seeded
>>> from thesis_repro.claims.stats import Contrast
>>> c = Contrast("a - b", Seeded((3.0, 3.2, 3.1), (0, 1, 2)), Seeded((1.0, 1.1, 0.9), (0, 1, 2)), paired=True)
>>> t = contrast_test(c, 0.1)
>>> t.p_yes < ALPHA, t.p_no < ALPHA, round(t.est, 2)
(True, False, 2.1)
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy import special
from scipy import stats as st

from thesis_repro.claims import seeds as K
from thesis_repro.claims.stats import LEVEL, NO, UNDECIDED, YES, Contrast, Unit, holm

#: One-sided error of every decision (a 95 % two-sided interval's).
ALPHA = (1 - LEVEL) / 2
_Z_CLIP = 0.999999


@dataclass(frozen=True)
class Test:
    """A contrast's (or slot's) v3 test: the directed effect beyond its v1 bound with its 95 % CI (margin units;
    r for correlations), the seeds, and the one-sided p-values of *yes* and *no*."""

    est: float
    lo: float
    hi: float
    n: int
    p_yes: float
    p_no: float

    def outcome(self, alpha: float = ALPHA) -> str:
        """``no`` (effects of the margin's size excluded), ``yes`` (effect above its bound), else ``undecided``;
        the point sign with fewer than two seeds."""
        if not math.isfinite(self.est):
            return UNDECIDED
        if self.n < 2:
            return YES if self.est > 0 else NO
        if self.p_no < alpha:
            return NO
        return YES if self.p_yes < alpha else UNDECIDED


def _atanh(x: float) -> float:
    return math.atanh(min(max(x, -_Z_CLIP), _Z_CLIP))


def _scale_side(c: Contrast) -> Sequence[float] | None:
    """The side whose mean a margin is a fraction of, or None when the contrast's scale is absolute (1)."""
    if c.kind in ("r", "share") or c.proportion:
        return None
    if c.b is None:
        return None if c.ref != 0 else c.a
    return c.a if c.scale_by == "a" else c.b


def scale(c: Contrast) -> tuple[float, float]:
    """``(S, s)``: what one margin unit is worth in ``c``'s raw values (``|mean|`` of its scale side, ``|ref|``
    for a one-sample contrast against a reference, 1 for correlations and shares) and that mean's sign."""
    side = _scale_side(c)
    if side is None:
        return (abs(c.ref) if c.b is None and c.ref != 0 and c.kind not in ("r", "share") else 1.0), 1.0
    vals = [v for v in K.series(side).values()]
    m = float(np.mean(vals)) if vals else float("nan")
    if not math.isfinite(m) or m == 0:
        return 1.0, 1.0
    return abs(m), (1.0 if m > 0 else -1.0)


def _p_pair(x: np.ndarray) -> tuple[float, float, float, float, float]:
    """Mean, its t-interval and the one-sided p-values of "mean <= 0" and "mean >= 0" of ``x``."""
    n = x.size
    m = float(x.mean()) if n else float("nan")
    if n < 2:
        return m, float("nan"), float("nan"), float("nan"), float("nan")
    se = float(x.std(ddof=1)) / math.sqrt(n)
    if se == 0:
        return m, m, m, float(m <= 0), float(m >= 0)
    h = float(special.stdtrit(n - 1, 1 - ALPHA)) * se
    t = m / se
    return m, m - h, m + h, float(special.stdtr(n - 1, -t)), float(special.stdtr(n - 1, t))


def _p_welch(x: np.ndarray, y: np.ndarray) -> tuple[float, float, float, float, float]:
    """:func:`_p_pair` of the difference of means of ``x`` and ``y`` (Welch-Satterthwaite)."""
    d = float(x.mean() - y.mean()) if x.size and y.size else float("nan")
    if x.size < 2 or y.size < 2:
        return d, float("nan"), float("nan"), float("nan"), float("nan")
    vx, vy = float(x.var(ddof=1)) / x.size, float(y.var(ddof=1)) / y.size
    if vx + vy == 0:
        return d, d, d, float(d <= 0), float(d >= 0)
    df = (vx + vy) ** 2 / (vx**2 / (x.size - 1) + vy**2 / (y.size - 1))
    se = math.sqrt(vx + vy)
    h = float(special.stdtrit(df, 1 - ALPHA)) * se
    t = d / se
    return d, d - h, d + h, float(special.stdtr(df, -t)), float(special.stdtr(df, t))


def seed_values(c: Contrast, t: float, leave_one_out: bool = False) -> dict[int, float]:
    """Per training seed, ``c``'s linear effect at threshold ``t`` (margin units), in margin units: ``(sign * (a - b)
    - t * s * R) / S`` with ``R`` the scale side's value at that seed (``sign * (z - atanh(ref)) - atanh(t)`` for a
    correlation; ``sign * (x - ref) - t`` for a 0/1 outcome). ``a`` and ``b`` are joined by seed: > 0 supports
    the claim beyond ``t``.

    ``leave_one_out`` (pooling across units): each seed's ``S`` is the scale side's mean over the *other* seeds, so
    a seed's value and the scale it is divided by are independent and a null effect pools to a null mean (with the
    plug-in ``S`` a seed with a low reference value is divided by a low mean too: the ratio is biased)."""
    sc, sg = scale(c)
    side = _scale_side(c)
    if c.kind == "r" and c.b is None:
        return {k: c.sign * (_atanh(v) - _atanh(c.ref)) - _atanh(t) for k, v in K.series(c.a).items()}
    if c.proportion:
        return {k: c.sign * (float(v > 0.5) - c.ref) - t for k, v in K.series(c.a).items()}
    if c.b is None:
        a = K.series(c.a)
        if side is None:
            return {k: (c.sign * (v - c.ref) - t * sc) / sc for k, v in a.items()}
        div = _loo_scales(a, sc) if leave_one_out else {}
        return {k: (c.sign * (v - c.ref) - t * sg * v) / div.get(k, sc) for k, v in a.items()}
    keys, a, b = K.joined(c.a, c.b)
    r = b if side is c.b else a if side is c.a else None
    div = _loo_scales(K.series(side), sc) if side is not None and leave_one_out else {}
    out = {}
    for i, k in enumerate(keys):
        lin = c.sign * (a[i] - b[i]) - t * (sg * r[i] if r is not None else 1.0)
        out[k] = lin / div.get(k, sc)
    return out


def _loo_scales(full: Mapping[int, float], fallback: float) -> dict[int, float]:
    """Per seed, ``|mean|`` of ``full``'s values at the other seeds (``fallback`` where none is left or it is 0).

    >>> _loo_scales({0: 1.0, 1: 3.0, 2: 5.0}, 1.0)
    {0: 4.0, 1: 3.0, 2: 2.0}
    """
    n, total = len(full), sum(full.values())
    out = {}
    for k, v in full.items():
        m = abs((total - v) / (n - 1)) if n > 1 else 0.0
        out[k] = m if m > 0 else fallback
    return out


def _sides(c: Contrast, t: float) -> tuple[np.ndarray, np.ndarray]:
    """Welch's two sides of ``c``'s linear contrast at ``t`` (margin units, divided by the scale)."""
    sc, sg = scale(c)
    side = _scale_side(c)
    a = np.array(list(K.series(c.a).values()), float)
    b = np.array(list(K.series(c.b).values()), float)
    if side is None:
        return (c.sign * a - t) / sc, c.sign * b / sc
    if side is c.a:
        return (c.sign * a - t * sg * a) / sc, c.sign * b / sc
    return c.sign * a / sc, (c.sign * b + t * sg * b) / sc


def _binom(c: Contrast, t: float, alternative: str) -> float:
    x = np.array(list(K.series(c.a).values()), float)
    k, n = int(np.sum(x > 0.5)), int(x.size)
    p0 = min(max(c.ref + c.sign * t, 1e-12), 1 - 1e-12)
    if (alternative == "greater") == (c.sign > 0):
        return float(st.binomtest(k, n, p0, alternative="greater").pvalue)
    return float(st.binomtest(k, n, p0, alternative="less").pvalue)


def contrast_test(c: Contrast, margin: float) -> Test:
    """``c``'s v3 :class:`Test` with smallest effect of interest ``margin`` (margin units; 0 where the v1 rule
    states its own bound, ``c.margin`` != 0, as in v2): *yes* tests "effect <= c.margin", *no* tests "effect >=
    c.margin + margin"; paired and one-sample contrasts on the seeds both sides hold, others by Welch."""
    k = c.margin
    m = 0.0 if k != 0 else margin
    if c.proportion:
        x = np.array(list(K.series(c.a).values()), float)
        n = int(x.size)
        if n == 0:
            return Test(*(float("nan"),) * 3, 0, float("nan"), float("nan"))
        succ = int(np.sum(x > 0.5))
        est = c.sign * (succ / n - c.ref) - k
        if n < 2:
            return Test(est, float("nan"), float("nan"), n, float("nan"), float("nan"))
        ci = st.binomtest(succ, n).proportion_ci(LEVEL)
        lo, hi = sorted((c.sign * (ci.low - c.ref) - k, c.sign * (ci.high - c.ref) - k))
        return Test(est, lo, hi, n, _binom(c, k, "greater"), _binom(c, k + m, "less"))
    r = c.kind == "r" and c.b is None
    if c.b is None or c.paired or r:
        e0 = seed_values(c, k if not r else 0.0)
        x0 = np.array(list(e0.values()), float)
        est, lo, hi, p_yes, _ = _p_pair(x0)
        if r:  # shown in r beyond the bound, as v2; tested in z
            est, lo, hi = (math.tanh(v) - k if math.isfinite(v) else v for v in (est, lo, hi))
            p_yes = _p_pair(np.array(list(seed_values(c, k).values()), float))[3]
        p_no = _p_pair(np.array(list(seed_values(c, k + m).values()), float))[4]
        return Test(est, lo, hi, int(x0.size), p_yes, p_no)
    est, lo, hi, p_yes, _ = _p_welch(*_sides(c, k))
    p_no = _p_welch(*_sides(c, k + m))[4]
    n = min(len(K.series(c.a)), len(K.series(c.b)))
    return Test(est, lo, hi, n, p_yes, p_no)


def structure(u: Unit) -> tuple[tuple[Contrast, ...], ...]:
    """A unit as ``any`` of ``all`` groups of contrasts (``all``: one group; ``any``: one contrast each)."""
    if u.groups:
        return tuple(u.groups)
    if u.combine == "all":
        return (tuple(u.parts),)
    return tuple((c,) for c in u.parts)


def combine_p(groups: Sequence[Sequence[tuple[float, float]]]) -> tuple[float, float]:
    """``(p_yes, p_no)`` of ``any`` of ``all`` groups of ``(p_yes, p_no)``: within a group, the largest ``p_yes``
    (intersection-union) and the Bonferroni-adjusted smallest ``p_no``; across groups, the Bonferroni-adjusted
    smallest ``p_yes`` and the largest ``p_no``.

    >>> combine_p([[(0.01, 0.5), (0.02, 0.2)]])
    (0.02, 0.4)
    >>> combine_p([[(0.01, 0.5)], [(0.3, 0.2)]])
    (0.02, 0.5)
    """
    gy, gn = [], []
    for g in groups:
        ys = [p for p, _ in g]
        ns = [q for _, q in g]
        gy.append(max(ys) if ys else float("nan"))
        gn.append(min(1.0, len(ns) * min(ns)) if ns else float("nan"))
    py = min(1.0, len(gy) * min(gy)) if gy else float("nan")
    pn = max(gn) if gn else float("nan")
    return py, pn


def _nan_safe(p: float) -> float:
    return p if math.isfinite(p) else 1.0


@dataclass(frozen=True)
class UnitTest:
    """A unit's v3 result: its contrasts' tests and its combined p-values."""

    label: str
    tests: tuple[Test, ...]
    labels: tuple[str, ...]
    p_yes: float
    p_no: float
    n: int


def unit_test(u: Unit, margin: float) -> UnitTest:
    """Every contrast of ``u`` tested (:func:`contrast_test`), combined by :func:`combine_p`."""
    groups = structure(u)
    tests = [[contrast_test(c, margin) for c in g] for g in groups]
    py, pn = combine_p([[(_nan_safe(t.p_yes), _nan_safe(t.p_no)) for t in g] for g in tests])
    flat = tuple(t for g in tests for t in g)
    labels = tuple(c.directed_label() for g in groups for c in g)
    n = min((t.n for t in flat), default=0)
    return UnitTest(u.label, flat, labels, py, pn, n)


def unit_outcomes(tests: Sequence[UnitTest], level: str) -> list[str]:
    """Each unit's outcome in a group: *yes* Holm-adjusted across the units for ``count`` (plain for ``each``: the
    claim needs every unit), *no* Holm-adjusted for both; a unit with fewer than two seeds by its point signs."""
    ys = [t.p_yes for t in tests]
    ns = [t.p_no for t in tests]
    yes = holm(ys) if level == "count" else [p < ALPHA for p in ys]
    no = holm(ns)
    out = []
    for t, y, n in zip(tests, yes, no, strict=True):
        if t.n < 2:
            pts = [x.outcome() for x in t.tests]
            out.append(YES if pts and all(p == YES for p in pts) else NO if NO in pts else UNDECIDED)
        else:
            out.append(NO if n else YES if y else UNDECIDED)
    return out


@dataclass(frozen=True)
class PooledTest:
    """A v3 pooled test over a group's units, slot by slot: the shown effect (the weakest slot's), the combined
    p-values, and each slot's test."""

    est: float
    lo: float
    hi: float
    n: int
    p_yes: float
    p_no: float
    kind: str
    slots: tuple[tuple[str, Test], ...]
    units: int

    def outcome(self, alpha: float = ALPHA) -> str:
        """As :meth:`Test.outcome` on the combined p-values."""
        return Test(self.est, self.lo, self.hi, self.n, self.p_yes, self.p_no).outcome(alpha)


def _slot_test(units: Sequence[Contrast], margin: float) -> Test:
    """One slot pooled over units: per seed, the mean over the units holding that seed of each unit's linear
    effect (:func:`seed_values`, each unit scaled leaving the seed out), then a t-test across seeds."""

    def per_seed(shift: float) -> np.ndarray:
        acc: dict[int, list[float]] = {}
        for c in units:
            k = c.margin
            t = (k + (0.0 if k != 0 else margin)) if shift else k
            for s, v in seed_values(c, t, leave_one_out=True).items():
                if math.isfinite(v):
                    acc.setdefault(s, []).append(v)
        return np.array([float(np.mean(acc[s])) for s in sorted(acc)], float)

    est, lo, hi, p_yes, _ = _p_pair(per_seed(0.0))
    p_no = _p_pair(per_seed(1.0))[4]
    n = per_seed(0.0).size
    return Test(est, lo, hi, n, p_yes, p_no)


def pooled_test(units: Sequence[Unit], margin: float) -> PooledTest:
    """The v3 pooled test of a group: each slot pooled by seed (:func:`_slot_test`), the slots combined as one unit's
    contrasts (:func:`combine_p`). Units of one contrast are all one slot (the claim's effect, replicated over
    units); in a unit of several contrasts each contrast label at its group position is a slot, across the units
    that hold it. Correlations in Fisher z (``margin`` in r, as v2)."""
    kinds = {c.kind for u in units for c in u.contrasts()}
    r = kinds == {"r"}
    slots: dict[tuple[int, str], list[Contrast]] = {}
    for u in units:
        st = structure(u)
        for gi, g in enumerate(st):
            for c in g:
                # a unit of one contrast is one replicate of the claim's one effect; a unit of several names each
                key = (0, "") if len(st) == 1 and len(g) == 1 else (gi, c.directed_label())
                slots.setdefault(key, []).append(c)
    tests = {key: _slot_test(cs, margin) for key, cs in slots.items()}
    by_group: dict[int, list[tuple[float, float]]] = {}
    for (gi, _), t in tests.items():
        by_group.setdefault(gi, []).append((_nan_safe(t.p_yes), _nan_safe(t.p_no)))
    py, pn = combine_p(list(by_group.values())) if tests else (float("nan"), float("nan"))
    weakest = max(tests.values(), key=lambda t: _nan_safe(t.p_yes), default=None)
    if weakest is None:
        nan = float("nan")
        return PooledTest(nan, nan, nan, 0, nan, nan, "r" if r else "value", (), len(units))
    named = tuple((lab, t) for (_, lab), t in tests.items())
    return PooledTest(weakest.est, weakest.lo, weakest.hi, weakest.n, py, pn, "r" if r else "value", named, len(units))


def decisive(p: PooledTest) -> float:
    """The p-value of the decision a pooled test reaches (the smaller one when it reaches none)."""
    o = p.outcome()
    return p.p_no if o == NO else p.p_yes if o == YES else min(_nan_safe(p.p_yes), _nan_safe(p.p_no))


def thesis_excluded(units: Sequence[Unit], effects: Mapping[str, float]) -> dict[str, object] | None:
    """Is the thesis's own effect excluded? Over the units with a thesis effect (single-contrast units only), our
    pooled effect (per seed, the mean over those units; margin units, r for correlations) with its 95 % CI
    against the mean of the thesis's effects (``excluded`` None without a CI: one value per unit). ``None`` when
    no unit has a thesis effect.

    >>> from thesis_repro.claims.seeds import Seeded
    >>> us = [Unit("a", (Contrast("r", Seeded((0.8, 0.7, 0.9), (0, 1, 2)), sign=-1, kind="r"),))]
    >>> thesis_excluded(us, {"a": 0.4})["excluded"]
    True
    """
    picked = [u for u in units if u.label in effects and math.isfinite(effects[u.label]) and len(u.contrasts()) == 1]
    if not picked:
        return None
    cs = [u.contrasts()[0] for u in picked]
    r = all(c.kind == "r" and c.b is None for c in cs)
    acc: dict[int, list[float]] = {}
    for c in cs:
        for s, v in seed_values(c, c.margin if not r else 0.0, leave_one_out=True).items():
            if math.isfinite(v):
                acc.setdefault(s, []).append(v)
    x = np.array([float(np.mean(acc[s])) for s in sorted(acc)], float)
    est, lo, hi, _, _ = _p_pair(x)
    th = [effects[u.label] for u in picked]
    thesis = math.tanh(float(np.mean([_atanh(v) for v in th]))) if r else float(np.mean(th))
    if r:
        est, lo, hi = (math.tanh(v) if math.isfinite(v) else v for v in (est, lo, hi))
    sign = cs[0].sign
    has_ci = math.isfinite(lo) and math.isfinite(hi)
    excluded = bool(has_ci and not lo <= thesis <= hi) if has_ci else None
    # shown in the claim's own sign (an r reads as r), like v2's pooled estimate
    f = (lambda v: -v) if sign < 0 else (lambda v: v)
    lo_s, hi_s = sorted((f(lo), f(hi)))
    side = "" if not excluded else "larger" if f(est) > f(thesis) else "smaller"
    return {
        "excluded": excluded,
        "ours_side": side,
        "thesis": f(thesis),
        "ours": f(est),
        "ci": [lo_s, hi_s],
        "n_seeds": int(x.size),
        "units": len(picked),
        "kind": "r" if r else "value",
    }
