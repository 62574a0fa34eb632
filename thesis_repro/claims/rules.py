"""A claim's count rule: its threshold (from the thesis's own numbers where the registry says so), in words.

Design v1's count rule asks for a share of "yes" units (:class:`~thesis_repro.claims.stats.CountRule`); a
``reproduces: thesis`` threshold is :data:`THESIS_SHARE` of the thesis's own k/n, the claim's measure counted on
the thesis's Tables 3.3-3.7 (:func:`thesis_data`). The same tables give the thesis's own effects, at which a
claim's power is computed (:func:`thesis_effects`).
"""

from __future__ import annotations

import json
import warnings
from collections.abc import Mapping
from functools import cache
from typing import Any

import numpy as np
import pandas as pd

from thesis_repro.claims import measures as M
from thesis_repro.claims.registry import Spec, spec
from thesis_repro.claims.stats import CountRule, _point, unit_seed_effects
from thesis_repro.core import thesis_numbers

#: Fraction of the thesis's own k/n a "thesis"-tied threshold asks for.
THESIS_SHARE = 0.75

#: The thesis table(s) whose learners a page's thesis-tied threshold is counted on.
THESIS_TABLES: dict[str, tuple[str, ...]] = {
    "table-3.4": ("table3_4",),
    "table-3.5": ("table3_5",),
    "fig-3.5": ("table3_5",),
    "table-3.6": ("table3_6",),
    "table-3.7": ("table3_7",),
}


def thesis_data(page: str = "") -> dict[str, pd.DataFrame]:
    """The thesis's Tables 3.3-3.7 as one-pseudo-seed frames (its means), for thesis-tied thresholds; AUCs of
    the page's own table (:data:`THESIS_TABLES`; all four tables otherwise)."""
    names = THESIS_TABLES.get(page, ("table3_4", "table3_5", "table3_6", "table3_7"))
    frames = [thesis_numbers.load(n) for n in names]
    t = pd.concat(frames).drop_duplicates(subset=["env", "test", "method"])
    aucs = t.assign(seed=0, value=t["mean"])[["env", "test", "method", "seed", "value"]]
    b = thesis_numbers.load("table3_3b")
    method = [("ppo" if s == 0 else M.NOISY[n]) for n, s in zip(b["noise_type"], b["train_sigma"], strict=True)]
    ret = pd.DataFrame(
        {
            "env": "Walker2d",
            "method": method,
            "seed": 0,
            "test": b["noise_type"],
            "sigma": b["sigma_te"],
            "return": b["mean"],
        }
    )
    a = thesis_numbers.load("table3_3a")
    names = {"none": "ppo", "obs": M.NOISY["obs"], "act": M.NOISY["act"], "env": M.NOISY["env"], "mdl": "ppo-mdl"}
    train = pd.DataFrame(
        {"env": "Walker2d", "method": [names[n] for n in a["noise_type"]], "seed": 0, "value": a["mean"]}
    )
    return {"aucs": aucs, "returns": ret, "train": train}


@cache
def thesis_fractions(claim_id: str) -> dict[str, tuple[int, int]]:
    """Per group of a claim: the thesis's own (k, n), its rule's units counted on the thesis's means."""
    s = spec(claim_id)
    groups = M.MEASURES[s.rule["measure"]](thesis_data(s.page), s.rule)
    return {g: (sum(_point(u) == "yes" for u in us), len(us)) for g, us in groups.items()}


def rule_for(s: Spec, group: str = "", rule: Mapping[str, Any] | None = None) -> tuple[CountRule, str]:
    """The count rule of a claim's group (under ``rule``, default its v1 rule) and the sentence saying where its
    threshold comes from."""
    r = dict(s.rule if rule is None else rule)
    r.update((r.get("groups") or {}).get(group, {}))
    partly = r.get("partly", 0.25)
    absolute = bool(r.get("absolute", False))
    if r.get("reproduces") == "thesis":
        k, n = r["thesis_k_n"] if "thesis_k_n" in r else thesis_fractions(s.id).get(group, (0, 0))
        floor = float(r.get("floor", 0.5))
        q = max(floor, round(THESIS_SHARE * k / n, 3)) if n else floor
        basis = f"thesis {k}/{n} on its own table; threshold max({floor:g}, {THESIS_SHARE:g} x {k}/{n}) = {q:.3g}"
    else:
        q = float(r.get("reproduces", 0.5))
        basis = r.get("basis", "the sentence's wording (the thesis reports no k/n)")
    return CountRule(q, None if partly is None else float(partly), absolute, bool(r.get("bonferroni", False))), basis


def rule_text(s: Spec) -> str:
    """The pre-registered rule in one paragraph: statistic, units, thresholds and what each verdict means."""
    r = s.rule
    if r.get("visual"):
        return "not judged: the sentence is about what the figure looks like (the frames are shown on the page)"
    if "page_verdict" in r:
        return (
            "the analysis page's own rule (thesis_repro.claims.analysis_4_kl.kl_verdicts: share of synthetic problems)"
        )
    if r.get("derived"):
        return f"derived: reproduces iff every one of {', '.join(r['derived'])} reproduces (statuses combined)"
    parts = [f"statistic: {r.get('statistic', '')}", f"units: {r.get('units', '')}"]
    groups = list((r.get("groups") or {}).keys()) or [""]
    for g in groups:
        rule, basis = rule_for(s, g)
        scale = "units (count)" if rule.absolute else "of the units"
        part = f" {rule.partly:g}" if rule.partly is not None else " (no partly region)"
        parts.append(
            f"{g + ': ' if g else ''}reproduces if the yes-share interval is >= {rule.reproduces:g} {scale}, "
            f"partly if >= {part.strip()}, does not below; inconclusive if the interval spans two regions "
            f"({basis})"
        )
    parts.append(
        "a unit is 'yes' when its 95 % CI across training seeds is on the claim's side"
        + (" (Bonferroni over units)" if r.get("bonferroni") else "")
    )
    parts.append("one seed: at most indicative")
    return "; ".join(parts)


def thesis_effects(s: Spec, rule2: Mapping[str, Any]) -> dict[str, float]:
    """Per unit label, the thesis's own effect in margin units (for power): Fig 3.3c's r per cell for the
    correlation measures, else the claim's measure on the thesis's tables (:func:`thesis_data`); ``{}`` when
    the thesis reports no number the measure can read. Computed once per (page, rule) in a process: the thesis's
    tables do not change while it runs."""
    return dict(_thesis_effects(s.page, json.dumps(rule2, sort_keys=True, default=str)))


@cache
def _thesis_effects(page: str, rule_json: str) -> tuple[tuple[str, float], ...]:
    return tuple(_compute_thesis_effects(page, json.loads(rule_json)).items())


def _compute_thesis_effects(page: str, rule2: Mapping[str, Any]) -> dict[str, float]:
    m = rule2.get("measure")
    if m in ("correlation", "mean_selection"):
        t = thesis_numbers.load("fig3_3c")
        return {f"{e}/{x}": -float(v) for e, x, v in zip(t["env"], t["test"], t["value"], strict=True)}
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            groups = M.MEASURES[m](thesis_data(page), rule2)
    except Exception:  # noqa: BLE001 - the thesis's tables cannot feed every measure: no thesis effect
        return {}
    out = {}
    for us in groups.values():
        for u in us:
            e = unit_seed_effects(u)
            e = e[np.isfinite(e)]
            if e.size:
                out[u.label] = float(e.mean())
    return out
