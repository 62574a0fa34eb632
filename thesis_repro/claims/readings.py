"""Chapter 4's claims once per reading of the thesis's update (design v3's :data:`~thesis_repro.claims.design.
READING_CLAIMS`): what each reading is judged on, and the answer the chapter's page opens with.

The thesis leaves Eq 4.11's damping, step size, line search and trust region open; the kit trains each reading
(:data:`thesis_repro.mdl.readings.READINGS`) and its one-seed pilot (``data/reference/pilots/ch4-readings.json``)
says what it does past the literal reading's collapse. Frozen in design v3, a reading is judged by the claim's v3
rule with ``ours`` set to it and ``drop_diverged`` on, and:

* a reading whose pilot diverged, or whose every grid run diverged, reads
  :data:`~thesis_repro.claims.measures.ch4.DIVERGED` for every claim;
* a reading that reduces to params_avg in its pilot (:data:`PARAMS_AVG`) is judged on params_avg's runs, shown
  under its own name (its contrast with params_avg is zero by construction: it cannot beat parameter averaging);
* a stable, distinct reading with no grid run on the claim's pages reads *not computed* until it is trained.

This module holds the pure parts; :func:`thesis_repro.claims.ledger.judge` judges.

>>> import pandas as pd
>>> f = {"curves": pd.DataFrame({"algo": ["params_avg", "joint"], "return": [1.0, 2.0]})}
>>> as_reading(f, "kl_avg_ls")["curves"]["algo"].tolist()
['params_avg', 'joint', 'kl_avg_ls']
>>> column("kl-avg-ls")
'kl_avg_ls'
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace
from functools import cache
from typing import Any

import pandas as pd

from thesis_repro.claims import design
from thesis_repro.claims.measures.ch4 import DIVERGED, diverged
from thesis_repro.claims.registry import Spec

#: A pilot's outcome: it trains and differs from params_avg, it reduces to params_avg, or it diverged.
DISTINCT, PARAMS_AVG, PILOT_DIVERGED = "distinct", "reduces to params_avg", "diverged in its pilot"
#: The pilot summary the outcomes come from (``python -m thesis_repro.runs.pilots ch4-readings`` writes it).
PILOTS = "ch4-readings"
#: The learner whose runs a reading that reduces to parameter averaging is judged on.
COMPARATOR = "params_avg"


def column(algo: str) -> str:
    """A hyperparameter id as the pages' frames spell the learner (``kl-avg-ls`` -> ``kl_avg_ls``)."""
    return algo.replace("-", "_")


@cache
def outcomes() -> dict[str, str]:
    """Each reading's pilot outcome (:data:`DISTINCT`, :data:`PARAMS_AVG` or :data:`PILOT_DIVERGED`), in the order
    of the readings table, from the shipped pilot summary ({} when none is shipped)."""
    from thesis_repro.mdl.readings import reading_ids  # local: the readings' maths loads torch only when asked
    from thesis_repro.runs import pilots  # local: the pilots load the learners (torch) only when asked

    try:
        table = pilots.pilot_table(pilots.load_summary(PILOTS))
    except (OSError, ValueError, KeyError):
        return {}
    out: dict[str, str] = {}
    for algo in reading_ids():
        row = table[table["learner"] == algo]
        if row.empty:
            continue
        r = row.iloc[0]
        if r["trains"] == "diverged":
            out[algo] = PILOT_DIVERGED
        else:
            out[algo] = PARAMS_AVG if r["reduces to params_avg"] else DISTINCT
    return out


def reading_name(algo: str) -> str:
    """A reading's short name (``kl-avg-ls`` -> ``line search``)."""
    from thesis_repro.mdl.readings import READINGS

    return next((r.name for r in READINGS if r.algo == algo), algo)


def spec_for(s: Spec, algo: str) -> Spec:
    """Claim ``s`` as design v3 judges it for reading ``algo``: ``ours`` set to it, ``drop_diverged`` on."""
    v3 = dict(s.v3)
    v3["rule"] = {**dict(v3.get("rule") or {}), "drop_diverged": True}
    return replace(s, id=f"{s.id}~{algo}", rule={**s.rule, "ours": column(algo)}, v3=v3, subset="", sensitivity=())


def as_reading(frames: Mapping[str, pd.DataFrame], name: str) -> dict[str, pd.DataFrame]:
    """``frames`` with params_avg's rows repeated under learner ``name`` in every frame with an ``algo`` column:
    a reading that reduces to params_avg, judged on params_avg's runs."""
    out = {}
    for k, f in frames.items():
        if isinstance(f, pd.DataFrame) and "algo" in f.columns and (f["algo"] == COMPARATOR).any():
            f = pd.concat([f, f[f["algo"] == COMPARATOR].assign(algo=name)], ignore_index=True)
        out[k] = f
    return out


def applies(s: Spec) -> bool:
    """Whether claim ``s`` is judged once per reading (a thesis claim of :data:`design.READING_CLAIMS`)."""
    return s.id in design.READING_CLAIMS


def routes(frames: Mapping[str, pd.DataFrame]) -> list[tuple[str, str, str]]:
    """Per reading: ``(algo, outcome, how)`` where ``how`` is ``"judge"`` (its runs are on every page the claim
    reads), ``"params_avg"`` (judged on params_avg's runs), ``"diverged"`` (its pilot diverged) or ``"not trained"``
    (also while its grid has reached only some of the claim's pages: a claim reads all of them or none).

    >>> import unittest.mock as mock
    >>> one = {"wind": pd.DataFrame({"algo": ["kl_exact"]}), "curves@fig-4.1": pd.DataFrame({"algo": ["joint"]})}
    >>> with mock.patch(f"{__name__}.outcomes", lambda: {"kl-exact": DISTINCT}):
    ...     routes(one), routes({"wind": one["wind"]})
    ([('kl-exact', 'distinct', 'not trained')], [('kl-exact', 'distinct', 'judge')])
    """
    sets = [set(f["algo"]) for f in frames.values() if isinstance(f, pd.DataFrame) and "algo" in f.columns]
    anywhere, everywhere = set().union(*sets), set.intersection(*sets) if sets else set()
    out = []
    for algo, outcome in outcomes().items():
        if outcome == PILOT_DIVERGED and column(algo) not in anywhere:
            how = "diverged"
        elif outcome == PARAMS_AVG:
            how = "params_avg"
        elif column(algo) in everywhere:
            how = "judge"
        else:
            how = "not trained"
        out.append((algo, outcome, how))
    return out


def entry(algo: str, outcome: str, how: str, status: str, ours: str = "", note: str = "") -> dict[str, Any]:
    """One reading's verdict as ``claims --json`` carries it."""
    return {
        "reading": algo,
        "name": reading_name(algo),
        "pilot": outcome,
        "judged_on": {"judge": column(algo), "params_avg": COMPARATOR}.get(how, ""),
        "verdict": status,
        "ours": ours,
        "note": note,
    }


def diverged_runs(frames: Mapping[str, pd.DataFrame], algo: str) -> tuple[int, int]:
    """How many of reading ``algo``'s training runs on the claim's pages diverged (:func:`~thesis_repro.claims.
    measures.ch4.diverged`, the rule that keeps them out of every claim), of how many: over each frame of training
    curves (``curves@<page>``; the bare ``curves`` only when no page is named), each run once however many pages
    show it (a run is known by its panel, seed and returns).

    >>> c = pd.DataFrame({"algo": "kl_x", "panel": ["a"] * 9 + ["b"] * 9, "seed": 0, "iteration": [*range(9)] * 2,
    ...                   "return": [100.0, 500] + [1000] * 7 + [900] * 3 + [-5] * 6, "entropy": 1.0})
    >>> diverged_runs({"curves": c, "wind": pd.DataFrame()}, "kl-x")
    (1, 2)
    >>> diverged_runs({"curves@fig-4.1": c, "curves@fig-4.3": c}, "kl-x")
    (1, 2)
    """
    named = [k for k in frames if k.startswith("curves@")]
    runs: dict[tuple[Any, ...], bool] = {}
    for k in named or ["curves"]:
        f = frames.get(k)
        if not (isinstance(f, pd.DataFrame) and "algo" in f.columns):
            continue
        mine = f[f["algo"] == column(algo)]
        if mine.empty:
            continue
        for (panel, seed), g in mine.sort_values("iteration").groupby(["panel", "seed"]):
            runs[(panel, seed, tuple(g["return"].round(6)))] = bool(diverged(g)["diverged"].iloc[0])
    return sum(runs.values()), len(runs)


def diverged_table(curves: pd.DataFrame) -> pd.DataFrame:
    """Per learner (rows) and panel (columns) of a chapter-4 page's training curves: how many of its training runs
    diverged (:func:`~thesis_repro.claims.measures.ch4.diverged`: late return below half its peak), of how many;
    the runs no claim reads.

    >>> c = pd.DataFrame({"algo": "kl_x", "panel": ["a"] * 9 + ["b"] * 9, "seed": 0, "iteration": [*range(9)] * 2,
    ...                   "return": [100.0, 500] + [1000] * 7 + [900] * 3 + [-5] * 6, "entropy": 1.0})
    >>> diverged_table(c).to_dict("index")
    {'kl_x': {'a': '0/1', 'b': '1/1'}}
    """
    d = diverged(curves)
    count = d.groupby(["algo", "panel"])["diverged"].agg(lambda v: f"{int(v.sum())}/{len(v)}")
    return count.unstack("panel").rename_axis(index="learner", columns="panel")


def dropped_note(bad: int, total: int) -> str:
    """The note a judged reading carries when some of its runs diverged ("" when none did).

    >>> dropped_note(4, 12)
    '4 of its 12 training runs diverged (late return below half its peak) and are not read'
    >>> dropped_note(0, 12)
    ''
    """
    if not bad:
        return ""
    return f"{bad} of its {total} training runs diverged (late return below half its peak) and are not read"


def calibration_summary(cal: Mapping[str, Any]) -> dict[str, Any]:
    """The parts of a v3 calibration a reading's entry carries: the gate's rates and the power figures."""
    keep = ("draws", "false_reproduces", "false_does_not", "effect", "power_at", "seeds_for_80", "max_seeds")
    return {k: cal[k] for k in keep if k in cal}


def diverged_note(how: str) -> str:
    """Why a reading is not judged: its pilot diverged, or every grid run of it did."""
    if how == "diverged":
        return f"{DIVERGED}: its pilot diverged (late return below half its peak), so it is not trained on the grid"
    return DIVERGED


def answer(rows: Sequence[Mapping[str, Any]]) -> str:
    """The chapter-4 page's first line: does the thesis's method, under any stable reading, deliver what the
    thesis claims against joint training and parameter averaging? *Yes* when a reading reproduces more than half
    of the claims it is judged on, *only in part* when one reproduces some, else *no*. ``rows``: ``claims
    --json``'s rows.

    >>> e = lambda a, v: {"reading": a, "verdict": v}
    >>> answer([{"id": "c1", "readings": [e("kl-avg-ls", "does not reproduce"), e("kl-avg-tr", DIVERGED)]}])
    '**No: under no stable reading does the method deliver what chapter 4 claims against joint training and \
parameter averaging.** `kl-avg-ls` (line search): none of 1. Diverged, not judged: `kl-avg-tr`.'
    """
    from thesis_repro.claims import report

    mine = [r for r in rows if r.get("readings")]
    if not mine:
        return ""
    won: dict[str, list[str]] = {}
    judged: dict[str, int] = {}
    diverged, untrained = set(), set()
    for r in mine:
        for e in r["readings"]:
            if e["verdict"] == DIVERGED:
                diverged.add(e["reading"])
            elif e["verdict"] == report.NOT_COMPUTED:
                untrained.add(e["reading"])
            else:
                judged[e["reading"]] = judged.get(e["reading"], 0) + 1
                if e["verdict"] == report.REPRODUCES:
                    won.setdefault(e["reading"], []).append(r["id"])
    share = {a: len(won.get(a, [])) / n for a, n in judged.items()}
    if any(v > 0.5 for v in share.values()):
        lead = "**Yes: under at least one stable reading the method delivers most of what chapter 4 claims"
    elif won:
        lead = "**Only in part: no stable reading delivers most of what chapter 4 claims"
    else:
        lead = "**No: under no stable reading does the method deliver what chapter 4 claims"
    lead += " against joint training and parameter averaging.**"

    def one(a: str) -> str:
        ids = won.get(a, [])
        got = f"{len(ids)} of {judged[a]} ({', '.join(ids)})" if ids else f"none of {judged[a]}"
        return f"`{a}` ({reading_name(a)}): {got}"

    tail = ["; ".join(one(a) for a in sorted(judged, key=_order))]
    if diverged:
        tail.append("Diverged, not judged: " + ", ".join(f"`{a}`" for a in sorted(diverged, key=_order)))
    if untrained:
        tail.append("Not yet trained on the grid: " + ", ".join(f"`{a}`" for a in sorted(untrained, key=_order)))
    return lead + " " + ". ".join(tail) + "."


def verdict_list(rows: Sequence[Mapping[str, Any]]) -> str:
    """Markdown: per claim judged by reading, one line with each reading's verdict and its key number (what the
    chapter-4 page shows under its answer). ``rows``: ``claims --json``'s rows.

    >>> e = {"reading": "kl-diag", "verdict": "inconclusive", "ours": "0/4 units yes", "judged_on": "params_avg"}
    >>> print(verdict_list([{"id": "4.3-wind", "readings": [e]}]))
    - **4.3-wind**: `kl-diag` (on params_avg's runs) *inconclusive*, 0/4 units yes
    >>> print(verdict_list([{"id": "4.3-wind", "readings": [{**e, "diverged_runs": [4, 12]}]}]))
    - **4.3-wind**: `kl-diag` (on params_avg's runs) *inconclusive*, 0/4 units yes (4 of 12 runs diverged, not read)
    """

    def one(e: Mapping[str, Any]) -> str:
        on = " (on params_avg's runs)" if e.get("judged_on") == COMPARATOR else ""
        num = f", {e['ours']}" if e.get("ours") else ""
        bad, total = e.get("diverged_runs") or (0, 0)
        drop = f" ({bad} of {total} runs diverged, not read)" if bad else ""
        return f"`{e['reading']}`{on} *{e['verdict']}*{num}{drop}"

    return "\n".join(f"- **{r['id']}**: " + "; ".join(one(e) for e in r["readings"]) for r in rows if r.get("readings"))


def _order(algo: str) -> int:
    from thesis_repro.mdl.readings import reading_ids  # local: the readings' maths loads torch only when asked

    ids = reading_ids()
    return ids.index(algo) if algo in ids else len(ids)
