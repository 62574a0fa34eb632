"""The pre-registered claims design: version v3 (and v2 before it): level, margin and rule of every claim, frozen.

Design v1 is the ``rule:`` of each claim in ``data/thesis/claims.yaml``; v2 is that rule updated with the claim's
``v2:`` block (``level``, ``margin``, ``margin_basis``, wording, and ``rule:`` overrides for the rules v2 fixed).
A v2 claim is judged at the level its sentence speaks (:data:`LEVELS`):

- ``pooled`` ("most", "generally", "on average"): one effect pooled over the claim's units, tasks as fixed
  effects, a t-interval across training seeds (:func:`thesis_repro.claims.stats.pooled`; r through Fisher z),
  Holm-adjusted across the pooled claims that share a page's data;
- ``each`` ("each", "every", "in all"): every unit must be *yes* (an intersection; the count rule at 1.0);
- ``count`` ("often", "many", "k of n"): v1's count thresholds on the yes-share interval.

A unit is *yes* when its 95 % CI lies above 0 and reaches the margin, *no* when the CI excludes effects of the
margin's size in the claim's direction, *undecided* otherwise (:func:`thesis_repro.claims.stats.outcome_v2`).

Design v3 keeps v2's levels and margins and changes how they are tested (:mod:`thesis_repro.claims.stats_v3`,
:mod:`thesis_repro.claims.judge_v3`; ``book/deviations.md`` lists every change and the verdicts it moves); a
claim's ``v3:`` block adds ``conjunction`` and ``rule:`` overrides (each with its ``why``).

The design is frozen in ``data/thesis/claims-design.json``: the version, a SHA-256 of every claim's rule and of
the judging code (:data:`ENGINE` and :data:`ENGINE_MODULES`, compared as syntax trees, so comments and docstrings
may change), with the previous version's record kept under ``previous``. A frozen rule changes only under a new
version (:func:`check_frozen`, tested), and both versions' verdicts are shown.

>>> d = frozen()
>>> d["version"] == VERSION and len(d["rules"]) == len(rule_hashes())
True
"""

from __future__ import annotations

import ast
import hashlib
import inspect
import json
import textwrap
from collections.abc import Mapping
from functools import cache
from typing import Any

from thesis_repro.claims import judge, judge_v3, registry, seeds, stats, stats_v3
from thesis_repro.claims.measures import ch3, ch4, ch5, common
from thesis_repro.core import paths

VERSION = "v3"
#: The version before :data:`VERSION`, still shown beside it (its record: the lock's ``previous``).
PREVIOUS = "v2"
LEVELS = ("pooled", "each", "count")
#: Wording fields of a ``v2:`` / ``v3:`` block: shown, not judged, so outside the rule's hash.
WORDING = ("short", "claim12", "thesis_value", "margin_basis", "why")
#: The judging code whose syntax trees the engine hash covers: v2's statistics, the judging of a claim's units,
#: and every top-level definition of the measures (by name, so moving a definition between modules keeps the hash).
ENGINE = (
    stats.Contrast,
    stats.Estimate,
    stats._mean_ci,
    stats._welch_ci,
    stats._combine,
    stats._point,
    stats.CountRule,
    stats.bounded_label,
    stats.label_bounds,
    stats.combine_bounded,
    stats.contrast_scale,
    stats.estimate_v2,
    stats.unit_margin,
    stats.outcome_v2,
    stats.unit_outcome_v2,
    stats.judge_count_v2,
    stats.seed_effects,
    stats.unit_seed_effects,
    stats.Pooled,
    stats.pooled,
    stats.holm,
    judge.count_rule,
    judge._pooled_status,
    judge.decisive_p,
    judge.holm_outcome,
    judge.judge_v2,
)
#: v3's judging code besides its modules: the v2 definitions it reuses.
ENGINE_V3 = (
    stats.Contrast,
    stats.Unit,
    stats.CountRule,
    stats.bounded_label,
    stats.label_bounds,
    stats.combine_bounded,
    stats.holm,
)
#: Every module of :mod:`thesis_repro.claims.measures` (``tests/test_claims_design.py`` checks none is missing).
ENGINE_MODULES = (common, ch3, ch4, ch5)
#: v3's own modules, hashed whole (every top-level definition).
ENGINE_MODULES_V3 = (*ENGINE_MODULES, seeds, stats_v3, judge_v3)


#: Chapter 4's claims that design v3 judges once per reading of the thesis's update (Eq 4.10/4.11): each stable
#: reading (a registered hyperparameter id beside ``kl_avg``, the literal one) is judged by the claim's v3 rule with
#: ``ours`` set to it and ``drop_diverged`` on; a reading whose every run diverged reads
#: :data:`thesis_repro.claims.measures.ch4.DIVERGED` for every claim, and a reading that reduces to parameter
#: averaging is judged on params_avg's runs.
READING_CLAIMS = (
    "4.1-harder-settings",
    "4.1-insensitive",
    "4.3-wind",
    "4.4-extrapolation",
    "4.5-mass-friction",
    "4.6-noise",
    "4.7-entropy",
    "6-contribution-4",
)


def lock_path() -> Any:
    """``data/thesis/claims-design.json``: the frozen design."""
    return paths.THESIS_DATA / "claims-design.json"


def block(entry: Mapping[str, Any]) -> dict[str, Any]:
    """A claim entry's ``v2:`` block (empty when it has none)."""
    return dict(entry.get("v2") or {})


def rule3(v1_rule: Mapping[str, Any], v2: Mapping[str, Any], v3: Mapping[str, Any]) -> dict[str, Any]:
    """The v3 rule: the v2 rule updated with the ``v3:`` block's ``rule:`` overrides (their ``why`` is wording).

    >>> rule3({"measure": "m"}, {"rule": {"a": 1}}, {"rule": {"drop_diverged": True, "why": "w"}})
    {'measure': 'm', 'a': 1, 'drop_diverged': True}
    """
    return rule(rule(v1_rule, v2), v3)


def level3(v2: Mapping[str, Any], v3: Mapping[str, Any]) -> str:
    """The v3 level: the ``v3:`` block's, else v2's."""
    return level({"level": v3["level"]} if "level" in v3 else v2)


def margin3(v2: Mapping[str, Any], v3: Mapping[str, Any]) -> float:
    """The v3 margin: the ``v3:`` block's, else v2's."""
    return margin(v3 if "margin" in v3 else v2)


def conjunction(v3: Mapping[str, Any]) -> bool:
    """Whether the claim's units are different statements of one sentence, judged as one intersection."""
    return bool(v3.get("conjunction", False))


def rule(v1_rule: Mapping[str, Any], v2: Mapping[str, Any]) -> dict[str, Any]:
    """The v2 rule: the v1 rule updated with the block's ``rule:`` overrides (their ``why`` is wording).

    >>> rule({"measure": "degrade", "reproduces": 0.5}, {"rule": {"min_drop": 0.25, "why": "w"}})
    {'measure': 'degrade', 'reproduces': 0.5, 'min_drop': 0.25}
    """
    out = dict(v1_rule)
    out.update({k: v for k, v in (v2.get("rule") or {}).items() if k != "why"})
    return out


def level(v2: Mapping[str, Any]) -> str:
    """The block's level (``count`` when it has none); an unknown one is a one-line error.

    >>> level({"level": "pooled"}), level({})
    ('pooled', 'count')
    >>> level({"level": "most"})
    Traceback (most recent call last):
    ...
    ValueError: claims.yaml: unknown v2 level 'most'; valid: pooled, each, count
    """
    lv = str(v2.get("level", "count"))
    if lv not in LEVELS:
        raise ValueError(f"claims.yaml: unknown v2 level {lv!r}; valid: {', '.join(LEVELS)}")
    return lv


def margin(v2: Mapping[str, Any]) -> float:
    """The block's smallest effect of interest (0 when it has none)."""
    return float(v2.get("margin", 0.0) or 0.0)


def _canonical(x: Any) -> str:
    return json.dumps(x, sort_keys=True, ensure_ascii=False, default=str)


def _sha(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()


@cache
def _tree(obj: Any) -> str:
    """The syntax tree of ``obj``'s source without docstrings (comments never reach the tree); kept per object (a
    process's source does not change, and a replaced function is another object), since the claims' hashes ask for
    the same dozens of trees on every judged claim."""
    tree = ast.parse(textwrap.dedent(inspect.getsource(obj)))
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if isinstance(body, list) and body and isinstance(body[0], ast.Expr):
            if isinstance(getattr(body[0], "value", None), ast.Constant) and isinstance(body[0].value.value, str):
                node.body = body[1:] or [ast.Pass()]
    return ast.dump(tree, annotate_fields=False, include_attributes=False)


@cache
def _def_names(module: Any) -> tuple[str, ...]:
    """Names of the top-level functions and classes in ``module``'s source."""
    tree = ast.parse(inspect.getsource(module))
    return tuple(node.name for node in tree.body if isinstance(node, (ast.FunctionDef, ast.ClassDef)))


def _module_defs(module: Any) -> list[tuple[str, str]]:
    """Every top-level function and class of ``module`` as (name, syntax tree without docstrings)."""
    return [(name, _tree(getattr(module, name))) for name in _def_names(module)]


def engine_hash() -> str:
    """SHA-256 over the syntax trees of :data:`ENGINE_V3`, the definitions of :data:`ENGINE_MODULES_V3` (sorted
    by name) and the v3 constants."""
    consts = _canonical(
        {
            "level": stats.LEVEL,
            "levels": LEVELS,
            "version": VERSION,
            "gate": [judge_v3.GATE_RATE, judge_v3.GATE_DRAWS, judge_v3.MIN_POWER],
            "readings": list(READING_CLAIMS),
        }
    )
    defs = sorted(d for m in ENGINE_MODULES_V3 for d in _module_defs(m))
    return _sha(consts + "".join(_tree(o) for o in ENGINE_V3) + "".join(f"{n}:{t}" for n, t in defs))


def calibration_hash() -> str:
    """SHA-256 of what a v3 calibration's numbers depend on: the statistics, the judging without its gate, the
    draws and the measures' contrasts (a change of wording or of the gate keeps every cached calibration)."""
    from thesis_repro.claims import calibration

    skip = {"gated", "gate_limit"}
    mods = (seeds, stats_v3, judge_v3, calibration)
    defs = sorted(d for m in mods for d in _module_defs(m) if d[0] not in skip)
    consts = _canonical({"level": stats.LEVEL, "draws": judge_v3.GATE_DRAWS})
    return _sha(consts + "".join(_tree(o) for o in ENGINE_V3) + "".join(f"{n}:{t}" for n, t in defs))


def _judged(b: Mapping[str, Any]) -> dict[str, Any]:
    out = {k: v for k, v in b.items() if k not in WORDING}
    if isinstance(out.get("rule"), Mapping):
        out["rule"] = {k: v for k, v in out["rule"].items() if k != "why"}
    return out


def rule_hashes(version: str = VERSION) -> dict[str, str]:
    """Per claim id with a rule: SHA-256 of its v1 rule, v2 block and (v3) v3 block, wording left out; ``v2``: the
    hash v2 froze (v1 rule and v2 block)."""
    out = {}
    for s in registry.specs():
        judged = {k: v for k, v in s.v2.items() if k not in WORDING[:4]}
        payload: dict[str, Any] = {"v1": s.rule, "v2": judged}
        if version != PREVIOUS:
            payload["v3"] = _judged(s.v3)
        out[s.id] = _sha(_canonical(payload))
    return out


def design_hash(rules: Mapping[str, str], engine: str) -> str:
    """One hash of the whole design: every rule's hash and the engine's."""
    return _sha(_canonical({"rules": dict(sorted(rules.items())), "engine": engine, "version": VERSION}))


def previous() -> dict[str, Any]:
    """The previous version's frozen record (``{}`` when the lock holds none)."""
    lock = frozen()
    if lock.get("version") == PREVIOUS:
        return lock
    return dict((lock.get("previous") or {}).get(PREVIOUS) or {})


@cache
def frozen() -> dict[str, Any]:
    """The frozen design as committed (``{}`` when none is)."""
    p = lock_path()
    return json.loads(p.read_text()) if p.exists() else {}


def current() -> dict[str, Any]:
    """The design as the registry and code stand now, in the lock file's shape (the previous version's record
    carried along)."""
    rules, engine = rule_hashes(), engine_hash()
    out: dict[str, Any] = {"version": VERSION, "hash": design_hash(rules, engine), "engine": engine, "rules": rules}
    before = previous()
    if before:
        out["previous"] = {PREVIOUS: {k: v for k, v in before.items() if k != "previous"}}
    return out


def check_frozen() -> list[str]:
    """What differs from the frozen design under the same version (empty: the design holds).

    A changed, added or removed rule, or changed judging code, under an unchanged :data:`VERSION` is a broken
    pre-registration: bump the version (and keep the old one's verdicts shown) instead.
    """
    lock, now = frozen(), current()
    if not lock:
        return [f"no frozen design at {lock_path()}"]
    if lock.get("version") != VERSION:
        return []  # a new version: freeze it with `claims --freeze`
    out = []
    for cid in sorted(set(lock["rules"]) | set(now["rules"])):
        a, b = lock["rules"].get(cid), now["rules"].get(cid)
        if a != b:
            out.append(f"claim {cid}: rule {'added' if a is None else 'removed' if b is None else 'changed'}")
    if lock.get("engine") != now["engine"]:
        out.append("the judging code (claims.design.ENGINE_V3, ENGINE_MODULES_V3) changed")
    before = previous()
    if before and rule_hashes(PREVIOUS) != before.get("rules"):
        out.append(f"a {PREVIOUS} rule changed: the previous version is shown as frozen")
    return out


def stamp() -> dict[str, str]:
    """The design a run or a ledger was made under: ``{"version", "hash"}`` of the frozen design."""
    lock = frozen()
    return {"version": str(lock.get("version", VERSION)), "hash": str(lock.get("hash", ""))}


def engine_of(version: str) -> str:
    """The frozen engine hash of ``version`` (the current one or :data:`PREVIOUS`), ``""`` when not frozen."""
    lock = frozen()
    if lock.get("version") == version:
        return str(lock.get("engine", ""))
    return str(previous().get("engine", "")) if version == PREVIOUS else ""


def freeze() -> dict[str, Any]:
    """Write :func:`current` as the frozen design (only for a new version: the test refuses a silent change)."""
    now = current()
    out = lock_path()
    tmp = out.with_suffix(".tmp")
    tmp.write_text(json.dumps(now, indent=1, sort_keys=True) + "\n")
    tmp.replace(out)
    frozen.cache_clear()
    return now
