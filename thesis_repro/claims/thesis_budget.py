"""The thesis-budget verdict: a claim's frozen rule judged again on the thesis-budget study's runs (4e6 steps).

Every verdict of the ledger is measured at the scale's budgets; the thesis-budget study
(:mod:`thesis_repro.runs.budget_study`) retrains Fig 3.3's variants at the thesis's own 4e6 steps. A page whose
runs the study retrains saves, in its meta under :data:`KEY` (:func:`thesis_repro.runs.budget_study.claims_meta`),
the study's budget, how many of the runs it needs are made (``runs`` of ``runs_total``) and, once all are, the
study's per-seed frames at that budget (``frames``, the same schema as the page's own). :func:`judge_on_study` runs the
claim's measure and a judgement handed to it unchanged on those frames (the ledger hands it design v3's seed-keyed
judgement, with its Holm family taken on the same frames: :func:`holm_family_on`, and v2's for the label beside it). The
label is the statistical one, as the fresh seeds' and the subset checks read it (no calibration gate). While runs
are missing it says *not computed (k of n runs)*; a page saved before it carried the study says so too.

Nothing here trains or reads runs: the numbers come from the page's saved meta (:mod:`thesis_repro.claims.store`).

>>> thesis_budget_line({"verdict": "not computed", "steps": 4_000_000, "runs": 12, "runs_total": 108})
"thesis's budget (4M steps): not computed (12 of 108 runs)"
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import pandas as pd

from thesis_repro.claims import design, report
from thesis_repro.claims import judge as J
from thesis_repro.claims import measures as M
from thesis_repro.claims import stats_v3 as T
from thesis_repro.claims.registry import Spec, specs
from thesis_repro.claims.stats import Unit, combine_bounded, pooled

#: The meta key under which a page saves the study's numbers.
KEY = "thesis_budget"
#: The pages whose runs the study retrains at the thesis's budget (the study's items:
#: :data:`thesis_repro.runs.budget_study.ITEMS`; ``tests/test_claims_thesis_budget.py`` checks they agree).
PAGES: tuple[str, ...] = ("fig-3.3", "table-3.4", "table-3.6")
#: The study's budget when a page saved none (the thesis's 4e6 steps, Appendix A).
THESIS_STEPS = 4_000_000


def _steps(steps: int) -> str:
    """An env-step budget in a few characters: ``4M`` from a million up, else with thousands separators.

    >>> _steps(4_000_000), _steps(2_500_000), _steps(256)
    ('4M', '2.5M', '256')
    """
    return f"{steps / 1e6:g}M" if steps >= 1_000_000 else f"{steps:,}"


def reads_study_runs(s: Spec) -> bool:
    """Whether claim ``s`` reads runs the study retrains (a page of :data:`PAGES` among its data pages)."""
    return bool(set(s.data_pages) & set(PAGES))


def saved(meta: Mapping[str, Any]) -> dict[str, Any] | None:
    """The study's numbers a page saved in its ``meta`` (None: saved before it carried them)."""
    got = meta.get(KEY)
    return dict(got) if isinstance(got, Mapping) else None


def frames_of(info: Mapping[str, Any]) -> dict[str, pd.DataFrame]:
    """The study's saved per-seed frames as DataFrames (``{}`` while runs are missing)."""
    return {k: pd.DataFrame(v) for k, v in (info.get("frames") or {}).items()}


def coverage(info: Mapping[str, Any]) -> str:
    """``k of n runs`` (``""`` when the page did not say).

    >>> coverage({"runs": 0, "runs_total": 108}), coverage({})
    ('0 of 108 runs', '')
    """
    if info.get("runs") is None or info.get("runs_total") is None:
        return ""
    return f"{int(info['runs'])} of {int(info['runs_total'])} runs"


def _groups(frames: Mapping[str, pd.DataFrame], rule: Mapping[str, Any]) -> dict[str, list[Unit]]:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return M.MEASURES[rule["measure"]](frames, rule)


def holm_family_on(
    s: Spec, frames: Mapping[str, pd.DataFrame], own: Mapping[str, Sequence[Unit]], version: int
) -> list[float]:
    """Holm's family of ``s`` on the study's ``frames``: the decisive p-values of the other pooled claims that read
    its page data, each measured on the same frames (design ``version`` 3: distinct tests only, as
    :func:`thesis_repro.claims.ledger.family_p3`; 2: as :func:`~thesis_repro.claims.ledger.family_p`)."""
    seen = {J.units_key({"": us}, "") for us in own.values()} if version == 3 else set()
    out: list[float] = []
    for f in specs():
        if f.id == s.id or f.rule.get("derived") or "measure" not in f.rule:
            continue
        if not set(f.data_pages) & set(s.data_pages):
            continue
        if version == 3:
            if design.level3(f.v2, f.v3) != "pooled" or design.conjunction(f.v3):
                continue
            rule, margin = design.rule3(f.rule, f.v2, f.v3), design.margin3(f.v2, f.v3)
        else:
            if design.level(f.v2) != "pooled":
                continue
            rule, margin = design.rule(f.rule, f.v2), design.margin(f.v2)
        try:
            groups = _groups(frames, rule)
        except (M.NotRun, M.Inconclusive):
            continue
        for us in groups.values():
            if not us:
                continue
            if version == 3:
                key = J.units_key({"": us}, "")
                if key not in seen:
                    seen.add(key)
                    out.append(T.decisive(T.pooled_test(us, margin)))
            else:
                out.append(J.decisive_p(pooled(us, margin)))
    return out


def judge_on_study(
    meta: Mapping[str, Any],
    rule: Mapping[str, Any],
    judge: Callable[[Mapping[str, Sequence[Unit]], Mapping[str, pd.DataFrame]], Any],
    judged: bool = True,
) -> dict[str, Any]:
    """The claim's judgement ``judge`` (its units by group and the frames -> a result with ``status``, ``groups``
    and ``n_seeds``) of ``rule``'s measure on the study's frames saved in ``meta``: ``verdict``, ``primary`` (the
    shape of the ledger row's), ``steps``, ``runs`` / ``runs_total``, ``n_seeds``, ``note``; *not computed* with
    the coverage while runs are missing. ``judged`` False (the ``smoke`` scale): the label is *not judged*."""
    info = saved(meta)
    out: dict[str, Any] = {"study": "thesis-budget", "steps": THESIS_STEPS, "runs": None, "runs_total": None}
    out.update(verdict=report.NOT_COMPUTED, primary={}, n_seeds=0, note="")
    if info is None:
        return {**out, "note": "the page's saved numbers carry no thesis-budget runs"}
    out.update(steps=int(info.get("steps", THESIS_STEPS)), runs=info.get("runs"), runs_total=info.get("runs_total"))
    frames = frames_of(info)
    if not frames or (out["runs"] is not None and out["runs"] < (out["runs_total"] or 0)):
        return {**out, "note": f"not computed ({coverage(out)})" if coverage(out) else "not computed"}
    try:
        groups = _groups(frames, rule)
    except M.NotRun as err:
        return {**out, "verdict": report.NOT_RUN, "note": str(err)}
    except M.Inconclusive as err:
        return {**out, "verdict": report.INCONCLUSIVE, "note": str(err)}
    run = {g: us for g, us in groups.items() if us}
    if not run:  # every unit is on a task or learner the study does not train: no run of it will ever come
        return {**out, "verdict": report.NOT_RUN, "note": "the study trains none of the claim's tasks or learners"}
    res = judge(run, frames)
    status = res.status
    if len(run) < len(groups):  # a part the study does not run may hold or not
        status = combine_bounded([status, report.INCONCLUSIVE])
    primary = {g: {k: v for k, v in i.items() if k != "units"} for g, i in res.groups.items()}
    return {
        **out,
        "verdict": status if judged else report.NOT_JUDGED,
        "primary": primary if len(primary) > 1 else next(iter(primary.values())),
        "n_seeds": res.n_seeds,
    }


def derived(parts: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """A derived claim's thesis-budget verdict: its parts' combined (*not computed* while any part is), with the
    coverage of the parts (the fewest runs made).

    >>> derived([{"verdict": "not computed", "steps": 4, "runs": 3, "runs_total": 9}, {"verdict": "reproduces"}])
    {'study': 'thesis-budget', 'steps': 4, 'runs': 3, 'runs_total': 9, 'verdict': 'not computed', 'parts': {}}
    """
    made = [p for p in parts if p.get("runs") is not None]
    least = min(made, key=lambda p: p["runs"], default={})
    verdicts = [str(p.get("verdict") or report.NOT_COMPUTED) for p in parts]
    return {
        "study": "thesis-budget",
        "steps": next((p["steps"] for p in parts if p.get("steps")), THESIS_STEPS),
        "runs": least.get("runs"),
        "runs_total": least.get("runs_total"),
        "verdict": combine_bounded(verdicts) if parts else report.NOT_COMPUTED,
        "parts": {str(p["id"]): str(p.get("verdict")) for p in parts if "id" in p},
    }


def thesis_budget_line(info: Mapping[str, Any], ours: str = "") -> str:
    """One short line for a page, ``claims --verbose`` and RESULTS.md: the thesis-budget label (design v2's beside it
    when ``info`` carries it), the runs it rests on, our number.

    >>> info = {"verdict": "does not reproduce", "v2_verdict": "does not reproduce", "steps": 4_000_000, "runs": 108}
    >>> thesis_budget_line({**info, "runs_total": 108}, "pooled r +0.61 [+0.40, +0.76]")
    "thesis's budget (4M steps, 108/108 runs): does not reproduce (v2: same) · pooled r +0.61 [+0.40, +0.76]"
    """
    steps = f"{_steps(int(info.get('steps') or THESIS_STEPS))} steps"
    verdict = str(info.get("verdict") or report.NOT_COMPUTED)
    if verdict == report.NOT_COMPUTED:
        why = coverage(info) or str(info.get("note") or "")
        return f"thesis's budget ({steps}): {verdict}" + (f" ({why})" if why else "")
    if verdict == report.NOT_RUN:
        return f"thesis's budget ({steps}): {verdict}" + (f" ({info['note']})" if info.get("note") else "")
    v2 = info.get("v2_verdict")
    beside = "" if not v2 else " (v2: same)" if v2 == verdict else f" (v2: {v2})"
    runs = f", {info['runs']}/{info['runs_total']} runs" if info.get("runs_total") else ""
    return f"thesis's budget ({steps}{runs}): {verdict}{beside}" + (f" · {ours}" if ours else "")


def cell(info: Mapping[str, Any] | None) -> str:
    """A RESULTS.md cell: the thesis-budget verdict, *not computed (k of n runs)* while runs are missing, ``-`` for a
    claim whose runs the study does not retrain.

    >>> cell(None), cell({"verdict": "not computed", "runs": 0, "runs_total": 108})
    ('-', 'not computed (0 of 108 runs)')
    >>> cell({"verdict": "reproduces", "runs": 108, "runs_total": 108, "ours": "pooled r -0.41 [-0.6, -0.2]"})
    'reproduces: pooled r -0.41 [-0.6, -0.2]'
    """
    if not info:
        return "-"
    verdict = str(info.get("verdict") or report.NOT_COMPUTED)
    if verdict == report.NOT_COMPUTED:
        why = coverage(info)
        return f"{verdict} ({why})" if why else verdict
    return f"{verdict}: {info['ours']}" if info.get("ours") else verdict
