"""Registered subset sensitivity: a claim's frozen rule (design v3's, v2's beside it) judged again on a subset of its
runs.

A claim entry may carry ``sensitivity_subset: trained`` in ``data/thesis/claims.yaml`` (outside its ``rule:`` and
``v2:`` blocks, so outside the design's hashes: :func:`thesis_repro.claims.design.rule_hashes`). Its page saves a
bool column of that name on every per-seed row (``trained``: :mod:`thesis_repro.runs.budgets` calls the row's
training run trained, :func:`thesis_repro.book.pages.claim_frames`). :func:`judge_subset` keeps the rows where the
column is True in every frame that carries it, runs the claim's measure and a judgement handed to it unchanged on
them (the judging code is not touched: the data are filtered before the measure; the ledger hands it design v3's
seed-keyed judgement, and v2's for the label beside it) and reports the label, the primary statistic and the units
and runs that remain, beside the primary verdict. A page saved before the column existed gives *not available*.

>>> import pandas as pd
>>> f = pd.DataFrame({"env": "Hopper", "algo": ["a", "a", "b"], "seed": [0, 1, 0], "trained": [True, False, True]})
>>> sub, kept, total = subset_frames({"points": f}, "trained")
>>> len(sub["points"]), kept, total
(2, 2, 3)
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import pandas as pd

from thesis_repro.claims import measures as M
from thesis_repro.claims import report
from thesis_repro.claims.stats import Unit, combine_bounded

#: Registered subsets: the saved bool column each keeps, and what its rows are (the words a reader sees).
SUBSETS: dict[str, str] = {
    "trained": "runs `budgets` calls trained (final training return >= 70 % of the 4e6-step return)",
}
#: Columns naming a row's training run besides ``env`` and ``seed`` (the learner).
LEARNER_COLUMNS: tuple[str, ...] = ("algo", "method")


class Unavailable(Exception):
    """The saved numbers cannot give the subset (the message says why and what to run)."""


def check_name(cid: str, name: Any) -> str:
    """A claim's ``sensitivity_subset`` value, validated (a one-line error names the valid subsets).

    >>> check_name("x", "trained")
    'trained'
    >>> check_name("x", "converged")
    Traceback (most recent call last):
    ...
    ValueError: claims.yaml: claim 'x': unknown sensitivity_subset 'converged'; valid: trained
    """
    if name not in SUBSETS:
        raise ValueError(
            f"claims.yaml: claim {cid!r}: unknown sensitivity_subset {name!r}; valid: {', '.join(SUBSETS)}"
        )
    return str(name)


def _runs(frame: pd.DataFrame) -> pd.Series | None:
    """One key per row naming its training run (learner, env, seed), or None when the frame does not say."""
    learner = next((c for c in LEARNER_COLUMNS if c in frame.columns), None)
    if learner is None or not {"env", "seed"} <= set(frame.columns):
        return None
    return frame[learner].astype(str) + "|" + frame["env"].astype(str) + "|" + frame["seed"].astype(str)


def subset_frames(frames: Mapping[str, pd.DataFrame], subset: str) -> tuple[dict[str, pd.DataFrame], int, int]:
    """``frames`` keeping only the rows whose bool column ``subset`` is True (frames without it unchanged), with the
    number of distinct training runs kept and in all (over the frames that carry the column). Raises
    :class:`Unavailable` when no frame carries it (a page saved before the column existed)."""
    marked = {k: f for k, f in frames.items() if subset in f.columns}
    if not marked:
        raise Unavailable(f"not available: page saved before the {subset} column (rebuild the page)")
    out = {k: f[f[subset].astype(bool)].reset_index(drop=True) if k in marked else f for k, f in frames.items()}
    every, kept = set(), set()
    for f in marked.values():
        runs = _runs(f)
        if runs is None:
            continue
        every |= set(runs)
        kept |= set(runs[f[subset].astype(bool).to_numpy()])
    return out, len(kept), len(every)


def lost_learners(frames: Mapping[str, pd.DataFrame], kept: Mapping[str, pd.DataFrame]) -> list[str]:
    """Learners with rows in ``frames`` and none left in ``kept`` (the same keys, filtered), in order of appearance.

    >>> f = pd.DataFrame({"method": ["a", "b", "b"]})
    >>> lost_learners({"x": f}, {"x": f[f["method"] == "b"]})
    ['a']
    """
    gone: dict[str, None] = {}
    for k, f in frames.items():
        col = next((c for c in LEARNER_COLUMNS if c in f.columns), None)
        if col is not None and k in kept:
            left = set(kept[k][col])
            gone.update((str(a), None) for a in f[col] if a not in left)
    return list(gone)


def _groups(frames: Mapping[str, pd.DataFrame], rule: Mapping[str, Any]) -> dict[str, list[Any]]:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return M.MEASURES[rule["measure"]](frames, rule)


def judge_subset(
    subset: str,
    frames: Mapping[str, pd.DataFrame],
    rule: Mapping[str, Any],
    judge: Callable[[Mapping[str, Sequence[Unit]]], Any],
    judged: bool = True,
) -> dict[str, Any]:
    """The claim's judgement ``judge`` (its units by group -> a result with ``status``, ``groups`` and ``n_seeds``:
    :func:`thesis_repro.claims.judge_v3.judge_v3` or :func:`thesis_repro.claims.judge.judge_v2` with the claim's
    level, margin, count rules and Holm family bound) of ``rule``'s measure on the ``subset`` rows of ``frames``:
    ``verdict``, ``primary`` (the shape of the ledger row's), ``units`` / ``units_total`` and ``runs`` /
    ``runs_total`` remaining, ``n_seeds``; ``available`` False with the reason in ``note`` when the page did not save
    the column. ``judged`` False (the ``smoke`` scale): the label is *not judged*."""
    out: dict[str, Any] = {"subset": subset, "of": SUBSETS[subset], "available": False, "verdict": None}
    try:
        sub, kept, total = subset_frames(frames, subset)
    except Unavailable as err:
        return {**out, "note": str(err)}
    out.update(available=True, runs=kept, runs_total=total, primary={}, n_seeds=0, note="")
    try:
        units_total = sum(len(us) for us in _groups(frames, rule).values())
    except (M.NotRun, M.Inconclusive):
        units_total = 0
    out["units_total"] = units_total
    gone = lost_learners(frames, sub)
    left = f"no unit remains: no {subset} run of {', '.join(gone)}" if gone else "no unit remains on these runs"
    try:
        groups = _groups(sub, rule)
    except M.NotRun as err:  # the scale ran the learner (the primary verdict has it), but none of its runs is kept
        return {**out, "verdict": report.NOT_COMPUTED, "units": 0, "note": left if gone else str(err)}
    except M.Inconclusive as err:
        return {**out, "verdict": report.INCONCLUSIVE, "units": 0, "note": str(err)}
    run = {g: us for g, us in groups.items() if us}
    out["units"] = sum(len(us) for us in run.values())
    if not run:
        return {**out, "verdict": report.NOT_COMPUTED, "note": left}
    res = judge(run)
    status = res.status
    if len(run) < len(groups):  # a part with no unit left may hold or not
        status = combine_bounded([status, report.INCONCLUSIVE])
    primary = {g: {k: v for k, v in info.items() if k != "units"} for g, info in res.groups.items()}
    return {
        **out,
        "verdict": status if judged else report.NOT_JUDGED,
        "primary": primary if len(primary) > 1 else next(iter(primary.values())),
        "n_seeds": res.n_seeds,
    }


def text(info: Mapping[str, Any], ours: str = "") -> str:
    """One short line for a claim's page and ``claims --verbose``: the subset's label (design v2's beside it when
    ``info`` carries it), what remains, its number.

    >>> text({"subset": "trained", "available": True, "verdict": "does not reproduce", "runs": 109,
    ...       "runs_total": 135, "units": 20, "units_total": 20}, "pooled r +0.75 [+0.60, +0.85]")
    'sensitivity, trained runs only (109/135 runs, 20/20 units): does not reproduce · pooled r +0.75 [+0.60, +0.85]'
    >>> text({"subset": "trained", "available": True, "verdict": "inconclusive", "v2_verdict": "reproduces",
    ...       "runs": 9, "runs_total": 9, "units": 2, "units_total": 2})
    'sensitivity, trained runs only (9/9 runs, 2/2 units): inconclusive (v2: reproduces)'
    >>> text({"subset": "trained", "available": False, "note": "not available: page saved before the trained column"})
    'sensitivity, trained runs only: not available: page saved before the trained column'
    """
    head = f"sensitivity, {info['subset']} runs only"
    if not info.get("available"):
        return f"{head}: {info.get('note', 'not available')}"
    counts = f"{info['runs']}/{info['runs_total']} runs, {info['units']}/{info['units_total']} units"
    tail = f" · {ours}" if ours else (f" ({info['note']})" if info.get("note") else "")
    v2 = info.get("v2_verdict")
    beside = "" if not v2 else " (v2: same)" if v2 == info["verdict"] else f" (v2: {v2})"
    return f"{head} ({counts}): {info['verdict']}{beside}{tail}"


def method_text(specs: Sequence[Any]) -> str:
    """The method page's paragraph on the registered subset checks: what they do and which claims carry which.

    >>> from types import SimpleNamespace as NS
    >>> t = method_text([NS(id="a", subset="trained"), NS(id="b", subset="")])
    >>> "on a: the same frozen v3 rule" in t, "on a, b" in t
    (True, False)
    """
    carriers: dict[str, list[str]] = {}
    for s in specs:
        if s.subset:
            carriers.setdefault(s.subset, []).append(s.id)
    declared = "; ".join(f"`{k}` ({SUBSETS[k]}) on {', '.join(ids)}" for k, ids in carriers.items())
    return (
        "**Subset sensitivity** (`sensitivity_subset:` in the registry, outside the frozen rules): "
        + (declared or "no claim declares one")
        + ": the same frozen v3 rule (measure, level, margin, count rule, Holm family; seed-keyed) judged again on "
        "the rows of that subset only, with design v2's label beside it (*v2: same* when they agree), shown beside "
        "the primary verdict with the runs and units that remain; it never changes the primary verdict. Like the "
        "fresh seeds' check it reads the statistical label (no calibration gate). A page saved before it saved the "
        "subset's column says *not available*.\n"
    )
