"""A ledger row's evidence in words: its statistic, each contrast's effect with its CI across seeds, its units.

Pure functions of a :class:`~thesis_repro.claims.ledger_row.Row`: :func:`describe` is the paragraph a page folds under
a verdict (and ``claims --verbose`` prints), :func:`units_table` the table a page displays beside it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import pandas as pd

from thesis_repro.claims.ledger_row import Row
from thesis_repro.claims.stats import LEVEL

#: Contrasts whose effect and CI :func:`describe` prints (the page's units table shows them all).
CI_SHOWN = 4


def describe(row: Row) -> str:
    """One paragraph of evidence: statistic with its interval, each contrast's effect with its 95 % CI across
    seeds (the first :data:`CI_SHOWN`), seeds, null pass rate, note, diagnosis."""
    st = row.statistic
    parts = []
    if "ci" in st:
        parts.append(_stat_text(st, row.n_seeds, row.pooled_seeds))
    elif st and "parts" not in st:
        parts.append("; ".join(f"{g}: {_stat_text(v, row.n_seeds, row.pooled_seeds)}" for g, v in st.items()))
    effects = effects_text(row)
    if effects:
        parts.append(effects)
    if row.pooled_seeds:
        parts.append(f"{row.pooled_seeds} training seeds pooled (no replication)")
    elif row.n_seeds:
        most = max((c["n"] for _, _, c, _ in _contrast_rows(row)), default=row.n_seeds)
        few = f"{row.n_seeds} training seed(s)"
        parts.append(f"{row.n_seeds}-{most} training seeds per unit" if most > row.n_seeds else few)
    if row.null_pass_rate is not None:
        parts.append(f"null pass rate {row.null_pass_rate:.2f}")
    if row.note:
        parts.append(row.note)
    if row.diagnosis:
        parts.append("why: " + row.diagnosis)
    if row.shipped:
        parts.append(f"numbers of {', '.join(row.shipped)} from the shipped claims snapshot (not computed here)")
    parts.extend(local_runs_text(page, u) for page, u in sorted(row.local_runs.items()))
    return "; ".join(parts)


def local_runs_text(page: str, use: Mapping[str, Any]) -> str:
    """What a page's verdicts rest on when some of its runs came from the local run cache, not the shipped layer
    (:func:`thesis_repro.book.pages.local_runs`).

    >>> local_runs_text("fig-3.4", {"local": 2, "replacing_shipped": 1, "of": 35, "noun": "runs"})
    'fig-3.4 used 2 of its 35 runs from the local run cache, not the shipped layer (1 in place of a shipped copy)'
    """
    replacing = int(use.get("replacing_shipped", 0))
    copies = "a shipped copy" if replacing == 1 else "shipped copies"
    return (
        f"{page} used {use['local']} of its {use['of']} {use.get('noun', 'runs')} from the local run cache, not the "
        f"shipped layer ({replacing} in place of {copies})"
    )


def no_ci_words(pooled: int = 0) -> str:
    """Why a verdict has no CI: one training seed, or one value pooled from ``pooled`` seeds' means.

    >>> no_ci_words(), no_ci_words(3)
    ('one training seed: no CI', 'one value per unit from the means of 3 training seeds: no CI')
    """
    if pooled:
        return f"one value per unit from the means of {pooled} training seeds: no CI"
    return "one training seed: no CI"


def _stat_text(st: Mapping[str, Any], n_seeds: int | None = None, pooled: int = 0) -> str:
    """A yes-share statistic in words; with one training seed a unit's "yes" is its point estimate, not a CI
    (likewise when each unit's one value pools ``pooled`` seeds' means).

    >>> _stat_text({"value": 0.5, "ci": [0.5, 0.5], "k": 1, "n": 2}, n_seeds=1)
    '1/2 units yes (point estimates: one training seed), point estimate 0.50'
    >>> _stat_text({"value": 0.5, "ci": [0.5, 0.5], "k": 1, "n": 2}, n_seeds=1, pooled=3)
    '1/2 units yes (point estimates: seed means), point estimate 0.50'
    >>> _stat_text({"value": 0.5, "ci": [0.5, 0.5], "k": 1, "n": 2}, n_seeds=3)
    '1/2 units yes (CI-supported), point estimate 0.50'
    """
    if not st.get("n"):
        return "no units"
    lo, hi = st["ci"]
    pt = st.get("value")
    basis = (
        "point estimates: " + ("seed means" if pooled else "one training seed")
        if n_seeds is not None and n_seeds < 2
        else "CI-supported"
    )
    head = f"{st['k']}/{st['n']} units yes ({basis})"
    if st.get("undecided"):
        head += f", {st['undecided']} undecided: yes-share in [{lo:.2f}, {hi:.2f}]"
    if pt is not None:
        head += f", point estimate {pt:.2f}"
    return head


def _effect_ci(c: Mapping[str, Any]) -> str:
    """A contrast's effect with its CI, ``+12.3 [4.1, 20.5]`` (no CI with one seed)."""
    if c["estimate"] is None:
        return "n/a (no seed with a value)" if not c.get("n") else "n/a"
    lo, hi = c["ci"]
    if lo is None or hi is None:
        return f"{c['estimate']:+.3g} (no CI)"
    return f"{c['estimate']:+.3g} [{lo:.3g}, {hi:.3g}]"


def ci_words(levels: Sequence[float]) -> str:
    """How the CIs of a row's units were made: ``95 % CI``, or the Bonferroni-adjusted level a rule uses.

    >>> ci_words([0.95]), ci_words([0.95 + 0.05 * 5 / 6])
    ('95 % CI', '99.2 % CI (Bonferroni-adjusted over the units)')
    >>> ci_words([0.95, 0.99])
    '95 % CI (99 % where the rule adjusts for its number of units)'
    """
    adjusted = sorted({round(x, 4) for x in levels if x > LEVEL + 1e-9})
    if not adjusted:
        return f"{LEVEL * 100:.3g} % CI"
    adj = ", ".join(f"{x * 100:.3g} %" for x in adjusted)
    if all(x > LEVEL + 1e-9 for x in levels):
        return f"{adj} CI (Bonferroni-adjusted over the units)"
    return f"{LEVEL * 100:.3g} % CI ({adj} where the rule adjusts for its number of units)"


def _contrast_rows(row: Row) -> list[tuple[str, dict[str, Any], Mapping[str, Any], float]]:
    """(group, unit, contrast, CI level) of every contrast of ``row``; a contrast repeated inside one unit once."""
    out = []
    for g, info in row.groups.items():
        for u in info["units"]:
            seen = set()
            for c in u["contrasts"]:
                key = (c["label"], c["estimate"], tuple(c["ci"]))
                if key not in seen:
                    seen.add(key)
                    out.append((g, u, c, float(info.get("level", LEVEL))))
    return out


def effects_text(row: Row, limit: int = CI_SHOWN) -> str:
    """The numbers behind a verdict: per unit, each contrast's effect in the claim's direction (> 0 supports
    the claim; margins subtracted) with its CI across training seeds, ``[lo, hi]``; the first ``limit``
    contrasts (those with a CI first), then how many more the units table shows. Empty when the row has no
    units. The CI is 95 %, or the Bonferroni-adjusted level of a rule that corrects for its number of units
    (:func:`ci_words`).

    >>> from thesis_repro.claims.registry import spec
    >>> c = {"label": "ppo-ent - ppo", "estimate": 12.3, "ci": [4.1, 20.5], "n": 3}
    >>> row = Row(spec("3.6-entropy"), "reproduces", 3, groups={"all": {"units": [{"label": "Hopper/obs",
    ...     "contrasts": [c]}]}})
    >>> head, text = effects_text(row).split(": ", 1)
    >>> head
    "effect in the claim's direction (> 0 supports it) [95 % CI across 3 training seeds]"
    >>> text
    'Hopper/obs: ppo-ent - ppo +12.3 [4.1, 20.5]'

    A claim mixing a 1-seed task with a 3-seed task says where the CIs come from:

    >>> one = {"label": "kl_avg - joint", "estimate": -794.0, "ci": [None, None], "n": 1}
    >>> row.groups["all"]["units"].append({"label": "Walker2d", "contrasts": [one]})
    >>> effects_text(row).split(": ", 1)[0].split("[")[1]
    '95 % CI across 3 training seeds; no CI where a contrast has under 2 seeds]'
    """
    rows = sorted(_contrast_rows(row), key=lambda r: r[2]["n"] < 2)  # contrasts with a CI first (stable)
    items = [f"{u['label']}: {c['label']} {_effect_ci(c)}" for _, u, c, _ in rows]
    ns = {c["n"] for _, _, c, _ in rows}
    if not items:
        return ""
    with_ci = {n for n in ns if n >= 2}
    if not with_ci:
        no_ci = "seed means: no CI" if row.pooled_seeds else no_ci_words()
        head = f"effect in the claim's direction (> 0 supports it), {no_ci}"
    else:
        seeds = f"{min(with_ci)}" if len(with_ci) == 1 else f"{min(with_ci)}-{max(with_ci)}"
        fewer = "; no CI where a contrast has under 2 seeds" if with_ci != ns else ""
        ci = ci_words([lv for *_, lv in rows])
        head = f"effect in the claim's direction (> 0 supports it) [{ci} across {seeds} training seeds{fewer}]"
    more = len(items) - limit
    tail = f"; ... {more} more contrast(s) in the units table" if more > 0 else ""
    return f"{head}: " + "; ".join(items[:limit]) + tail


def units_table(row: Row) -> pd.DataFrame:
    """Per contrast: group, unit, the unit's outcome (its contrasts combined by the rule), the contrast, its
    estimate, its CI across seeds with the CI's level, the contrast's own outcome and its seeds."""
    recs = []
    for g, u, c, level in _contrast_rows(row):
        lo, hi = c["ci"]
        recs.append(
            {
                "group": g,
                "unit": u["label"],
                "unit outcome": u["outcome"],
                "contrast": c["label"],
                "estimate": "" if c["estimate"] is None else f"{c['estimate']:.3g}",
                "CI": "" if lo is None else f"[{lo:.3g}, {hi:.3g}]",
                "CI level": f"{level * 100:.3g} %",
                "contrast outcome": c.get("outcome", ""),
                "seeds": c["n"],
            }
        )
    return pd.DataFrame(recs)
