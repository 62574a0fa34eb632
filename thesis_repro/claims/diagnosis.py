"""Why a claim does not (fully) reproduce: seed spread, training regime, and the protocol studies' measurements.

A claim may name the protocol studies its evidence rests on (``sensitivity: [lr-schedule]``,
:data:`thesis_repro.runs.study.STUDIES`): its "why" (:func:`diagnose`) then shows each study's measured difference,
from the study's cached / shipped runs (:func:`study_result`; nothing when they are not available, never trained
here).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from thesis_repro.claims.evidence import ci_words
from thesis_repro.claims.registry import specs
from thesis_repro.core import paths
from thesis_repro.runs import study


def diagnose(judged: Mapping[str, Any], meta: Mapping[str, Any], sensitivities: Sequence[Any] = ()) -> str:
    """Why a claim does not (fully) reproduce, from the kit's own measurements: seed spread, training regime
    (half vs final budget, :mod:`thesis_repro.runs.budgets`), protocol sensitivity where measured (a page's
    ``meta["protocol"]``, and the claim's registered studies' results, :func:`study_result`)."""
    widths, against, short = [], [], []
    for j in judged.values():
        for u in j.units:
            for c in u["contrasts"]:
                lo, hi = c["ci"]
                if lo is not None and hi is not None:
                    widths.append(hi - lo)
            if u["outcome"] == "no":
                # a "no" whose CI lies on the claim's side excludes the margin, not the claim's direction
                (short if u["contrasts"] and all(c.get("below_margin") for c in u["contrasts"]) else against).append(
                    u["label"]
                )
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
    if short:
        bits.append(
            f"{len(short)} unit(s) on the claim's side but below its margin ({', '.join(short[:4])}"
            + (", ..." if len(short) > 4 else "")
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


_STUDY_RESULTS: dict[tuple[Any, ...], Any] = {}


def study_result(name: str) -> Any:
    """The protocol study ``name``'s :class:`~thesis_repro.runs.study.Sensitivity` from the runs available in the
    run cache and the shipped layer, or ``None`` (never trains). Computed once per study function and cache
    location in a process."""
    fn = study.STUDIES[name]
    key = (name, fn, str(paths.runs_dir()), None if paths.retrain() else str(paths.reference()))
    if key not in _STUDY_RESULTS:
        _STUDY_RESULTS[key] = fn()
    return _STUDY_RESULTS[key]


def sensitivity_text(m: Any) -> str:
    """One "why" clause from a :class:`~thesis_repro.runs.study.Sensitivity`: per task the difference with its Welch
    95 % CI across seeds, and whether every CI contains 0 (within seed spread)."""
    cells = []
    for i, e in enumerate(m.effects):
        lo, hi = e.ci
        ci = f"{'95 % CI ' if i == 0 else ''}{lo:,.0f} to {hi:,.0f}"
        cells.append(f"{study.SHORT.get(e.task, e.task)} {e.difference:+,.0f} ({ci})")
    if m.within_spread:
        verdict = "within seed spread"
    else:
        moved = [study.SHORT.get(e.task, e.task) for e in m.effects if not e.within_spread]
        verdict = f"outside seed spread on {', '.join(moved)} (the CI excludes 0)"
    head = f"{m.setting}, {m.learner}, {m.budget}, {m.seeds}; {m.measure}, {m.contrast}"
    return f"protocol sensitivity ({head}): {', '.join(cells)}: {verdict}"


def sensitivity_dict(m: Any) -> dict[str, Any]:
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
        "study varied (`sensitivity:` in the registry; `python -m thesis_repro.runs.study`) shows in its *why* the "
        "setting's effect with its Welch 95 % CI across seeds, from the study's cached / shipped runs (left out when "
        "they are not available); a CI containing 0 means the setting moves the result less than the seed spread. "
        + ("; ".join(studies) if studies else "No claim names a study")
        + ".\n"
    )
