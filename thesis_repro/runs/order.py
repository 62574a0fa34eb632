"""The order the reference-run generator makes items in: claims settled per core-hour.

An item (a figure or a table) is worth the claims its runs can settle: a claim whose power figure (design v2's
calibration, ``seeds_for_80``: the training seeds that give 80 % power) is at most the seeds the item is made to.
:func:`rank` orders items greedily by the claims each newly settles per core-hour of the runs it newly pays for
(runs that items share cost once: the first item in the order pays); ties, and items that settle nothing, come
cheapest first. The order decides only what runs first, never what is judged: every item in the plan is made to
its target seed count, whatever its early seeds show.

:func:`confirmatory_plan` is the confirmatory replication's plan: every chapter-3 item to the requested seeds, chapter
5's CMA-ES
items to :data:`CH5_TARGET_SEEDS`, and the chapter-4 items only where one of their claims can be settled at the
requested seed count; a claim no seed was judged on (such as one resting only on kl_avg, whose every run
diverged) is skipped with the ledger's own reason. ``python -m thesis_repro plan order --scale small --seeds 3 4 5``
prints it (:func:`order_report`); ``reference-runs --order claims`` makes the items in that order, item by item.

>>> items = [Item("a", 6, {"k1": 2.0}), Item("b", 6, {"k2": 1.0}), Item("c", 6, {"k1": 2.0, "k3": 0.5})]
>>> claims = [Claim("a-1", ("a",), 3), Claim("a-2", ("a",), 5), Claim("b-1", ("b",), 12), Claim("c-1", ("c",), 6)]
>>> [(r.item, r.settles, r.core_hours) for r in rank(items, claims)]
[('a', ('a-1', 'a-2'), 2.0), ('c', ('c-1',), 0.5), ('b', (), 1.0)]
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from thesis_repro import figures
from thesis_repro.core.cache import RunCache
from thesis_repro.runs.costs import core_hours, text_table, to_compute
from thesis_repro.runs.needs import CH5_TARGET_SEEDS, seed_count, seed_jobs
from thesis_repro.runs.throughput import Rates, job_rate, work, work_left

#: The chapters whose every item is in the plan; the other items (chapter 4's) only where they can settle a claim.
EVERY_ITEM_CHAPTERS: tuple[int, ...] = (3, 5)


@dataclass(frozen=True)
class Claim:
    """A claim as the order sees it: its id, the items whose runs it reads, its power figure (``None``: no seed
    count the calibration tried reaches 80 % power) and, if no seed of it was judged, why (it is skipped)."""

    id: str
    items: tuple[str, ...]
    seeds_for_80: int | None
    skip: str = ""

    def settled_at(self, seeds: int) -> bool:
        """Whether ``seeds`` training seeds settle it (its power figure is at most that many)."""
        return not self.skip and self.seeds_for_80 is not None and self.seeds_for_80 <= seeds


@dataclass(frozen=True)
class Item:
    """An item to make: its figure id, the training seeds it is made to, and its runs' priced cost (job key ->
    core-hours) for the seeds requested."""

    id: str
    target: int
    runs: Mapping[str, float]

    @property
    def core_hours(self) -> float:
        return sum(self.runs.values())


@dataclass(frozen=True)
class Ranked:
    """An item's place in the order: the claims it settles (those its completion settles first) and the core-hours
    of the runs no earlier item paid for."""

    rank: int
    item: str
    target: int
    settles: tuple[str, ...]
    core_hours: float

    @property
    def per_core_hour(self) -> float:
        """Claims settled per core-hour (``inf`` for claims bought with runs already paid for)."""
        if not self.settles:
            return 0.0
        return len(self.settles) / self.core_hours if self.core_hours > 0 else math.inf


def rank(items: Sequence[Item], claims: Iterable[Claim]) -> list[Ranked]:
    """``items`` in the order of claims settled per core-hour, greedily: at each step the item whose completion
    settles the most claims not yet settled (:meth:`Claim.settled_at` its target, every item the claim reads made
    by then) per core-hour of its runs not yet paid for; ties and items that settle nothing cheapest first, then by
    id. A claim reading an item not among ``items`` is never settled.

    >>> shared = [Item("x", 6, {"k": 4.0}), Item("y", 6, {"k": 4.0, "m": 1.0})]
    >>> [(r.item, r.core_hours) for r in rank(shared, [Claim("y-1", ("y",), 3)])]  # the first item pays for "k"
    [('y', 5.0), ('x', 0.0)]
    """
    todo = {i.id: i for i in items}
    target = {i.id: i.target for i in items}
    claims = [c for c in claims if c.items and set(c.items) <= set(todo)]
    done: set[str] = set()
    paid: set[str] = set()
    settled: set[str] = set()
    out: list[Ranked] = []

    def value(item: Item) -> tuple[tuple[str, ...], float]:
        """The claims ``item`` settles now, and the core-hours of its runs not yet paid for."""
        have = done | {item.id}
        new = tuple(
            c.id
            for c in claims
            if c.id not in settled
            and item.id in c.items
            and set(c.items) <= have
            and c.settled_at(min(target[i] for i in c.items))
        )
        return new, float(sum(h for k, h in item.runs.items() if k not in paid))

    def key(item: Item) -> tuple[Any, ...]:
        new, cost = value(item)
        ratio = (len(new) / cost if cost > 0 else math.inf) if new else 0.0
        return (-ratio, cost, item.id)

    while todo:
        best = min(todo.values(), key=key)
        new, cost = value(best)
        out.append(Ranked(len(out) + 1, best.id, best.target, new, cost))
        settled.update(new)
        paid.update(best.runs)
        done.add(best.id)
        del todo[best.id]
    return out


# ---------------------------------------------------------------- the confirmatory replication's plan
def chapter(figure_id: str) -> int:
    """The thesis chapter of an item.

    >>> chapter("table-3.4"), chapter("5.3")
    (3, 5)
    """
    return int(figure_id.removeprefix("table-").split(".")[0])


def item_seeds(figure_id: str, seeds: Iterable[int]) -> list[int]:
    """The training seeds an item is made to when ``seeds`` are requested: those, and for chapter 5 every seed past
    them up to :data:`CH5_TARGET_SEEDS`.

    >>> item_seeds("3.4", [3, 4, 5]), item_seeds("5.6", [3, 4, 5])
    ([3, 4, 5], [3, 4, 5, 6, 7, 8, 9])
    """
    seeds = sorted({int(s) for s in seeds})
    if chapter(figure_id) == 5 and seeds:
        seeds = sorted(set(seeds) | set(range(seeds[-1] + 1, CH5_TARGET_SEEDS)))
    return seeds


def priced_runs(
    figure_id: str, scale: str, seeds: Iterable[int], rates: Rates, missing: bool = False
) -> dict[str, float]:
    """Core-hours of each job (by key) figure ``figure_id`` runs at ``scale`` for ``seeds`` (:func:`item_seeds`),
    priced with ``rates``; with ``missing``, only the jobs neither cached nor shipped, each at its work left
    (:func:`~thesis_repro.runs.throughput.work_left`)."""
    jobs = seed_jobs(figure_id, scale, item_seeds(figure_id, seeds))
    if not missing:
        return {j.key: core_hours(work(j), job_rate(j, rates)) for j in jobs}
    cache = RunCache()
    return {j.key: core_hours(work_left(j, cache), job_rate(j, rates)) for j in to_compute(jobs, cache)}


def item_state(figure_id: str, scale: str, seeds: Iterable[int]) -> str:
    """Where an item's fresh ``seeds`` (:func:`item_seeds`) are: ``to make`` (some of their jobs are neither shipped
    nor cached), ``made`` (all are, but the item's block in the scale table does not read them yet: raise it,
    rebuild the page, ship the claims) or ``read`` (its page, and so its claims' verdicts, hold them)."""
    wanted = item_seeds(figure_id, seeds)
    if to_compute(seed_jobs(figure_id, scale, wanted)):
        return "to make"
    return "made" if seed_count(figure_id, scale, set(wanted)) else "read"


def page_items() -> dict[str, str]:
    """Page (``fig-3.3``, ``table-3.4``) -> the figure id whose runs it shows."""
    return {figures.get(f).notebook_id: f for f in figures.ids()}


def claims_from(rows: Iterable[Mapping[str, Any]]) -> list[Claim]:
    """:class:`Claim` s from the claims ledger's JSON (``claims --json``'s claim objects), each with ``pages``:
    the pages whose saved numbers it reads (:func:`thesis_repro.claims.registry.pages_read`). A claim no seed was
    judged on (``n_seeds`` 0) is skipped with its ``note`` (or its verdict) as the reason."""
    items = page_items()
    out = []
    for r in rows:
        cal = r.get("calibration") or {}
        why = str(r.get("note") or r.get("verdict") or "no seed judged")
        skip = "" if r.get("n_seeds") else why.split(": ")[0].split("; ")[0]
        read = tuple(sorted(items[p] for p in r.get("pages", [r["page"]]) if p in items))
        out.append(Claim(r["id"], read, cal.get("seeds_for_80"), skip))
    return out


@dataclass
class OrderPlan:
    """The confirmatory replication's plan in order: the ranked items, the items left out and the skipped claims (with
    why)."""

    scale: str
    seeds: list[int]
    ranked: list[Ranked]
    left_out: dict[str, str] = field(default_factory=dict)
    skipped: dict[str, str] = field(default_factory=dict)
    unsettled: list[str] = field(default_factory=list)
    states: dict[str, str] = field(default_factory=dict)  # item -> item_state


def confirmatory_plan(
    scale: str,
    seeds: Iterable[int],
    claims: Sequence[Claim],
    rates: Rates,
    missing: bool = False,
    figure_ids: Iterable[str] | None = None,
) -> OrderPlan:
    """The confirmatory replication's plan for ``seeds`` at ``scale`` in the order of :func:`rank`: every item of
    :data:`EVERY_ITEM_CHAPTERS` (chapter 5's to :data:`CH5_TARGET_SEEDS`), the other items only where one of their
    claims can be settled at their target; ``figure_ids``: those items instead, every one of them ranked; ``missing``
    prices only what is not made yet. Pure but for the pricing (:func:`priced_runs`)."""
    seeds = sorted({int(s) for s in seeds})
    if not seeds:
        raise ValueError("the plan's order needs the seeds to add (such as --seeds 3 4 5)")
    ids = list(figure_ids) if figure_ids is not None else figures.ids()
    targets = {f: max(item_seeds(f, seeds)) + 1 for f in ids}
    left_out = {
        f: f"no claim of it can be settled by {targets[f]} seeds"
        for f in ids
        if figure_ids is None
        and chapter(f) not in EVERY_ITEM_CHAPTERS
        and not any(f in c.items and c.settled_at(targets[f]) for c in claims)
    }
    items = [Item(f, targets[f], priced_runs(f, scale, seeds, rates, missing)) for f in ids if f not in left_out]
    ranked = rank(items, claims)
    settled = {c for r in ranked for c in r.settles}
    skipped = {c.id: c.skip for c in claims if c.skip and c.items}  # claims on no item's runs: not the plan's
    unsettled = sorted(c.id for c in claims if not c.skip and c.id not in settled)
    states = {r.item: item_state(r.item, scale, seeds) for r in ranked}
    return OrderPlan(scale, seeds, ranked, left_out, skipped, unsettled, states)


def order_report(p: OrderPlan) -> str:
    """The plan as a table (rank, item, seeds, state, claims it can settle, core-hours, claims per core-hour,
    running total), then the items made but not read yet, the items left out and the claims skipped, each with
    why."""
    total = 0.0
    rows = []
    for r in p.ranked:
        total += r.core_hours
        rows.append(
            {
                "rank": str(r.rank),
                "item": r.item,
                "seeds": f"{min(p.seeds)}-{r.target - 1}",
                "state": p.states.get(r.item, "-"),
                "claims it can settle": f"{len(r.settles)}: {', '.join(r.settles)}" if r.settles else "0",
                "core-hours": f"{r.core_hours:,.1f}",
                "per core-hour": "-" if not r.settles else f"{r.per_core_hour:,.2f}",
                "total": f"{total:,.1f}",
            }
        )
    cols = ("rank", "item", "seeds", "state", "claims it can settle", "core-hours", "per core-hour", "total")
    settled = sum(len(r.settles) for r in p.ranked)
    lines = [
        f"the generator's order at {p.scale} for seeds {' '.join(map(str, p.seeds))}: claims settled per core-hour "
        "(the order decides what runs first, never what is judged; every item is made to its target)",
        text_table(rows, cols),
        f"{len(p.ranked)} items, {total:,.1f} core-hours; {settled} claims can be settled",
    ]
    made = [f for f, state in p.states.items() if state == "made"]
    if made:
        lines.append(
            f"made but not read yet: {', '.join(made)}: raise each one's block in thesis_repro/config/scales.yaml "
            f"(train_seeds: {max(p.seeds) + 1}; chapter 5: its seeds list), then `make figure-<item> SCALE={p.scale}` "
            f"(or `make book SCALE={p.scale}`), `make ship-claims SCALE={p.scale}` and `make results`"
        )
    if p.left_out:
        lines.append(
            f"left out (no claim settled at these seeds): {'; '.join(f'{f}: {why}' for f, why in p.left_out.items())}"
        )
    if p.skipped:
        lines.append("claims skipped, no seed judged on them: " + "; ".join(f"{c} ({w})" for c, w in p.skipped.items()))
    if p.unsettled:
        lines.append(f"claims no item settles at its target (power below 80 %): {', '.join(p.unsettled)}")
    return "\n".join(lines)


def item_order(p: OrderPlan) -> list[str]:
    """The plan's items in rank order (what ``reference-runs --order claims`` makes, item by item)."""
    return [r.item for r in p.ranked]
