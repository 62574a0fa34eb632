"""The pre-registered claims design: version v2's level, margin and rule for every claim, and its freeze.

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

The design is frozen in ``data/thesis/claims-design.json``: the version, a SHA-256 of every claim's v2 rule and
of the judging code (:data:`ENGINE`, compared as syntax trees, so comments and docstrings may change). A frozen
rule changes only under a new version (:func:`check_frozen`, tested), and both versions' verdicts are shown.

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

from thesis_repro import paths
from thesis_repro.claims import judge, registry, stats
from thesis_repro.claims.measures import ch3, ch4, ch5, common

VERSION = "v2"
LEVELS = ("pooled", "each", "count")
#: Wording fields of a ``v2:`` block: shown, not judged, so outside the rule's hash.
WORDING = ("short", "claim12", "thesis_value", "margin_basis")
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
#: Every module of :mod:`thesis_repro.claims.measures` (``tests/test_claims_design.py`` checks none is missing).
ENGINE_MODULES = (common, ch3, ch4, ch5)


def lock_path() -> Any:
    """``data/thesis/claims-design.json``: the frozen design."""
    return paths.THESIS_DATA / "claims-design.json"


def block(entry: Mapping[str, Any]) -> dict[str, Any]:
    """A claim entry's ``v2:`` block (empty when it has none)."""
    return dict(entry.get("v2") or {})


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


def _tree(obj: Any) -> str:
    """The syntax tree of ``obj``'s source without docstrings (comments never reach the tree)."""
    tree = ast.parse(textwrap.dedent(inspect.getsource(obj)))
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if isinstance(body, list) and body and isinstance(body[0], ast.Expr):
            if isinstance(getattr(body[0], "value", None), ast.Constant) and isinstance(body[0].value.value, str):
                node.body = body[1:] or [ast.Pass()]
    return ast.dump(tree, annotate_fields=False, include_attributes=False)


def _module_defs(module: Any) -> list[tuple[str, str]]:
    """Every top-level function and class of ``module`` as (name, syntax tree without docstrings)."""
    tree = ast.parse(inspect.getsource(module))
    out = []
    for node in tree.body:
        if isinstance(node, (ast.FunctionDef, ast.ClassDef)):
            out.append((node.name, _tree(getattr(module, node.name))))
    return out


def engine_hash() -> str:
    """SHA-256 over the syntax trees of :data:`ENGINE`, the definitions of :data:`ENGINE_MODULES` (sorted by
    name) and the v2 constants."""
    consts = _canonical({"level": stats.LEVEL, "levels": LEVELS, "version": VERSION})
    defs = sorted(d for m in ENGINE_MODULES for d in _module_defs(m))
    return _sha(consts + "".join(_tree(o) for o in ENGINE) + "".join(f"{n}:{t}" for n, t in defs))


def rule_hashes() -> dict[str, str]:
    """Per claim id with a rule: SHA-256 of its v1 rule, v2 rule, level and margin (wording left out)."""
    out = {}
    for s in registry.specs():
        judged = {k: v for k, v in s.v2.items() if k not in WORDING}
        out[s.id] = _sha(_canonical({"v1": s.rule, "v2": judged}))
    return out


def design_hash(rules: Mapping[str, str], engine: str) -> str:
    """One hash of the whole design: every rule's hash and the engine's."""
    return _sha(_canonical({"rules": dict(sorted(rules.items())), "engine": engine, "version": VERSION}))


@cache
def frozen() -> dict[str, Any]:
    """The frozen design as committed (``{}`` when none is)."""
    p = lock_path()
    return json.loads(p.read_text()) if p.exists() else {}


def current() -> dict[str, Any]:
    """The design as the registry and code stand now, in the lock file's shape."""
    rules, engine = rule_hashes(), engine_hash()
    return {"version": VERSION, "hash": design_hash(rules, engine), "engine": engine, "rules": rules}


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
        out.append("the judging code (claims.design.ENGINE) changed")
    return out


def stamp() -> dict[str, str]:
    """The design a run or a ledger was made under: ``{"version", "hash"}`` of the frozen design."""
    lock = frozen()
    return {"version": str(lock.get("version", VERSION)), "hash": str(lock.get("hash", ""))}


def freeze() -> dict[str, Any]:
    """Write :func:`current` as the frozen design (only for a new version: the test refuses a silent change)."""
    now = current()
    out = lock_path()
    tmp = out.with_suffix(".tmp")
    tmp.write_text(json.dumps(now, indent=1, sort_keys=True) + "\n")
    tmp.replace(out)
    frozen.cache_clear()
    return now
