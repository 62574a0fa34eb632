"""The book's page "What changed from v2, and why": design v3's changes, each with its reason and the verdicts it
moves on the registered seeds, generated from the ledger's JSON (:func:`page`; written by ``make results``).

A claim's verdict moves from v2 to v3 through four steps, added one at a time in this order (the ledger judges
each, :func:`thesis_repro.claims.ledger._judge_v3`'s ``ablation``): v3's statistics alone (v2's rule, no
conjunction), then the conjunction, then v3's rule overrides, then the calibration gate. A step *moves* a claim
when its verdict differs from the step before.

>>> c = {"id": "a", "verdict": "not calibrated", "v2_verdict": "reproduces", "v3_statistical": "reproduces",
...      "v3_ablation": {"statistics": "reproduces", "conjunction": "reproduces"}}
>>> moved_by(c)
['the calibration gate']
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

#: Where the page is written (a book page).
PAGE = Path("book") / "deviations.md"

#: Each change of design v3 (in the order its steps are added) with its reason.
CHANGES: tuple[tuple[str, str, str], ...] = (
    (
        "the statistics",
        "Seed-keyed statistics, linear margin tests, compound units and multiplicity",
        "Per-seed values were paired by position: a seed with an undefined value (e.g. every variant at the ceiling) "
        "shifted the next seed into its slot. They now carry their seed and are joined by it. A margin that is a "
        "fraction of a learner's mean was tested by dividing by that noisy mean, a biased ratio that let null "
        "effects pass above nominal; it is now tested as a linear contrast, whose null is exact. A unit of several "
        "contrasts took each seed's minimum over noisy contrasts, biased low, so two rules could never pass; it is "
        "now an intersection-union test, and a pooled claim pools each contrast across its units apart. A count "
        "claim's units were each tested at 5 %, so 20 null units gave at least one *yes* about 40 % of the time; "
        "their decisions are now Holm-adjusted. Holm's family across a page counts each distinct test once "
        "(3.6-entropy and 3.6-promising's ppo-ent part were one test counted twice).",
    ),
    (
        "the conjunction",
        "A sentence of several statements is one conjunction",
        "Where a claim's units are different statements joined by 'and' or 'but' (not one statement replicated over "
        "tasks, rows or learners), one trivial part could carry a *partly* label while the claim's point was "
        "undecided or wrong-signed. Such a claim now reproduces when every part does, does not when any part does "
        "not, and is inconclusive otherwise. Each such claim says why in its `v3:` block.",
    ),
    (
        "the rule overrides",
        "No claim reads a diverged run",
        "Figs 4.3-4.7's measures already left out runs that diverged in training; Fig 4.1's training-return and "
        "insensitivity claims and contribution 4 read them, as a ratio to a mean near zero. Every chapter-4 claim "
        "now leaves them out, worded 'diverged, not judged' when no run of the learner is left.",
    ),
    (
        "the calibration gate",
        "A plain verdict only from a rule that passes its own calibration",
        "The kit's calibration showed false *reproduces* rates up to 0.128 behind a *reproduces*, and two rules "
        "with power 0 at 128 seeds. A plain label now stands only when, over 2,000 draws each way at the observed "
        "spread, the rule's false R and false D are at most 0.05 + 2 Monte-Carlo SE; otherwise it reads *not "
        "calibrated*, with the rates. A rule that reproduces in under half the draws at the thesis's own effect "
        "even at 128 seeds reads *cannot be settled by this design*.",
    ),
)


def steps(claim: Mapping[str, Any]) -> list[tuple[str, str]]:
    """The claim's verdict after each step, from v2 to the label a reader sees: ``[(step, verdict), ...]``."""
    ab = claim.get("v3_ablation") or {}
    v2 = str(claim.get("v2_verdict") or claim.get("verdict") or "")
    stat = str(claim.get("v3_statistical") or claim.get("verdict") or "")
    return [
        ("v2", v2),
        ("the statistics", str(ab.get("statistics", stat))),
        ("the conjunction", str(ab.get("conjunction", stat))),
        ("the rule overrides", stat),
        ("the calibration gate", str(claim.get("verdict") or stat)),
    ]


def moved_by(claim: Mapping[str, Any]) -> list[str]:
    """The changes whose step moved the claim's verdict (in order)."""
    st = steps(claim)
    return [name for (_, before), (name, after) in zip(st, st[1:], strict=False) if before != after]


def _cell(text: Any) -> str:
    return " ".join(str(text).replace("|", "\\|").split())


def page(ledger_json: Mapping[str, Any], scale: str) -> str:
    """The whole page: the count of moved verdicts, each change with its reason and the claims it moves, and the
    claims whose verdict moved with every step."""
    claims: Sequence[Mapping[str, Any]] = [
        *(ledger_json.get("claims") or []),
        *(ledger_json.get("beyond_the_thesis") or []),
    ]
    thesis = [c for c in claims if not c.get("beyond_the_thesis")]
    moved = [c for c in claims if moved_by(c)]
    design = ledger_json.get("design") or {}
    before = next(iter((ledger_json.get("previous_design") or {}).items()), ("v2", ""))
    out = [
        "# What changed from v2, and why",
        "",
        f"**Design {design.get('version', '')} moves the verdicts of {sum(1 for c in thesis if moved_by(c))} of "
        f"{len(thesis)} thesis claims on the registered seeds; design {before[0]} stays shown beside it on every "
        "page, in `claims --json` and in RESULTS.md.**",
        "",
        f"Design {design.get('version', '')} (hash `{str(design.get('hash', ''))[:12]}`) was frozen before any run "
        f"of the thesis-budget study or of chapter 4's readings existed; design {before[0]} (hash "
        f"`{str(before[1])[:12]}`) remains the registered analysis of seeds 0-5. Generated by "
        f"`python -m thesis_repro results` from the shipped claims snapshot at `{scale}`; do not edit by hand.",
        "",
        "Each change is added in turn, in the order below; a change *moves* a claim when the claim's verdict after "
        "it differs from its verdict before it.",
    ]
    for key, title, why in CHANGES:
        hits = [c for c in claims if key in moved_by(c)]
        out += ["", f"## {title}", "", why, ""]
        if hits:
            out.append(f"Moves {len(hits)} verdict(s):")
            out.append("")
            for c in hits:
                st = dict(steps(c))
                names = [n for n, _ in steps(c)]
                prev = st[names[names.index(key) - 1]]
                tag = " (beyond the thesis)" if c.get("beyond_the_thesis") else ""
                out.append(f"- `{c.get('id')}`{tag}: {_cell(prev)} → **{_cell(st[key])}**")
        else:
            out.append("Moves no verdict.")
    out += ["", "## Every moved claim", ""]
    if moved:
        out += ["| claim | v2 | v3 | moved by | ours, v2 → v3 |", "|---|---|---|---|---|"]
        for c in moved:
            ours = f"{c.get('v2_ours') or '-'} → {c.get('ours') or '-'}"
            out.append(
                f"| `{c.get('id')}` | {_cell(c.get('v2_verdict'))} | **{_cell(c.get('verdict'))}** | "
                f"{_cell(', '.join(moved_by(c)))} | {_cell(ours)} |"
            )
    else:
        out.append("No verdict moved.")
    gated = [c for c in claims if c.get("gate_reason")]
    if gated:
        out += ["", "## Why the gate relabels", ""]
        out += [f"- `{c.get('id')}`: {_cell(c.get('gate_reason'))}" for c in gated]
    return "\n".join(out) + "\n"
