"""Design v3's judging of one claim's units, and the calibration gate its label passes through.

:func:`judge_v3` turns a claim's units into a :class:`V3` result with :mod:`thesis_repro.claims.stats_v3`'s tests:
pooled claims slot by slot with Holm across the page's distinct pooled tests; *each* and *count* claims unit by
unit (Holm-adjusted as :func:`~thesis_repro.claims.stats_v3.unit_outcomes` says) into v2's bounded labels; a
*conjunction* (a sentence whose units are different statements joined by "and" / "but", not one statement
replicated over tasks, rows or learners) is one intersection over all its units: reproduces when every unit is
yes, does not when any is no, else inconclusive (no "partly" carried by one part).

:func:`gated` is the label a reader sees: the statistical label only when the rule passes its own calibration
(false R and false D at most :data:`GATE_RATE` + 2 Monte-Carlo SE over at least :data:`GATE_DRAWS` draws at the
observed spread) and can be settled (power at least :data:`MIN_POWER` at the largest seed count simulated, at the
thesis's own effect; where the thesis gives no number, the power at the margin is shown, not gated); otherwise
*not calibrated* or *cannot be settled by this design*, with the reason.

>>> from thesis_repro.claims.seeds import Seeded
>>> from thesis_repro.claims.stats import Contrast, CountRule, Unit
>>> us = {"": [Unit(t, (Contrast("r", Seeded((0.7, 0.8, 0.75), (0, 1, 2)), sign=-1, kind="r"),)) for t in "abcde"]}
>>> judge_v3(us, "pooled", 0.1, {"": CountRule(0.5, 0.25)}).status
'does not reproduce'
>>> gated("reproduces", {"false_reproduces": 0.2, "false_does_not": 0.0, "draws": 2000})[0]
'not calibrated'
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from thesis_repro.claims import stats_v3 as T
from thesis_repro.claims.report import (
    CANNOT_SETTLE,
    DOES_NOT,
    INCONCLUSIVE,
    INDICATIVE,
    NOT_CALIBRATED,
    REPRODUCES,
)
from thesis_repro.claims.stats import NO, UNDECIDED, YES, CountRule, Unit, bounded_label, combine_bounded, holm

#: The calibration gate: a rule's false R and false D at most this plus two Monte-Carlo SE ...
GATE_RATE = 0.05
#: ... over at least this many draws each way.
GATE_DRAWS = 2000
#: A rule whose power at the thesis's effect stays below this at the largest seed count cannot settle the claim.
MIN_POWER = 0.5
#: The statistical labels the gate applies to (others, e.g. "not run", pass through).
JUDGED = (REPRODUCES, DOES_NOT, INCONCLUSIVE, "partly reproduces", "at least partly", "at most partly")


@dataclass
class V3:
    """A claim's v3 result before the gate: its label, per group the primary statistic and the units."""

    status: str
    level: str
    margin: float
    groups: dict[str, dict[str, Any]] = field(default_factory=dict)
    n_seeds: int = 0


def _r(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else float(f"{x:.4g}")


def _test_dict(label: str, t: T.Test, margin: float) -> dict[str, Any]:
    return {
        "label": label,
        "estimate": _r(t.est),
        "ci": [_r(t.lo), _r(t.hi)],
        "margin": _r(margin),
        "n": t.n,
        "p_yes": _r(t.p_yes),
        "p_no": _r(t.p_no),
        "outcome": t.outcome(),
        # on the claim's side but short of the margin: "no" excludes the margin, not every effect
        "below_margin": bool(t.outcome() == NO and math.isfinite(t.lo) and t.lo > 0),
    }


def unit_dict(u: T.UnitTest, outcome: str, margin: float) -> dict[str, Any]:
    """JSON-ready v3 unit: label, outcome, seeds, combined p-values and each contrast's test."""
    return {
        "label": u.label,
        "outcome": outcome,
        "n_seeds": u.n,
        "p_yes": _r(u.p_yes),
        "p_no": _r(u.p_no),
        "contrasts": [_test_dict(lab, t, margin) for lab, t in zip(u.labels, u.tests, strict=True)],
    }


def holm_outcome(p: T.PooledTest, family: Sequence[float], index: int) -> str:
    """``p``'s outcome after Holm's step-down over ``family`` (its own decisive p at ``index``)."""
    o = p.outcome()
    if o == UNDECIDED or p.n < 2:
        return o
    return o if holm(list(family))[index] else UNDECIDED


def _count(rule: CountRule, outcomes: Sequence[str]) -> str:
    n = len(outcomes)
    yes, und = outcomes.count(YES), outcomes.count(UNDECIDED)
    low, high = rule.region(yes / n, n), rule.region((yes + und) / n, n)
    return bounded_label(low, high) if rule.partly is not None else (low if low == high else INCONCLUSIVE)


def judge_v3(
    groups: Mapping[str, Sequence[Unit]],
    level: str,
    margin: float,
    rules: Mapping[str, CountRule],
    conjunction: bool = False,
    family: Sequence[float] = (),
    summaries: bool = True,
) -> V3:
    """The v3 verdict of a claim's non-empty ``groups``. ``family``: the decisive p-values of the other distinct
    pooled tests on the claim's page data (Holm); ``summaries`` False: the status only (a simulation's draw)."""
    groups = {g: list(us) for g, us in groups.items() if us}
    if conjunction:
        groups = {"all parts": [u for us in groups.values() for u in us]}
        rules = {"all parts": CountRule(1.0, None)}
        level = "each"
    if not groups:
        return V3(INCONCLUSIVE, level, margin)
    out: dict[str, dict[str, Any]] = {}
    statuses: list[str] = []
    n_seeds = 0
    if level == "pooled":
        pooled = {g: T.pooled_test(us, margin) for g, us in groups.items()}
        fam = [*family, *(T.decisive(p) for p in pooled.values())]
        for i, (g, p) in enumerate(pooled.items()):
            o = holm_outcome(p, fam, len(family) + i)
            status = INDICATIVE if p.n < 2 else REPRODUCES if o == YES else DOES_NOT if o == NO else INCONCLUSIVE
            statuses.append(status)
            n_seeds = max(n_seeds, p.n)
            if summaries:
                sign = next((c.sign for u in groups[g] for c in u.contrasts()), 1)
                out[g or "all"] = {
                    "verdict": status,
                    "pooled": {
                        "estimate": _r(p.est),
                        "ci": [_r(p.lo), _r(p.hi)],
                        "kind": p.kind,
                        "margin": _r(math.atanh(min(margin, 0.999999)) if p.kind == "r" else margin),
                        "n_seeds": p.n,
                        "units": p.units,
                        "p_yes": _r(p.p_yes),
                        "p_no": _r(p.p_no),
                        "holm_family": len(fam),
                        "sign": sign,
                        "outcome": o,
                        "slots": [_test_dict(lab, t, margin) for lab, t in p.slots] if len(p.slots) > 1 else [],
                    },
                    "k": 0,
                    "undecided": 0,
                    "n": len(groups[g]),
                }
        if summaries:  # each unit's own test, for the evidence (the decision is the pooled one)
            for g, us in groups.items():
                tests = [T.unit_test(u, margin) for u in us]
                outs = T.unit_outcomes(tests, "each")
                out[g or "all"]["units"] = [unit_dict(t, o, margin) for t, o in zip(tests, outs, strict=True)]
                out[g or "all"]["k"] = outs.count(YES)
                out[g or "all"]["undecided"] = outs.count(UNDECIDED)
        return V3(combine_bounded(statuses), level, margin, out, n_seeds)
    for g, us in groups.items():
        tests = [T.unit_test(u, margin) for u in us]
        n = min((t.n for t in tests if t.n > 0), default=0)
        outs = T.unit_outcomes(tests, level)
        rule = rules[g]
        status = INDICATIVE if n == 1 else _count(rule, outs)
        statuses.append(status)
        n_seeds = max(n_seeds, n)
        if summaries:
            k, und = outs.count(YES), outs.count(UNDECIDED)
            out[g or "all"] = {
                "verdict": status,
                "k": k,
                "undecided": und,
                "n": len(outs),
                "share_ci": [k / len(outs), (k + und) / len(outs)],
                "thresholds": {"reproduces": rule.reproduces, "partly": rule.partly, "absolute": rule.absolute},
                "units": [unit_dict(t, o, margin) for t, o in zip(tests, outs, strict=True)],
            }
    return V3(combine_bounded(statuses), level, margin, out, n_seeds)


def gate_limit(draws: int) -> float:
    """The largest false-R / false-D rate the gate admits over ``draws`` draws: 0.05 + 2 Monte-Carlo SE.

    >>> round(gate_limit(2000), 4)
    0.0597
    """
    return GATE_RATE + 2 * math.sqrt(GATE_RATE * (1 - GATE_RATE) / max(draws, 1))


def gated(status: str, cal: Mapping[str, Any]) -> tuple[str, str]:
    """The label a reader sees and why: ``status`` when its rule passes the calibration gate and can be settled,
    else *not calibrated* / *cannot be settled by this design* with the reason (``""`` when none)."""
    if status not in JUDGED:
        return status, ""
    if not cal:
        return NOT_CALIBRATED, "its calibration has not been simulated for these numbers"
    draws = int(cal.get("draws", 0))
    fr, fd = float(cal.get("false_reproduces", 1.0)), float(cal.get("false_does_not", 1.0))
    if draws < GATE_DRAWS:
        return NOT_CALIBRATED, f"calibrated over {draws} draws, fewer than the gate's {GATE_DRAWS}"
    limit = gate_limit(draws)
    if fr > limit or fd > limit:
        return NOT_CALIBRATED, (
            f"false reproduces {fr:.3f}, false does-not {fd:.3f} over {draws:,} draws at the observed spread: above "
            f"the gate's {limit:.3f}"
        )
    low = cal.get("seeds_for_80") is None and float(cal.get("power_at", 0.0)) < MIN_POWER
    if low and cal.get("effect") == "thesis":  # where the thesis gives no number, its power is shown, not gated
        return CANNOT_SETTLE, (
            f"at the thesis's own effect it reproduces in {float(cal.get('power_at', 0.0)):.0%} of draws even at "
            f"{cal.get('max_seeds', 128)} training seeds (needs {MIN_POWER:.0%})"
        )
    return status, ""
