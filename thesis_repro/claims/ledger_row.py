"""One ledger row: a claim's verdict with its statistics, its JSON form and its one-line headline.

:class:`Row` is what :func:`thesis_repro.claims.ledger.judge` returns; :func:`ours_text` and :func:`headline` are
the words its JSON form (:meth:`Row.as_dict`) carries, so they sit here, below the judging.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from thesis_repro.claims import design
from thesis_repro.claims.confirmatory import Confirmation
from thesis_repro.claims.registry import Spec
from thesis_repro.claims.rules import rule_text

UNIT_OF_REPLICATION = "training seeds (values averaged over rollouts / episodes inside each seed first)"


@dataclass
class Row:
    """One ledger row (JSON-ready through :meth:`as_dict`)."""

    spec: Spec
    status: str
    n_seeds: int = 0
    statistic: dict[str, Any] = field(default_factory=dict)
    groups: dict[str, Any] = field(default_factory=dict)
    null_pass_rate: float | None = None
    note: str = ""
    diagnosis: str = ""
    sensitivity: list[dict[str, Any]] = field(default_factory=list)
    stale: list[str] = field(default_factory=list)  # pages whose saved numbers other kit code wrote
    shipped: list[str] = field(default_factory=list)  # pages whose numbers came from the shipped snapshot
    local_runs: dict[str, dict[str, Any]] = field(default_factory=dict)  # page -> its runs from the local cache
    pooled_seeds: int = 0  # > 0: each unit's one value is a statistic of this many seeds' means (no replication)
    v1_status: str = ""  # the verdict of design v1 (the registry's `rule:` as first registered)
    v1_statistic: dict[str, Any] = field(default_factory=dict)
    level: str = ""  # v2: pooled / each / count
    margin: float | None = None  # v2: the smallest effect of interest (margin units)
    primary: dict[str, Any] = field(default_factory=dict)  # v2's primary statistic (pooled effect or yes-share)
    calibration: dict[str, Any] = field(default_factory=dict)  # v2: false R / false D over null draws, power
    confirmation: Confirmation | None = None  # the same frozen rule on the fresh seeds alone (None: not shipped yet)
    subset: dict[str, Any] = field(default_factory=dict)  # the registered subset sensitivity check (subset_check)
    v2_status: str = ""  # design v2's verdict (the registered analysis of seeds 0-5), shown beside v3's
    v2_primary: dict[str, Any] = field(default_factory=dict)
    v2_groups: dict[str, Any] = field(default_factory=dict)
    v2_calibration: dict[str, Any] = field(default_factory=dict)
    #: design v3: ``status`` (the statistical label before the calibration gate), ``reason`` (why the gate
    #: changed it), ``conjunction``, ``thesis_effect`` (is the thesis's own effect excluded?)
    v3: dict[str, Any] = field(default_factory=dict)
    #: chapter 4's claims: the verdict per reading of the thesis's update (:mod:`thesis_repro.claims.readings`)
    readings: list[dict[str, Any]] = field(default_factory=list)
    #: the same frozen rule on the thesis-budget study's runs (:mod:`thesis_repro.claims.thesis_budget`); ``{}`` for a
    #: claim whose runs the study does not retrain
    thesis_budget: dict[str, Any] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        s = self.spec
        return {
            "id": s.id,
            "page": s.page,
            "repeated_on": list(s.pages),
            "beyond_the_thesis": s.beyond,
            "thesis_lines": list(s.lines),
            "claim": s.text,
            "rule": rule_text(s),
            "unit": UNIT_OF_REPLICATION,
            "n_seeds": self.n_seeds,
            "pooled_seeds": self.pooled_seeds,
            "statistic": self.statistic,
            "verdict": self.status,
            "label": self.status,
            "design": design.stamp(),
            "v2_verdict": self.v2_status or self.status,
            "v2_primary": self.v2_primary,
            "v2_ours": ours_text(Row(self.spec, self.v2_status, primary=self.v2_primary)) if self.v2_primary else "",
            "v2_calibration": self.v2_calibration,
            "v3_statistical": self.v3.get("status", self.status),
            "gate_reason": self.v3.get("reason", ""),
            "conjunction": bool(self.v3.get("conjunction", False)),
            "thesis_effect": self.v3.get("thesis_effect"),
            "thesis_effect_text": thesis_effect_text(self),
            "v3_ablation": self.v3.get("ablation", {}),
            "readings": self.readings,
            "v1_verdict": self.v1_status or self.status,
            "v1_statistic": self.v1_statistic,
            "level": self.level,
            "margin": self.margin,
            "margin_basis": s.v2.get("margin_basis", ""),
            "primary": self.primary,
            "calibration": self.calibration,
            "confirmatory": None if self.confirmation is None else self.confirmation.as_dict(),
            "short": s.v2.get("short", ""),
            "claim12": s.v2.get("claim12", ""),
            "thesis_value": s.v2.get("thesis_value", ""),
            "ours": ours_text(self),
            "headline": headline(self, width=1000),  # whole here; the terminal and pages cut at report.LINE
            "null_pass_rate": self.null_pass_rate,
            "note": self.note,
            "diagnosis": self.diagnosis,
            "sensitivity_studies": list(s.sensitivity),
            "protocol_sensitivity": self.sensitivity,
            "sensitivity": self.subset or None,
            "thesis_budget": self.thesis_budget or None,
            "groups": self.groups,
            "stale_pages": self.stale,
            "shipped_pages": self.shipped,
            "local_runs": self.local_runs,
        }


def _num(x: float | None) -> str:
    return "n/a" if x is None or not math.isfinite(x) else f"{x:+.2f}" if abs(x) < 100 else f"{x:+,.0f}"


def ours_text(row: Row) -> str:
    """The key number of a v2 verdict with its CI, in the claim's own sign: a pooled effect (r for correlations,
    else a fraction of the reference's value) and the units' count; or the count of yes units with the
    yes-share interval. ``''`` when the row has no v2 statistic.

    >>> pooled = {"estimate": -1.0986, "ci": [-1.472, -0.8673], "kind": "r", "sign": -1, "n_seeds": 3}  # in z
    >>> row = Row(Spec("x", "fig-3.3", "c", (555,), {}), "does not reproduce", primary={"pooled": pooled, "k": 0,
    ...     "n": 20})
    >>> ours_text(row)
    'pooled r +0.80 [+0.70, +0.90], 0/20 units yes'
    >>> row.primary["pooled"] = dict(pooled, ci=[None, None])  # one value per unit: nothing to replicate
    >>> ours_text(row)
    'pooled r +0.80 (no CI: no replication), 0/20 units yes'
    """
    prim = row.primary
    if not prim:
        return ""
    parts = [prim] if "n" in prim else [dict(v, group=g) for g, v in prim.items()]
    out = []
    for p in parts:
        head = f"{p['group']}: " if "group" in p else ""
        if "pooled" in p:
            q = p["pooled"]
            sign = q.get("sign", 1)
            est, lo, hi = (None if x is None else sign * x for x in (q["estimate"], *q["ci"]))
            if sign < 0:
                lo, hi = hi, lo
            if q["kind"] == "r":
                est, lo, hi = (None if x is None else math.tanh(x) for x in (est, lo, hi))
            what = "r" if q["kind"] == "r" else "effect"
            ci = " (no CI: no replication)" if lo is None and hi is None else f" [{_num(lo)}, {_num(hi)}]"
            out.append(f"{head}pooled {what} {_num(est)}{ci}, {p['k']}/{p['n']} units yes")
        else:
            lo, hi = p.get("share_ci", [None, None])
            band = f" (share {lo:.2f}-{hi:.2f})" if lo is not None and hi is not None and lo != hi else ""
            out.append(f"{head}{p['k']}/{p['n']} units yes{band}")
    return "; ".join(out)


def thesis_effect_text(row: Row) -> str:
    """Whether the thesis's own effect is excluded, e.g. ``thesis's +0.21 excluded (ours -0.05 [-0.23, +0.12])``;
    ``''`` where the thesis gives no number the claim's measure reads.

    >>> row = Row(Spec("x", "p", "c", (), {}), "inconclusive", v3={"thesis_effect": {"excluded": True,
    ...     "ours_side": "smaller", "thesis": 0.21, "ours": -0.05, "ci": [-0.23, 0.12], "kind": "value"}})
    >>> thesis_effect_text(row)
    "thesis's +0.21 excluded, ours smaller (ours -0.05 [-0.23, +0.12])"
    """
    t = row.v3.get("thesis_effect") if row.v3 else None
    if not t:
        return ""
    lo, hi = t["ci"]
    what = "r " if t.get("kind") == "r" else ""
    lo = float("nan") if lo is None else lo
    hi = float("nan") if hi is None else hi
    if t["excluded"] is None:
        return f"thesis's {what}{_num(t['thesis'])}, ours {_num(t['ours'])} (no CI: no replication)"
    word = f"excluded, ours {t['ours_side']}" if t["excluded"] else "not excluded"
    return f"thesis's {what}{_num(t['thesis'])} {word} (ours {_num(t['ours'])} [{_num(lo)}, {_num(hi)}])"


def headline(row: Row, width: int = 160) -> str:
    """One line per claim: label · id · l. lines short claim · thesis: value · ours: key number with its CI.

    >>> s = Spec("3.3-x", "fig-3.3", "c", (555,), {}, v2={"short": "negative correlation", "thesis_value": "18/20"})
    >>> headline(Row(s, "does not reproduce", primary={"k": 0, "n": 20}))
    'does not reproduce · 3.3-x · l. 555 negative correlation · thesis: 18/20 · ours: 0/20 units yes'
    """
    s = row.spec
    where = f"l. {','.join(map(str, s.lines))} " if s.lines else ""
    short = s.v2.get("short") or " ".join(s.text.split()[:6])
    head = [row.status, s.id, f"{where}{short}"]
    ours = ours_text(row)
    t = row.v3.get("thesis_effect") if row.v3 else None
    # last and short (ours is already on the line): whether our CI excludes the thesis's own effect
    effect = f"thesis's {_num(t['thesis'])} {'excluded' if t['excluded'] else 'not excluded'}" if t else ""
    effect = effect if not t or t["excluded"] is not None else ""
    tail = [f"ours: {ours}"] if ours else []
    tail += [effect] if effect else []
    thesis = str(s.v2.get("thesis_value") or "")
    room = width - len(" · ".join([*head, *tail])) - len(" · thesis: ")
    if thesis and len(thesis) > room:  # too long for one line: the thesis's value gives way before ours
        thesis = thesis[: room - 1] + "…" if room > 12 else ""
    line = " · ".join([*head, *([f"thesis: {thesis}"] if thesis else []), *tail])
    return line if len(line) <= width else line[: width - 1] + "…"


def stale_pages(rows: Sequence[Row]) -> list[str]:
    """Pages whose saved numbers some of ``rows`` were judged from, written by other kit code (sorted)."""
    return sorted({p for r in rows for p in r.stale})


def shipped_pages(rows: Sequence[Row]) -> list[str]:
    """Pages whose numbers some of ``rows`` were judged from came from the shipped snapshot (sorted)."""
    return sorted({p for r in rows for p in r.shipped})
