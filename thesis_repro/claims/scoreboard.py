"""The ledger as a whole, in words: the book's scoreboard and method, ``claims --json``, and the one-line hints.

Pure functions of the rows :func:`thesis_repro.claims.ledger.ledger` judged: :func:`counts` of distinct claims,
:func:`as_json`, :func:`scoreboard` (with :func:`method`, the decision rule :data:`RULE_WORDS` and each claim's
calibration), and the hints on numbers not computed, shipped or stale.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from typing import Any

from thesis_repro.claims import design, report, snapshot
from thesis_repro.claims import sensitivity as subsets
from thesis_repro.claims.confirmatory import FIRST_FRESH, FRESH_SEEDS, fresh_summary
from thesis_repro.claims.diagnosis import sensitivity_method
from thesis_repro.claims.ledger_row import Row, headline, shipped_pages, stale_pages
from thesis_repro.claims.registry import specs
from thesis_repro.claims.store import make_target

#: Statuses counted on the scoreboard, in its column order.
COUNTED: tuple[str, ...] = (
    report.REPRODUCES,
    report.AT_LEAST_PARTLY,
    report.PARTLY,
    report.AT_MOST_PARTLY,
    report.DOES_NOT,
    report.INCONCLUSIVE,
    report.INDICATIVE,
    report.NOT_CALIBRATED,
    report.CANNOT_SETTLE,
    report.NOT_RUN,
    report.NOT_JUDGED,
    report.NOT_COMPUTED,
    report.VISUAL,
)

SHORT = {
    report.REPRODUCES: "reproduces",
    report.AT_LEAST_PARTLY: "at least partly",
    report.AT_MOST_PARTLY: "at most partly",
    report.PARTLY: "partly",
    report.DOES_NOT: "does not",
    report.INCONCLUSIVE: "inconclusive",
    report.INDICATIVE: "indicative",
    report.NOT_CALIBRATED: "not calibrated",
    report.CANNOT_SETTLE: "cannot be settled",
    report.NOT_RUN: "not run",
    report.NOT_JUDGED: "not judged",
    report.NOT_COMPUTED: "not computed",
    report.VISUAL: "visual",
}


def counts(rows: Sequence[Row], beyond: bool = False) -> Counter:
    """Status counts of distinct claims (each claim once, whichever pages repeat it)."""
    return Counter(r.status for r in rows if r.spec.beyond == beyond)


def confirmatory_counts(rows: Sequence[Row]) -> Counter:
    """Confirmatory verdict counts of the distinct thesis claims (``not yet judged``: fresh seeds not shipped)."""
    return Counter(r.confirmation.status if r.confirmation else NOT_YET for r in rows if not r.spec.beyond)


#: A claim's confirmatory count when its pages do not hold the fresh seeds yet (as README and RESULTS.md say it).
NOT_YET = "not yet judged"


def as_json(rows: Sequence[Row], scale: str = "") -> dict[str, Any]:
    """The ledger as one JSON-ready object: thesis claims, beyond-the-thesis claims, both counts, and where the
    numbers of pages read from the shipped snapshot come from (``snapshot``, at ``scale``)."""
    return {
        "claims": [r.as_dict() for r in rows if not r.spec.beyond],
        "beyond_the_thesis": [r.as_dict() for r in rows if r.spec.beyond],
        "design": design.stamp(),
        "decision_rule": RULE_WORDS + " " + RULE_WORDS_V3,
        "previous_design": {design.PREVIOUS: design.previous().get("hash", "")},
        "counts": dict(counts(rows)),
        "v2_counts": dict(Counter(r.v2_status or r.status for r in rows if not r.spec.beyond)),
        "v1_counts": dict(Counter(r.v1_status or r.status for r in rows if not r.spec.beyond)),
        "confirmatory_counts": dict(confirmatory_counts(rows)),
        "confirmatory_seeds": f"{FIRST_FRESH} and above (judged once a claim's pages hold {list(FRESH_SEEDS)})",
        "confirmatory_disagree": [r.spec.id for r in rows if r.confirmation and r.confirmation.disagrees],
        "beyond_counts": dict(counts(rows, beyond=True)),
        "stale_pages": stale_pages(rows),
        "shipped_pages": shipped_pages(rows),
        "snapshot": snapshot.snapshot_source(scale) if scale and shipped_pages(rows) else None,
    }


def scoreboard(scale: str, rows: Sequence[Row]) -> str:
    """Markdown scoreboard of distinct thesis claims: the counts under design v3 (v2's and v1's beside them), which
    claims reproduce and which do not (one line each), a table of verdicts by chapter (one row per verdict, one
    short column per chapter: it reads at a laptop's width), the beyond-the-thesis count, and the method."""
    cols = [c for c in COUNTED if any(r.status == c for r in rows if not r.spec.beyond)]
    total: Counter = Counter()
    by_ch: dict[str, Counter] = {}
    for r in rows:
        if r.spec.beyond:
            continue
        ch = r.spec.page.split("-", 1)[1].split("-")[0].split(".")[0]
        by_ch.setdefault(ch, Counter())[r.status] += 1
        total[r.status] += 1
    chapters = sorted(by_ch, key=int)
    head = [
        "| verdict | " + " | ".join(f"{{doc}}`Chapter\u00a0{ch} <chapter-{ch}>`" for ch in chapters) + " | **all** |",
        "|---|" + "---|" * (len(chapters) + 1),
    ]
    for c in cols:
        counts_ = " | ".join(str(by_ch[ch].get(c, 0)) for ch in chapters)
        head.append(f"| {SHORT[c]} | {counts_} | **{total.get(c, 0)}** |")
    extra = counts(rows, beyond=True)
    v1 = Counter(r.v1_status or r.status for r in rows if not r.spec.beyond)
    v2 = Counter(r.v2_status or r.status for r in rows if not r.spec.beyond)
    d = design.stamp()

    def listed(c: Counter) -> str:
        return ", ".join(f"{v} {SHORT.get(k, k)}" for k, v in sorted(c.items(), key=lambda kv: _order(kv[0])))

    lead = (
        f"\n\n## Scoreboard at scale `{scale}` (claims design {d['version']})\n\n"
        f"Distinct claims of the thesis: **{sum(total.values())}**: "
        + ", ".join(f"**{v} {SHORT.get(k, k)}**" for k, v in sorted(total.items(), key=lambda kv: _order(kv[0])))
        + f". Under design {design.PREVIOUS} (the registered analysis of seeds 0-5) the same numbers read: "
        + listed(v2)
        + "; under v1: "
        + listed(v1)
        + " ({doc}`What changed from v2, and why <deviations>`).\n\n"
    )
    thesis = [r.as_dict() for r in rows if not r.spec.beyond]
    lead += (
        f"**Fresh seeds.** {fresh_summary(thesis)} Counts on the fresh seeds alone: "
        + ", ".join(f"{v} {SHORT.get(k, k)}" for k, v in sorted(confirmatory_counts(rows).items(), key=fresh_order))
        + " ({doc}`the confirmatory check <fresh-seeds>`).\n\n"
    )
    for label, want in (("Do not reproduce", report.DOES_NOT), ("Reproduce", report.REPRODUCES)):
        hits = [r for r in rows if not r.spec.beyond and r.status == want]
        if hits:
            lead += f"**{label}:**\n\n" + "\n".join(f"- {headline(r, 400)}" for r in hits) + "\n\n"
    lead += (
        "Beyond the thesis (the kit's own extensions: kl_exact, the Eq 4.11 analysis): "
        + ", ".join(f"{v} {SHORT.get(k, k)}" for k, v in sorted(extra.items(), key=lambda kv: _order(kv[0])))
        + " (not in the counts above).\n\n"
    )
    hint = stale_hint(stale_pages(rows), scale)
    lead += f"```{{warning}}\n{hint}\n```\n\n" if hint else ""
    tail = (
        "\n\nEach thesis sentence is one claim, judged once by the rule registered for it in "
        "`data/thesis/claims.yaml` (pages that repeat it show the same verdict). Kit-made checks such as the "
        "agreement of the Welch bolding are shown on their pages and not counted. `python -m thesis_repro claims "
        f"--scale {scale} --json` prints this ledger; {{doc}}`What changed from v2, and why <deviations>` and "
        "{doc}`what changed from v1 <claims-design-v2>` "
        "explain the design.\n"
    )
    if scale == "smoke":
        tail += "At `smoke` nothing is judged: the runs only exercise the plumbing.\n"
    return lead + "\n".join(head) + tail + method(rows)


def _order(status: str) -> int:
    return COUNTED.index(status) if status in COUNTED else len(COUNTED)


def fresh_order(kv: tuple[str, int]) -> tuple[int, int]:
    """Sort key of (confirmatory verdict, count) pairs: the verdicts in the scoreboard's order, then by count."""
    return (_order(kv[0]), -kv[1])


#: What design v3 changes in v2's rule, in words (the method page and ``claims --json``).
RULE_WORDS_V3 = (
    "**Design v3** keeps v2's levels and margins and changes how they are tested. Every per-seed value carries "
    "its training seed: two sides and the units of a pooled test are joined by seed (a missing value is a missing "
    "seed). A margin that is a fraction of a learner's mean is tested as a linear contrast (Fieller's device), "
    "not as a ratio to a noisy mean. Each unit gets two one-sided p-values (*yes*: effect above its bound; *no*: "
    "effect below the margin); a unit of several contrasts is an intersection-union test, and a pooled claim "
    "pools each contrast across its units separately. Count claims Holm-adjust their units' *yes* and *no* "
    "decisions; *each* claims Holm-adjust *no*. A claim whose units are different statements of one sentence is "
    "one conjunction (every unit yes: reproduces; any no: does not; else inconclusive). Holm's family across a "
    "page counts each distinct test once. A plain label stands only when the rule passes its calibration gate "
    "(false R and false D at most 0.05 + 2 Monte-Carlo SE over 2,000 draws each at the observed spread); "
    "otherwise it reads *not calibrated*, and a rule that reproduces in under half the draws at the thesis's "
    "own effect even at 128 seeds reads *cannot be settled by this design*. Beside each verdict: is the "
    "thesis's own effect excluded by our 95 % CI?"
)

#: The v2 decision rule in words (the method page and ``claims --json``).
RULE_WORDS = (
    "Every claim has a level, a margin and a rule registered before the confirmatory seeds existed "
    "(`data/thesis/claims.yaml`, frozen in `data/thesis/claims-design.json`). The unit of replication is the "
    "training seed. Each unit compares per-seed values with a 95 % CI (Welch across seeds; a one-sample or "
    "paired t interval; correlations through Fisher z; Clopper-Pearson for 0/1 outcomes). With margin m (the "
    "smallest effect of interest, in the claim's units: r for correlations, a share for success rates, else a "
    "fraction of the reference learner's value on that task), a unit is **yes** when its CI lies above 0 and "
    "reaches m, **no** when its CI ends below m (effects of the margin's size are excluded: an equivalence / "
    "non-superiority test; a unit whose v1 rule states its own bound uses m = 0), **undecided** otherwise. "
    '**pooled** claims ("most", "generally", "on average") pool each seed\'s effect over the units '
    "(tasks as fixed effects) and take a t-interval across seeds, Holm-adjusted across the pooled claims that "
    "share a page's data: yes -> reproduces, no -> does not reproduce, else inconclusive. **each** claims "
    '("each", "every", "in all") need every unit yes; **count** claims keep their thresholds. The '
    "yes-share interval [yes / n, (yes + undecided) / n] gives two regions: one region -> that verdict; partly "
    "to reproduces -> *at least partly*; does not to partly -> *at most partly*; all three -> *inconclusive*. A "
    "claim of several parts holds when each part does (lower and upper regions combined apart). One seed -> at "
    "most indicative. **Calibration**: over 1,000 synthetic draws each way at the observed spread (>= 3 seeds), "
    "the share judged *reproduces* when every effect is 0 (false R), and *does not reproduce* when every effect "
    "equals the margin (false D). **Power**: the fewest training seeds at which 80 % of draws reproduce when "
    "the effects are the thesis's own (or the margin where the thesis reports none)."
)


def method(rows: Sequence[Row]) -> str:
    """The method section: the v2 decision rule, and per claim its level, margin, both verdicts, calibration and
    power."""
    out = [
        "\n\n## Method: rules fixed in advance, statistics across training seeds\n",
        RULE_WORDS + "\n",
        RULE_WORDS_V3 + "\n",
        sensitivity_method(),
        subsets.method_text(specs()),
        "One row per claim: its level and margin, its verdict under design v3 and v2, v3's calibration (the share "
        "of null draws judged *reproduces*, false R, and of draws at the margin judged *does not*, false D) and the "
        "training seeds at which 80 % of draws at the thesis's effect reproduce.\n",
        "| claim | level, margin | verdict | v2 | false\u00a0R | false\u00a0D | seeds\u00a0(80\u00a0%) |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        c = r.calibration
        fr = "n/a" if c.get("false_reproduces") is None else f"{c['false_reproduces']:.3f}"
        fd = "n/a" if c.get("false_does_not") is None else f"{c['false_does_not']:.3f}"
        seeds = c.get("seeds_for_80", "n/a") if c else "n/a"
        seeds = ">\u00a0128" if c and seeds is None else seeds
        tag = " (beyond)" if r.spec.beyond else ""
        level = ",\u00a0".join(x for x in (r.level, "" if r.margin is None else f"{r.margin:g}") if x) or "-"
        v2 = r.v2_status or r.status
        out.append(
            f"| {r.spec.id}{tag} | {level} | {SHORT.get(r.status, r.status)} | {SHORT.get(v2, v2)} | {fr} | {fd} "
            f"| {seeds} |"
        )
    return "\n".join(out) + "\n"


def not_computed_hint(rows: Sequence[Row], scale: str) -> str:
    """One line telling how to compute the claims whose pages have not run at ``scale`` ('' when none): the
    ledger judges saved page numbers, so a fresh clone has none until its book (or the pages) ran.

    >>> from thesis_repro.claims.registry import Spec
    >>> spec = Spec("x", "fig-3.3", "c", (547,), {})
    >>> not_computed_hint([Row(spec, report.NOT_COMPUTED)], "small")  # doctest: +NORMALIZE_WHITESPACE
    'not computed: 1 claim(s) whose pages have not run at small (fig-3.3); `make book SCALE=small` executes every
    page from the shipped runs without training, or `make figure-3.3 SCALE=small` per page'
    """
    pages = sorted({r.spec.page for r in rows if r.status == report.NOT_COMPUTED})
    if not pages:
        return ""
    n = sum(r.status == report.NOT_COMPUTED for r in rows)
    shown = ", ".join(pages[:6]) + (f" and {len(pages) - 6} more" if len(pages) > 6 else "")
    return (
        f"not computed: {n} claim(s) whose pages have not run at {scale} ({shown}); `make book SCALE={scale}` "
        "executes every page from the shipped runs without training, or "
        f"`make {make_target(pages[0])} SCALE={scale}` per page"
    )


def shipped_hint(rows: Sequence[Row], scale: str) -> str:
    """One line saying which pages' numbers came from the shipped snapshot ('' when none did).

    >>> from thesis_repro.claims.registry import Spec
    >>> row = Row(Spec("x", "fig-3.3", "c", (547,), {}), report.INCONCLUSIVE, shipped=["fig-3.3"])
    >>> shipped_hint([row], "no-such-scale")  # doctest: +NORMALIZE_WHITESPACE
    'shipped: the numbers of 1 page(s) (fig-3.3) come from the shipped claims snapshot (the numbers those pages
    saved when the book ran where they were shipped); `make book SCALE=no-such-scale` recomputes them here from
    the shipped runs'
    """
    pages = shipped_pages(rows)
    if not pages:
        return ""
    shown = ", ".join(pages[:6]) + (f" and {len(pages) - 6} more" if len(pages) > 6 else "")
    where = snapshot.snapshot_source(scale)
    return (
        f"shipped: the numbers of {len(pages)} page(s) ({shown}) come from the shipped claims snapshot "
        f"({where + ': ' if where else ''}the numbers those pages saved when the book ran where they were shipped); "
        f"`make book SCALE={scale}` recomputes them here from the shipped runs"
    )


def stale_hint(pages: Sequence[str], scale: str) -> str:
    """One line telling how to refresh stale ``pages`` ('' when there are none).

    >>> "`make table-3.4 SCALE=small`" in stale_hint(["table-3.4"], "small")
    True
    >>> stale_hint(["fig-5.6", "table-3.4"], "small")  # doctest: +NORMALIZE_WHITESPACE
    'stale: the saved numbers of fig-5.6, table-3.4 were written by other kit code (thesis_repro/, notebooks/ or
    data/thesis/ changed since); refresh them with `make figure-5.6 SCALE=small` per page, or `make book
    SCALE=small`'
    """
    if not pages:
        return ""
    return (
        f"stale: the saved numbers of {', '.join(pages)} were written by other kit code (thesis_repro/, "
        f"notebooks/ or data/thesis/ changed since); refresh them with `make {make_target(pages[0])} "
        f"SCALE={scale}` per page, or `make book SCALE={scale}`"
    )
