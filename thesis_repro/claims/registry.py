"""The claims registry: every thesis sentence the kit judges, read from ``data/thesis/claims.yaml``.

Under each page, ``claims`` quote the thesis (a claim with a ``rule`` is judged on that page; the same ``id`` on
another page only repeats its verdict), and ``beyond`` holds the kit's own extensions, counted apart. Each claim
carries its v1 ``rule`` and its v2 block (:mod:`thesis_repro.claims.design`).

>>> ids = [s.id for s in specs()]
>>> len(ids) == len(set(ids)) and "3.3-negative-correlation" in ids
True
>>> spec("3.3-negative-correlation").page
'fig-3.3'
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from functools import cache
from typing import Any

from thesis_repro.core import paths, yamlfile


@dataclass(frozen=True)
class Spec:
    """One registered claim: its sentence (or the kit's wording, ``beyond``), page, rule and pages repeating it."""

    id: str
    page: str
    text: str
    lines: tuple[int, ...]
    rule: Mapping[str, Any]
    beyond: bool = False
    pages: tuple[str, ...] = ()
    evidence: str = ""
    sensitivity: tuple[str, ...] = ()
    #: the claim's design-v2 block (level, margin, wording, rule overrides): :mod:`thesis_repro.claims.design`
    v2: Mapping[str, Any] = field(default_factory=dict)
    #: the claim's design-v3 block (``conjunction``, rule overrides with their ``why``)
    v3: Mapping[str, Any] = field(default_factory=dict)
    #: the registered subset sensitivity check (``sensitivity_subset``, :mod:`thesis_repro.claims.sensitivity`),
    #: outside the rule's hash; ``""`` for none
    subset: str = ""

    @property
    def data_pages(self) -> list[str]:
        """Pages whose saved numbers the measure reads (default: its own page)."""
        return list(self.rule.get("data", [self.page]))


@cache
def registry() -> dict[str, Any]:
    """``data/thesis/claims.yaml`` as loaded."""
    return yamlfile.parse((paths.THESIS_DATA / "claims.yaml").read_text())


@cache
def specs() -> tuple[Spec, ...]:
    """Every claim with a rule (thesis claims, then beyond-the-thesis ones), each once."""
    return parse_specs(registry())


def _sensitivity_names(cid: str, c: Mapping[str, Any]) -> tuple[str, ...]:
    """A claim's ``sensitivity`` field: protocol-study names, each one of :data:`thesis_repro.runs.study.STUDIES`."""
    from thesis_repro.runs.study import STUDIES  # cheap: the study module imports no learner until it runs

    names = c.get("sensitivity", [])
    if isinstance(names, str) or not isinstance(names, list):
        raise ValueError(f"claims.yaml: claim {cid!r}: 'sensitivity' must be a list of study names, got {names!r}")
    for name in names:
        if name not in STUDIES:
            raise ValueError(
                f"claims.yaml: claim {cid!r}: unknown sensitivity study {name!r}; valid: {', '.join(STUDIES)}"
            )
    if names and "rule" not in c:
        raise ValueError(f"claims.yaml: claim {cid!r}: 'sensitivity' goes with the entry that carries the rule")
    return tuple(names)


def _subset_name(cid: str, c: Mapping[str, Any]) -> str:
    """A claim's ``sensitivity_subset`` (``""`` for none): a registered subset, on the entry whose rule measures."""
    if "sensitivity_subset" not in c:
        return ""
    from thesis_repro.claims.sensitivity import check_name

    name = check_name(cid, c["sensitivity_subset"])
    if "measure" not in (c.get("rule") or {}):
        raise ValueError(
            f"claims.yaml: claim {cid!r}: 'sensitivity_subset' goes with the entry whose rule has a measure"
        )
    return name


def parse_specs(reg: Mapping[str, Any]) -> tuple[Spec, ...]:
    """The claims of a loaded registry (:func:`registry`), validated: ids, one rule per id, sensitivity names and
    subsets."""
    out: dict[str, Spec] = {}
    repeats: dict[str, list[str]] = {}
    for page, entry in reg.items():
        for beyond, items in ((False, entry.get("claims", [])), (True, entry.get("beyond", []))):
            for c in items:
                cid = c.get("id")
                if cid is None:
                    raise ValueError(f"claims.yaml: a claim of {page} has no id: {c.get('text', '')[:60]!r}")
                if c.get("context"):
                    continue
                sens = _sensitivity_names(cid, c)
                subset = _subset_name(cid, c)
                if "rule" not in c:
                    repeats.setdefault(cid, []).append(page)
                    continue
                if cid in out:
                    raise ValueError(f"claims.yaml: claim {cid!r} has a rule on {out[cid].page} and on {page}")
                lines = tuple(int(n) for n in c.get("lines", []))
                v2, v3 = dict(c.get("v2") or {}), dict(c.get("v3") or {})
                out[cid] = Spec(
                    cid, page, c["text"], lines, c["rule"], beyond, (), c.get("evidence", page), sens, v2, v3, subset
                )
    missing = sorted(set(repeats) - set(out))
    if missing:
        raise ValueError(f"claims.yaml: claims repeated but never given a rule: {missing}")
    return tuple(replace(s, pages=tuple(repeats.get(s.id, []))) for s in out.values())


def data_name(page: str) -> str:
    """The file name of a page's saved per-seed numbers: ``fig-3.3`` -> ``fig-3.3.data.json``."""
    return f"{page}.data.json"


def spec(claim_id: str) -> Spec:
    """The registered claim ``claim_id``."""
    for s in specs():
        if s.id == claim_id:
            return s
    raise ValueError(f"unknown claim {claim_id!r}; known: {', '.join(s.id for s in specs())}")


def page_claims(page: str) -> list[Spec]:
    """Claims a page shows: those judged on it, those it repeats, and its beyond-the-thesis ones."""
    return [s for s in specs() if s.page == page or page in s.pages]


def reads(page: str) -> set[str]:
    """Other pages whose saved numbers ``page``'s verdicts read (its repeated and derived claims' data pages,
    its page-verdict claims' pages); run them first and the page shows those verdicts, not "not computed".

    >>> "table-3.4" in reads("fig-3.7")
    True
    """

    return set().union(set(), *(pages_read(s) for s in page_claims(page))) - {page}


def pages_read(s: Spec) -> set[str]:
    """The pages whose saved numbers claim ``s`` is judged on: its data pages, a derived claim's claims' pages, a
    page-verdict claim's own page.

    >>> sorted(pages_read(spec("6-contribution-4")))
    ['fig-4.1', 'fig-4.3', 'fig-4.4']
    """
    r = s.rule
    if r.get("derived"):
        return set().union(*(pages_read(spec(i)) for i in r["derived"]))
    return {s.page} if "page_verdict" in r else set(s.data_pages)
