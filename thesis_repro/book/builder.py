"""Build the Jupyter Book (1.x, offline) of one scale: the thesis's claims, each page with its verdict.

One file on purpose (over 600 lines): every part serves :func:`build` alone (the command line is its only caller)
and changes with the book's layout: staging, the reader's copy of each executed page, the chapter verdict lists and the
scoreboard, the table of contents, the progress lines and the pending / failed pages. What other commands share
lives in their own modules (:mod:`thesis_repro.book.notebooks`: execution keys; :mod:`thesis_repro.book.pages`: a page's
runs; :mod:`thesis_repro.book.clips`: the clips; :mod:`thesis_repro.claims`: the verdicts).

``build(scale)`` stages a copy of ``book/`` in ``build/<scale>/book/`` and generates, in the copy only:

* one page per executed notebook (``executed/<page id>.ipynb``), *cleaned for readers*: progress bars,
  stderr and log lines removed, the parameters cells dropped, code inputs collapsed, and the thesis's
  caption and claims (``data/thesis/claims.yaml``) inserted under the page title;
* at the end of each ``chapter-N.md`` a list of the chapter's verdicts, one line each (from the notebooks'
  ``build/<scale>/figures/<page id>.verdicts.json``), and at the end of ``intro.md`` a scoreboard of the
  whole thesis at that scale;
* the table of contents (``_toc.yml``): chapter pages, each with its figures, then tables, then analyses;
* the page "Protocol: thesis beside kit" (``protocol.md``, :mod:`thesis_repro.book.protocol`), last in the contents;
* each guide notebook (``notebooks/guide-*.py``, :func:`thesis_repro.book.notebooks.is_guide`) as a page of its own
  among the guides (:func:`prepare_guide`: its code shown, no thesis claims, no verdict);
* the chapter-3 landing page's clips of the basic learners (:func:`thesis_repro.book.clips.book_clips`).

Execution cache: a notebook whose executed copy carries today's execution key (notebook source, scale,
parameters, ``THESIS_REPRO_RETRAIN``, the kit modules it imported, configuration and thesis data; see
:func:`thesis_repro.book.notebooks.execution_key`) is not executed again; ``force=True`` re-executes everything,
``reuse=True`` takes any executed copy. A notebook that fails gets an error page; the build then raises.

``shipped_only=True`` (``make book SCALE=small SHIPPED_ONLY=1``) executes only the notebooks whose training
runs are all shipped or cached; each other page says how many of its runs are still to train and how to
train them, and counts as *no verdict* (a book in minutes while the shipped runs are still landing).

>>> clean_stream("train:  50%|#####     | 1/2 [00:01<00:01, 1.0it/s]\\rtrain: 100%|##########| 2/2\\nAUC 3.2\\n")
'AUC 3.2\\n'
>>> md_cell("x")["cell_type"]
'markdown'
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import re
import shutil
import subprocess
import sys
import time
from collections import Counter
from functools import cache
from pathlib import Path
from typing import Any

import yaml

from thesis_repro.book import notebooks, protocol, warm_kernels
from thesis_repro.claims import ledger, readings, registry, report, results
from thesis_repro.claims import scoreboard as claims_scoreboard
from thesis_repro.core import paths, yamlfile
from thesis_repro.core.scales import check_scale

#: Lines of a stream output that are progress or log, not content (tqdm bars, file logs, verdict echo).
_NOISE = re.compile(
    r"(\d+%\|)|(\bit/s\])|(\bs/it\])|(^\s*saved\s+/)|(^\[thesis_repro\])"
    r"|(^\[[^\]]+\] (" + "|".join(re.escape(s.upper()) for s in report.STATUSES) + r")( - | · ))"
)
#: ``text/plain``-only reprs of matplotlib objects left by a cell's last expression.
_MPL_REPR = re.compile(r"^[\[(]?\s*<(matplotlib|Figure|Axes|seaborn)")
_LABELS = {"fig": "Figure", "table": "Table", "analysis": "Analysis"}
_SHORT = {
    report.REPRODUCES: "reproduces",
    report.PARTLY: "partly",
    report.DOES_NOT: "does not",
    report.NOT_RUN: "not run",
    report.NOT_JUDGED: "not judged",
}
NO_VERDICT = "no verdict"


#: LaTeX of the thesis's captions shown as text (the offline book has no MathJax).
_TEX = {
    r"\mathcal{U}": "U",
    r"\mathcal{N}": "N",
    r"\mathcal{W}": "W",
    r"\mathcal{L}": "L",
    r"\mathbb{E}": "E",
    r"\sigma": "σ",
    r"\Sigma": "Σ",
    r"\times": "×",
    r"\xi": "ξ",
    r"\sim": "~",
    r"\theta": "θ",
    r"\eta": "η",
    r"\pi": "π",
    r"\rightarrow": "→",
    r"\cdot": "·",
    r"\pm": "±",
    r"\alpha": "α",
    r"\gamma": "γ",
    r"\epsilon": "ε",
    r"\leq": "≤",
    r"\geq": "≥",
    r"\approx": "≈",
    r"\ldots": "…",
    r"\|": "‖",
}


def plain_math(text: str) -> str:
    """The thesis's inline LaTeX as plain text: ``$\\sigma_{tr} = 0.2$`` -> ``σ_tr = 0.2``.

    >>> plain_math(r"(a): $c_a = 0.001$, $\\xi \\sim \\mathcal{U}(-0.5, 0.5)$; 12 seeds \\times 20")
    '(a): c_a = 0.001, ξ ~ U(-0.5, 0.5); 12 seeds × 20'
    """
    for tex, uni in _TEX.items():
        text = text.replace(tex, uni)
    text = re.sub(r"\\text\{([^}]*)\}", r"\1", text)
    text = re.sub(r"\\[A-Za-z]+", lambda m: m.group(0)[1:], text)  # any other macro: its name
    text = re.sub(r"([_^])\{([^{}]*)\}", r"\1\2", text)  # x_{tr} -> x_tr
    return text.replace("$", "").replace("{", "").replace("}", "")


@cache
def claims() -> dict[str, dict[str, Any]]:
    """The thesis's caption and claims per page id, from ``data/thesis/claims.yaml``."""
    return yamlfile.parse((paths.THESIS_DATA / "claims.yaml").read_text())


def title(page: str) -> str:
    """Reader-facing name of a page id: ``"Figure 3.3"``, ``"Table 3.4"``, ``"Analysis 4-kl"``."""
    kind, rest = page.split("-", 1)
    return f"{_LABELS.get(kind, kind)} {rest}"


def md_cell(text: str, tags: list[str] | None = None) -> dict[str, Any]:
    """A markdown notebook cell (nbformat 4.5 dict, with a content-derived id)."""
    cid = "tr-" + hashlib.sha1(text.encode()).hexdigest()[:12]
    return {"cell_type": "markdown", "id": cid, "metadata": {"tags": tags or []}, "source": text}


def clean_stream(text: str) -> str:
    """Drop progress-bar, log and verdict-echo lines; a carriage return keeps only the text after it."""
    kept = []
    for line in text.split("\n"):
        line = line.rsplit("\r", 1)[-1]
        if _NOISE.search(line):
            continue
        kept.append(line)
    out = "\n".join(kept)
    return "" if not out.strip() else re.sub(r"\n{3,}", "\n\n", out.lstrip("\n"))


def _text(x: Any) -> str:
    return "".join(x) if isinstance(x, list) else str(x)


def clean_outputs(outputs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Outputs fit for a reader: no stderr, no progress/log lines, no bare matplotlib reprs."""
    kept: list[dict[str, Any]] = []
    for o in outputs:
        kind = o.get("output_type")
        if kind == "stream":
            if o.get("name") == "stderr":
                continue
            text = clean_stream(_text(o.get("text", "")))
            if not text:
                continue
            if kept and kept[-1].get("output_type") == "stream":  # one block per run of prints
                kept[-1] = {**kept[-1], "text": _text(kept[-1]["text"]) + text}
                continue
            o = {**o, "text": text}
        elif kind in ("execute_result", "display_data"):
            data = o.get("data", {})
            if set(data) == {"text/plain"} and _MPL_REPR.match(_text(data["text/plain"])):
                continue
        kept.append(o)
    return kept


def verdict_line(v: report.Verdict) -> str:
    """A verdict's one line for a page: design v3's label with design v2's beside it, then the rest of its
    headline (id · claim · thesis · ours with its CI), or its claim when it was saved without one.

    >>> v = report.Verdict("3.3", "c", report.INCONCLUSIVE, headline="inconclusive · 3.3-x · l. 5 c", v2="reproduces")
    >>> verdict_line(v)
    '**inconclusive** (v2: reproduces) · 3.3-x · l. 5 c'
    """
    rest = v.headline.partition(" · ")[2] if v.headline else v.claim
    beside = f" ({v.v2_text()})" if v.v2 else ""
    return f"**{v.status}**{beside} · {_escape_md(rest)}"


def budget_sentence(verdicts: list[report.Verdict]) -> str:
    """The page's answer at the thesis's budget, for its first line: the thesis-budget line of its first claim that
    has one (the headline claim, listed first), a verdict or that the study's runs are not computed yet (k of n);
    ``""`` for a page whose runs the thesis-budget study does not retrain.

    >>> v = report.Verdict("3.3", "c", report.DOES_NOT, headline="does not reproduce · 3.3-x · l. 5 c",
    ...     thesis_budget="thesis's budget (4M steps): not computed (0 of 108 runs)")
    >>> budget_sentence([v])
    "**At the thesis's budget (4M steps):** 3.3-x not computed (0 of 108 runs)."
    """
    first = next((v for v in verdicts if v.thesis_budget), None)
    if first is None:
        return ""
    parts = first.headline.split(" · ")
    cid = parts[1] if len(parts) > 1 else first.claim
    where, _, said = first.thesis_budget.partition("): ")
    head = f"At the {where})" if said else "At the thesis's budget"
    return f"**{_escape_md(head)}:** {_escape_md(cid)} {_escape_md(said or first.thesis_budget)}."


def verdicts_cell(page: str, scale: str) -> dict[str, Any] | None:
    """The page's verdicts first, one line per claim (:func:`verdict_line`), each with its confirmatory line and its
    thesis-budget line under it when they exist, or None when the page saved none; for a page whose runs the
    thesis-budget study retrains, the cell opens with whether its headline claim holds at the thesis's budget
    (:func:`budget_sentence`); each verdict's evidence stays at the end of the page."""
    saved = report.load_verdicts(page, scale)
    lines = [
        f"- {verdict_line(v)}"
        + (f"\n  - *{_escape_md(v.confirmatory)}*" if v.confirmatory else "")
        + (f"\n  - *{_escape_md(v.thesis_budget)}*" if v.thesis_budget else "")
        for v in saved
    ]
    if not lines:
        return None
    budget = budget_sentence(saved)
    head = (
        (f"{budget} The verdicts below are at this scale's budgets.\n\n" if budget else "")
        + "**Verdicts** (claims design v3, design v2's verdict beside each; each one's evidence is at the end of the "
        "page):\n\n"
    )
    return md_cell(head + "\n".join(lines))


def _escape_md(text: str) -> str:
    return text.replace("*", "\\*").replace("_", "\\_")


#: Chapters whose pages say in one line whether the thesis reports its curves' values (chapter 4: plots only).
CURVE_CHAPTERS: tuple[str, ...] = ("4",)


def thesis_values(page: str) -> list[Path]:
    """The thesis's transcribed values for ``page`` in ``data/thesis/`` (``fig-4.3`` -> ``fig4_3*.csv``).

    >>> thesis_values("fig-4.3"), [p.name for p in thesis_values("fig-3.3")]
    ([], ['fig3_3c.csv'])
    """
    kind, _, rest = page.partition("-")
    return sorted(paths.THESIS_DATA.glob(f"{kind}{rest.replace('.', '_')}*.csv"))


def thesis_values_line(page: str) -> str | None:
    """For a page of :data:`CURVE_CHAPTERS`, one line: the thesis's values shown beside ours (which file), or that
    the thesis reports none; None for other chapters.

    >>> thesis_values_line("fig-4.3")
    '**Thesis values:** none; the thesis shows Figure 4.3 as a plot with no numbers, so the curves are ours alone.'
    >>> thesis_values_line("fig-3.3") is None, "kit's own" in thesis_values_line("analysis-4-kl")
    (True, True)
    """
    if notebooks.page_chapter(page) not in CURVE_CHAPTERS:
        return None
    files = thesis_values(page)
    if files:
        names = ", ".join(f"`data/thesis/{f.name}`" for f in files)
        return f"**Thesis values:** {names}, shown beside ours and labelled *thesis*."
    if not page.startswith("fig-"):
        return "**Thesis values:** none; this analysis is the kit's own, with no figure of the thesis behind it."
    plot = f"the thesis shows {title(page)} as a plot with no numbers"
    return f"**Thesis values:** none; {plot}, so the curves are ours alone."


def thesis_cell(page: str, scale: str) -> dict[str, Any]:
    """The page's opening: the thesis's caption and claims, quoted with line references, and the scale."""
    entry = claims().get(page)
    label = title(page)
    lines = []
    if entry is None:
        lines.append(f"```{{admonition}} {label} in the thesis\n:class: note\n")
        lines.append("This page has no entry in `data/thesis/claims.yaml` yet.\n```\n")
    else:
        lines.append(f"```{{admonition}} {label} in the thesis: {entry['title']}\n:class: note\n")
        if entry.get("caption"):
            lines.append(f"**Caption** (thesis, line {entry['caption_line']}): {plain_math(entry['caption'])}\n")
        for c in entry.get("claims", []):
            where = ", ".join(str(n) for n in c["lines"])
            lines.append(f"- **Claim** (thesis, line {where}): “{plain_math(c['text'])}”")
        if values := thesis_values_line(page):
            lines.append(f"\n{values}")
        lines.append("```\n")
    cmd = f"make {page if not page.startswith('fig-') else 'figure-' + page[4:]} SCALE={scale}"
    if page.startswith("analysis-"):
        cmd = f"python -m thesis_repro figure {page} --scale {scale}"
    lines.append(
        f"Executed at scale **`{scale}`** (`{cmd}`). Numbers labelled *thesis* are the thesis's own; "
        "numbers labelled *reproduced* were computed by the kit. Each verdict's evidence is at the end of the page."
    )
    return md_cell("\n".join(lines))


def reader_cells(nb: dict[str, Any], hide_input: bool) -> list[dict[str, Any]]:
    """An executed notebook's cells as a reader sees them: parameters cells dropped, outputs cleaned
    (:func:`clean_outputs`), and with ``hide_input`` the code folded away."""
    cells = []
    for cell in nb["cells"]:
        tags = cell.get("metadata", {}).get("tags", [])
        if "parameters" in tags or "injected-parameters" in tags:
            continue
        cell = dict(cell)
        if cell["cell_type"] == "code":
            cell["outputs"] = clean_outputs(cell.get("outputs", []))
            if hide_input and "hide-input" not in tags:
                cell["metadata"] = {**cell.get("metadata", {}), "tags": [*tags, "hide-input"]}
        cells.append(cell)
    return cells


def prepare_page(nb: dict[str, Any], nid: str, scale: str) -> dict[str, Any]:
    """A reader's copy of an executed notebook (see the module docstring)."""
    page = notebooks.page_id(nid)
    cells = reader_cells(nb, hide_input=True)
    first = next((i for i, c in enumerate(cells) if c["cell_type"] == "markdown"), None)
    if first is not None and _text(cells[first]["source"]).lstrip().startswith("# "):
        head, _, rest = _text(cells[first]["source"]).lstrip().partition("\n")
        cells[first] = {**cells[first], "source": head}
        at = first + 1
        if rest.strip():  # the notebook's own introduction follows the thesis's claims
            cells.insert(at, {**md_cell(rest.strip()), "metadata": dict(cells[first].get("metadata", {}))})
    else:
        cells.insert(0, md_cell(f"# {title(page)}"))
        at = 1
    cells.insert(at, thesis_cell(page, scale))
    first_verdicts = verdicts_cell(page, scale)
    if first_verdicts is not None:
        cells.insert(at, first_verdicts)
    if not report.load_verdicts(page, scale):
        cells.append(
            md_cell(
                f"```{{admonition}} No computed verdict\n:class: warning\n"
                f"This page wrote no `{page}.verdicts.json` at scale `{scale}`.\n```\n"
            )
        )
    out = dict(nb)
    out["cells"] = cells
    return out


def prepare_guide(nb: dict[str, Any], nid: str, scale: str) -> dict[str, Any]:
    """A reader's copy of an executed guide notebook: parameters cells dropped, outputs cleaned, the code shown
    (a guide teaches the calls), and under its title the scale it ran at; no thesis claims, no verdict."""
    cells = reader_cells(nb, hide_input=False)
    cmd = f"python -m thesis_repro figure {notebooks.page_id(nid)} --scale {scale}"
    line = md_cell(f"Executed at scale **`{scale}`** (`{cmd}`); a guide, not a thesis item: no verdict.")
    first = next((i for i, c in enumerate(cells) if c["cell_type"] == "markdown"), None)
    if first is None:
        return {**nb, "cells": [line, *cells]}
    head, _, rest = _text(cells[first]["source"]).lstrip().partition("\n")
    if not head.startswith("# "):  # no title line: the scale first
        return {**nb, "cells": [*cells[:first], line, *cells[first:]]}
    intro = [md_cell(rest.strip())] if rest.strip() else []
    return {**nb, "cells": [*cells[:first], {**cells[first], "source": head}, line, *intro, *cells[first + 1 :]]}


def page_file(nid: str) -> str:
    """Where a notebook's page goes in the book, without suffix: ``executed/<page id>`` for a thesis page,
    ``<page id>`` (beside the static guides) for a guide.

    >>> page_file("3.3"), page_file("guide-score-agent")
    ('executed/fig-3.3', 'guide-score-agent')
    """
    page = notebooks.page_id(nid)
    return page if notebooks.is_guide(nid) else f"executed/{page}"


def _status_counts(verdicts: list[report.Verdict]) -> Counter:
    return Counter(v.status for v in verdicts)


def _escape(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ").strip()


def chapter_summary(chapter: str, executed: list[str], scale: str, notes: dict[str, str] | None = None) -> str:
    """The verdicts of a chapter's pages at ``scale``: per page, one line per claim (:func:`verdict_line`: design
    v3's label with v2's beside it; the saved evidence for a verdict without a one-line headline; the full evidence
    is on its page), a list rather than a table so the line keeps the text column's width; pages without a verdict
    are listed too, with ``notes[page]`` as the reason, else "not in this build"."""
    pages = [notebooks.page_id(n) for n in executed if notebooks.page_chapter(n) == chapter]
    known = [p for p in claims() if p.split("-", 1)[1].split("-")[0].split(".")[0] == chapter]
    items = []
    for page in pages:
        verdicts = report.load_verdicts(page, scale)
        link = f"{{doc}}`{title(page)} <executed/{page}>`"
        if not verdicts:
            items.append(f"- {link}: {NO_VERDICT} (no verdict written)")
            continue
        lines = [  # each verdict's one line; a verdict saved without one shows its evidence (escaped: one line)
            f"  - {verdict_line(v)}" + ("" if v.headline or not v.evidence else f": {_escape_md(_escape(v.evidence))}")
            for v in verdicts
        ]
        items.append(f"- {link}\n" + "\n".join(lines))
    for page in (p for p in known if p not in pages):
        why = _escape((notes or {}).get(page, "not in this build"))
        items.append(f"- {title(page)} ({_escape(claims()[page]['title'])}): {NO_VERDICT}: {why}")
    head = f"\n\n## Verdicts at scale `{scale}`\n\n"
    lead = (
        "One line per claim judged by the kit: design v3's verdict, design v2's beside it (*v2: same* when they "
        "agree), then the claim, the thesis's number and ours with its 95 % CI. *Thesis* numbers come from "
        "`data/thesis/`, ours from this build's runs; each page holds the evidence. Pages of the thesis with no "
        "notebook (or not executed) are listed as *no verdict*.\n\n"
    )
    return head + lead + "\n".join(items) + "\n"


#: The chapter whose page opens with the answer over the readings of its method (:func:`readings.answer`).
READINGS_CHAPTER = "4"
#: The summary of the folded list under that answer: each claim's verdict per reading.
READINGS_LIST = "Each claim's verdict per reading of the update"


def readings_opening(rows: list[dict[str, Any]]) -> str:
    """The chapter-4 page's opening: the answer over the readings (:func:`readings.answer`), then each claim's
    verdict per reading folded under it, so that the page's first verdict stays on its first screen ("" when no
    claim is judged by reading). ``rows``: ``claims --json``'s rows.

    >>> e = {"reading": "kl-diag", "verdict": "inconclusive", "ours": "0/4 units yes", "judged_on": "params_avg"}
    >>> text = readings_opening([{"id": "4.3-wind", "readings": [e]}])
    >>> text.startswith("**No") and "<details><summary>Each claim's verdict per reading" in text
    True
    """
    line = readings.answer(rows)
    if not line:
        return ""
    return f"{line}\n\n<details><summary>{READINGS_LIST}</summary>\n\n{readings.verdict_list(rows)}\n\n</details>"


def open_with(page: str, line: str) -> str:
    """``page`` (markdown) with ``line`` as its first paragraph, under its title.

    >>> open_with("# Title\\n\\nText.\\n", "**Answer.**")
    '# Title\\n\\n**Answer.**\\n\\nText.\\n'
    >>> open_with("# Title\\n", "")
    '# Title\\n'
    """
    if not line:
        return page
    title, _, rest = page.partition("\n")
    return "\n\n".join((title, line, rest.lstrip("\n")))


def book_scoreboard(executed: list[str], scale: str, rows: list[Any] | None = None) -> str:
    """The scoreboard of distinct thesis claims at ``scale``, read from the claims ledger (the claims ledger:
    :func:`thesis_repro.claims.scoreboard.scoreboard`, the same ledger as ``python -m thesis_repro claims``),
    with the beyond-the-thesis count and the method section (each rule's null pass rate). ``executed`` is
    kept for the caller; the ledger judges every registered claim from the numbers the pages saved."""
    rows = ledger.ledger(scale) if rows is None else rows
    head, sep, method = claims_scoreboard.scoreboard(scale, rows).partition(_METHOD)
    return f"{head}\n\n{results.verdict_lists(claims_scoreboard.as_json(rows, scale))}\n{sep}{method}"


#: Where ``intro.md`` takes the scoreboard (else it is appended); the method section goes last either way.
SCOREBOARD_MARK = "<!-- scoreboard -->"
_METHOD = "\n\n## Method"


def place_scoreboard(intro: str, board: str) -> str:
    r"""``intro`` with the scoreboard ``board`` at :data:`SCOREBOARD_MARK` and its method section at the end.

    >>> place_scoreboard("# T\n<!-- scoreboard -->\nHow to read", "\n\n## Scoreboard\n\n## Method\nm")
    '# T\n\n\n## Scoreboard\nHow to read\n\n## Method\nm'
    >>> place_scoreboard("# T", "\n\n## Scoreboard")
    '# T\n\n## Scoreboard'
    """
    if SCOREBOARD_MARK not in intro:
        return intro + board
    head, sep, method = board.partition(_METHOD)
    return intro.replace(SCOREBOARD_MARK, head, 1) + sep + method


#: Static pages of ``book/`` on how the kit works (moved out of the README), last in the contents, in this order.
GUIDES: tuple[str, ...] = ("kit", "runs", "learners", "cluster")


def chapter_pages(root: Path) -> list[Path]:
    """The chapter landing pages ``chapter-N.md`` of a book folder, in chapter order (not their static sections
    ``chapter-N-<name>.md``)."""
    found = [p for p in root.glob("chapter-*.md") if p.stem.split("-", 1)[1].isdigit()]
    return sorted(found, key=lambda p: int(p.stem.split("-", 1)[1]))


def write_toc(executed: list[str], root: Path) -> Path:
    """Write ``<root>/_toc.yml``: each ``chapter-N.md`` with its pages (figures, tables, analyses, then its static
    pages ``chapter-N-<name>.md``), the protocol page, then the guide notebooks among ``executed`` and the static
    :data:`GUIDES`."""
    chapters = []
    for md in chapter_pages(root):
        num = md.stem.split("-", 1)[1]
        ids = sorted((n for n in executed if notebooks.page_chapter(n) == num), key=notebooks.sort_key)
        entry: dict = {"file": md.stem}
        sections = [{"file": f"executed/{notebooks.page_id(n)}"} for n in ids]
        sections += [{"file": p.stem} for p in sorted(root.glob(f"chapter-{num}-*.md"))]
        if sections:
            entry["sections"] = sections
        chapters.append(entry)
    if (root / "deviations.md").exists():  # design v3: what changed from v2, and why (generated by `make results`)
        chapters.append({"file": "deviations"})
    if (root / "claims-design-v2.md").exists():  # the claims design: what changed from v1, and why
        chapters.append({"file": "claims-design-v2"})
    if (root / "fresh-seeds.md").exists():  # the confirmatory check (generated by `make results`)
        chapters.append({"file": "fresh-seeds"})
    if (root / "protocol.md").exists():  # generated by thesis_repro.book.protocol (build)
        chapters.append({"file": "protocol"})
    chapters += [{"file": page_file(n)} for n in executed if notebooks.is_guide(n)]
    chapters += [{"file": g} for g in GUIDES if (root / f"{g}.md").exists()]
    toc = {"format": "jb-book", "root": "intro", "chapters": chapters}
    out = root / "_toc.yml"
    out.write_text("# generated by thesis_repro.book.builder -- do not edit\n" + yaml.safe_dump(toc, sort_keys=False))
    return out


def stage(root: Path) -> None:
    """Copy the book's sources (everything in ``book/`` but build products) into ``root``; keep ``_build``."""
    root.mkdir(parents=True, exist_ok=True)
    for p in root.iterdir():
        if p.name != "_build":
            shutil.rmtree(p) if p.is_dir() else p.unlink()
    skip = {"_build", "executed", "_toc.yml"}
    for src in paths.BOOK.iterdir():
        if src.name in skip or src.name.startswith("."):
            continue
        dst = root / src.name
        shutil.copytree(src, dst) if src.is_dir() else shutil.copy(src, dst)


def execution_order(ids: list[str]) -> list[str]:
    """``ids`` (notebook ids, book order) with each page moved after the pages whose saved numbers its claims
    read (:func:`thesis_repro.claims.registry.reads`), so a verdict repeated on Fig 3.4 from Table 3.4 is shown
    there; pages outside ``ids`` are not added. Otherwise book order.

    >>> execution_order(["3.3", "3.4", "table-3.4"])
    ['3.3', 'table-3.4', '3.4']
    """
    by_page = {notebooks.page_id(n): n for n in ids}
    out: list[str] = []
    seen: set[str] = set()

    def visit(nid: str) -> None:
        if nid in seen:
            return
        seen.add(nid)
        for other in sorted(registry.reads(notebooks.page_id(nid)), key=lambda p: ids.index(by_page.get(p, nid))):
            if other in by_page:
                visit(by_page[other])
        out.append(nid)

    for nid in ids:
        visit(nid)
    return out


def progress_line(i: int, n: int, page: str, action: str) -> str:
    """The line saying which notebook the book is on.

    >>> progress_line(7, 24, "fig-3.6", "executing ...")
    '[7/24] fig-3.6 executing ...'
    """
    return f"[{i}/{n}] {page} {action}"


class BookProgress:
    r"""Which notebook the book is on: one plain line per notebook (:func:`progress_line`); in a terminal (``bar``:
    force it; default: whether ``stream`` is a TTY) also a tqdm bar below the output, which the notebooks' printed
    lines pass above while it is open (a context manager).

    >>> import io; out = io.StringIO()
    >>> with BookProgress(2, out) as p:
    ...     p.step("fig-3.3", "up to date")
    >>> out.getvalue()
    '[1/2] fig-3.3 up to date\n'
    """

    def __init__(self, total: int, stream: Any = None, bar: bool | None = None):
        self.total, self.done = total, 0
        self.stream = sys.stdout if stream is None else stream
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)()) if bar is None else bar
        self.bar: Any = None
        self._exit = contextlib.ExitStack()

    def __enter__(self) -> BookProgress:
        if self.tty:
            from tqdm import tqdm
            from tqdm.contrib import DummyTqdmFile

            self.bar = tqdm(total=self.total, file=self.stream, bar_format="{desc} |{bar}| {elapsed}", leave=False)
            self._exit.callback(self.bar.close)
            self._exit.enter_context(contextlib.redirect_stdout(DummyTqdmFile(self.stream)))
        return self

    def __exit__(self, *exc: Any) -> None:
        self._exit.close()
        self.bar = None

    def step(self, page: str, action: str) -> None:
        """The next notebook, ``page``, and what happens to it (``executing ...``, ``up to date``, ...)."""
        self.done += 1
        line = progress_line(self.done, self.total, page, action)
        if self.bar is None:
            print(line, file=self.stream, flush=True)
            return
        self.bar.write(line, file=self.stream)  # above the bar
        self.bar.update(1)
        self.bar.set_description_str(f"[{self.done}/{self.total}] {page}")  # redrawn now: it may run for minutes


def _git_rev() -> str:
    try:
        out = subprocess.run(
            ["git", "-C", str(paths.ROOT), "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=True
        )
        return out.stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def build(
    scale: str,
    reuse: bool = False,
    ids: list[str] | None = None,
    root: Path | None = None,
    force: bool = False,
    shipped_only: bool = False,
) -> Path:
    """Execute (or reuse up-to-date) notebooks at ``scale`` and build the HTML book; returns ``index.html``.

    ``root`` (default ``build/<scale>/book``) receives the staged sources and ``_build/html``;
    ``shipped_only`` leaves out (with a page saying why) the notebooks that would have to train.
    """
    check_scale(scale)
    t0 = time.time()
    ids = notebooks.notebook_ids(guides=True) if ids is None else [notebooks.check_notebook(n) for n in ids]
    root = Path(root) if root is not None else paths.build_dir(scale) / "book"
    stage(root)
    protocol.write_page(root)
    (root / "executed").mkdir()
    ran, kept, failed, pending = [], [], {}, {}
    order = execution_order(ids)  # pages read by other pages' claims first; the TOC keeps book order
    with BookProgress(len(order)) as progress, warm_kernels.warm_kernels():  # kernels forked, imports done
        for nid in order:
            total, todo = untrained(nid, scale) if shipped_only else (0, [])
            if todo:
                page_id = notebooks.page_id(nid)
                pending[page_id] = pending_note(nid, scale, total, len(todo))
                progress.step(page_id, f"not run: {len(todo)}/{total} training runs to compute")
                page = pending_page(nid, scale, pending[page_id])
                (root / f"{page_file(nid)}.ipynb").write_text(json.dumps(page, indent=1, ensure_ascii=False))
                continue
            src = notebooks.executed_path(nid, scale)
            fresh = src.exists() and (reuse or notebooks.is_current(nid, scale))
            try:
                if force or not fresh:
                    ran.append(nid)
                    progress.step(notebooks.page_id(nid), "executing ...")
                    src = notebooks.execute_notebook(nid, scale)
                else:
                    kept.append(nid)
                    progress.step(notebooks.page_id(nid), "up to date")
                prepare = prepare_guide if notebooks.is_guide(nid) else prepare_page
                page = prepare(json.loads(src.read_text()), nid, scale)
            except Exception as err:  # one broken notebook must not sink an hour-long build: report it at the end
                failed[nid] = (
                    _last_line(err)
                    if isinstance(err, notebooks.NotebookError)
                    else f"{type(err).__name__}: {_last_line(err)}"
                )
                print(
                    f"[thesis_repro] {notebooks.page_id(nid)} FAILED at scale {scale}: {failed[nid]}", file=sys.stderr
                )
                page = failed_page(nid, scale, failed[nid])
            (root / f"{page_file(nid)}.ipynb").write_text(json.dumps(page, indent=1, ensure_ascii=False))
    from thesis_repro.book import clips  # local: it loads the evaluation layer (torch); only this last step needs it

    clips.book_clips(root, scale)
    judged = [n for n in ids if notebooks.page_id(n) not in pending]
    rows = ledger.ledger(scale)
    for md in chapter_pages(root):
        chapter = md.stem.split("-", 1)[1]
        if chapter == READINGS_CHAPTER and scale != "smoke":
            md.write_text(open_with(md.read_text(), readings_opening([r.as_dict() for r in rows])))
        with md.open("a") as f:
            f.write(chapter_summary(chapter, judged, scale, pending))
    intro = root / "intro.md"
    built = f"\n_Built at scale `{scale}` from commit `{_git_rev()}` on {time.strftime('%Y-%m-%d %H:%M')}._\n"
    intro.write_text(place_scoreboard(intro.read_text(), book_scoreboard(judged, scale, rows)) + built)
    write_toc(ids, root)
    jb = Path(sys.executable).parent / "jupyter-book"
    done = subprocess.run([str(jb), "build", str(root), "--quiet"], capture_output=True, text=True)
    warnings = [ln for ln in (done.stdout + done.stderr).splitlines() if "WARNING" in ln or "ERROR" in ln]
    if done.returncode != 0:
        print(done.stdout + done.stderr, file=sys.stderr)
        raise RuntimeError(f"jupyter-book build of {root} failed (exit {done.returncode}); its output is above")
    for ln in warnings:
        print(ln, file=sys.stderr)
    index = root / "_build" / "html" / "index.html"
    print(
        f"[thesis_repro] book ({scale}) built in {time.time() - t0:.0f} s "
        f"({len(ran)} notebook(s) executed, {len(kept)} up to date"
        + (f", {len(pending)} not run: runs to train" if pending else "")
        + f"): {index}"
    )
    from thesis_repro.claims import snapshot  # the book reads the claims layer's snapshot only to say it is out of date

    if hint := snapshot.refresh_hint(scale):
        print(f"[thesis_repro] {hint}")
    if failed:
        names = ", ".join(notebooks.page_id(n) for n in failed)
        raise RuntimeError(f"{len(failed)} notebook(s) failed at scale {scale} ({names}); their pages say so: {index}")
    return index


def _last_line(err: BaseException) -> str:
    """The last non-empty line of an error (papermill's errors carry the whole traceback)."""
    ename, evalue = getattr(err, "ename", None), getattr(err, "evalue", None)
    if ename:
        return f"{ename}: {evalue}".splitlines()[0]
    lines = [ln for ln in str(err).splitlines() if ln.strip()]
    return lines[-1] if lines else repr(err)


def untrained(nid: str, scale: str) -> tuple[int, list[Any]]:
    """(number of training runs, those neither cached nor shipped) of notebook ``nid`` at ``scale``."""
    from thesis_repro import figures
    from thesis_repro.runs import costs as plan  # local: figure modules import the learners

    if nid not in figures.ids():
        return 0, []
    jobs = list({j.key: j for j in figures.training_jobs(nid, scale)}.values())
    return len(jobs), plan.to_compute(jobs)


def pending_note(nid: str, scale: str, total: int, todo: int) -> str:
    """Why a page was not executed by a ``shipped_only`` build, and the commands that would execute it."""
    return (
        f"not built: {todo} of its {total} training runs are neither shipped nor cached; "
        f"`make figure-{notebooks.page_id(nid).removeprefix('fig-')} SCALE={scale}` trains them "
        f"(cost first: `make plan-{nid} SCALE={scale} MISSING=1`)"
    )


def pending_page(nid: str, scale: str, note: str) -> dict[str, Any]:
    """Page of a notebook a ``shipped_only`` build did not execute: title, the thesis's claims and why."""
    page = notebooks.page_id(nid)
    head = f"```{{admonition}} Not run in this build (scale {scale})\n:class: warning\n"
    body = f"{head}{note[0].upper()}{note[1:]}.\n```\n"
    return _page([md_cell(f"# {title(page)}"), thesis_cell(page, scale), md_cell(body)])


def _page(cells: list[dict[str, Any]]) -> dict[str, Any]:
    meta = {"kernelspec": {"name": "python3", "display_name": "Python 3", "language": "python"}}
    return {"cells": cells, "metadata": meta, "nbformat": 4, "nbformat_minor": 5}


def failed_page(nid: str, scale: str, error: str) -> dict[str, Any]:
    """Page of a notebook that failed to execute: its title, the thesis's claims and the error's last line."""
    page = notebooks.page_id(nid)
    body = (
        f"```{{admonition}} Execution failed at scale {scale}\n:class: error\n"
        f"`{error}`\n\nThe failed notebook, with its traceback: `{paths.shown(notebooks.failed_path(nid, scale))}` "
        f"(`python -m thesis_repro figure {page} --scale {scale}` runs it again).\n```\n"
    )
    return _page([md_cell(f"# {title(page)}"), thesis_cell(page, scale), md_cell(body)])
