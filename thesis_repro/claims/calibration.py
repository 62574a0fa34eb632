"""Calibration both ways and power of a v2 rule, by simulation at the observed seed spread.

A *draw* replaces every contrast of a claim's units with synthetic per-seed values of the same shape and spread,
at a chosen true effect (in margin units, :func:`thesis_repro.claims.stats.contrast_scale`):

- at 0 (the null): how often the rule says *reproduces* (false R);
- at the margin (the smallest effect of interest, true): how often it says *does not reproduce* (false D);
- at the thesis's own effect per unit, with more seeds: the smallest number of training seeds at which the rule
  says *reproduces* in at least 80 % of draws (its power).

Each rate carries its Monte-Carlo standard error. Pooled rules are simulated without Holm's adjustment across a
page (which only makes them more conservative).

>>> from thesis_repro.claims.stats import Contrast, CountRule, Unit
>>> us = {"": [Unit(t, (Contrast("a - b", (1.0, 1.2, 0.9), (1.0, 1.1, 1.0)),)) for t in "abc"]}
>>> c = calibrate(us, "pooled", 0.05, {"": CountRule()}, draws=400)
>>> c["false_reproduces"] <= 0.05 + 2 * c["mc_se"] and c["false_does_not"] <= 0.05 + 2 * c["mc_se"]
True
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from thesis_repro.claims import stats as S
from thesis_repro.claims.judge import judge_v2
from thesis_repro.claims.judge_v3 import GATE_DRAWS, judge_v3
from thesis_repro.claims.report import DOES_NOT, REPRODUCES
from thesis_repro.claims.seeds import Seeded
from thesis_repro.claims.stats import Contrast, CountRule, Unit

#: Draws per calibration direction (Monte-Carlo SE of a 5 % rate: 0.007).
DRAWS = 1000
#: Draws per seed count of the power search.
POWER_DRAWS = 200
#: Training seeds the power search tries, in order ("> 128" past the last).
SEED_GRID = (3, 4, 5, 6, 8, 10, 12, 16, 24, 32, 48, 64, 96, 128)
POWER = 0.8
#: Spread of a side with fewer than two finite seeds, in margin units (a unit with no spread cannot be simulated).
FALLBACK_SD = 1.0


def _sd(x: Sequence[float] | None, fallback: float) -> float:
    a = np.asarray([] if x is None else x, float)
    a = a[np.isfinite(a)]
    s = float(np.std(a, ddof=1)) if a.size >= 2 else 0.0
    return s if s > 0 else fallback


def _m(x: Sequence[float] | None) -> float:
    a = np.asarray([] if x is None else x, float)
    a = a[np.isfinite(a)]
    return float(a.mean()) if a.size else 0.0


@dataclass(frozen=True)
class _Plan:
    """What a draw of one contrast needs, computed once from its observed values."""

    c: Contrast
    mb: float  # the reference side's mean (``ref`` when there is no ``b``)
    scale: float  # raw value of one margin unit
    sd_a: float
    sd_b: float
    sd_d: float  # spread of the paired differences (of Fisher z for a correlation)


def plan(c: Contrast) -> _Plan:
    """The observed spreads and scale a draw of ``c`` uses."""
    if c.kind == "r" and c.b is None:
        z = np.arctanh(np.clip(np.asarray(c.a, float), -0.999999, 0.999999))
        return _Plan(c, 0.0, 1.0, 0.0, 0.0, _sd(z, 0.3))
    mb = _m(c.b) if c.b is not None else c.ref
    scale = abs(mb) if c.relative and mb != 0 else S.contrast_scale(c)
    if c.scale_by == "a" and c.b is not None and c.kind not in ("r", "share") and not c.proportion:
        scale = abs(_m(c.a)) or scale  # v3's margin is a fraction of a's mean: draws shift b below a by it
    fb = FALLBACK_SD * scale
    sd_d = fb
    if c.b is not None and c.paired:
        m = min(len(c.a), len(c.b))
        sd_d = _sd(np.asarray(c.a, float)[:m] - np.asarray(c.b, float)[:m], fb)
    return _Plan(c, mb, scale, _sd(c.a, fb), _sd(c.b, fb), sd_d)


def draw_contrast(p: _Plan, rng: np.random.Generator, n: int, effect: float) -> Contrast:
    """The planned contrast redrawn with ``n`` seeds per side whose true directed effect is ``effect`` (margin
    units) beyond its v1 bound, each side with its observed spread (correlations in Fisher z; shares as 0/1
    outcomes when the contrast is a proportion)."""
    c = p.c
    seeds = range(n)

    def sd(x: Any) -> Seeded:
        return Seeded(x, seeds)

    if c.proportion:
        q = min(max(c.ref + c.sign * (effect + c.margin), 0.0), 1.0)
        return replace(c, a=sd((rng.random(n) < q).astype(float)))
    if c.kind == "r" and c.b is None:
        mu = math.atanh(c.ref) + c.sign * math.atanh(max(min(effect + c.margin, 0.999999), -0.999999))
        return replace(c, a=sd(np.tanh(mu + p.sd_d * rng.standard_normal(n))))
    shift = c.sign * (effect + c.margin) * p.scale
    if c.b is None:
        return replace(c, a=sd(c.ref + shift + p.sd_a * rng.standard_normal(n)))
    mb = p.mb if c.scale_by != "a" else _m(c.a) - shift  # a's mean stays the observed one when it is the scale
    bb = mb + p.sd_b * rng.standard_normal(n)
    if c.paired:
        return replace(c, a=sd(bb + shift + p.sd_d * rng.standard_normal(n)), b=sd(bb))
    return replace(c, a=sd(mb + shift + p.sd_a * rng.standard_normal(n)), b=sd(bb))


def draw_unit(u: Unit, plans: Mapping[int, _Plan], rng: np.random.Generator, n: int, effect: float) -> Unit:
    """Every contrast of ``u`` redrawn (:func:`draw_contrast`) from its plan (by ``id`` of the contrast)."""
    if u.groups:
        groups = tuple(tuple(draw_contrast(plans[id(c)], rng, n, effect) for c in g) for g in u.groups)
        return replace(u, groups=groups)
    return replace(u, parts=tuple(draw_contrast(plans[id(c)], rng, n, effect) for c in u.parts))


def judge_groups(
    groups: Mapping[str, Sequence[Unit]], level: str, margin: float, rules: Mapping[str, CountRule]
) -> str:
    """The v2 status of a claim's units without Holm (:func:`thesis_repro.claims.judge.judge_v2`)."""
    return judge_v2({g: us for g, us in groups.items() if us}, level, margin, rules, summaries=False).status


def _rate(
    groups: Mapping[str, Sequence[Unit]],
    judge: Callable[[Mapping[str, Sequence[Unit]]], str],
    effects: Callable[[str, Unit], float],
    n_seeds: int | None,
    status: str,
    draws: int,
    seed: int,
) -> float:
    rng = np.random.default_rng(seed)
    plans = {id(c): plan(c) for us in groups.values() for u in us for c in u.contrasts()}
    sizes = {id(u): n_seeds or max(u.n(), S.NULL_SEEDS) for us in groups.values() for u in us}
    eff = {id(u): effects(g, u) for g, us in groups.items() for u in us}
    hits = 0
    for _ in range(draws):
        drawn = {g: [draw_unit(u, plans, rng, sizes[id(u)], eff[id(u)]) for u in us] for g, us in groups.items()}
        hits += judge(drawn) == status
    return hits / draws


def calibrate(
    groups: Mapping[str, Sequence[Unit]],
    level: str,
    margin: float,
    rules: Mapping[str, CountRule],
    draws: int = DRAWS,
    seed: int = 0,
) -> dict[str, Any]:
    """False *reproduces* (every unit at effect 0) and false *does not* (every unit at the margin) over ``draws``
    draws each, at the observed spread and seeds (at least 3), with the Monte-Carlo SE of a 5 % rate."""

    def judge(gs: Mapping[str, Sequence[Unit]]) -> str:
        return judge_groups(gs, level, margin, rules)

    fr = _rate(groups, judge, lambda g, u: 0.0, None, REPRODUCES, draws, seed)
    fd = _rate(groups, judge, lambda g, u: margin, None, DOES_NOT, draws, seed + 1)
    return {
        "false_reproduces": fr,
        "false_does_not": fd,
        "draws": draws,
        "mc_se": round(math.sqrt(0.05 * 0.95 / draws), 4),
    }


def calibration_result(
    groups: Mapping[str, Sequence[Unit]],
    level: str,
    margin: float,
    rules: Mapping[str, CountRule],
    effects: Mapping[str, float],
) -> dict[str, Any]:
    """A claim's :func:`calibrate` and :func:`power` in one dict."""
    return {**calibrate(groups, level, margin, rules), **power(groups, level, margin, rules, effects)}


def power(
    groups: Mapping[str, Sequence[Unit]],
    level: str,
    margin: float,
    rules: Mapping[str, CountRule],
    effects: Mapping[str, float] | None = None,
    draws: int = POWER_DRAWS,
    seed: int = 0,
) -> dict[str, Any]:
    """The fewest training seeds (of :data:`SEED_GRID`, bisected) at which the rule says *reproduces* in >= 80 %
    of draws when each unit's true effect is ``effects[label]`` (the thesis's; units without one: the mean of
    those given, or the margin when none is), at the observed spread. ``None`` past the grid's end."""

    def judge(gs: Mapping[str, Sequence[Unit]]) -> str:
        return judge_groups(gs, level, margin, rules)

    return power_with(groups, judge, margin, effects, draws, seed)


def power_with(
    groups: Mapping[str, Sequence[Unit]],
    judge: Callable[[Mapping[str, Sequence[Unit]]], str],
    margin: float,
    effects: Mapping[str, float] | None = None,
    draws: int = POWER_DRAWS,
    seed: int = 0,
) -> dict[str, Any]:
    """:func:`power` of any ``judge`` (a claim's units to its status)."""
    effects = dict(effects or {})
    known = [v for v in effects.values() if math.isfinite(v)]
    fallback = float(np.mean(known)) if known else margin

    def eff(g: str, u: Unit) -> float:
        v = effects.get(u.label, fallback)
        return v if math.isfinite(v) else fallback

    basis = "thesis" if known else "margin"
    rate = {}

    def at(i: int) -> float:
        if i not in rate:
            rate[i] = _rate(groups, judge, eff, SEED_GRID[i], REPRODUCES, draws, seed + SEED_GRID[i])
        return rate[i]

    lo, hi = 0, len(SEED_GRID) - 1
    if at(hi) < POWER:
        return {"seeds_for_80": None, "power_at": round(at(hi), 3), "effect": basis, "max_seeds": SEED_GRID[hi]}
    while lo < hi:  # the power rises with the seeds: bisect the grid
        mid = (lo + hi) // 2
        lo, hi = (lo, mid) if at(mid) >= POWER else (mid + 1, hi)
    return {"seeds_for_80": SEED_GRID[lo], "power_at": round(at(lo), 3), "effect": basis}


def calibration_v3(
    groups: Mapping[str, Sequence[Unit]],
    level: str,
    margin: float,
    rules: Mapping[str, CountRule],
    conjunction: bool,
    effects: Mapping[str, float],
    draws: int = GATE_DRAWS,
) -> dict[str, Any]:
    """Design v3's calibration (false R at effect 0, false D at the margin, ``draws`` each, at the observed spread
    and seeds) and power (:func:`power_with`) of a claim judged by :func:`~thesis_repro.claims.judge_v3.judge_v3`
    without Holm's page family (which only makes it more conservative)."""

    def judge(gs: Mapping[str, Sequence[Unit]]) -> str:
        return judge_v3(gs, level, margin, rules, conjunction, summaries=False).status

    fr = _rate(groups, judge, lambda g, u: 0.0, None, REPRODUCES, draws, 0)
    fd = _rate(groups, judge, lambda g, u: margin, None, DOES_NOT, draws, 1)
    return {
        "false_reproduces": fr,
        "false_does_not": fd,
        "draws": draws,
        "mc_se": round(math.sqrt(0.05 * 0.95 / draws), 4),
        **power_with(groups, judge, margin, effects),
    }
