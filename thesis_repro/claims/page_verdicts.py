"""A page's verdicts: what a notebook's last call (:func:`judge_page`) saves, prints and displays, kit checks too.

:func:`judge_page` saves the page's per-seed numbers (:func:`thesis_repro.claims.store.save_page`), judges its
claims from them (:func:`thesis_repro.claims.ledger.judge`) and reports them (:mod:`thesis_repro.claims.report`):
one headline each, the evidence folded under it, each claim's units table. Kit-made checks such as the Welch
bolding's agreement (:func:`bolding_check`) are printed apart, worded as agreement, never counted.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import pandas as pd

from thesis_repro.claims import report
from thesis_repro.claims.evidence import describe, units_table
from thesis_repro.claims.ledger import judge
from thesis_repro.claims.ledger_row import headline
from thesis_repro.claims.registry import page_claims
from thesis_repro.claims.store import save_page
from thesis_repro.claims.thesis_budget import thesis_budget_line


def verdicts(page: str, scale: str) -> list[report.Verdict]:
    """A page's claims as :class:`~thesis_repro.claims.report.Verdict` (repeats say where they are judged)."""
    out = []
    for s in page_claims(page):
        row = judge(s, scale)
        where = f"thesis l. {', '.join(map(str, s.lines))}" if s.lines else "kit extension"
        tag = "[beyond the thesis] " if s.beyond else ""
        again = f" (judged on {s.page}; repeated here, counted once)" if s.page != page else ""
        claim = f"{tag}{s.text} ({where}){again}"
        gate = f" ({row.v3['reason']})" if row.v3.get("reason") else ""
        before = f"design v2 verdict: {row.v2_status or row.status}; v1: {row.v1_status or row.status}"
        evidence = f"design v3 verdict: {row.status}{gate}; {before}; {describe(row)}"
        if row.subset:  # the registered sensitivity check: its own paragraph at the top of the folded evidence
            evidence = f"{row.subset['line']}.\n\n{evidence}"
        fig = page.removeprefix("fig-")
        line = headline(row, width=report.LINE - len(f"[{fig}] "))  # the terminal's line is the page's first line
        fresh = row.confirmation.line() if row.confirmation else ""
        budget = budget_line(row.thesis_budget)
        out.append(report.Verdict(fig, claim, row.status, evidence, line, fresh, row.v2_status or row.status, budget))
    return out


def budget_line(info: Mapping[str, Any]) -> str:
    """A claim's thesis-budget line for its page (``""`` when the study does not retrain its runs).

    >>> budget_line({}), budget_line({"verdict": "not computed", "runs": 0, "runs_total": 108, "steps": 4_000_000})
    ('', "thesis's budget (4M steps): not computed (0 of 108 runs)")
    """
    if not info:
        return ""
    return str(info.get("line") or thesis_budget_line(info))


def judge_page(
    page: str,
    scale: str,
    frames: Mapping[str, pd.DataFrame],
    meta: Mapping[str, Any] | None = None,
    kit_checks: Sequence[report.Verdict] = (),
    display: bool = True,
    page_rule: Sequence[report.Verdict] = (),
) -> list[report.Verdict]:
    """A notebook's last call: save its per-seed numbers, print / display its claims' verdicts (each with
    its units table) and the kit-made checks (outside the scoreboard); writes ``<page>.verdicts.json``.
    ``page_rule``: the verdicts of the page's own rule (``analysis-4-kl``), saved first for its ``page_verdict``
    claims (:func:`~thesis_repro.claims.report.rule_path`)."""
    save_page(page, scale, frames, {"scale": scale, **dict(meta or {})})
    if page_rule:
        report.save_rule(page, scale, page_rule)
    vs = verdicts(page, scale)
    report.report(page, scale, vs, display=display)
    if display:
        _show_units(page, scale)
    for k in kit_checks:
        print(kit_check_text(k))
    return vs


#: A kit check's result in its own words (it tests the kit's agreement with the thesis, not a thesis claim).
KIT_CHECK_WORDS = {
    report.REPRODUCES: "agrees",
    report.PARTLY: "partly agrees",
    report.DOES_NOT: "disagrees",
}


def kit_check_text(v: report.Verdict) -> str:
    """One printed line of a kit check, worded as agreement (never as a thesis verdict).

    >>> kit_check_text(report.Verdict("table-3.4", "Bold rows agree", report.PARTLY, "3/20 rows"))
    '[kit check, not a thesis claim] [table-3.4] PARTLY AGREES - Bold rows agree: 3/20 rows'
    """
    word = KIT_CHECK_WORDS.get(v.status, v.status)
    tail = f": {v.evidence}" if v.evidence else ""
    return f"[kit check, not a thesis claim] [{v.figure}] {word.upper()} - {v.claim}{tail}"


def bolding_check(page: str, agreement: Mapping[str, int], scale: str) -> report.Verdict:
    """Kit check (not a thesis claim, shown through ``judge_page(kit_checks=...)``): does our Welch bolding
    agree with the thesis's? ``agreement`` is :func:`thesis_repro.evaluation.tables.bold_agreement`'s count
    (a page's ``Comparison.agreement``); holds if the best learner is the thesis's in most rows.

    >>> a = {"rows": 4, "best_same": 1, "same": 10, "cells": 16, "bold_both": 2, "bold_ours": 3, "bold_thesis": 4}
    >>> bolding_check("table-3.4", a, "small").status
    'partly reproduces'
    """
    from thesis_repro.evaluation import tables  # at call time: the package imports the learners (2 s)

    a = agreement
    claim = "The best learner of each row (bold, Welch p >= alpha) is the thesis's"
    ev = (
        f"best learner the same in {a['best_same']}/{a['rows']} rows; bold/not-bold agrees in {a['same']}/"
        f"{a['cells']} cells ({a['bold_both']} bold in both; {a['bold_ours']} bold reproduced, "
        f"{a['bold_thesis']} bold thesis, on the learners run); thesis bolding derived from its mean ± std with "
        f"n = {tables.thesis_n()}, alpha = {tables.significance_level()}; ours by the same Welch test on each cell's "
        "seed x rollout samples (the thesis's method: rollouts count as samples here, unlike the claims above, "
        "whose unit is the training seed)"
    )
    holds = None if not a["rows"] else a["best_same"] > a["rows"] / 2
    return report.Verdict(page, claim, report.status(holds, scale, partly=a["best_same"] > 0), ev)


def _show_units(page: str, scale: str) -> None:
    try:  # IPython: an optional extra, present inside a notebook's kernel only
        from IPython import get_ipython
        from IPython.display import display as show
    except ImportError:  # pragma: no cover
        return
    if get_ipython() is None:
        return
    for s in page_claims(page):
        if s.page != page or s.rule.get("derived"):  # a derived claim's units: its parts' tables
            continue
        t = units_table(judge(s, scale, with_null=False))
        if len(t):
            print(
                f"{s.id}: units (effect in the claim's direction, > 0 supports it; CI across training seeds at the "
                "level shown; a unit's outcome combines its contrasts by the claim's rule)"
            )
            show(t)
