"""The claims ledger: every registered claim judged from its pages' saved numbers, design v2 with v1 beside it.

The registry is ``data/thesis/claims.yaml`` (:mod:`thesis_repro.claims.registry`): under each page, ``claims``
quote the thesis (a claim with a ``rule`` is judged on that page; the same ``id`` on another page only repeats its
verdict), and ``beyond`` holds the kit's own extensions, counted apart. :func:`judge` reads a claim's saved page
numbers (:mod:`thesis_repro.claims.store`: the build's, else the shipped snapshot's, and each row says so), runs
its measure and judges the units (:mod:`thesis_repro.claims.judge`), with its calibration and power, its
confirmatory verdict on the fresh seeds, its subset check and its "why" (:mod:`thesis_repro.claims.diagnosis`).
:func:`ledger` judges every claim (no training, no evaluation), so the book's scoreboard and ``python -m
thesis_repro claims`` read one ledger; their words are :mod:`thesis_repro.claims.scoreboard`'s.

>>> ids = [s.id for s in specs()]
>>> len(ids) == len(set(ids)) and "3.3-negative-correlation" in ids
True
>>> spec("3.3-negative-correlation").page
'fig-3.3'
"""

from __future__ import annotations

import json
import math
import os
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

from thesis_repro.claims import calibration, design, report, snapshot
from thesis_repro.claims import judge as J
from thesis_repro.claims import judge_v3 as J3
from thesis_repro.claims import measures as M
from thesis_repro.claims import readings as R
from thesis_repro.claims import sensitivity as subsets
from thesis_repro.claims import stats_v3 as T
from thesis_repro.claims import thesis_budget as budget
from thesis_repro.claims.confirmatory import FIRST_FRESH, Confirmation, fresh_frames, fresh_seeds, seeds_in
from thesis_repro.claims.diagnosis import diagnose, sensitivity_dict, study_result
from thesis_repro.claims.evidence import no_ci_words
from thesis_repro.claims.ledger_row import Row, ours_text, shipped_pages, stale_pages
from thesis_repro.claims.registry import Spec, spec, specs
from thesis_repro.claims.rules import rule_for, thesis_effects
from thesis_repro.claims.stats import LEVEL, CountRule, Unit, combine_bounded, combine_groups, null_pass_rate, pooled
from thesis_repro.claims.store import in_pass, make_target, one_pass, page_data, read_json, saved_blob
from thesis_repro.core import paths

NULL_DRAWS = 60

#: The build's (and the shipped snapshot's) cache of v2 calibration and power, keyed by content.
CALIBRATION = "claims-calibration.json"

#: ``judge(with_null=CACHED)``: calibration and power from the caches only, never computed.
CACHED = "cached"


def judge(s: Spec, scale: str, with_null: bool | str = CACHED) -> Row:
    """One claim's ledger row at ``scale`` from the saved numbers of its page(s). ``with_null``: compute the
    claim's calibration and power when they are not cached (True), read them only from the caches
    (:data:`CACHED`, the default: a book page never spends minutes on them), or leave them out (False)."""
    r = s.rule
    if r.get("visual"):
        return Row(s, report.VISUAL, note="the claim is about the gait's look; the page shows the key frames")
    if "page_verdict" in r:
        try:
            blob = saved_blob(s.page, report.rule_path(s.page, scale).name, scale) or {"verdicts": []}
        except snapshot.CorruptSnapshot as err:
            return _corrupt(s, scale, err)
        saved = [report.Verdict(**v) for v in blob["verdicts"]]
        if len(saved) <= int(r["page_verdict"]):
            return Row(s, report.NOT_COMPUTED, note=f"{s.page} not executed at {scale}")
        v = saved[int(r["page_verdict"])]
        return Row(
            s,
            v.status,
            note=v.evidence,
            stale=[s.page] if blob.get("stale") else [],
            shipped=[s.page] if blob.get("shipped") else [],
        )
    if r.get("derived"):
        rows = [judge(spec(i), scale, with_null) for i in r["derived"]]
        plain = combine_bounded([x.v3.get("status", x.status) for x in rows])
        gate = [f"{x.spec.id}: {x.status} ({x.v3.get('reason', '')})" for x in rows if x.v3.get("reason")]
        status = report.NOT_CALIBRATED if gate else plain
        if scale == "smoke":
            status = plain = report.NOT_JUDGED
        v2 = combine_bounded([x.v2_status or x.status for x in rows]) if scale != "smoke" else report.NOT_JUDGED
        v1 = combine_groups([x.v1_status or x.status for x in rows])
        rates = [x.null_pass_rate for x in rows if x.null_pass_rate is not None]
        return Row(
            s,
            status,
            min((x.n_seeds for x in rows), default=0),
            {"parts": {x.spec.id: x.status for x in rows}},
            # the parts' units, so the verdict carries the CIs across seeds it rests on (JSON, units table, text)
            {f"{x.spec.id}: {g}": info for x in rows for g, info in x.groups.items()},
            null_pass_rate=min(rates) if rates else None,
            note="derived from " + ", ".join(f"{x.spec.id}: {x.status}" for x in rows),
            stale=stale_pages(rows),
            shipped=shipped_pages(rows),
            local_runs={p: u for x in rows for p, u in x.local_runs.items()},
            v1_status=v1,
            level="each",
            confirmation=_derived_confirmation(rows, plain),
            v2_status=v2,
            v3={"status": plain, "reason": "; ".join(gate), "derived": True},
            # a derived claim's calibration is its parts' (each one gated on its own)
            calibration={"parts": {x.spec.id: x.calibration for x in rows}} if with_null else {},
            thesis_budget=budget.derived([{**x.thesis_budget, "id": x.spec.id} for x in rows if x.thesis_budget])
            if budget.reads_study_runs(s) or any(x.thesis_budget for x in rows)
            else {},
        )
    try:
        got = page_data(s, scale)
    except snapshot.CorruptSnapshot as err:
        return _corrupt(s, scale, err)
    if got is None:
        pages = ", ".join(s.data_pages)
        return Row(s, report.NOT_COMPUTED, note=f"no saved numbers of {pages} at {scale}: execute the page(s) first")
    frames, meta = got
    row = _judge_frames(s, scale, with_null, frames, meta)
    row.stale = list(meta["stale_pages"])
    row.shipped = list(meta["shipped_pages"])
    row.local_runs = dict(meta["local_runs"])
    row.confirmation = confirm(s, scale, row, frames, meta)
    if budget.reads_study_runs(s):
        row.thesis_budget = budget_check(s, scale, meta)
    if R.applies(s):
        row.readings = judge_readings(s, scale, with_null, frames)
    return row


def judge_readings(
    s: Spec, scale: str, with_null: bool | str, frames: Mapping[str, pd.DataFrame]
) -> list[dict[str, Any]]:
    """Claim ``s`` once per reading of the thesis's update (:mod:`thesis_repro.claims.readings`): design v3's
    gated label with its primary statistic, *diverged, not judged* where the reading diverged, *not computed*
    where it is stable and distinct but not trained on the claim's pages."""
    out = []
    for algo, outcome, how in R.routes(frames):
        if how == "diverged":
            out.append(R.entry(algo, outcome, how, R.DIVERGED, note=R.diverged_note(how)))
            continue
        if how == "not trained":
            note = f"stable and distinct in its pilot, not yet trained on {', '.join(s.data_pages)}'s grid at {scale}"
            out.append(R.entry(algo, outcome, how, report.NOT_COMPUTED, note=note))
            continue
        v = R.spec_for(s, algo)
        got = R.as_reading(frames, R.column(algo)) if how == "params_avg" else frames
        v3 = _judge_v3(v, scale, with_null, got, M.NotRun("judged by design v3's rule alone"), None)
        if v3 is None:
            out.append(R.entry(algo, outcome, how, report.NOT_COMPUTED, note="nothing to judge"))
        elif "note" in v3:
            diverged = str(v3["note"]).startswith(R.DIVERGED)
            out.append(R.entry(algo, outcome, how, R.DIVERGED if diverged else v3["label"], note=v3["note"]))
        else:
            row = Row(v, v3["label"], primary=v3["primary"])
            row.v3 = {"reason": v3["reason"]}
            bad, total = R.diverged_runs(got, algo)  # params_avg's runs for a reading judged on them
            note = "; ".join(t for t in (v3["reason"], R.dropped_note(bad, total)) if t)
            entry = R.entry(algo, outcome, how, v3["label"], ours_text(row), note)
            cal = R.calibration_summary(v3["calibration"])
            out.append({**entry, "n_seeds": v3["n_seeds"], "diverged_runs": [bad, total], "calibration": cal})
    return out


def confirm(
    s: Spec, scale: str, row: Row, frames: Mapping[str, pd.DataFrame], meta: dict[str, Any]
) -> Confirmation | None:
    """The claim's confirmatory verdict (:mod:`~thesis_repro.claims.confirmatory`): its frozen rule on the fresh
    seeds alone, with Holm's family judged on them too; None when its pages do not hold the fresh seeds beside the
    design seeds, or nothing is judged (smoke, a page-level verdict)."""
    if scale == "smoke" or not row.level or min(seeds_in(frames), default=FIRST_FRESH) >= FIRST_FRESH:
        return None
    fresh = fresh_frames(frames)
    if fresh is None:
        return None
    seeds = fresh_seeds(frames)
    c = _judge_frames(s, scale, False, fresh, meta, seeds=seeds)
    v3 = c.v3.get("status", c.status)
    return Confirmation(v3, ours_text(c), row.v3.get("status", row.status), seeds, c.v2_status or v3)


def _derived_confirmation(parts: Sequence[Row], primary: str) -> Confirmation | None:
    """A derived claim's confirmatory verdict: its parts' combined, when every part has one."""
    got = [r.confirmation for r in parts]
    if not got or any(c is None for c in got):
        return None
    v2 = combine_bounded([c.v2 or c.status for c in got if c])
    return Confirmation(combine_bounded([c.status for c in got if c]), "", primary, v2=v2)


def _judge_v3(
    s: Spec,
    scale: str,
    with_null: bool | str,
    frames: Mapping[str, pd.DataFrame],
    measured2: dict[str, list[Unit]] | Exception,
    seeds: Sequence[int] | None,
) -> dict[str, Any] | None:
    """Design v3's verdict of a claim with a measure (None when its measure cannot run): the statistical label, the
    gated label a reader sees (:func:`~thesis_repro.claims.judge_v3.gated`) and why, its groups, its primary
    statistic, calibration and power, and whether the thesis's own effect is excluded."""
    rule2 = design.rule(s.rule, s.v2)
    rule3 = design.rule3(s.rule, s.v2, s.v3)
    lv, mg, conj = design.level3(s.v2, s.v3), design.margin3(s.v2, s.v3), design.conjunction(s.v3)
    measured = measured2 if rule3 == rule2 else _measure(frames, rule3)
    try:
        groups = _units(measured)
    except (M.NotRun, M.Inconclusive) as err:
        if measured is measured2:  # v3 judges what v2 judges: the same label under both
            return None
        label = report.NOT_RUN if isinstance(err, M.NotRun) else report.INCONCLUSIVE
        if scale == "smoke":
            label = report.NOT_JUDGED
        return {
            "status": label,
            "label": label,
            "reason": "",
            "note": str(err),
            "conjunction": conj,
            "ablation": _ablation(s, lv, mg, conj, measured2, label),
        }
    run = {g: us for g, us in groups.items() if us}
    if not run:
        return None
    rules = {g: J.count_rule(rule_for(s, g, rule3)[0], lv, rule3) for g in run}
    family = family_p3(s, scale, seeds, run) if lv == "pooled" and not conj else ()
    res = J3.judge_v3(run, lv, mg, rules, conj, family)
    partial = any(not us for us in groups.values())  # a part the scale did not run may hold or not

    def finish(x: str) -> str:
        return combine_bounded([x, report.INCONCLUSIVE]) if partial else x

    status = finish(res.status)
    ablation = _ablation(s, lv, mg, conj, measured2 if rule3 != rule2 else run, status, family, finish)
    effects = thesis_effects(s, rule3)
    thesis = _finite(T.thesis_excluded([u for us in run.values() for u in us], effects))
    cal: dict[str, Any] = {}
    if with_null and scale != "smoke":
        cal = calibration_v3_of(s, scale, run, lv, mg, rules, conj, effects, compute=with_null is True)
    if scale == "smoke":
        status = report.NOT_JUDGED
    # the gate reads the calibration: a caller that skips it (``with_null`` False: the fresh seeds' check, `claims
    # --no-null`) gets the statistical label; the book, RESULTS.md and `claims` read the cached calibration
    gate = seeds is None and scale != "smoke" and bool(with_null)
    label, reason = J3.gated(status, cal) if gate else (status, "")
    primary = {g: {k: v for k, v in info.items() if k != "units"} for g, info in res.groups.items()}
    return {
        "status": status,
        "label": label,
        "reason": reason,
        "level": res.level,
        "margin": mg,
        "conjunction": conj,
        "n_seeds": res.n_seeds,
        "groups": {g: {"verdict": i["verdict"], "level": LEVEL, "units": i["units"]} for g, i in res.groups.items()},
        "primary": primary if len(primary) > 1 else next(iter(primary.values())),
        "shares": {g: _share(info) for g, info in res.groups.items()},
        "calibration": cal,
        "thesis_effect": thesis,
        "ablation": ablation,
    }


def _corrupt(s: Spec, scale: str, err: snapshot.CorruptSnapshot) -> Row:
    """The row of a claim whose shipped numbers are corrupt: not computed, with the command that recomputes them."""
    return Row(s, report.NOT_COMPUTED, note=f"{err}: `make {make_target(s.page)} SCALE={scale}` recomputes it")


def _judge_frames(
    s: Spec,
    scale: str,
    with_null: bool | str,
    frames: Mapping[str, pd.DataFrame],
    meta: dict[str, Any],
    seeds: Sequence[int] | None = None,
) -> Row:
    """:func:`judge` of a claim with a measure, from its pages' saved ``frames`` and ``meta``: design v2's verdict
    (:mod:`thesis_repro.claims.judge`), with design v1's beside it; ``seeds``: the frames hold only these training
    seeds' rows (the confirmatory check), and so does Holm's family (:func:`family_p`)."""
    rule2, lv, mg = design.rule(s.rule, s.v2), design.level(s.v2), design.margin(s.v2)
    measured = _measure(frames, rule2)
    v1 = _judge_v1_frames(s, scale, False, frames, meta, measured if rule2 == s.rule else None)
    v3 = _judge_v3(s, scale, with_null, frames, measured, seeds)
    try:
        groups = _units(measured)
    except (M.NotRun, M.Inconclusive):
        v1.v1_status, v1.v1_statistic, v1.level, v1.margin = v1.status, v1.statistic, lv, mg
        return _as_v3(v1, v3)
    run = {g: us for g, us in groups.items() if us}
    not_run = [g for g, us in groups.items() if not us]
    if not run:
        return _as_v3(v1, v3)
    rules = {g: J.count_rule(rule_for(s, g, rule2)[0], lv, rule2) for g in run}
    family = family_p(s, scale, seeds) if lv == "pooled" else ()
    res = J.judge_v2(run, lv, mg, rules, family)
    status = res.status
    if not_run:  # a part the scale did not run may hold or not
        status = combine_bounded([status, report.INCONCLUSIVE])
    if scale == "smoke":
        status = report.NOT_JUDGED
    primary = {g: {k: v for k, v in info.items() if k != "units"} for g, info in res.groups.items()}
    gsum = {g: {"verdict": info["verdict"], "level": LEVEL, "units": info["units"]} for g, info in res.groups.items()}
    shares = {g: _share(info) for g, info in res.groups.items()}
    row = Row(
        s,
        status,
        res.n_seeds or v1.n_seeds,
        shares if len(shares) > 1 else next(iter(shares.values())),
        gsum,
        note=v1.note,
        v1_status=v1.status,
        v1_statistic=v1.statistic,
        level=lv,
        margin=mg,
        primary=primary if len(primary) > 1 else next(iter(primary.values())),
    )
    row.pooled_seeds = v1.pooled_seeds
    if s.subset and seeds is None:  # the confirmatory check (seeds given) keeps only its verdict
        row.subset = subset_check(s, scale, frames)
    if with_null and scale != "smoke":
        row.calibration = calibration_of(s, scale, run, lv, mg, rules, rule2, compute=with_null is True)
        row.null_pass_rate = row.calibration.get("false_reproduces")
    if status == report.INDICATIVE:  # one seed: no spread to report; v1's lean and its measured sensitivity
        row.diagnosis, row.sensitivity = v1.diagnosis, v1.sensitivity
    elif status not in (report.REPRODUCES, report.NOT_JUDGED):
        measured = [m for m in (study_result(n) for n in s.sensitivity) if m is not None]
        shim = {g: _Judged(info["units"], LEVEL) for g, info in res.groups.items()}
        row.diagnosis = diagnose(shim, meta, measured)
        row.sensitivity = [sensitivity_dict(m) for m in measured]
    return _as_v3(row, v3)


def _finite(x: Any) -> Any:
    """``x`` with every non-finite float (a CI that does not exist) as None, so equal rows compare equal (JSON)."""
    if isinstance(x, dict):
        return {k: _finite(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_finite(v) for v in x]
    return None if isinstance(x, float) and not math.isfinite(x) else x


def _ablation(
    s: Spec,
    lv: str,
    mg: float,
    conj: bool,
    measured2: Mapping[str, Sequence[Unit]] | Exception,
    status: str,
    family: Sequence[float] = (),
    finish: Any = lambda x: x,
) -> dict[str, str]:
    """What each v3 change moves, added one at a time (the deviations page): v3's statistics alone (on v2's rule's
    units, no conjunction), then the conjunction; v3's rule overrides then give ``status`` and the gate the label."""
    try:
        run2 = {g: list(us) for g, us in _units(measured2).items() if us}  # type: ignore[arg-type]
    except (M.NotRun, M.Inconclusive) as err:
        x = report.INCONCLUSIVE if isinstance(err, M.Inconclusive) else report.NOT_RUN
        return {"statistics": x, "conjunction": x}
    if not run2:
        return {"statistics": status, "conjunction": status}
    rule2 = design.rule(s.rule, s.v2)
    rules = {g: J.count_rule(rule_for(s, g, rule2)[0], lv, rule2) for g in run2}
    return {
        "statistics": finish(J3.judge_v3(run2, lv, mg, rules, False, family, False).status),
        "conjunction": finish(J3.judge_v3(run2, lv, mg, rules, conj, family, False).status),
    }


def _as_v3(row: Row, v3: dict[str, Any] | None) -> Row:
    """``row`` (design v2's, with v1's beside it) turned into design v3's: v3's label, statistic and units become
    the row's, v2's move beside them (``v2_status``, ``v2_primary``, ``v2_groups``)."""
    row.v2_status, row.v2_primary, row.v2_groups = row.status, row.primary, row.groups
    row.v2_calibration = row.calibration
    if v3 is None:  # v3 judges what v2 judges: a measure that cannot run is the same label under both
        row.v3 = {"status": row.status, "reason": ""}
        return row
    if "note" in v3:  # v3's rule leaves nothing to judge (e.g. every run of the learner diverged)
        row.status, row.note = v3["label"], v3["note"]
        row.primary, row.groups, row.statistic, row.calibration = {}, {}, {}, {}
        row.v3 = {k: v3[k] for k in ("status", "reason", "conjunction", "ablation")}
        return row
    row.status = v3["label"]
    row.primary = v3["primary"]
    row.groups = v3["groups"]
    row.calibration = v3["calibration"]
    row.statistic = v3["shares"] if len(v3["shares"]) > 1 else next(iter(v3["shares"].values()))
    row.level, row.margin = v3["level"], v3["margin"]
    row.n_seeds = v3["n_seeds"] or row.n_seeds
    row.null_pass_rate = v3["calibration"].get("false_reproduces")
    row.v3 = {k: v3[k] for k in ("status", "reason", "conjunction", "thesis_effect", "ablation")}
    return row


def _share(info: Mapping[str, Any]) -> dict[str, Any]:
    """A group's yes-share statistic under v2 (the shape of :meth:`~thesis_repro.claims.stats.Judgement.statistic`):
    CI-supported yes units, their interval ``[yes / n, (yes + undecided) / n]`` and the point estimates' share."""
    k, und, n = info["k"], info["undecided"], info["n"]
    if not n:
        return {"value": None, "ci": [None, None], "k": 0, "n": 0}
    point = sum(u.get("point") == "yes" for u in info["units"]) / n
    return {"value": point, "ci": [k / n, (k + und) / n], "k": k, "undecided": und, "n": n}


@dataclass
class _Judged:
    """What :func:`diagnose` reads of a group's judgement: its units and their CI level."""

    units: list[dict[str, Any]]
    level: float


def family_p(s: Spec, scale: str, seeds: Sequence[int] | None = None) -> list[float]:
    """The decisive p-values of the other pooled claims that read ``s``'s page data (Holm's family), on ``seeds``
    only when given."""
    out: list[float] = []
    for f in specs():
        if f.id == s.id or f.rule.get("derived") or "measure" not in f.rule or design.level(f.v2) != "pooled":
            continue
        if not set(f.data_pages) & set(s.data_pages):
            continue
        out += _decisive_ps(f, scale, None if seeds is None else tuple(seeds))
    return out


def family_p3(s: Spec, scale: str, seeds: Sequence[int] | None, own: Mapping[str, Sequence[Unit]]) -> list[float]:
    """Design v3's Holm family of ``s``: the decisive p-values of the other *distinct* pooled tests that read its
    page data (a test with the same units as one of ``s``'s own groups, or as another member, counts once)."""
    seen = {J.units_key({"": us}, "") for us in own.values()}
    out: list[float] = []
    for f in specs():
        if f.id == s.id or f.rule.get("derived") or "measure" not in f.rule:
            continue
        if design.level3(f.v2, f.v3) != "pooled" or design.conjunction(f.v3):
            continue
        if not set(f.data_pages) & set(s.data_pages):
            continue
        for key, p in _decisive_ps3(f, scale, None if seeds is None else tuple(seeds)):
            if key not in seen:
                seen.add(key)
                out.append(p)
    return out


def _decisive_ps3(f: Spec, scale: str, seeds: tuple[int, ...] | None) -> list[tuple[str, float]]:
    """Claim ``f``'s v3 decisive p-value per group of units, each with its units' content key (memoised)."""

    def compute() -> list[tuple[str, float]]:
        got = page_data(f, scale, seeds)
        if got is None:
            return []
        rule3 = design.rule3(f.rule, f.v2, f.v3)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                groups = M.MEASURES[rule3["measure"]](got[0], rule3)
        except (M.NotRun, M.Inconclusive):
            return []
        mg = design.margin3(f.v2, f.v3)
        return [(J.units_key({"": us}, ""), T.decisive(T.pooled_test(us, mg))) for us in groups.values() if us]

    return in_pass(("decisive3", f.id, scale, seeds), compute)


def _decisive_ps(f: Spec, scale: str, seeds: tuple[int, ...] | None) -> list[float]:
    """Claim ``f``'s decisive p-value per group of units (memoised within a :func:`ledger` pass)."""

    def compute() -> list[float]:
        got = page_data(f, scale, seeds)
        if got is None:
            return []
        rule2 = design.rule(f.rule, f.v2)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                groups = M.MEASURES[rule2["measure"]](got[0], rule2)
            return [J.decisive_p(pooled(us, design.margin(f.v2))) for us in groups.values() if us]
        except (M.NotRun, M.Inconclusive):
            return []

    return in_pass(("decisive", f.id, scale, seeds), compute)


def calibration_of(
    s: Spec,
    scale: str,
    run: Mapping[str, Sequence[Unit]],
    lv: str,
    mg: float,
    rules: Mapping[str, CountRule],
    rule2: Mapping[str, Any],
    compute: bool = True,
) -> dict[str, Any]:
    """A claim's calibration and power (:func:`thesis_repro.claims.calibration.calibration_result`), cached by the
    content of its units and rule: the build's cache first, then the shipped snapshot's."""
    key = J.units_key(run, design.rule_hashes(design.PREVIOUS).get(s.id, "") + design.engine_of(design.PREVIOUS))
    return _cached_calibration(
        scale, key, compute, lambda: calibration.calibration_result(run, lv, mg, rules, thesis_effects(s, rule2))
    )


def calibration_v3_of(
    s: Spec,
    scale: str,
    run: Mapping[str, Sequence[Unit]],
    lv: str,
    mg: float,
    rules: Mapping[str, CountRule],
    conj: bool,
    effects: Mapping[str, float],
    compute: bool = True,
) -> dict[str, Any]:
    """A claim's v3 calibration and power (:func:`thesis_repro.claims.calibration.calibration_v3`), cached by the
    content of its units with their seeds and its v3 rule and engine."""
    seeds = {
        g: [[list(getattr(c.a, "seeds", ())), list(getattr(c.b, "seeds", ()))] for u in us for c in u.contrasts()]
        for g, us in sorted(run.items())
    }
    salt = json.dumps(seeds, sort_keys=True) + design.rule_hashes().get(s.id, "") + design.calibration_hash()
    key = "v3:" + J.units_key(run, salt)
    return _cached_calibration(
        scale, key, compute, lambda: calibration.calibration_v3(run, lv, mg, rules, conj, effects)
    )


def _cached_calibration(scale: str, key: str, compute: bool, make: Any) -> dict[str, Any]:
    """The calibration entry ``key``: the build's cache first, then the shipped snapshot's, else ``make()`` (when
    ``compute``) written atomically into the build's cache."""
    store = paths.figures_dir(scale) / CALIBRATION
    for p in (paths.page_output(scale, CALIBRATION), snapshot.folder(scale) / CALIBRATION):
        known = read_json(p)
        if key in known:
            _USED[key] = known[key]
            return known[key]
    if not compute:
        return {}
    got = _USED[key] = make()
    known = read_json(store)
    known[key] = got
    store.parent.mkdir(parents=True, exist_ok=True)
    tmp = store.with_suffix(f".{os.getpid()}.tmp")
    tmp.write_text(json.dumps(known, sort_keys=True, indent=0))
    tmp.replace(store)
    return got


#: Calibration entries read or computed in this process, by key (what :func:`ship_calibration` ships).
_USED: dict[str, dict[str, Any]] = {}


def ship_calibration(scale: str) -> Path:
    """Judge every claim at ``scale`` computing what is not cached, and write the calibration and power of exactly
    those claims into the shipped snapshot (``data/reference/claims/<scale>/claims-calibration.json``), so a fresh
    clone's ``claims --json`` carries them without recomputing."""
    _USED.clear()
    ledger(scale, with_null=True)
    out = snapshot.folder(scale) / CALIBRATION
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(".tmp")
    tmp.write_text(json.dumps(dict(sorted(_USED.items())), sort_keys=True, indent=0) + "\n")
    tmp.replace(out)
    return out


def _measure(frames: Mapping[str, pd.DataFrame], rule: Mapping[str, Any]) -> dict[str, list[Unit]] | Exception:
    """A rule's measure on ``frames``: its units per group, or the :class:`~thesis_repro.claims.measures.NotRun` /
    ``Inconclusive`` it raised (kept, so that v1 and v2 share one measurement when their rules are the same)."""
    try:
        with warnings.catch_warnings():  # empty slices of a scale's missing cells are skipped as NaN
            warnings.simplefilter("ignore", RuntimeWarning)
            return M.MEASURES[rule["measure"]](frames, rule)
    except (M.NotRun, M.Inconclusive) as err:
        return err


def _units(measured: dict[str, list[Unit]] | Exception) -> dict[str, list[Unit]]:
    """The units of a :func:`_measure` (a copy of each group's list, so no judge sees another's changes), or its
    exception raised again."""
    if isinstance(measured, Exception):
        raise measured
    return {g: list(us) for g, us in measured.items()}


def _judge_v1_frames(
    s: Spec,
    scale: str,
    with_null: bool,
    frames: Mapping[str, pd.DataFrame],
    meta: dict[str, Any],
    measured: dict[str, list[Unit]] | Exception | None = None,
) -> Row:
    """Design v1's :func:`judge` of a claim with a measure (kept to show each claim's v1 verdict beside v2's);
    ``measured``: its measure's :func:`_measure` when already taken (v2's, under the same rule)."""
    r = s.rule
    try:
        groups = _units(_measure(frames, r) if measured is None else measured)
    except M.NotRun as err:
        return Row(s, report.NOT_RUN, note=str(err))
    except M.Inconclusive as err:
        return Row(s, report.INCONCLUSIVE, note=str(err))
    run = {g: us for g, us in groups.items() if us}
    not_run = [g for g, us in groups.items() if not us]
    if not run:
        return Row(s, report.NOT_COMPUTED, note="no unit could be computed from the saved numbers")
    judged = {g: rule_for(s, g)[0].judge(us) for g, us in run.items()}
    status = combine_groups([j.status for j in judged.values()])
    if not_run and status == report.REPRODUCES:
        status = report.PARTLY
    n_seeds = min((j.n_seeds for j in judged.values() if j.n_seeds > 0), default=0)
    stat = {g or "all": j.statistic() for g, j in judged.items()}
    gsum = {
        g or "all": {"verdict": j.status, "leaning": j.leaning, "level": j.level, "units": j.units}
        for g, j in judged.items()
    }
    if scale == "smoke":
        status = report.NOT_JUDGED
    note, lean = "", ""
    pooled = M.pooled_seeds(r["measure"], frames)
    if status == report.INDICATIVE:
        lean = combine_groups([j.leaning for j in judged.values()])
        why = no_ci_words(pooled)
        note = (
            f"{why}; the point estimates do not decide (a unit has none)"
            if lean == report.INCONCLUSIVE
            else f"{why}; the point estimates lean '{lean}'"
        )
    if not_run:
        note += ("; " if note else "") + "not judged (not run): " + ", ".join(not_run)
    rate = _null_rate(s, scale, run, meta.get("versions", [])) if with_null else None
    row = Row(s, status, n_seeds, stat if len(stat) > 1 else next(iter(stat.values())), gsum, rate, note)
    row.pooled_seeds = pooled
    if status in (report.DOES_NOT, report.PARTLY, report.INCONCLUSIVE):
        measured = [m for m in (study_result(n) for n in s.sensitivity) if m is not None]
        row.diagnosis = diagnose(judged, meta, measured)
        row.sensitivity = [sensitivity_dict(m) for m in measured]
    elif status == report.INDICATIVE and lean != report.REPRODUCES:
        # one seed leaning away from the claim: no seed spread to report, but the training regime and any
        # measured protocol sensitivity still say how much the lean can be trusted
        measured = [m for m in (study_result(n) for n in s.sensitivity) if m is not None]
        row.diagnosis = diagnose({}, meta, measured)
        row.sensitivity = [sensitivity_dict(m) for m in measured]
    return row


def subset_check(s: Spec, scale: str, frames: Mapping[str, pd.DataFrame]) -> dict[str, Any]:
    """The claim's registered subset sensitivity check (:func:`thesis_repro.claims.sensitivity.judge_subset`) on the
    subset's rows: design v3's seed-keyed rule, count rules and Holm family, as its primary verdict (the statistical
    label: no calibration gate, as the fresh seeds' check), with design v2's beside it (``v2_verdict``,
    ``v2_primary``, ``v2_ours``); ``ours`` is its number (:func:`ours_text`) and ``line`` the one line its page folds
    under the verdict."""
    rule2, lv2, mg2 = design.rule(s.rule, s.v2), design.level(s.v2), design.margin(s.v2)
    rule3 = design.rule3(s.rule, s.v2, s.v3)
    lv3, mg3, conj = design.level3(s.v2, s.v3), design.margin3(s.v2, s.v3), design.conjunction(s.v3)
    family2 = family_p(s, scale) if lv2 == "pooled" else ()

    def v2(run: Mapping[str, Sequence[Unit]]) -> Any:
        return J.judge_v2(run, lv2, mg2, {g: J.count_rule(rule_for(s, g, rule2)[0], lv2, rule2) for g in run}, family2)

    def v3(run: Mapping[str, Sequence[Unit]]) -> Any:
        rules = {g: J.count_rule(rule_for(s, g, rule3)[0], lv3, rule3) for g in run}
        family = family_p3(s, scale, None, run) if lv3 == "pooled" and not conj else ()
        return J3.judge_v3(run, lv3, mg3, rules, conj, family)

    judged = scale != "smoke"
    info = subsets.judge_subset(s.subset, frames, rule3, v3, judged)
    before = subsets.judge_subset(s.subset, frames, rule2, v2, judged)
    info["v2_verdict"], info["v2_primary"] = before["verdict"], before.get("primary", {})
    ours = ours_text(Row(s, str(info["verdict"]), primary=info["primary"])) if info.get("primary") else ""
    v2_ours = ours_text(Row(s, str(before["verdict"]), primary=before["primary"])) if before.get("primary") else ""
    return {**info, "ours": ours, "v2_ours": v2_ours, "line": subsets.text(info, ours)}


def budget_check(s: Spec, scale: str, meta: Mapping[str, Any]) -> dict[str, Any]:
    """The claim's thesis-budget verdict (:func:`thesis_repro.claims.thesis_budget.judge_on_study`) on the study's
    frames its page saved: design v3's seed-keyed rule, count rules and Holm family (taken on the same frames), as its
    primary verdict (the statistical label, as the subset and fresh seeds' checks), with design v2's beside it
    (``v2_verdict``, ``v2_ours``); ``ours`` is its number (:func:`ours_text`) and ``line`` its one line."""
    rule2, lv2, mg2 = design.rule(s.rule, s.v2), design.level(s.v2), design.margin(s.v2)
    rule3 = design.rule3(s.rule, s.v2, s.v3)
    lv3, mg3, conj = design.level3(s.v2, s.v3), design.margin3(s.v2, s.v3), design.conjunction(s.v3)

    def v2(run: Mapping[str, Sequence[Unit]], frames: Mapping[str, pd.DataFrame]) -> Any:
        family = budget.holm_family_on(s, frames, run, 2) if lv2 == "pooled" else ()
        return J.judge_v2(run, lv2, mg2, {g: J.count_rule(rule_for(s, g, rule2)[0], lv2, rule2) for g in run}, family)

    def v3(run: Mapping[str, Sequence[Unit]], frames: Mapping[str, pd.DataFrame]) -> Any:
        rules = {g: J.count_rule(rule_for(s, g, rule3)[0], lv3, rule3) for g in run}
        family = budget.holm_family_on(s, frames, run, 3) if lv3 == "pooled" and not conj else ()
        return J3.judge_v3(run, lv3, mg3, rules, conj, family)

    judged = scale != "smoke"
    info = budget.judge_on_study(meta, rule3, v3, judged)
    before = budget.judge_on_study(meta, rule2, v2, judged)
    info["v2_verdict"] = before["verdict"]
    ours = ours_text(Row(s, str(info["verdict"]), primary=info["primary"])) if info.get("primary") else ""
    v2_ours = ours_text(Row(s, str(before["verdict"]), primary=before["primary"])) if before.get("primary") else ""
    return {**info, "ours": ours, "v2_ours": v2_ours, "line": budget.thesis_budget_line(info, ours)}


def _null_rate(s: Spec, scale: str, run: Mapping[str, Sequence[Unit]], versions: Sequence[str]) -> float:
    """:func:`~thesis_repro.claims.stats.null_pass_rate` of a claim, cached per version of the saved numbers it
    was judged from (:func:`saved_blob`'s ``version``)."""
    key = f"{s.id}|" + "|".join(versions)
    store = paths.figures_dir(scale) / "claims-null.json"
    known_at = paths.page_output(scale, store.name)  # inside a notebook: start from the finished pages' cache
    known = json.loads(known_at.read_text()) if known_at.exists() else {}
    if key not in known:
        known = {k: v for k, v in known.items() if not k.startswith(f"{s.id}|")}
        known[key] = null_pass_rate(run, {g: rule_for(s, g)[0] for g in run}, NULL_DRAWS)
        store.parent.mkdir(parents=True, exist_ok=True)
        tmp = store.with_suffix(f".{s.id}.tmp")
        tmp.write_text(json.dumps(known))
        tmp.replace(store)
    return float(known[key])


def ledger(scale: str, with_null: bool | str = CACHED) -> list[Row]:
    """Every registered claim judged at ``scale`` from saved numbers (thesis claims first, then beyond)."""
    with one_pass():
        rows = [judge(s, scale, with_null) for s in specs()]
    return sorted(rows, key=lambda r: r.spec.beyond)
