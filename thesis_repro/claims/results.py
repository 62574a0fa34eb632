"""``python -m thesis_repro results`` (``make results``): RESULTS.md and the README's generated blocks.

Everything here but :func:`main` is wording: pure functions over the claims ledger's JSON dicts
(:func:`thesis_repro.claims.scoreboard.as_json`) and the scale table's resolved settings. A claim's dict is read
through :func:`verdict_label`, :func:`short`, :func:`thesis_value` and :func:`ours`, which use the keys ``label``,
``short``, ``thesis_value`` and ``ours`` when the ledger provides them, else today's ``verdict``, ``claim`` and
``statistic``. :func:`main` judges every claim from the shipped claims snapshot
(``data/reference/claims/<scale>/``, never a build's own pages, so the files match a fresh clone) and writes
``RESULTS.md`` and the README blocks between :data:`RESULTS_MARKERS` and :data:`SCALES_MARKERS`; ``--check``
only says which are out of date (exit 1).

>>> words("one two three", limit=2)
'one two ...'
>>> verdict_label({"verdict": "inconclusive"})
'inconclusive'
>>> verdict_label({"verdict": "inconclusive", "label": "holds within bounds"})
'holds within bounds'
>>> replace_block("a\\n<!-- x:start -->\\nold\\n<!-- x:end -->\\nb", ("<!-- x:start -->", "<!-- x:end -->"), "new")
'a\\n<!-- x:start -->\\nnew\\n<!-- x:end -->\\nb'
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
import tempfile
import warnings
from collections import Counter
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any
from unittest import mock

from thesis_repro.claims import deviations, ledger, scoreboard, thesis_budget
from thesis_repro.claims.confirmatory import (
    FIRST_FRESH,
    FRESH_WORDS,
    fresh_summary,
    fresh_verdict,
    seed_range,
    v2_words,
)
from thesis_repro.claims.ledger_row import Row
from thesis_repro.core import paths, scales, yamlfile

#: The README's generated blocks: the results summary and the scale table.
RESULTS_MARKERS = ("<!-- results:start -->", "<!-- results:end -->")
SCALES_MARKERS = ("<!-- scales:start -->", "<!-- scales:end -->")
#: Words of a claim shown when the ledger gives no ``short`` wording.
SHORT_WORDS = 12
#: Labels of a claim that does not reproduce (listed one by one in the README); a label starting with
#: "does not" counts too.
NOT_REPRODUCING: tuple[str, ...] = ("does not reproduce", "contradicted", "refuted")
COMMAND = "python -m thesis_repro results"
#: The scale whose claims snapshot is shipped, and so the one RESULTS.md reports.
SCALE = "small"
#: The book's generated page on the confirmatory check (its first line: which claims did not hold up).
FRESH_PAGE = Path("book") / "fresh-seeds.md"


# ---------------------------------------------------------------- one claim's fields
def words(text: str, limit: int = SHORT_WORDS) -> str:
    """``text`` on one line, cut to its first ``limit`` words (``...`` when cut)."""
    parts = " ".join(str(text).split()).split(" ")
    return " ".join(parts[:limit]) + (" ..." if len(parts) > limit else "")


def verdict_label(claim: Mapping[str, Any]) -> str:
    """The claim's verdict label (``label``, else today's ``verdict``)."""
    return str(claim.get("label") or claim.get("verdict") or "not computed")


def short(claim: Mapping[str, Any]) -> str:
    """The claim in at most :data:`SHORT_WORDS` words (``short``, else the thesis's sentence cut)."""
    return words(claim.get("short") or claim.get("claim") or "")


def thesis_value(claim: Mapping[str, Any]) -> str:
    """The thesis's own value (``thesis_value``), or ``-``."""
    return str(claim.get("thesis_value") or "-")


def ours(claim: Mapping[str, Any]) -> str:
    """Our key number with its CI (``ours``), else the yes-share of the units with its interval, else (a derived
    claim) the verdicts of the claims it combines, or ``-``.

    >>> ours({"statistic": {"k": 3, "n": 20, "value": 0.4, "ci": [0.15, 0.9], "undecided": 14}})
    '3/20 units yes, yes-share [0.15, 0.90]'
    >>> ours({"ours": "r = 0.71 [0.02, 1.39]"}), ours({"statistic": {}})
    ('r = 0.71 [0.02, 1.39]', '-')
    >>> ours({"statistic": {"parts": {"3.3-a": "reproduces", "3.3-b": "does not reproduce"}}})
    'from 3.3-a (reproduces) and 3.3-b (does not reproduce)'
    """
    if claim.get("ours"):
        return str(claim["ours"])
    st = claim.get("statistic") or {}
    parts = st.get("parts")
    if isinstance(parts, Mapping) and parts:
        return "from " + " and ".join(f"{cid} ({verdict})" for cid, verdict in parts.items())
    stats = [st] if "n" in st else [v for v in st.values() if isinstance(v, Mapping) and "n" in v]
    stats = [s for s in stats if s.get("n")]
    if not stats:
        return "-"
    k, n = sum(int(s.get("k", 0)) for s in stats), sum(int(s["n"]) for s in stats)
    if len(stats) > 1:
        return f"{k}/{n} units yes"
    lo, hi = stats[0].get("ci") or (None, None)
    interval = f", yes-share [{lo:.2f}, {hi:.2f}]" if lo is not None and hi is not None else ""
    return f"{k}/{n} units yes{interval}"


def thesis_effect(claim: Mapping[str, Any]) -> str:
    """Whether our 95 % CI excludes the thesis's own effect, in a few words (``-``: the thesis gives no number).

    >>> thesis_effect({"thesis_effect": {"excluded": True, "ours_side": "smaller"}}), thesis_effect({})
    ('excluded (ours smaller)', '-')
    """
    t = claim.get("thesis_effect")
    if not t:
        return "-"
    if t.get("excluded") is None:
        return "no CI"
    return f"excluded (ours {t.get('ours_side')})" if t["excluded"] else "not excluded"


def v2_label(claim: Mapping[str, Any]) -> str:
    """The claim's design-v2 verdict (the registered analysis of seeds 0-5)."""
    return str(claim.get("v2_verdict") or verdict_label(claim))


def thesis_lines(claim: Mapping[str, Any]) -> str:
    """``l. 547`` (``l. 547, 555`` for several lines; ``-`` for none)."""
    lines = claim.get("thesis_lines") or []
    return "l. " + ", ".join(str(x) for x in lines) if lines else "-"


def does_not_reproduce(lab: str) -> bool:
    """Whether a verdict label says the claim does not reproduce.

    >>> does_not_reproduce("does not reproduce"), does_not_reproduce("inconclusive")
    (True, False)
    """
    lab = lab.lower()
    return lab in NOT_REPRODUCING or lab.startswith("does not")


def _cell(text: str) -> str:
    return " ".join(str(text).replace("|", "\\|").split())


# ---------------------------------------------------------------- whole documents
def label_counts(claims: Sequence[Mapping[str, Any]]) -> list[tuple[str, int]]:
    """(label, number of claims), most frequent first (ties by name).

    >>> label_counts([{"verdict": "b"}, {"verdict": "a"}, {"verdict": "b"}])
    [('b', 2), ('a', 1)]
    """
    c = Counter(verdict_label(x) for x in claims)
    return sorted(c.items(), key=lambda kv: (-kv[1], kv[0]))


def v2_counts(claims: Sequence[Mapping[str, Any]]) -> list[tuple[str, int]]:
    """:func:`label_counts` of the design-v2 verdicts.

    >>> v2_counts([{"v2_verdict": "b"}, {"verdict": "a"}])
    [('a', 1), ('b', 1)]
    """
    return label_counts([{"verdict": v2_label(c)} for c in claims])


def _chapter(claim: Mapping[str, Any]) -> str:
    page = str(claim.get("page", ""))
    return page.split("-", 1)[-1].split("-")[0].split(".")[0]


def fresh_counts(claims: Sequence[Mapping[str, Any]]) -> str:
    """The confirmatory counts in one sentence (fresh seeds alone, the same frozen rules).

    >>> fresh_counts([{"confirmatory": {"verdict": "reproduces"}}, {}])
    'On the fresh seeds alone (confirmatory, the same frozen rules): reproduces 1, not yet judged 1.'
    """
    c = Counter(fresh_verdict(x) or "not yet judged" for x in claims)
    parts = sorted(c.items(), key=lambda kv: (kv[0] == "not yet judged", -kv[1], kv[0]))
    return (
        "On the fresh seeds alone (confirmatory, the same frozen rules): "
        + ", ".join(f"{lab} {n}" for lab, n in parts)
        + "."
    )


def fresh_cell(claim: Mapping[str, Any]) -> str:
    """A claim's confirmatory verdict for a table cell, flagged when it leans against the primary one."""
    v = fresh_verdict(claim)
    if v is None:
        return "-"
    return f"{v} (disagrees)" if claim["confirmatory"].get("disagrees") else v


def fresh_md(ledger_json: Mapping[str, Any], scale: str) -> str:
    """The book's page on the confirmatory check: its first line says which thesis claims did not hold up on
    the fresh seeds; then the counts and one row per claim judged on them."""
    claims = list(ledger_json.get("claims") or [])
    out = [
        "# Fresh seeds: the confirmatory check",
        "",
        f"**{fresh_summary(claims)}**",
        "",
        f"Design v2 was frozen while only seeds 0-2 existed. Every seed from {FIRST_FRESH} on was trained after it, "
        f"and every claim whose pages hold them is judged twice with the same frozen rule: its primary verdict on "
        f"every seed, and its confirmatory verdict on {FRESH_WORDS} alone. Both are design v3's (seed-keyed; on "
        "the fresh seeds its statistical label, with no calibration gate), with design v2's beside each (*v2: "
        "same* when they agree). The two *disagree* when they lean opposite ways. "
        f"Generated by `{COMMAND}` from the shipped claims snapshot at `{scale}`; do not edit by hand.",
        "",
        fresh_counts(claims),
    ]
    judged = [c for c in claims if fresh_verdict(c) is not None]
    if judged:  # one entry per claim, its evidence on its own line: the text gets the page's whole width
        out += ["", "Each claim: its verdict on every seed, then on the fresh seeds alone, and our number on them.", ""]
    for c in judged:
        fresh = str(fresh_verdict(c))
        seeds = seed_range(c["confirmatory"]["seeds"]) if c["confirmatory"].get("seeds") else "-"
        out.append(
            f"- `{c.get('id', '?')}` ({thesis_lines(c)}, {_cell(short(c))}): every seed **{_cell(verdict_label(c))}** "
            f"({v2_words(verdict_label(c), v2_label(c))}); fresh seeds {seeds} alone **{_cell(fresh_cell(c))}**"
            + (f" ({v2_words(fresh, c['confirmatory']['v2_verdict'])})" if c["confirmatory"].get("v2_verdict") else "")
        )
        out.append(f"  <br>ours on the fresh seeds: {_cell(c['confirmatory'].get('ours') or '-')}")
    return "\n".join(out) + "\n"


def claims_table(claims: Sequence[Mapping[str, Any]]) -> str:
    """The Markdown table of RESULTS.md: one row per claim."""
    rows = [
        "| claim | thesis line | claim, in short | thesis | ours (95 % CI) | verdict | thesis's effect | v2 "
        "| fresh seeds alone | thesis's budget (4M steps) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for c in claims:
        cells = (
            f"`{c.get('id', '?')}`",
            thesis_lines(c),
            short(c),
            thesis_value(c),
            ours(c),
            f"**{verdict_label(c)}**",
            thesis_effect(c),
            v2_label(c),
            fresh_cell(c),
            thesis_budget.cell(c.get("thesis_budget")),
        )
        rows.append("| " + " | ".join(_cell(x) for x in cells) + " |")
    return "\n".join(rows)


def results_md(ledger_json: Mapping[str, Any], scale: str) -> str:
    """The whole RESULTS.md: counts, then each chapter's claims, then the claims beyond the thesis."""
    claims = list(ledger_json.get("claims") or [])
    beyond = list(ledger_json.get("beyond_the_thesis") or [])
    out = [
        f"# Results at scale `{scale}`",
        "",
        f"Generated by `{COMMAND}` (`make results`) from the shipped claims snapshot"
        + (f" ({ledger_json['snapshot']})" if ledger_json.get("snapshot") else "")
        + "; do not edit by hand. Each row is one sentence of the thesis, judged by the rule registered for it in "
        "`data/thesis/claims.yaml`, with training seeds as the unit of replication. The book's pages show the "
        "evidence; `python -m thesis_repro claims --scale " + scale + " --json` prints all of it.",
        "",
        f"**{len(claims)} distinct thesis claims (design {ledger_json.get('design', {}).get('version', '')}):** "
        + ", ".join(f"{lab} {n}" for lab, n in label_counts(claims))
        + ". Under design v2 (the registered analysis of seeds 0-5, kept beside it): "
        + ", ".join(f"{lab} {n}" for lab, n in v2_counts(claims))
        + f". [What changed from v2, and why]({deviations.PAGE.as_posix()}).",
        "",
        "The *thesis's effect* column says whether our 95 % CI excludes the effect size the thesis itself reports "
        "(where it gives a number the claim's measure reads). The *thesis's budget* column judges the same frozen v3 "
        "rule on the thesis-budget study's runs (Fig 3.3's variants trained for the thesis's 4e6 steps, `make "
        "thesis-budget`), for the claims whose runs it retrains; *not computed (k of n runs)* until they are all made.",
    ]
    out += ["", fresh_counts(claims), "", fresh_summary(claims)]
    if ledger_json.get("stale_pages"):
        out += ["", "Stale (written by other kit code): " + ", ".join(ledger_json["stale_pages"]) + "."]
    for ch in sorted({_chapter(c) for c in claims}, key=lambda x: (not x.isdigit(), int(x) if x.isdigit() else x)):
        out += ["", f"## Chapter {ch}", "", claims_table([c for c in claims if _chapter(c) == ch])]
    if beyond:
        out += [
            "",
            "## Beyond the thesis",
            "",
            "The kit's own extensions (not counted above): "
            + ", ".join(f"{lab} {n}" for lab, n in label_counts(beyond))
            + ".",
            "",
            claims_table(beyond),
        ]
    return "\n".join(out) + "\n"


def readme_results(ledger_json: Mapping[str, Any], scale: str) -> str:
    """The README's results block: counts per label, and one line per thesis claim that does not reproduce."""
    claims = list(ledger_json.get("claims") or [])
    now, old = dict(label_counts(claims)), dict(v2_counts(claims))
    out = [
        f"At scale `{scale}` the shipped runs judge **{len(claims)}** distinct claims of the thesis:",
        "",
        "| verdict (design v3) | claims | under v2 |",
        "|---|---|---|",
        *(f"| {lab} | {n} | {old.get(lab, 0)} |" for lab, n in now.items()),
        *(f"| {lab} | 0 | {n} |" for lab, n in old.items() if lab not in now),
        "",
        fresh_counts(claims) + " " + fresh_summary(claims),
        "",
    ]
    first = next((c for c in claims if c.get(thesis_budget.KEY)), None)  # the headline claim comes first
    if first is not None:
        line = thesis_budget.thesis_budget_line(first[thesis_budget.KEY], first[thesis_budget.KEY].get("ours", ""))
        out += [f"The headline at the thesis's own budget: `{first.get('id')}`, {line}.", ""]
    against = [c for c in claims if does_not_reproduce(verdict_label(c))]
    if against:
        out.append("Claims that do not reproduce:")
        out.append("")
        out += [f"- `{c.get('id')}` ({thesis_lines(c)}): {short(c)}; ours: {ours(c)}" for c in against]
    else:
        out.append("No claim of the thesis is judged not to reproduce.")
    out += ["", "Every claim, with the thesis's value beside ours: [RESULTS.md](RESULTS.md)."]
    return "\n".join(out)


#: A verdict group of the book's scoreboard lists its claims one by one up to this many (else only its count).
LIST_AT_MOST = 10


def verdict_lists(ledger_json: Mapping[str, Any]) -> str:
    """The scoreboard's lists of which thesis claims got which verdict: one list per label with at most
    :data:`LIST_AT_MOST` claims (the larger groups by count only).

    >>> print(verdict_lists({"claims": [{"id": "a", "verdict": "reproduces", "claim": "x", "thesis_lines": [1]}]}))
    **reproduces (1):**
    <BLANKLINE>
    - `a` (l. 1): x
    """
    claims = list(ledger_json.get("claims") or [])
    blocks, big = [], []
    for lab, n in label_counts(claims):
        if n > LIST_AT_MOST:
            big.append(f"{n} {lab}")
            continue
        items = [f"- `{c.get('id')}` ({thesis_lines(c)}): {short(c)}" for c in claims if verdict_label(c) == lab]
        blocks.append(f"**{lab} ({n}):**\n\n" + "\n".join(items))
    if big:
        blocks.append("Not listed: " + ", ".join(big) + " (the chapter pages table every claim).")
    return "\n\n".join(blocks)


def scales_table(settings: Mapping[str, Mapping[str, Any]], descriptions: Mapping[str, str]) -> str:
    """The README's scale table from each scale's resolved default settings.

    >>> print(scales_table({"smoke": {"train_seeds": 1, "test_rollouts": 2, "sigmas": [0, 0.5],
    ...     "max_episode_steps": 50}}, {"smoke": "for CI"}))
    | scale | for | training seeds | test rollouts | testing σ grid | episode steps |
    |---|---|---|---|---|---|
    | `smoke` | for CI | 1 | 2 | 2 points, 0 to 0.5 | 50 |
    """
    rows = [
        "| scale | for | training seeds | test rollouts | testing σ grid | episode steps |",
        "|---|---|---|---|---|---|",
    ]
    for scale, s in settings.items():
        sig = list(s.get("sigmas") or [])
        grid = f"{len(sig)} points, {sig[0]:g} to {sig[-1]:g}" if sig else "-"
        cells = (
            f"`{scale}`",
            descriptions.get(scale, ""),
            s.get("train_seeds", "-"),
            s.get("test_rollouts", "-"),
            grid,
            s.get("max_episode_steps", "-"),
        )
        rows.append("| " + " | ".join(_cell(str(x)) for x in cells) + " |")
    return "\n".join(rows)


def replace_block(text: str, markers: tuple[str, str], body: str) -> str:
    """``text`` with the lines between ``markers`` replaced by ``body``; a ``ValueError`` when the markers are
    not there exactly once each, in order."""
    start, end = markers
    if text.count(start) != 1 or text.count(end) != 1 or text.index(start) > text.index(end):
        raise ValueError(f"README.md needs one {start} ... {end} block, in that order")
    head, rest = text.split(start, 1)
    _, tail = rest.split(end, 1)
    return f"{head}{start}\n{body.strip()}\n{end}{tail}"


def render_results(ledger_json: Mapping[str, Any], scale: str, readme: str, scale_rows: str) -> dict[str, str]:
    """{file name: its new text} for RESULTS.md, README.md (given its current text) and the book's fresh-seeds
    page."""
    text = replace_block(readme, RESULTS_MARKERS, readme_results(ledger_json, scale))
    return {
        "RESULTS.md": results_md(ledger_json, scale),
        "README.md": replace_block(text, SCALES_MARKERS, scale_rows),
        str(FRESH_PAGE): fresh_md(ledger_json, scale),
        str(deviations.PAGE): deviations.page(ledger_json, scale),
    }


# ---------------------------------------------------------------- gathering and writing
@contextlib.contextmanager
def snapshot_only() -> Iterator[None]:
    """Inside: the ledger sees no build pages, so it judges the shipped claims snapshot (as a fresh clone does)."""
    with tempfile.TemporaryDirectory(prefix="thesis-repro-results-") as empty:
        with mock.patch.dict(os.environ, {"THESIS_REPRO_BUILD": empty}):  # the whole environment comes back after
            os.environ.pop(paths.PUBLISHED_ENV, None)
            yield


def snapshot_ledger(scale: str) -> list[Row]:
    """Every claim judged at ``scale`` from the shipped snapshot alone, with the shipped calibration (v3's gate
    reads it; nothing is simulated here): what a fresh clone's ``claims`` prints."""
    with snapshot_only():
        return ledger.ledger(scale)


def ledger_json(scale: str, rows: Sequence[Row] | None = None) -> dict[str, Any]:
    """The ledger's JSON at ``scale`` from the shipped snapshot (``rows``: :func:`snapshot_ledger`'s, when already
    judged)."""
    rows = snapshot_ledger(scale) if rows is None else rows
    with snapshot_only():
        return scoreboard.as_json(list(rows), scale)


def more_seeds(scale: str) -> dict[str, int]:
    """The items whose block at ``scale`` reads more training seeds than the scale's default (an item's fresh seeds,
    once all are shipped): figure id -> its training seeds (chapter 5: its ``seeds`` list's length)."""
    default = int(scales.figure_settings("_example", scale)["train_seeds"])
    out = {}
    for fid in scales.figures():
        s = scales.figure_settings(fid, scale)
        n = len(s["seeds"]) if isinstance(s.get("seeds"), list) else int(s.get("train_seeds") or default)
        if n > default:
            out[fid] = n
    return out


def seeds_note(more: Mapping[str, Mapping[str, int]]) -> str:
    """The line under the scale table naming the items that read more seeds than their scale's default.

    >>> seeds_note({"smoke": {}, "small": {"3.4": 6, "table-3.5": 6, "5.3": 10}})[-41:]
    'Fig 3.4 (6), Table 3.5 (6), Fig 5.3 (10).'
    >>> seeds_note({"small": {}})
    ''
    """
    parts = []
    for scale, items in more.items():
        if items:
            named = ", ".join(
                f"{'Table ' + f.removeprefix('table-') if f.startswith('table-') else 'Fig ' + f} ({n})"
                for f, n in items.items()
            )
            parts.append(f"Items that read more training seeds at `{scale}` (their fresh seeds, all shipped): {named}.")
    return " ".join(parts)


def scale_rows() -> str:
    """The README's scale table, from ``thesis_repro/config/scales.yaml``, and the items that read more seeds."""
    descriptions = yamlfile.parse((paths.CONFIG / "scales.yaml").read_text())["scales"]
    table = scales_table({s: scales.figure_settings("_example", s) for s in scales.SCALES}, descriptions)
    note = seeds_note({s: more_seeds(s) for s in scales.SCALES})
    return f"{table}\n\n{note}" if note else table


def generated_files(scale: str = SCALE, root: Path | None = None, rows: Sequence[Row] | None = None) -> dict[Path, str]:
    """{path: text} of every generated file, rendered from the shipped snapshot (nothing is written; ``rows``:
    :func:`snapshot_ledger`'s, when already judged)."""
    root = Path(root) if root is not None else paths.ROOT
    readme = (root / "README.md").read_text()
    texts = render_results(ledger_json(scale, rows), scale, readme, scale_rows())
    return {root / name: text for name, text in texts.items()}


def main(argv: list[str] | None = None, parser: type[argparse.ArgumentParser] = argparse.ArgumentParser) -> int:
    """Write (or with ``--check`` compare) RESULTS.md and the README blocks; returns the exit code (``parser``:
    the command line's own class, whose errors are one line)."""
    warnings.simplefilter("ignore", RuntimeWarning)  # NaN means of cells a scale does not run
    ap = parser(prog=COMMAND, description=__doc__.split("\n")[0])
    ap.add_argument("--check", action="store_true", help="write nothing; exit 1 if a generated file is out of date")
    args = ap.parse_args(argv)
    stale = []
    for path, text in generated_files(SCALE).items():
        if (path.read_text() if path.exists() else None) == text:
            continue
        stale.append(path.name)
        if not args.check:
            path.write_text(text)
    if args.check:
        print(f"out of date: {', '.join(stale)}; `make results` rewrites them" if stale else "up to date")
        return 1 if stale else 0
    print(f"wrote {', '.join(stale)}" if stale else "RESULTS.md and README.md already up to date", file=sys.stderr)
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
