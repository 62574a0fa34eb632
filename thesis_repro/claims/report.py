"""Verdicts: one wording for "does the thesis's claim reproduce at this scale?", and how a page prints and saves them.

The claims layer (:func:`thesis_repro.claims.judge_page`, the last call of every figure and table
notebook) judges a page's numbers into :class:`Verdict` objects and hands them to ``report(figure, scale,
verdicts)``, which prints one line per claim (the terminal and the executed notebook), displays each as a
visible admonition in the book, and writes ``build/<scale>/figures/<figure>.verdicts.json`` for the chapter
summaries (:mod:`thesis_repro.book.builder`). The figure layer computes numbers only and builds no verdict.

>>> v = Verdict("3.3", "Training return and testing AUC are negatively correlated",
...             REPRODUCES, "15/20 cells negative (thesis: 18/20)")
>>> print(v)
[3.3] REPRODUCES - Training return and testing AUC are negatively correlated: 15/20 cells negative (thesis: 18/20)
>>> decide(None, "smoke").status
'not judged at this scale'
>>> Verdict("3.3", "claim", "maybe", "")  # doctest: +ELLIPSIS
Traceback (most recent call last):
...
ValueError: unknown verdict status 'maybe'; valid verdict statuses are: 'reproduces', ...
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

from thesis_repro.core import paths, stamps
from thesis_repro.core.scales import NOT_RUN  # the words a figure's table uses too
from thesis_repro.core.validation import check_choice

REPRODUCES = "reproduces"
PARTLY = "partly reproduces"
DOES_NOT = "does not reproduce"
NOT_JUDGED = "not judged at this scale"  # smoke: numbers only exercise the plumbing
INCONCLUSIVE = "inconclusive"  # the CI across training seeds spans two outcomes
INDICATIVE = "indicative"  # one training seed: no CI, the point estimate only leans one way
NOT_COMPUTED = "not computed"  # the claim's numbers are not in this build (its page was not executed)
VISUAL = "not judged (visual)"  # the thesis's claim is about what a figure looks like
#: design v2's labels that carry their bounds: the evidence rules out "does not" / "reproduces"
AT_LEAST_PARTLY = "at least partly"
AT_MOST_PARTLY = "at most partly"
#: design v3's labels of a rule that fails its own calibration, or cannot reach a verdict at any seed count
NOT_CALIBRATED = "not calibrated"
CANNOT_SETTLE = "cannot be settled by this design"
STATUSES: tuple[str, ...] = (
    REPRODUCES,
    AT_LEAST_PARTLY,
    PARTLY,
    AT_MOST_PARTLY,
    DOES_NOT,
    INCONCLUSIVE,
    INDICATIVE,
    NOT_CALIBRATED,
    CANNOT_SETTLE,
    NOT_RUN,
    NOT_JUDGED,
    NOT_COMPUTED,
    VISUAL,
)

#: Longest printed verdict line (the book and ``claims --json`` carry the whole line and its evidence).
LINE = 160

#: Admonition class of each status in the book (MyST ``{admonition}`` with a class).
_STYLE = {
    REPRODUCES: "tip",
    PARTLY: "note",
    AT_LEAST_PARTLY: "note",
    AT_MOST_PARTLY: "note",
    DOES_NOT: "warning",
    INCONCLUSIVE: "note",
    INDICATIVE: "note",
    NOT_CALIBRATED: "seealso",
    CANNOT_SETTLE: "seealso",
    NOT_RUN: "seealso",
    NOT_JUDGED: "seealso",
    NOT_COMPUTED: "seealso",
    VISUAL: "seealso",
}


@dataclass(frozen=True)
class Verdict:
    """One thesis claim judged from the kit's own numbers (``evidence``: the numbers, thesis beside ours)."""

    figure: str
    claim: str
    status: str
    evidence: str = ""
    #: one line (``label · id · l. N short claim · thesis: value · ours: value [CI]``): printed alone, the
    #: evidence folded below it in the book
    headline: str = ""
    #: the confirmatory check's line (the same frozen rule on the fresh seeds alone), ``""`` before they exist
    confirmatory: str = ""
    #: design v2's verdict (the registered analysis of seeds 0-5), shown beside ``status`` (design v3's); ``""``
    #: for a verdict no design judges (a kit check, a page's own rule)
    v2: str = ""
    #: the same frozen rule on the thesis-budget study's runs (:mod:`thesis_repro.claims.thesis_budget`): its line,
    #: ``""`` for a claim whose runs the study does not retrain
    thesis_budget: str = ""

    def __post_init__(self) -> None:
        check_choice(self.status, STATUSES, "verdict status")

    def v2_text(self) -> str:
        """Design v2's verdict in a few words beside v3's: ``v2: same``, ``v2: at least partly``, or ``""``.

        >>> Verdict("3.3", "c", INCONCLUSIVE, v2=AT_LEAST_PARTLY).v2_text(), Verdict("3.3", "c", REPRODUCES).v2_text()
        ('v2: at least partly', '')
        """
        return "" if not self.v2 else "v2: same" if self.v2 == self.status else f"v2: {self.v2}"

    def __str__(self) -> str:
        if self.headline:
            label, _, rest = self.headline.partition(" · ")
            line = f"[{self.figure}] {label.upper()} · {rest}"
            line = line if len(line) <= LINE else line[: LINE - 1] + "…"
            if "DISAGREES" in self.confirmatory:  # the terminal adds a line only for a flagged confirmatory check
                more = f"  {self.confirmatory}"
                line += "\n" + (more if len(more) <= LINE else more[: LINE - 1] + "…")
            return line
        tail = f": {self.evidence}" if self.evidence else ""
        return f"[{self.figure}] {self.status.upper()} - {self.claim}{tail}"

    def _repr_markdown_(self) -> str:
        if self.headline:
            label, _, rest = self.headline.partition(" · ")
            fresh = f"\n\n{self.confirmatory}" if self.confirmatory else ""
            fresh += f"\n\n{self.thesis_budget}" if self.thesis_budget else ""
            v2 = f" *(design {self.v2_text()})*" if self.v2 else ""
            body = f"{self.claim}{v2}{fresh}\n\n<details><summary>evidence</summary>\n\n{self.evidence}\n\n</details>"
            return f"```{{admonition}} {label.capitalize()} · {rest}\n:class: {_STYLE[self.status]}\n{body}\n```\n"
        title = f"{self.status.capitalize()}: {self.claim}"
        body = self.evidence or ""
        return f"```{{admonition}} {title}\n:class: {_STYLE[self.status]}\n{body}\n```\n"


def decide(holds: bool | None, scale: str, partly: bool = False) -> Verdict:
    """Status for a claim test: ``holds`` True/False, ``partly`` for a mixed outcome, None = not judged.

    Smoke numbers are never judged. Returns a placeholder Verdict whose ``status`` field is the answer.
    """
    if scale == "smoke" or holds is None:
        status = NOT_JUDGED
    elif holds:
        status = REPRODUCES
    else:
        status = PARTLY if partly else DOES_NOT
    return Verdict("", "", status)


def status(holds: bool | None, scale: str, partly: bool = False) -> str:
    """The status string of :func:`decide`."""
    return decide(holds, scale, partly).status


def verdicts_path(figure: str, scale: str) -> Path:
    """``build/<scale>/figures/<figure>.verdicts.json`` (``figure`` like ``fig-3.3`` or ``table-3.4``)."""
    return paths.figures_dir(scale) / f"{figure}.verdicts.json"


def rule_path(page: str, scale: str) -> Path:
    """``build/<scale>/figures/<page>.rule.json``: the verdicts of a page's own rule (``analysis-4-kl``'s), which
    its ``page_verdict`` claims read; the page's judged verdicts go to :func:`verdicts_path`, as every page's."""
    return paths.figures_dir(scale) / f"{page}.rule.json"


def save_rule(page: str, scale: str, verdicts: Sequence[Verdict]) -> Path:
    """Save the verdicts of a page's own rule (:func:`rule_path`) without printing them; returns the path."""
    return _write(rule_path(page, scale), page, scale, verdicts)


def _write(out: Path, figure: str, scale: str, verdicts: Sequence[Verdict]) -> Path:
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(".tmp")
    blob = {"figure": figure, "scale": scale, **stamps.page_stamp(figure), "verdicts": [asdict(v) for v in verdicts]}
    tmp.write_text(json.dumps(blob, indent=1))
    tmp.replace(out)
    return out


def report(figure: str, scale: str, verdicts: Sequence[Verdict], display: bool = True) -> Path:
    """Print, display (in a notebook) and save the verdicts of one figure run; returns the JSON path."""
    for v in verdicts:
        print(v)
    if display:
        try:
            from IPython import get_ipython
            from IPython.display import Markdown
            from IPython.display import display as show

            if get_ipython() is not None:
                for v in verdicts:
                    show(Markdown(v._repr_markdown_()))
        except ImportError:  # pragma: no cover - IPython ships with the kit
            pass
    return _write(verdicts_path(figure, scale), figure, scale, verdicts)


def load_verdicts(figure: str, scale: str) -> list[Verdict]:
    """Verdicts saved by :func:`report` (empty if the figure was not run at ``scale``); inside a notebook, also
    those of finished pages (:func:`~thesis_repro.core.paths.page_output`)."""
    p = paths.page_output(scale, verdicts_path(figure, scale).name)
    if not p.exists():
        return []
    return [Verdict(**v) for v in json.loads(p.read_text())["verdicts"]]


def stale(figure: str, scale: str) -> bool:
    """Whether the verdicts :func:`load_verdicts` reads were saved by other kit code
    (:func:`~thesis_repro.core.stamps.is_stale`)."""
    p = paths.page_output(scale, verdicts_path(figure, scale).name)
    return p.exists() and stamps.is_stale(figure, json.loads(p.read_text()))
