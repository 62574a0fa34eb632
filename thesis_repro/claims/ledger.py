"""The claims ledger: one verdict per thesis sentence, from the registry's pre-registered rules.

The registry is ``data/thesis/claims.yaml``: under each page, ``claims`` quote the thesis (a claim with a
``rule`` is judged on that page; the same ``id`` on another page only repeats its verdict), and ``beyond``
holds the kit's own extensions (kl_exact, the Eq 4.11 analysis), counted apart. A claim may name the protocol
studies its evidence rests on (``sensitivity: [lr-schedule]``, :data:`thesis_repro.study.STUDIES`): a claim
that does not (fully) reproduce then shows each study's measured difference in its "why" (from the study's
cached / shipped runs; nothing when they are not available, never trained here). A notebook ends with
:func:`judge_page`, which saves its per-seed numbers to ``build/<scale>/figures/<page>.data.json`` and
prints the verdicts of its claims; :func:`ledger` re-judges every claim from those saved numbers (no
training, no evaluation), so the book's scoreboard and ``python -m thesis_repro claims`` read one ledger. Where
a build has no fresh copy of a page's numbers (a fresh clone before its book), the shipped claims snapshot's
(:mod:`thesis_repro.claims.snapshot`) are judged instead, and each row says so (``shipped``).

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
from collections import Counter
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from thesis_repro import paths
from thesis_repro.claims import calibration, design, report, snapshot
from thesis_repro.claims import judge as J
from thesis_repro.claims import measures as M
from thesis_repro.claims import sensitivity as subsets
from thesis_repro.claims.confirmatory import (
    FIRST_FRESH,
    FRESH_SEEDS,
    Confirmation,
    fresh_frames,
    fresh_seeds,
    fresh_summary,
    seeds_in,
)
from thesis_repro.claims.registry import (  # noqa: F401 - parse_specs, reads, registry: re-exported for callers
    Spec,
    data_name,
    page_claims,
    parse_specs,
    reads,
    registry,
    spec,
    specs,
)
from thesis_repro.claims.stats import (
    LEVEL,
    CountRule,
    Unit,
    _point,
    combine_bounded,
    combine_groups,
    null_pass_rate,
    pooled,
    unit_seed_effects,
)

#: Statuses counted on the scoreboard, in its column order.
COUNTED: tuple[str, ...] = (
    report.REPRODUCES,
    report.AT_LEAST_PARTLY,
    report.PARTLY,
    report.AT_MOST_PARTLY,
    report.DOES_NOT,
    report.INCONCLUSIVE,
    report.INDICATIVE,
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
    report.NOT_RUN: "not run",
    report.NOT_JUDGED: "not judged",
    report.NOT_COMPUTED: "not computed",
    report.VISUAL: "visual",
}
UNIT_OF_REPLICATION = "training seeds (values averaged over rollouts / episodes inside each seed first)"
#: Fraction of the thesis's own k/n a "thesis"-tied threshold asks for.
THESIS_SHARE = 0.75
NULL_DRAWS = 60
#: The build's (and the shipped snapshot's) cache of v2 calibration and power, keyed by content.
CALIBRATION = "claims-calibration.json"
#: ``judge(with_null=CACHED)``: calibration and power from the caches only, never computed.
CACHED = "cached"


# ---------------------------------------------------------------- thresholds (from the thesis's own numbers)
#: The thesis table(s) whose learners a page's thesis-tied threshold is counted on.
THESIS_TABLES: dict[str, tuple[str, ...]] = {
    "table-3.4": ("table3_4",),
    "table-3.5": ("table3_5",),
    "fig-3.5": ("table3_5",),
    "table-3.6": ("table3_6",),
    "table-3.7": ("table3_7",),
}


def thesis_data(page: str = "") -> dict[str, pd.DataFrame]:
    """The thesis's Tables 3.3-3.7 as one-pseudo-seed frames (its means), for thesis-tied thresholds; AUCs of
    the page's own table (:data:`THESIS_TABLES`; all four tables otherwise)."""
    from thesis_repro import thesis_numbers

    names = THESIS_TABLES.get(page, ("table3_4", "table3_5", "table3_6", "table3_7"))
    frames = [thesis_numbers.load(n) for n in names]
    t = pd.concat(frames).drop_duplicates(subset=["env", "test", "method"])
    aucs = t.assign(seed=0, value=t["mean"])[["env", "test", "method", "seed", "value"]]
    b = thesis_numbers.load("table3_3b")
    method = [("ppo" if s == 0 else M.NOISY[n]) for n, s in zip(b["noise_type"], b["train_sigma"], strict=True)]
    ret = pd.DataFrame(
        {
            "env": "Walker2d",
            "method": method,
            "seed": 0,
            "test": b["noise_type"],
            "sigma": b["sigma_te"],
            "return": b["mean"],
        }
    )
    a = thesis_numbers.load("table3_3a")
    names = {"none": "ppo", "obs": M.NOISY["obs"], "act": M.NOISY["act"], "env": M.NOISY["env"], "mdl": "ppo-mdl"}
    train = pd.DataFrame(
        {"env": "Walker2d", "method": [names[n] for n in a["noise_type"]], "seed": 0, "value": a["mean"]}
    )
    return {"aucs": aucs, "returns": ret, "train": train}


@cache
def thesis_fractions(claim_id: str) -> dict[str, tuple[int, int]]:
    """Per group of a claim: the thesis's own (k, n), its rule's units counted on the thesis's means."""
    s = spec(claim_id)
    groups = M.MEASURES[s.rule["measure"]](thesis_data(s.page), s.rule)
    return {g: (sum(_point(u) == "yes" for u in us), len(us)) for g, us in groups.items()}


def rule_for(s: Spec, group: str = "", rule: Mapping[str, Any] | None = None) -> tuple[CountRule, str]:
    """The count rule of a claim's group (under ``rule``, default its v1 rule) and the sentence saying where its
    threshold comes from."""
    r = dict(s.rule if rule is None else rule)
    r.update((r.get("groups") or {}).get(group, {}))
    partly = r.get("partly", 0.25)
    absolute = bool(r.get("absolute", False))
    if r.get("reproduces") == "thesis":
        k, n = r["thesis_k_n"] if "thesis_k_n" in r else thesis_fractions(s.id).get(group, (0, 0))
        floor = float(r.get("floor", 0.5))
        q = max(floor, round(THESIS_SHARE * k / n, 3)) if n else floor
        basis = f"thesis {k}/{n} on its own table; threshold max({floor:g}, {THESIS_SHARE:g} x {k}/{n}) = {q:.3g}"
    else:
        q = float(r.get("reproduces", 0.5))
        basis = r.get("basis", "the sentence's wording (the thesis reports no k/n)")
    return CountRule(q, None if partly is None else float(partly), absolute, bool(r.get("bonferroni", False))), basis


# ---------------------------------------------------------------- saved page numbers
def data_path(page: str, scale: str) -> Path:
    """``build/<scale>/figures/<page>.data.json``: the per-seed numbers a notebook saved for its claims."""
    return paths.figures(scale) / data_name(page)


def save_page(page: str, scale: str, frames: Mapping[str, pd.DataFrame], meta: Mapping[str, Any]) -> Path:
    """Write a page's per-seed frames (records) and meta (scale, seeds, budget note) atomically, stamped
    with :func:`~thesis_repro.paths.code_stamp` over the kit modules this process imported."""
    out = data_path(page, scale)
    out.parent.mkdir(parents=True, exist_ok=True)
    blob = {
        "page": page,
        "scale": scale,
        **report.stamp(page),
        "meta": dict(meta),
        "frames": {k: json.loads(v.to_json(orient="records")) for k, v in frames.items()},
    }
    tmp = out.with_suffix(".tmp")
    tmp.write_text(json.dumps(blob, default=_jsonable))
    tmp.replace(out)
    return out


def _jsonable(x: Any) -> Any:
    if isinstance(x, (np.integer, np.floating)):
        return x.item()
    if isinstance(x, (set, tuple)):
        return list(x)
    return str(x)


def saved_blob(page: str, name: str, scale: str) -> dict[str, Any] | None:
    """The file ``name`` (``<page>.data.json`` or ``<page>.verdicts.json``) as ``page`` saved it at ``scale``, or
    None: the build's copy (inside a notebook, also a finished page's: :func:`~thesis_repro.paths.page_output`)
    unless it is missing or stale and the shipped snapshot (:mod:`~thesis_repro.claims.snapshot`) has one that is
    not. ``blob["stale"]``: written by other kit code (:func:`~thesis_repro.paths.code_stamp`);
    ``blob["shipped"]``: read from the snapshot; ``blob["version"]``: changes whenever the numbers may have.
    A corrupt shipped file with no build copy raises :class:`~thesis_repro.claims.snapshot.CorruptSnapshot`."""
    p = paths.page_output(scale, name)
    built = json.loads(p.read_text()) if p.exists() else None
    if built is not None:
        built["version"] = f"{p}@{p.stat().st_mtime_ns}"
    if built is not None and not report.is_stale(page, built):
        return {**built, "stale": False, "shipped": False}
    try:
        shipped = snapshot.read(name, scale)
    except snapshot.CorruptSnapshot:
        if built is None:
            raise
        shipped = None
    if shipped is not None and (built is None or not report.is_stale(page, shipped)):
        return {**shipped, "stale": report.is_stale(page, shipped), "shipped": True}
    return None if built is None else {**built, "stale": True, "shipped": False}


def load_page(page: str, scale: str) -> dict[str, Any] | None:
    """The saved blob of ``page`` (:func:`saved_blob`, frames as DataFrames) or None; read once per
    :func:`ledger` pass (:func:`_one_pass`)."""
    if _PASS is not None and (page, scale) in _PASS:
        return _PASS[(page, scale)]
    blob = saved_blob(page, data_path(page, scale).name, scale)
    if blob is not None:
        blob["frames"] = {k: pd.DataFrame(v) for k, v in blob["frames"].items()}
    if _PASS is not None:
        _PASS[(page, scale)] = blob
    return blob


#: Within one :func:`ledger` pass: the pages read and the measures run so far (pages do not change inside a pass).
_PASS: dict[Any, Any] | None = None


@contextmanager
def _one_pass() -> Iterator[None]:
    """Read each page and run each claim's measure once while judging every claim (Holm's families re-read the
    same pages); outside a pass every call reads afresh, as a notebook that just saved its numbers needs."""
    global _PASS
    outer, _PASS = _PASS, _PASS if _PASS is not None else {}
    try:
        yield
    finally:
        _PASS = outer


def stale_pages(rows: Sequence[Row]) -> list[str]:
    """Pages whose saved numbers some of ``rows`` were judged from, written by other kit code (sorted)."""
    return sorted({p for r in rows for p in r.stale})


def _make_target(page: str) -> str:
    """The Makefile target of a page: ``table-3.4`` -> ``table-3.4``, ``fig-3.3`` -> ``figure-3.3``."""
    return page if page.startswith("table-") else f"figure-{page.removeprefix('fig-')}"


def not_computed_hint(rows: Sequence[Row], scale: str) -> str:
    """One line telling how to compute the claims whose pages have not run at ``scale`` ('' when none): the
    ledger judges saved page numbers, so a fresh clone has none until its book (or the pages) ran.

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
        f"`make {_make_target(pages[0])} SCALE={scale}` per page"
    )


def shipped_pages(rows: Sequence[Row]) -> list[str]:
    """Pages whose numbers some of ``rows`` were judged from came from the shipped snapshot (sorted)."""
    return sorted({p for r in rows for p in r.shipped})


def shipped_hint(rows: Sequence[Row], scale: str) -> str:
    """One line saying which pages' numbers came from the shipped snapshot ('' when none did).

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
    where = snapshot.provenance(scale)
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
        f"notebooks/ or data/thesis/ changed since); refresh them with `make {_make_target(pages[0])} "
        f"SCALE={scale}` per page, or `make book SCALE={scale}`"
    )


# ---------------------------------------------------------------- judging
@dataclass
class Row:
    """One ledger row (JSON-ready through :meth:`as_dict`)."""

    spec: Spec
    status: str
    n_seeds: int = 0
    statistic: dict[str, Any] = field(default_factory=dict)
    groups: dict[str, Any] = field(default_factory=dict)
    null_pass_rate: float | None = None
    note: str = ""
    diagnosis: str = ""
    sensitivity: list[dict[str, Any]] = field(default_factory=list)
    stale: list[str] = field(default_factory=list)  # pages whose saved numbers other kit code wrote
    shipped: list[str] = field(default_factory=list)  # pages whose numbers came from the shipped snapshot
    local_runs: dict[str, dict[str, Any]] = field(default_factory=dict)  # page -> its runs from the local cache
    pooled_seeds: int = 0  # > 0: each unit's one value is a statistic of this many seeds' means (no replication)
    v1_status: str = ""  # the verdict of design v1 (the registry's `rule:` as first registered)
    v1_statistic: dict[str, Any] = field(default_factory=dict)
    level: str = ""  # v2: pooled / each / count
    margin: float | None = None  # v2: the smallest effect of interest (margin units)
    primary: dict[str, Any] = field(default_factory=dict)  # v2's primary statistic (pooled effect or yes-share)
    calibration: dict[str, Any] = field(default_factory=dict)  # v2: false R / false D over null draws, power
    confirmation: Confirmation | None = None  # the same frozen rule on the fresh seeds alone (None: not shipped yet)
    subset: dict[str, Any] = field(default_factory=dict)  # the registered subset sensitivity check (subset_check)

    def as_dict(self) -> dict[str, Any]:
        s = self.spec
        return {
            "id": s.id,
            "page": s.page,
            "repeated_on": list(s.pages),
            "beyond_the_thesis": s.beyond,
            "thesis_lines": list(s.lines),
            "claim": s.text,
            "rule": rule_text(s),
            "unit": UNIT_OF_REPLICATION,
            "n_seeds": self.n_seeds,
            "pooled_seeds": self.pooled_seeds,
            "statistic": self.statistic,
            "verdict": self.status,
            "label": self.status,
            "design": design.stamp(),
            "v1_verdict": self.v1_status or self.status,
            "v1_statistic": self.v1_statistic,
            "level": self.level,
            "margin": self.margin,
            "margin_basis": s.v2.get("margin_basis", ""),
            "primary": self.primary,
            "calibration": self.calibration,
            "confirmatory": None if self.confirmation is None else self.confirmation.as_dict(),
            "short": s.v2.get("short", ""),
            "claim12": s.v2.get("claim12", ""),
            "thesis_value": s.v2.get("thesis_value", ""),
            "ours": ours_text(self),
            "headline": headline(self, width=1000),  # whole here; the terminal and pages cut at report.LINE
            "null_pass_rate": self.null_pass_rate,
            "note": self.note,
            "diagnosis": self.diagnosis,
            "sensitivity_studies": list(s.sensitivity),
            "protocol_sensitivity": self.sensitivity,
            "sensitivity": self.subset or None,
            "groups": self.groups,
            "stale_pages": self.stale,
            "shipped_pages": self.shipped,
            "local_runs": self.local_runs,
        }


def rule_text(s: Spec) -> str:
    """The pre-registered rule in one paragraph: statistic, units, thresholds and what each verdict means."""
    r = s.rule
    if r.get("visual"):
        return "not judged: the sentence is about what the figure looks like (the frames are shown on the page)"
    if "page_verdict" in r:
        return "the analysis page's own rule (thesis_repro.claims.analysis_4_kl.verdicts: share of synthetic problems)"
    if r.get("derived"):
        return f"derived: reproduces iff every one of {', '.join(r['derived'])} reproduces (statuses combined)"
    parts = [f"statistic: {r.get('statistic', '')}", f"units: {r.get('units', '')}"]
    groups = list((r.get("groups") or {}).keys()) or [""]
    for g in groups:
        rule, basis = rule_for(s, g)
        scale = "units (count)" if rule.absolute else "of the units"
        part = f" {rule.partly:g}" if rule.partly is not None else " (no partly region)"
        parts.append(
            f"{g + ': ' if g else ''}reproduces if the yes-share interval is >= {rule.reproduces:g} {scale}, "
            f"partly if >= {part.strip()}, does not below; inconclusive if the interval spans two regions "
            f"({basis})"
        )
    parts.append(
        "a unit is 'yes' when its 95 % CI across training seeds is on the claim's side"
        + (" (Bonferroni over units)" if r.get("bonferroni") else "")
    )
    parts.append("one seed: at most indicative")
    return "; ".join(parts)


def page_data(
    s: Spec, scale: str, seeds: Sequence[int] | None = None
) -> tuple[dict[str, pd.DataFrame], dict[str, Any]] | None:
    """The frames a claim's measure reads (``name`` for its own page, ``name@page`` for others) and meta
    (``meta["stale_pages"]``: those of its pages written by other kit code); with ``seeds``, only those training
    seeds' rows (None when the pages do not hold them all: :func:`~thesis_repro.claims.confirmatory.fresh_frames`)."""
    frames: dict[str, pd.DataFrame] = {}
    meta: dict[str, Any] = {}
    found, stale, shipped, versions, local = False, [], [], [], {}
    for p in s.data_pages:
        blob = load_page(p, scale)
        if blob is None:
            continue
        found = True
        versions.append(blob["version"])
        meta = meta or blob["meta"]
        stale += [p] if blob["stale"] else []
        shipped += [p] if blob["shipped"] else []
        if blob["meta"].get("local_runs"):
            local[p] = blob["meta"]["local_runs"]
        for k, v in blob["frames"].items():
            frames[f"{k}@{p}"] = v
            if p == s.page or len(s.data_pages) == 1:
                frames[k] = v
    extra = {"stale_pages": stale, "shipped_pages": shipped, "versions": versions, "local_runs": local}
    if found and seeds is not None:
        picked = fresh_frames(frames, seeds)
        if picked is None:
            return None
        frames = picked
    return (frames, {**meta, **extra}) if found else None


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
        status = combine_bounded([x.status for x in rows]) if scale != "smoke" else report.NOT_JUDGED
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
            confirmation=_derived_confirmation(rows, status),
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
    return row


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
    return Confirmation(c.status, ours_text(c), row.status, seeds)


def _derived_confirmation(parts: Sequence[Row], primary: str) -> Confirmation | None:
    """A derived claim's confirmatory verdict: its parts' combined, when every part has one."""
    got = [r.confirmation for r in parts]
    if not got or any(c is None for c in got):
        return None
    return Confirmation(combine_bounded([c.status for c in got if c]), "", primary)


def _corrupt(s: Spec, scale: str, err: snapshot.CorruptSnapshot) -> Row:
    """The row of a claim whose shipped numbers are corrupt: not computed, with the command that recomputes them."""
    return Row(s, report.NOT_COMPUTED, note=f"{err}: `make {_make_target(s.page)} SCALE={scale}` recomputes it")


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
    v1 = _judge_v1_frames(s, scale, False, frames, meta)
    rule2, lv, mg = design.rule(s.rule, s.v2), design.level(s.v2), design.margin(s.v2)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            groups = M.MEASURES[rule2["measure"]](frames, rule2)
    except (M.NotRun, M.Inconclusive):
        v1.v1_status, v1.v1_statistic, v1.level, v1.margin = v1.status, v1.statistic, lv, mg
        return v1
    run = {g: us for g, us in groups.items() if us}
    not_run = [g for g, us in groups.items() if not us]
    if not run:
        return v1
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
        row.subset = subset_check(s, frames, rule2, lv, mg, family, scale != "smoke")
    if with_null and scale != "smoke":
        row.calibration = calibration_of(s, scale, run, lv, mg, rules, rule2, compute=with_null is True)
        row.null_pass_rate = row.calibration.get("false_reproduces")
    if status == report.INDICATIVE:  # one seed: no spread to report; v1's lean and its measured sensitivity
        row.diagnosis, row.sensitivity = v1.diagnosis, v1.sensitivity
    elif status not in (report.REPRODUCES, report.NOT_JUDGED):
        measured = [m for m in (study_result(n) for n in s.sensitivity) if m is not None]
        shim = {g: _Judged(info["units"], LEVEL) for g, info in res.groups.items()}
        row.diagnosis = diagnose(shim, meta, measured)
        row.sensitivity = [_sensitivity_dict(m) for m in measured]
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


def _decisive_ps(f: Spec, scale: str, seeds: tuple[int, ...] | None) -> list[float]:
    """Claim ``f``'s decisive p-value per group of units (memoised within a :func:`ledger` pass)."""
    key = ("decisive", f.id, scale, seeds)
    if _PASS is not None and key in _PASS:
        return _PASS[key]
    got = page_data(f, scale, seeds)
    out: list[float] = []
    if got is not None:
        rule2 = design.rule(f.rule, f.v2)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                groups = M.MEASURES[rule2["measure"]](got[0], rule2)
            out = [J.decisive_p(pooled(us, design.margin(f.v2))) for us in groups.values() if us]
        except (M.NotRun, M.Inconclusive):
            out = []
    if _PASS is not None:
        _PASS[key] = out
    return out


def thesis_effects(s: Spec, rule2: Mapping[str, Any]) -> dict[str, float]:
    """Per unit label, the thesis's own effect in margin units (for power): Fig 3.3c's r per cell for the
    correlation measures, else the claim's measure on the thesis's tables (:func:`thesis_data`); ``{}`` when
    the thesis reports no number the measure can read."""
    from thesis_repro import thesis_numbers

    m = rule2.get("measure")
    if m in ("correlation", "mean_selection"):
        t = thesis_numbers.load("fig3_3c")
        return {f"{e}/{x}": -float(v) for e, x, v in zip(t["env"], t["test"], t["value"], strict=True)}
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            groups = M.MEASURES[m](thesis_data(s.page), rule2)
    except Exception:  # noqa: BLE001 - the thesis's tables cannot feed every measure: no thesis effect
        return {}
    out = {}
    for us in groups.values():
        for u in us:
            e = unit_seed_effects(u)
            e = e[np.isfinite(e)]
            if e.size:
                out[u.label] = float(e.mean())
    return out


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
    key = J.units_key(run, design.rule_hashes().get(s.id, "") + design.frozen().get("engine", ""))
    store = paths.figures(scale) / CALIBRATION
    for p in (paths.page_output(scale, CALIBRATION), snapshot.folder(scale) / CALIBRATION):
        known = _read_json(p)
        if key in known:
            _USED[key] = known[key]
            return known[key]
    if not compute:
        return {}
    got = _USED[key] = calibration.calibration_result(run, lv, mg, rules, thesis_effects(s, rule2))
    known = _read_json(store)
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


def _read_json(p: Path) -> dict[str, Any]:
    try:
        return json.loads(p.read_text())
    except (OSError, ValueError):
        return {}


def _judge_v1_frames(
    s: Spec, scale: str, with_null: bool, frames: dict[str, pd.DataFrame], meta: dict[str, Any]
) -> Row:
    """Design v1's :func:`judge` of a claim with a measure (kept to show each claim's v1 verdict beside v2's)."""
    r = s.rule
    try:
        with warnings.catch_warnings():  # empty slices of a scale's missing cells are skipped as NaN
            warnings.simplefilter("ignore", RuntimeWarning)
            groups = M.MEASURES[r["measure"]](frames, r)
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
        why = _no_ci_words(pooled)
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
        row.sensitivity = [_sensitivity_dict(m) for m in measured]
    elif status == report.INDICATIVE and lean != report.REPRODUCES:
        # one seed leaning away from the claim: no seed spread to report, but the training regime and any
        # measured protocol sensitivity still say how much the lean can be trusted
        measured = [m for m in (study_result(n) for n in s.sensitivity) if m is not None]
        row.diagnosis = diagnose({}, meta, measured)
        row.sensitivity = [_sensitivity_dict(m) for m in measured]
    return row


# ---------------------------------------------------------------- protocol sensitivity (thesis_repro.study)
_STUDY_RESULTS: dict[tuple[Any, ...], Any] = {}


def study_result(name: str) -> Any:
    """The protocol study ``name``'s :class:`~thesis_repro.study.Sensitivity` from the runs available in the
    run cache and the shipped layer, or ``None`` (never trains). Computed once per study function and cache
    location in a process."""
    from thesis_repro import study

    fn = study.STUDIES[name]
    key = (name, fn, str(paths.runs()), None if paths.retrain() else str(paths.reference()))
    if key not in _STUDY_RESULTS:
        _STUDY_RESULTS[key] = fn()
    return _STUDY_RESULTS[key]


def sensitivity_text(m: Any) -> str:
    """One "why" clause from a :class:`~thesis_repro.study.Sensitivity`: per task the difference with its Welch
    95 % CI across seeds, and whether every CI contains 0 (within seed spread)."""
    from thesis_repro.study import SHORT

    cells = []
    for i, e in enumerate(m.effects):
        lo, hi = e.ci
        ci = f"{'95 % CI ' if i == 0 else ''}{lo:,.0f} to {hi:,.0f}"
        cells.append(f"{SHORT.get(e.task, e.task)} {e.difference:+,.0f} ({ci})")
    if m.within_spread:
        verdict = "within seed spread"
    else:
        moved = [SHORT.get(e.task, e.task) for e in m.effects if not e.within_spread]
        verdict = f"outside seed spread on {', '.join(moved)} (the CI excludes 0)"
    head = f"{m.setting}, {m.learner}, {m.budget}, {m.seeds}; {m.measure}, {m.contrast}"
    return f"protocol sensitivity ({head}): {', '.join(cells)}: {verdict}"


def _sensitivity_dict(m: Any) -> dict[str, Any]:
    return {
        "study": m.study,
        "setting": m.setting,
        "learner": m.learner,
        "budget": m.budget,
        "contrast": m.contrast,
        "measure": m.measure,
        "within_seed_spread": m.within_spread,
        "effects": [
            {"task": e.task, "difference": e.difference, "ci": list(e.ci), "p": e.pvalue, "seeds": list(e.n)}
            for e in m.effects
        ],
    }


def subset_check(
    s: Spec,
    frames: Mapping[str, pd.DataFrame],
    rule2: Mapping[str, Any],
    lv: str,
    mg: float,
    family: Sequence[float],
    judged: bool = True,
) -> dict[str, Any]:
    """The claim's registered subset sensitivity check (:func:`thesis_repro.claims.sensitivity.check`: the same v2
    rule, count rules and Holm family as its primary verdict, on the subset's rows), with ``ours`` (its number, as
    :func:`ours_text`) and ``line`` (the one line its page folds under the verdict)."""
    info = subsets.check(
        s.subset, frames, rule2, lv, mg, lambda g: J.count_rule(rule_for(s, g, rule2)[0], lv, rule2), family, judged
    )
    ours = ours_text(Row(s, str(info["verdict"]), primary=info["primary"])) if info.get("primary") else ""
    return {**info, "ours": ours, "line": subsets.text(info, ours)}


def _null_rate(s: Spec, scale: str, run: Mapping[str, Sequence[Unit]], versions: Sequence[str]) -> float:
    """:func:`~thesis_repro.claims.stats.null_pass_rate` of a claim, cached per version of the saved numbers it
    was judged from (:func:`saved_blob`'s ``version``)."""
    key = f"{s.id}|" + "|".join(versions)
    store = paths.figures(scale) / "claims-null.json"
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


def diagnose(judged: Mapping[str, Any], meta: Mapping[str, Any], sensitivities: Sequence[Any] = ()) -> str:
    """Why a claim does not (fully) reproduce, from the kit's own measurements: seed spread, training regime
    (half vs final budget, :mod:`thesis_repro.budgets`), protocol sensitivity where measured (a page's
    ``meta["protocol"]``, and the claim's registered studies' results, :func:`study_result`)."""
    widths, against = [], []
    for j in judged.values():
        for u in j.units:
            for c in u["contrasts"]:
                lo, hi = c["ci"]
                if lo is not None and hi is not None:
                    widths.append(hi - lo)
            if u["outcome"] == "no":
                against.append(u["label"])
    bits = []
    if widths:
        ci = ci_words([j.level for j in judged.values()])
        bits.append(f"seed spread: median {ci} width {np.median(widths):.3g} over {len(widths)} contrasts")
    if against:
        bits.append(
            f"{len(against)} unit(s) significantly against the claim ({', '.join(against[:4])}"
            + (", ..." if len(against) > 4 else "")
            + ")"
        )
    b = meta.get("budgets")
    if b:
        bits.append(
            f"training regime: {b.get('trained', 0)}/{b.get('runs', 0)} runs trained, {b.get('still learning', 0)} "
            f"still learning (return at half vs final budget, make budgets), {b.get('fell from its peak', 0)} fell "
            "from their peak"
        )
    if meta.get("protocol"):
        bits.append(f"protocol sensitivity: {meta['protocol']}")
    bits.extend(sensitivity_text(m) for m in sensitivities)
    if meta.get("note"):
        bits.append(str(meta["note"]))
    return "; ".join(bits)


def ledger(scale: str, with_null: bool | str = CACHED) -> list[Row]:
    """Every registered claim judged at ``scale`` from saved numbers (thesis claims first, then beyond)."""
    with _one_pass():
        rows = [judge(s, scale, with_null) for s in specs()]
    return sorted(rows, key=lambda r: r.spec.beyond)


def counts(rows: Sequence[Row], beyond: bool = False) -> Counter:
    """Status counts of distinct claims (each claim once, whichever pages repeat it)."""
    return Counter(r.status for r in rows if r.spec.beyond == beyond)


def confirmatory_counts(rows: Sequence[Row]) -> Counter:
    """Confirmatory verdict counts of the distinct thesis claims (``not yet judged``: fresh seeds not shipped)."""
    return Counter(r.confirmation.status if r.confirmation else NOT_YET for r in rows if not r.spec.beyond)


#: A claim's confirmatory count when its pages do not hold the fresh seeds yet.
NOT_YET = "fresh seeds not yet shipped"


# ---------------------------------------------------------------- output
def _num(x: float | None) -> str:
    return "n/a" if x is None or not math.isfinite(x) else f"{x:+.2f}" if abs(x) < 100 else f"{x:+,.0f}"


def ours_text(row: Row) -> str:
    """The key number of a v2 verdict with its CI, in the claim's own sign: a pooled effect (r for correlations,
    else a fraction of the reference's value) and the units' count; or the count of yes units with the
    yes-share interval. ``''`` when the row has no v2 statistic.

    >>> pooled = {"estimate": -1.0986, "ci": [-1.472, -0.8673], "kind": "r", "sign": -1, "n_seeds": 3}  # in z
    >>> row = Row(Spec("x", "fig-3.3", "c", (555,), {}), "does not reproduce", primary={"pooled": pooled, "k": 0,
    ...     "n": 20})
    >>> ours_text(row)
    'pooled r +0.80 [+0.70, +0.90], 0/20 units yes'
    """
    prim = row.primary
    if not prim:
        return ""
    parts = [prim] if "n" in prim else [dict(v, group=g) for g, v in prim.items()]
    out = []
    for p in parts:
        head = f"{p['group']}: " if "group" in p else ""
        if "pooled" in p:
            q = p["pooled"]
            sign = q.get("sign", 1)
            est, lo, hi = (None if x is None else sign * x for x in (q["estimate"], *q["ci"]))
            if sign < 0:
                lo, hi = hi, lo
            if q["kind"] == "r":
                est, lo, hi = (None if x is None else math.tanh(x) for x in (est, lo, hi))
            what = "r" if q["kind"] == "r" else "effect"
            out.append(f"{head}pooled {what} {_num(est)} [{_num(lo)}, {_num(hi)}], {p['k']}/{p['n']} units yes")
        else:
            lo, hi = p.get("share_ci", [None, None])
            band = f" (share {lo:.2f}-{hi:.2f})" if lo is not None and hi is not None and lo != hi else ""
            out.append(f"{head}{p['k']}/{p['n']} units yes{band}")
    return "; ".join(out)


def headline(row: Row, width: int = 160) -> str:
    """One line per claim: label · id · l. lines short claim · thesis: value · ours: key number with its CI.

    >>> s = Spec("3.3-x", "fig-3.3", "c", (555,), {}, v2={"short": "negative correlation", "thesis_value": "18/20"})
    >>> headline(Row(s, "does not reproduce", primary={"k": 0, "n": 20}))
    'does not reproduce · 3.3-x · l. 555 negative correlation · thesis: 18/20 · ours: 0/20 units yes'
    """
    s = row.spec
    where = f"l. {','.join(map(str, s.lines))} " if s.lines else ""
    short = s.v2.get("short") or " ".join(s.text.split()[:6])
    head = [row.status, s.id, f"{where}{short}"]
    ours = ours_text(row)
    tail = [f"ours: {ours}"] if ours else []
    thesis = str(s.v2.get("thesis_value") or "")
    room = width - len(" · ".join([*head, *tail])) - len(" · thesis: ")
    if thesis and len(thesis) > room:  # too long for one line: the thesis's value gives way before ours
        thesis = thesis[: room - 1] + "…" if room > 12 else ""
    line = " · ".join([*head, *([f"thesis: {thesis}"] if thesis else []), *tail])
    return line if len(line) <= width else line[: width - 1] + "…"


#: Contrasts whose effect and CI :func:`describe` prints (the page's units table shows them all).
CI_SHOWN = 4


def describe(row: Row) -> str:
    """One paragraph of evidence: statistic with its interval, each contrast's effect with its 95 % CI across
    seeds (the first :data:`CI_SHOWN`), seeds, null pass rate, note, diagnosis."""
    st = row.statistic
    parts = []
    if "ci" in st:
        parts.append(_stat_text(st, row.n_seeds, row.pooled_seeds))
    elif st and "parts" not in st:
        parts.append("; ".join(f"{g}: {_stat_text(v, row.n_seeds, row.pooled_seeds)}" for g, v in st.items()))
    effects = effects_text(row)
    if effects:
        parts.append(effects)
    if row.pooled_seeds:
        parts.append(f"{row.pooled_seeds} training seeds pooled (no replication)")
    elif row.n_seeds:
        most = max((c["n"] for _, _, c, _ in _contrast_rows(row)), default=row.n_seeds)
        few = f"{row.n_seeds} training seed(s)"
        parts.append(f"{row.n_seeds}-{most} training seeds per unit" if most > row.n_seeds else few)
    if row.null_pass_rate is not None:
        parts.append(f"null pass rate {row.null_pass_rate:.2f}")
    if row.note:
        parts.append(row.note)
    if row.diagnosis:
        parts.append("why: " + row.diagnosis)
    if row.shipped:
        parts.append(f"numbers of {', '.join(row.shipped)} from the shipped claims snapshot (not computed here)")
    parts.extend(local_runs_text(page, u) for page, u in sorted(row.local_runs.items()))
    return "; ".join(parts)


def local_runs_text(page: str, use: Mapping[str, Any]) -> str:
    """What a page's verdicts rest on when some of its runs came from the local run cache, not the shipped layer
    (:func:`thesis_repro.pages.local_runs`).

    >>> local_runs_text("fig-3.4", {"local": 2, "replacing_shipped": 1, "of": 35, "noun": "runs"})
    'fig-3.4 used 2 of its 35 runs from the local run cache, not the shipped layer (1 in place of a shipped copy)'
    """
    replacing = int(use.get("replacing_shipped", 0))
    copies = "a shipped copy" if replacing == 1 else "shipped copies"
    return (
        f"{page} used {use['local']} of its {use['of']} {use.get('noun', 'runs')} from the local run cache, not the "
        f"shipped layer ({replacing} in place of {copies})"
    )


def _no_ci_words(pooled: int = 0) -> str:
    """Why a verdict has no CI: one training seed, or one value pooled from ``pooled`` seeds' means.

    >>> _no_ci_words(), _no_ci_words(3)
    ('one training seed: no CI', 'one value per unit from the means of 3 training seeds: no CI')
    """
    if pooled:
        return f"one value per unit from the means of {pooled} training seeds: no CI"
    return "one training seed: no CI"


def _stat_text(st: Mapping[str, Any], n_seeds: int | None = None, pooled: int = 0) -> str:
    """A yes-share statistic in words; with one training seed a unit's "yes" is its point estimate, not a CI
    (likewise when each unit's one value pools ``pooled`` seeds' means).

    >>> _stat_text({"value": 0.5, "ci": [0.5, 0.5], "k": 1, "n": 2}, n_seeds=1)
    '1/2 units yes (point estimates: one training seed), point estimate 0.50'
    >>> _stat_text({"value": 0.5, "ci": [0.5, 0.5], "k": 1, "n": 2}, n_seeds=1, pooled=3)
    '1/2 units yes (point estimates: seed means), point estimate 0.50'
    >>> _stat_text({"value": 0.5, "ci": [0.5, 0.5], "k": 1, "n": 2}, n_seeds=3)
    '1/2 units yes (CI-supported), point estimate 0.50'
    """
    if not st.get("n"):
        return "no units"
    lo, hi = st["ci"]
    pt = st.get("value")
    basis = (
        "point estimates: " + ("seed means" if pooled else "one training seed")
        if n_seeds is not None and n_seeds < 2
        else "CI-supported"
    )
    head = f"{st['k']}/{st['n']} units yes ({basis})"
    if st.get("undecided"):
        head += f", {st['undecided']} undecided: yes-share in [{lo:.2f}, {hi:.2f}]"
    if pt is not None:
        head += f", point estimate {pt:.2f}"
    return head


def _effect_ci(c: Mapping[str, Any]) -> str:
    """A contrast's effect with its CI, ``+12.3 [4.1, 20.5]`` (no CI with one seed)."""
    if c["estimate"] is None:
        return "n/a (no seed with a value)" if not c.get("n") else "n/a"
    lo, hi = c["ci"]
    if lo is None or hi is None:
        return f"{c['estimate']:+.3g} (no CI)"
    return f"{c['estimate']:+.3g} [{lo:.3g}, {hi:.3g}]"


def ci_words(levels: Sequence[float]) -> str:
    """How the CIs of a row's units were made: ``95 % CI``, or the Bonferroni-adjusted level a rule uses.

    >>> ci_words([0.95]), ci_words([0.95 + 0.05 * 5 / 6])
    ('95 % CI', '99.2 % CI (Bonferroni-adjusted over the units)')
    >>> ci_words([0.95, 0.99])
    '95 % CI (99 % where the rule adjusts for its number of units)'
    """
    adjusted = sorted({round(x, 4) for x in levels if x > LEVEL + 1e-9})
    if not adjusted:
        return f"{LEVEL * 100:.3g} % CI"
    adj = ", ".join(f"{x * 100:.3g} %" for x in adjusted)
    if all(x > LEVEL + 1e-9 for x in levels):
        return f"{adj} CI (Bonferroni-adjusted over the units)"
    return f"{LEVEL * 100:.3g} % CI ({adj} where the rule adjusts for its number of units)"


def _contrast_rows(row: Row) -> list[tuple[str, dict[str, Any], Mapping[str, Any], float]]:
    """(group, unit, contrast, CI level) of every contrast of ``row``; a contrast repeated inside one unit once."""
    out = []
    for g, info in row.groups.items():
        for u in info["units"]:
            seen = set()
            for c in u["contrasts"]:
                key = (c["label"], c["estimate"], tuple(c["ci"]))
                if key not in seen:
                    seen.add(key)
                    out.append((g, u, c, float(info.get("level", LEVEL))))
    return out


def effects_text(row: Row, limit: int = CI_SHOWN) -> str:
    """The numbers behind a verdict: per unit, each contrast's effect in the claim's direction (> 0 supports
    the claim; margins subtracted) with its CI across training seeds, ``[lo, hi]``; the first ``limit``
    contrasts (those with a CI first), then how many more the units table shows. Empty when the row has no
    units. The CI is 95 %, or the Bonferroni-adjusted level of a rule that corrects for its number of units
    (:func:`ci_words`).

    >>> c = {"label": "ppo-ent - ppo", "estimate": 12.3, "ci": [4.1, 20.5], "n": 3}
    >>> row = Row(spec("3.6-entropy"), "reproduces", 3, groups={"all": {"units": [{"label": "Hopper/obs",
    ...     "contrasts": [c]}]}})
    >>> head, text = effects_text(row).split(": ", 1)
    >>> head
    "effect in the claim's direction (> 0 supports it) [95 % CI across 3 training seeds]"
    >>> text
    'Hopper/obs: ppo-ent - ppo +12.3 [4.1, 20.5]'

    A claim mixing a 1-seed task with a 3-seed task says where the CIs come from:

    >>> one = {"label": "kl_avg - joint", "estimate": -794.0, "ci": [None, None], "n": 1}
    >>> row.groups["all"]["units"].append({"label": "Walker2d", "contrasts": [one]})
    >>> effects_text(row).split(": ", 1)[0].split("[")[1]
    '95 % CI across 3 training seeds; no CI where a contrast has under 2 seeds]'
    """
    rows = sorted(_contrast_rows(row), key=lambda r: r[2]["n"] < 2)  # contrasts with a CI first (stable)
    items = [f"{u['label']}: {c['label']} {_effect_ci(c)}" for _, u, c, _ in rows]
    ns = {c["n"] for _, _, c, _ in rows}
    if not items:
        return ""
    with_ci = {n for n in ns if n >= 2}
    if not with_ci:
        no_ci = "seed means: no CI" if row.pooled_seeds else _no_ci_words()
        head = f"effect in the claim's direction (> 0 supports it), {no_ci}"
    else:
        seeds = f"{min(with_ci)}" if len(with_ci) == 1 else f"{min(with_ci)}-{max(with_ci)}"
        fewer = "; no CI where a contrast has under 2 seeds" if with_ci != ns else ""
        ci = ci_words([lv for *_, lv in rows])
        head = f"effect in the claim's direction (> 0 supports it) [{ci} across {seeds} training seeds{fewer}]"
    more = len(items) - limit
    tail = f"; ... {more} more contrast(s) in the units table" if more > 0 else ""
    return f"{head}: " + "; ".join(items[:limit]) + tail


def units_table(row: Row) -> pd.DataFrame:
    """Per contrast: group, unit, the unit's outcome (its contrasts combined by the rule), the contrast, its
    estimate, its CI across seeds with the CI's level, the contrast's own outcome and its seeds."""
    recs = []
    for g, u, c, level in _contrast_rows(row):
        lo, hi = c["ci"]
        recs.append(
            {
                "group": g,
                "unit": u["label"],
                "unit outcome": u["outcome"],
                "contrast": c["label"],
                "estimate": "" if c["estimate"] is None else f"{c['estimate']:.3g}",
                "CI": "" if lo is None else f"[{lo:.3g}, {hi:.3g}]",
                "CI level": f"{level * 100:.3g} %",
                "contrast outcome": c.get("outcome", ""),
                "seeds": c["n"],
            }
        )
    return pd.DataFrame(recs)


def verdicts(page: str, scale: str) -> list[report.Verdict]:
    """A page's claims as :class:`~thesis_repro.claims.report.Verdict` (repeats say where they are judged)."""
    out = []
    for s in page_claims(page):
        row = judge(s, scale)
        where = f"thesis l. {', '.join(map(str, s.lines))}" if s.lines else "kit extension"
        tag = "[beyond the thesis] " if s.beyond else ""
        again = f" (judged on {s.page}; repeated here, counted once)" if s.page != page else ""
        claim = f"{tag}{s.text} ({where}){again}"
        evidence = f"v1 verdict: {row.v1_status or row.status}; {describe(row)}"
        if row.subset:  # the registered sensitivity check: its own paragraph at the top of the folded evidence
            evidence = f"{row.subset['line']}.\n\n{evidence}"
        fig = page.removeprefix("fig-")
        line = headline(row, width=report.LINE - len(f"[{fig}] "))  # the terminal's line is the page's first line
        fresh = row.confirmation.line() if row.confirmation else ""
        out.append(report.Verdict(fig, claim, row.status, evidence, line, fresh))
    return out


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
    try:
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


def as_json(rows: Sequence[Row], scale: str = "") -> dict[str, Any]:
    """The ledger as one JSON-ready object: thesis claims, beyond-the-thesis claims, both counts, and where the
    numbers of pages read from the shipped snapshot come from (``snapshot``, at ``scale``)."""
    return {
        "claims": [r.as_dict() for r in rows if not r.spec.beyond],
        "beyond_the_thesis": [r.as_dict() for r in rows if r.spec.beyond],
        "design": design.stamp(),
        "decision_rule": RULE_WORDS,
        "counts": dict(counts(rows)),
        "v1_counts": dict(Counter(r.v1_status or r.status for r in rows if not r.spec.beyond)),
        "confirmatory_counts": dict(confirmatory_counts(rows)),
        "confirmatory_seeds": f"{FIRST_FRESH} and above (judged once a claim's pages hold {list(FRESH_SEEDS)})",
        "confirmatory_disagree": [r.spec.id for r in rows if r.confirmation and r.confirmation.disagrees],
        "beyond_counts": dict(counts(rows, beyond=True)),
        "stale_pages": stale_pages(rows),
        "shipped_pages": shipped_pages(rows),
        "snapshot": snapshot.provenance(scale) if scale and shipped_pages(rows) else None,
    }


def scoreboard(scale: str, rows: Sequence[Row] | None = None) -> str:
    """Markdown scoreboard of distinct thesis claims: the counts under design v2 (v1's beside them), which claims
    reproduce and which do not (one line each), per chapter, the beyond-the-thesis count, and the method."""
    rows = ledger(scale) if rows is None else rows
    cols = [c for c in COUNTED if any(r.status == c for r in rows if not r.spec.beyond)]
    head = ["| chapter | " + " | ".join(SHORT[c] for c in cols) + " |", "|---|" + "---|" * len(cols)]
    total: Counter = Counter()
    by_ch: dict[str, Counter] = {}
    for r in rows:
        if r.spec.beyond:
            continue
        ch = r.spec.page.split("-", 1)[1].split("-")[0].split(".")[0]
        by_ch.setdefault(ch, Counter())[r.status] += 1
        total[r.status] += 1
    for ch in sorted(by_ch, key=int):
        head.append(
            f"| {{doc}}`Chapter {ch} <chapter-{ch}>` | " + " | ".join(str(by_ch[ch].get(c, 0)) for c in cols) + " |"
        )
    head.append("| **all** | " + " | ".join(f"**{total.get(c, 0)}**" for c in cols) + " |")
    extra = counts(rows, beyond=True)
    v1 = Counter(r.v1_status or r.status for r in rows if not r.spec.beyond)
    d = design.stamp()
    lead = (
        f"\n\n## Scoreboard at scale `{scale}` (claims design {d['version']})\n\n"
        f"Distinct claims of the thesis: **{sum(total.values())}**: "
        + ", ".join(f"**{v} {SHORT.get(k, k)}**" for k, v in sorted(total.items(), key=lambda kv: _order(kv[0])))
        + ". Under design v1 the same numbers read: "
        + ", ".join(f"{v} {SHORT.get(k, k)}" for k, v in sorted(v1.items(), key=lambda kv: _order(kv[0])))
        + ".\n\n"
    )
    thesis = [r.as_dict() for r in rows if not r.spec.beyond]
    lead += (
        f"**Fresh seeds.** {fresh_summary(thesis)} Counts on the fresh seeds alone: "
        + ", ".join(f"{v} {SHORT.get(k, k)}" for k, v in sorted(confirmatory_counts(rows).items(), key=_fresh_order))
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
        f"--scale {scale} --json` prints this ledger; {{doc}}`What changed from v1, and why <claims-design-v2>` "
        "explains the design.\n"
    )
    if scale == "smoke":
        tail += "At `smoke` nothing is judged: the runs only exercise the plumbing.\n"
    return lead + "\n".join(head) + tail + method(rows)


def _order(status: str) -> int:
    return COUNTED.index(status) if status in COUNTED else len(COUNTED)


def _fresh_order(kv: tuple[str, int]) -> tuple[int, int]:
    return (_order(kv[0]), -kv[1])


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
        sensitivity_method(),
        subsets.method_text(specs()),
        "| claim | level | margin | verdict | v1 | false R | false D | seeds for 80 % |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        c = r.calibration
        fr = "n/a" if c.get("false_reproduces") is None else f"{c['false_reproduces']:.3f}"
        fd = "n/a" if c.get("false_does_not") is None else f"{c['false_does_not']:.3f}"
        seeds = c.get("seeds_for_80", "n/a") if c else "n/a"
        seeds = "> 128" if c and seeds is None else seeds
        tag = " (beyond)" if r.spec.beyond else ""
        mg = "" if r.margin is None else f"{r.margin:g}"
        out.append(
            f"| {r.spec.id}{tag} | {r.level or '-'} | {mg} | {r.status} | {r.v1_status or r.status} | {fr} | {fd} "
            f"| {seeds} |"
        )
    return "\n".join(out) + "\n"


def sensitivity_method() -> str:
    """The method's line on protocol sensitivity: what it is, which claims carry which study, and each study's
    result from the runs available (left out when they are not)."""
    carriers: dict[str, list[str]] = {}
    for s in specs():
        for name in s.sensitivity:
            carriers.setdefault(name, []).append(s.id)
    studies = []
    for name, ids in carriers.items():
        m = study_result(name)
        result = sensitivity_text(m) if m is not None else "its runs are not available here"
        studies.append(f"`{name}`, declared on {', '.join(ids)}: {result}")
    return (
        "**Protocol sensitivity**: a claim that does not fully reproduce and whose evidence rests on runs a protocol "
        "study varied (`sensitivity:` in the registry; `python -m thesis_repro.study`) shows in its *why* the "
        "setting's effect with its Welch 95 % CI across seeds, from the study's cached / shipped runs (left out when "
        "they are not available); a CI containing 0 means the setting moves the result less than the seed spread. "
        + ("; ".join(studies) if studies else "No claim names a study")
        + ".\n"
    )


def _finite(x: float | None) -> bool:
    return x is not None and math.isfinite(x)
