"""Design v2's judging of one claim's units: level, margin, pooled test with Holm, bounded labels, calibration.

:func:`judge_v2` turns a claim's units (from its measure, :mod:`thesis_repro.claims.measures`, under its v2 rule)
into a :class:`V2` result; the ledger (:mod:`thesis_repro.claims.ledger`) loads the saved numbers and words the
result. :func:`units_key` names a claim's units by content, for the cache of their calibration and power
(:mod:`thesis_repro.claims.calibration`) that two clones share and the shipped snapshot carries.

>>> from thesis_repro.claims.stats import Contrast, Unit, CountRule
>>> us = {"": [Unit(t, (Contrast("r", (0.7, 0.8, 0.75), sign=-1, kind="r"),)) for t in "abcde"]}
>>> judge_v2(us, "pooled", 0.1, {"": CountRule(0.5, 0.25)}).status
'does not reproduce'
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from thesis_repro.claims import stats as S
from thesis_repro.claims.report import DOES_NOT, INCONCLUSIVE, INDICATIVE, REPRODUCES
from thesis_repro.claims.stats import CountRule, Pooled, Unit


@dataclass
class V2:
    """A claim's v2 result: its label, per group the primary statistic and the units' v2 outcomes."""

    status: str
    level: str
    margin: float
    groups: dict[str, dict[str, Any]] = field(default_factory=dict)
    n_seeds: int = 0


def count_rule(v1: CountRule, level: str, rule: Mapping[str, Any]) -> CountRule:
    """The count rule a v2 level judges with: *each* is an intersection (every unit yes: 1.0 of the units, partly
    from half); *count* keeps the rule's thresholds."""
    if level == "each":
        partly = rule.get("partly", 0.5)
        return CountRule(1.0, None if partly is None else float(partly), False, v1.bonferroni)
    return v1


def _pooled_status(p: Pooled, outcome: str) -> str:
    if p.n < 2:
        return INDICATIVE
    return REPRODUCES if outcome == S.YES else DOES_NOT if outcome == S.NO else INCONCLUSIVE


def decisive_p(p: Pooled) -> float:
    """The p-value of the decision a pooled test reaches (the smaller one when it reaches none)."""
    o = p.outcome()
    return p.p_no if o == S.NO else p.p_yes if o == S.YES else min(p.p_yes, p.p_no)


def holm_outcome(p: Pooled, family: Sequence[float], index: int) -> str:
    """``p``'s outcome after Holm's step-down over ``family`` (its own decisive p at ``index``)."""
    o = p.outcome()
    if o == S.UNDECIDED or p.n < 2:
        return o
    return o if S.holm(list(family))[index] else S.UNDECIDED


def judge_v2(
    groups: Mapping[str, Sequence[Unit]],
    level: str,
    margin: float,
    rules: Mapping[str, CountRule],
    family: Sequence[float] = (),
    summaries: bool = True,
) -> V2:
    """The v2 verdict of a claim's non-empty ``groups`` of units. ``family``: the decisive p-values of the other
    pooled tests on the claim's page data (Holm); a pooled claim's groups join it."""
    out: dict[str, dict[str, Any]] = {}
    statuses = []
    n_seeds = 0
    pooled = {g: S.pooled(us, margin) for g, us in groups.items()} if level == "pooled" else {}
    fam = [*family, *(decisive_p(p) for p in pooled.values())]
    for i, (g, us) in enumerate(groups.items()):
        rule = rules[g]
        if level == "pooled" and not summaries:  # a simulation's draw: the status only
            statuses.append(_pooled_status(pooled[g], holm_outcome(pooled[g], fam, len(family) + i)))
            continue
        if not summaries:
            statuses.append(S.judge_count_v2(rule, us, margin).status)
            continue
        units = [{**S.unit_summary_v2(u, margin, rule.level(len(us))), "point": S._point(u)} for u in us]
        yes = sum(u["outcome"] == S.YES for u in units)
        und = sum(u["outcome"] == S.UNDECIDED for u in units)
        info: dict[str, Any] = {"units": units, "k": yes, "undecided": und, "n": len(units)}
        if level == "pooled":
            p = pooled[g]
            o = holm_outcome(p, fam, len(family) + i)
            status = _pooled_status(p, o)
            info["pooled"] = {
                "estimate": _r(p.est),
                "ci": [_r(p.lo), _r(p.hi)],
                "kind": p.kind,
                "margin": _r(p.margin),
                "n_seeds": p.n,
                "units": p.units,
                "p_yes": _r(p.p_yes),
                "p_no": _r(p.p_no),
                "holm_family": len(fam),
                "sign": next((c.sign for u in us for c in u.contrasts()), 1),
                "outcome": o,
            }
            n_seeds = max(n_seeds, p.n)
        else:
            j = S.judge_count_v2(rule, us, margin)
            status = j.status
            info["share_ci"] = [j.yes / j.n, (j.yes + j.undecided) / j.n] if j.n else [None, None]
            info["thresholds"] = {"reproduces": rule.reproduces, "partly": rule.partly, "absolute": rule.absolute}
            n_seeds = max(n_seeds, j.n_seeds)
        info["verdict"] = status
        statuses.append(status)
        out[g or "all"] = info
    return V2(S.combine_bounded(statuses), level, margin, out, n_seeds)


def _r(x: float) -> float | None:
    return None if x is None or not math.isfinite(x) else float(f"{x:.4g}")


def units_key(groups: Mapping[str, Sequence[Unit]], rule_hash: str) -> str:
    """A content key of a claim's units and rule: equal in any clone that judges the same numbers."""
    payload = {
        g: [[u.label, u.combine, [[c.label, c.a, c.b, c.sign, c.paired, c.kind] for c in u.contrasts()]] for u in us]
        for g, us in sorted(groups.items())
    }
    text = json.dumps({"units": payload, "rule": rule_hash}, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:32]
