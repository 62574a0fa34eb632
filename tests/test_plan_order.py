"""The generator's order (`plan order`, `reference-runs --order`): claims settled per core-hour, item by item.

The ranking is a pure function of a claims snapshot and the items' priced runs; these tests feed it small fakes.
"""

from __future__ import annotations

import json
import math

import pytest

from thesis_repro import figures
from thesis_repro.cli.commands import main
from thesis_repro.core import job_kinds, paths
from thesis_repro.core.cache import Job
from thesis_repro.runs import generator, needs, order
from thesis_repro.runs.order import Claim, Item


def _never(config: dict, workdir) -> dict:  # a toy kind's job function: planned, never run here
    raise AssertionError("not run")


job_kinds.register("order-toy", "tests.test_plan_order:_never")


def _order(items, claims):
    return [(r.item, r.settles, r.core_hours) for r in order.rank(items, claims)]


def test_items_rank_by_claims_settled_per_core_hour():
    items = [Item("cheap-one", 6, {"a": 1.0}), Item("dear-two", 6, {"b": 4.0}), Item("dear-three", 6, {"c": 2.0})]
    claims = [
        Claim("c1", ("cheap-one",), 3),
        Claim("d1", ("dear-two",), 5),
        Claim("d2", ("dear-two",), 6),
        Claim("t1", ("dear-three",), 3),
        Claim("t2", ("dear-three",), 4),
        Claim("t3", ("dear-three",), 5),
    ]
    assert [r[0] for r in _order(items, claims)] == ["dear-three", "cheap-one", "dear-two"]  # 3/2, 1/1, 2/4
    ranked = order.rank(items, claims)
    assert [r.rank for r in ranked] == [1, 2, 3] and ranked[0].per_core_hour == pytest.approx(1.5)


def test_only_claims_the_target_seeds_can_settle_count_and_skipped_claims_never():
    items = [Item("x", 6, {"a": 1.0}), Item("y", 10, {"b": 1.0})]
    claims = [
        Claim("x-needs-8", ("x",), 8),
        Claim("x-untestable", ("x",), None),
        Claim("x-kl-avg", ("x",), 3, skip="every kl_avg run diverged"),
        Claim("y-needs-8", ("y",), 8),
    ]
    assert _order(items, claims) == [("y", ("y-needs-8",), 1.0), ("x", (), 1.0)]
    assert Claim("z", ("x",), 6).settled_at(6) and not Claim("z", ("x",), 7).settled_at(6)


def test_ties_and_zero_value_items_come_cheapest_first():
    items = [Item("b", 6, {"k2": 2.0}), Item("a", 6, {"k1": 2.0}), Item("c", 6, {"k3": 0.5}), Item("d", 6, {})]
    claims = [Claim("a1", ("a",), 3), Claim("b1", ("b",), 3)]
    assert [r[0] for r in _order(items, claims)] == ["a", "b", "d", "c"]  # a ties b (by id); then 0 h before 0.5 h


def test_shared_runs_are_paid_once_by_the_first_item():
    items = [Item("big", 6, {"s": 3.0, "own": 1.0}), Item("small", 6, {"s": 3.0})]
    claims = [Claim("big1", ("big",), 3), Claim("big2", ("big",), 3), Claim("small1", ("small",), 3)]
    got = _order(items, claims)
    assert got == [("big", ("big1", "big2"), 4.0), ("small", ("small1",), 0.0)]
    assert order.rank(items, claims)[1].per_core_hour == math.inf
    assert sum(h for _, _, h in got) == 4.0  # the book's cost once, however the items share it


def test_a_claim_on_two_items_settles_with_the_later_one():
    items = [Item("p", 6, {"a": 1.0}), Item("q", 6, {"b": 2.0})]
    got = _order(items, [Claim("pq", ("p", "q"), 3), Claim("only-p", ("p",), 3)])
    assert got == [("p", ("only-p",), 1.0), ("q", ("pq",), 2.0)]
    assert _order(items[:1], [Claim("pq", ("p", "q"), 3)]) == [("p", (), 1.0)]  # q is not in the plan: never


def test_claims_from_the_ledger_json():
    rows = [
        {"id": "3.3-x", "page": "fig-3.3", "pages": ["fig-3.3"], "n_seeds": 3, "calibration": {"seeds_for_80": 5}},
        {"id": "3.4-y", "page": "table-3.4", "pages": ["table-3.4"], "n_seeds": 3, "calibration": {}},
        {"id": "4.3-z", "page": "fig-4.3", "n_seeds": 0, "note": "every kl_avg run (12) diverged: not judged"},
        {"id": "4-kl", "page": "analysis-4-kl", "n_seeds": 0, "verdict": "reproduces"},
    ]
    got = order.claims_from(rows)
    assert got[0] == Claim("3.3-x", ("3.3",), 5) and got[1] == Claim("3.4-y", ("table-3.4",), None)
    assert got[2] == Claim("4.3-z", ("4.3",), None, skip="every kl_avg run (12) diverged")
    assert got[3].items == () and got[3].skip  # a page of no item: never settled, never listed


def test_chapter_5_goes_to_10_seeds_and_the_others_to_the_seeds_asked():
    assert order.item_seeds("5.4", [3, 4, 5]) == list(range(3, 10))
    assert order.item_seeds("table-3.3", [5, 3, 4]) == [3, 4, 5]
    assert order.item_seeds("5.4", [12]) == [12] and order.chapter("table-3.7") == 3


def test_the_plan_leaves_out_chapter_4_items_no_claim_of_which_6_seeds_settle(monkeypatch):
    monkeypatch.setattr(figures, "ids", lambda: ["3.2", "4.1", "4.7", "5.3"])
    monkeypatch.setattr(order, "priced_runs", lambda f, *a, **k: {f"{f}-run": 1.0})
    monkeypatch.setattr(order, "item_state", lambda f, *a: {"3.2": "made", "4.7": "read"}.get(f, "to make"))
    claims = [
        Claim("4.1-a", ("4.1",), None),
        Claim("4.7-b", ("4.7",), 6),
        Claim("3.2-c", ("3.2",), None),
        Claim("4.3-d", ("4.1",), None, skip="every kl_avg run diverged"),
    ]
    p = order.confirmatory_plan("small", [3, 4, 5], claims, rates=None)
    assert [r.item for r in p.ranked] == ["4.7", "3.2", "5.3"] and p.ranked[2].target == 10
    assert p.left_out == {"4.1": "no claim of it can be settled by 6 seeds"}
    assert p.skipped == {"4.3-d": "every kl_avg run diverged"} and p.unsettled == ["3.2-c", "4.1-a"]
    text = order.order_report(p)
    assert "left out (no claim settled at these seeds): 4.1" in text and "4.7-b" in text and "3-9" in text
    assert p.states == {"4.7": "read", "3.2": "made", "5.3": "to make"}
    assert "made but not read yet: 3.2: raise each one's block" in text and "train_seeds: 6" in text
    named = order.confirmatory_plan("small", [3, 4, 5], claims, rates=None, figure_ids=["4.1", "3.2"])
    assert [r.item for r in named.ranked] == ["3.2", "4.1"] and not named.left_out  # named items are all ranked
    with pytest.raises(ValueError, match="seeds"):
        order.confirmatory_plan("small", [], claims, rates=None)


@pytest.fixture
def two_items(monkeypatch):
    """Two toy items of three seeds each."""
    monkeypatch.setattr(figures, "FIGURES", {})
    monkeypatch.setattr(figures, "TRAINING_KINDS", ("order-toy",))

    def cfg(name, steps, seed):
        return {"algorithm": name, "env": "Toy", "seed": seed, "timesteps": steps}

    grids = {
        "9.1": lambda s: [Job("order-toy", cfg(n, t, seed)) for seed in (0, 1, 2) for n, t in (("c", 30), ("a", 5))],
        "9.2": lambda s: [Job("order-toy", cfg("b", 1, seed)) for seed in (0, 1, 2)],
    }
    for fid, grid in grids.items():
        figures.register_figure(fid, f"toy figure {fid}", kinds=["order-toy"], settings_id="_example")(grid)


def _labels(planned):
    return [f"{p.job.config['algorithm']}{p.job.config['seed']}" for p in planned]


def test_item_by_item_makes_every_seed_of_an_item_before_the_next(two_items):
    item = generator.job_queue("smoke", ["9.1", "9.2"], kinds=["order-toy"], seeds=[0, 1, 2], order="item")
    assert _labels(item) == ["a0", "c0", "a1", "c1", "a2", "c2", "b0", "b1", "b2"]
    seed_first = generator.job_queue("smoke", ["9.1", "9.2"], kinds=["order-toy"], by_figure=True, seeds=[0, 1, 2])
    assert _labels(seed_first) == ["a0", "c0", "b0", "a1", "c1", "a2", "c2", "b1", "b2"]  # still available
    own = generator.job_queue(
        "smoke", ["9.2", "9.1"], kinds=["order-toy"], seeds=[1], order="item", item_seeds={"9.1": [2]}
    )
    assert _labels(own) == ["b1", "a2", "c2"]  # an item's own seeds (chapter 5's to 10)


def test_a_bad_order_is_one_error_line(capsys):
    assert main(["reference-runs", "--scale", "smoke", "--order", "fastest"]) == 2
    err = capsys.readouterr().err
    assert err == "error: unknown order 'fastest'; valid orders are: 'seed-first', 'item', 'claims'\n"
    with pytest.raises(ValueError, match="valid generator orders are: 'seed-first', 'item'"):
        generator.job_queue("smoke", order="claims")
    assert main(["plan", "order", "--scale", "small"]) == 2
    assert capsys.readouterr().err.startswith("error: plan order needs --seeds")


def test_seeds_past_chapter_5_s_list_are_planned_without_changing_the_scale():
    """`--seeds 3 4 5` plans chapter 5's CMA-ES seeds too (they list `seeds`, not a `train_seeds` count), while the
    scale's own list stays: a fresh clone's page never trains seeds that are not shipped."""
    from thesis_repro.runs import costs as plan
    from thesis_repro.runs import throughput

    listed = figures.settings("5.3", "small")["seeds"]  # [0, 1, 2], or more once its fresh seeds are shipped
    assert needs.seed_count("5.3", "small", {20, 21}) == {"seeds": [*listed, 20, 21]}
    assert needs.seed_count("5.3", "small", {listed[0], listed[-1]}) == {}
    jobs = needs.seed_jobs("5.3", "small", [20, 21])
    assert sorted(needs.training_seed(j) for j in jobs) == [20, 21]
    assert {needs.training_seed(j) for j in figures.jobs("5.3", "small")} == set(listed)
    per_seed = len(needs.seed_jobs("5.4", "small", [0]))
    assert len(needs.seed_jobs("5.4", "small", range(3, 10))) == 7 * per_seed > 0
    planned = generator.job_queue("small", ["5.3"], kinds=["arm-solve"], seeds=[4, 3], order="item")
    assert [p.job.config["seed"] for p in planned] == [4, 3]
    p = plan.plan_figure("5.6", "small", rates=throughput.Rates({"arm": 1.0}, {}), seeds=[3, 4, 5, 6, 7, 8, 9])
    assert p.n_other == 7 * len(needs.seed_jobs("5.6", "small", [0])) and p.core_hours > 0


def test_shipped_pace_prices_chapter_5_by_kind(tmp_path):
    """`--rates shipped` (and `plan order`) price an arm job at the pace its kind's shipped entries kept."""
    from thesis_repro.runs import throughput

    job = Job("arm-solve", {"popsize": 10, "generations": 30, "seed": 0})
    entry = tmp_path / "arm-solve" / "solve__key"
    entry.mkdir(parents=True)
    (entry / "config.json").write_text(json.dumps({"kind": "arm-solve", "config": dict(job.config)}))
    (entry / "provenance.json").write_text(json.dumps({"wall_seconds": 3.0}))
    rates = throughput.shipped_rates(root=tmp_path, by_env=True)
    assert rates.rate("arm:arm-solve") == pytest.approx(100.0)  # 10 x 30 rollouts in 3 s
    assert (
        throughput.job_rate(job, rates) == pytest.approx(100.0)
        and throughput.job_rate(Job("arm-target", {}), rates) > 100
    )


def test_an_item_s_fresh_seeds_are_read_made_or_to_make(monkeypatch):
    """Fig 3.4's seeds 3-5 are shipped and its block reads them; a seed nobody made is still to make."""
    monkeypatch.setenv("THESIS_REPRO_REFERENCE", str(paths.ROOT / "data" / "reference"))
    assert order.item_state("3.4", "small", [3, 4, 5]) == "read"
    assert order.item_state("3.4", "small", [40]) == "to make"
