"""The thesis-budget verdict: Fig 3.3's r against training budget from the study's runs made so far (read only), and
each claim whose runs the study retrains judged again by the same frozen v3 rule on the study's runs at 4e6 steps,
*not computed (k of n runs)* until they are all made.

Synthetic throughout: a stand-in cache answers the study's jobs from their configs, so nothing trains or evaluates
(the trainer and the job runner raise if called)."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from thesis_repro.claims import ledger, ledger_row, page_verdicts, registry, report, results, store
from thesis_repro.claims import thesis_budget as tb
from thesis_repro.core import cache as cache_mod
from thesis_repro.core.cache import Job
from thesis_repro.figures import ch3
from thesis_repro.runs import budget_study as bs

STEPS = bs.budgets("small")
FIG33 = [s for s in registry.specs() if s.page == "fig-3.3" and "measure" in s.rule]


@pytest.fixture(autouse=True)
def _never_train(monkeypatch):
    """Nothing here may train or evaluate: the cache's computing paths and the job runner raise."""

    def refuse(*a, **k):
        raise AssertionError("the thesis-budget figures and claims must never train or evaluate")

    monkeypatch.setattr(cache_mod.RunCache, "run", refuse)
    monkeypatch.setattr(cache_mod.RunCache, "compute", refuse)
    monkeypatch.setattr(bs, "run_jobs", refuse, raising=False)
    import thesis_repro.core.backends as backends

    monkeypatch.setattr(backends, "run_jobs", refuse)


class FakeCache:
    """Answers the study's jobs from their configs: a variant's training return rises with its index, its testing
    AUC falls with it after ``flip`` env steps and rises with it before (r > 0 early, r < 0 late); ``missing``
    training runs (by label) are not made."""

    def __init__(self, variants: list[str], flip: int = 2_500_000, missing: set[str] = frozenset()):
        self.rank = {a: i for i, a in enumerate(variants)}
        self.flip, self.missing = flip, set(missing)

    def load(self, job: Job):
        cfg = job.config if job.kind == "train" else job.config["train"]
        if Job("train", cfg).label in self.missing:
            return None
        i, seed = self.rank[cfg["algorithm"]], int(cfg["seed"])
        if job.kind == "train":
            t = np.arange(1, int(cfg["timesteps"]) + 1, 10_000)
            # later training return grows with the variant; a little noise by seed
            return {"episode_timesteps": t, "episode_returns": 1000.0 + 100.0 * i + 10.0 * seed + 0.0 * t}
        snap = job.config["test"].get("snapshot") or int(cfg["timesteps"])
        sign = 1.0 if snap < self.flip else -1.0
        value = 500.0 + sign * 20.0 * i + 5.0 * ((seed * 7 + i) % 3)
        n_sig = len(job.config["test"]["sigmas"])
        return {"returns": np.full((n_sig, 2), value)}


def _made(missing: set[str] = frozenset()) -> FakeCache:
    return FakeCache(bs.variants(bs.budget_settings("small")), missing=missing)


# ---------------------------------------------------------------- r against training budget (figures, runs)
def test_r_per_budget_on_a_synthetic_benchmark_flips_sign_where_the_auc_does():
    at = bs.budget_points("small", _made())
    assert [b.steps for b in at] == STEPS == [1_000_000, 2_000_000, 3_000_000, 4_000_000]
    assert all(b.complete and b.coverage == "108 of 108 runs" for b in at)
    cells, by_budget = bs.r_by_budget(at)
    assert len(cells) == 4 * 12 and set(cells["algos"]) == {9} and set(cells["seeds"]) == {4}
    early = cells[cells["steps"] < 2_500_000]
    late = cells[cells["steps"] > 2_500_000]
    assert (early["r"] > 0.9).all() and (early["r_seeds"] > 0.9).all()
    assert (late["r"] < -0.9).all() and (late["r_seeds"] < -0.9).all()
    assert by_budget["negative"].tolist() == [0, 0, 12, 12] and by_budget["cells"].tolist() == [12] * 4
    assert (by_budget["pooled_r"].to_numpy()[:2] > 0.9).all() and (by_budget["pooled_r"].to_numpy()[2:] < -0.9).all()
    line = bs.budget_headline(at[-1], by_budget, ch3.thesis_negative())
    assert line.startswith("At the thesis's budget (4M steps, 108 runs): r < 0 in 12/12 cells (thesis: 18/20)")


def test_the_thesis_side_comes_from_its_transcribed_table():
    """18 of Fig 3.3(c)'s 20 cells are negative (D-Pendulum's env and dom are not), all 12 on the study's tasks."""
    assert ch3.thesis_negative() == (18, 20)
    assert ch3.thesis_negative(bs.task_order(bs.budget_settings("small"))) == (12, 12)


def test_the_thesis_statistic_is_the_best_training_seed_per_variant():
    """The per-cell r is correlation_table's: each variant's best-training seed, not the seed mean."""
    pts = pd.DataFrame(
        [
            {"steps": 1, "env": "E", "test": "obs", "algo": a, "seed": s, "train_return": tr, "auc": au}
            for a, rows in {"a": [(1, 9), (5, 1)], "b": [(2, 8), (3, 5)], "c": [(4, 0), (0, 9)]}.items()
            for s, (tr, au) in enumerate(rows)
        ]
    )
    r = ch3.budget_correlations(pts)["r"].item()
    best = {"a": (5, 1), "b": (3, 5), "c": (4, 0)}  # each variant's seed with the best training return
    x, y = zip(*best.values(), strict=True)
    assert r == pytest.approx(np.corrcoef(x, y)[0, 1])


def test_the_budget_figure_draws_and_lists_only_the_cells_with_an_r():
    """A cell whose runs are too few for an r at every budget (a task the study has barely started) is neither a
    line nor a legend entry; a cell with an r at some budget is both."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from thesis_repro.figures import plot

    cells = pd.DataFrame(
        [{"steps": s, "env": "Walker2d", "test": "obs", "r": r} for s, r in ((1, 0.5), (2, np.nan))]
        + [{"steps": s, "env": "Hopper", "test": "obs", "r": np.nan} for s in (1, 2)]
    )
    summary = pd.DataFrame(
        {
            "steps": [1, 2],
            "pooled_r": [0.5, np.nan],
            "runs": [3, 3],
            "runs_total": [8, 8],
            "negative": [0, 0],
            "cells": [1, 0],
        }
    )
    fig, ax = plt.subplots()
    plot.r_by_budget_lines(ax, cells, summary, (18, 20))
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    plt.close(fig)
    assert labels == ["Walker2d/obs", "pooled r (seed-keyed)"]

    none, by_budget = bs.r_by_budget(bs.budget_points("small"))  # no run made yet (as at smoke)
    fig, ax = plt.subplots()
    plot.r_by_budget_lines(ax, none, by_budget, (18, 20))
    texts = [t.get_text() for t in ax.texts]
    plt.close(fig)
    assert ax.get_legend() is None and texts == ["no study run computed yet"]


def test_with_no_runs_made_every_budget_reads_not_computed_k_of_n():
    at = bs.budget_points("small")  # the empty cache and shipped layer of the test
    assert [(b.runs, b.runs_total, len(b.points)) for b in at] == [(0, 108, 0)] * 4
    cells, by_budget = bs.r_by_budget(at)
    assert cells.empty and by_budget["negative"].tolist() == [0] * 4 and by_budget["runs"].tolist() == [0] * 4
    assert bs.budget_headline(at[-1], by_budget, (18, 20)) == (
        "At the thesis's budget (4M steps) the study's runs are not all computed yet (0 of 108 runs)."
    )
    meta = bs.claims_meta(at[-1])
    assert meta == {"study": "thesis-budget", "steps": 4_000_000, "runs": 0, "runs_total": 108}


def test_a_missing_run_leaves_the_budget_partial_and_the_frames_unsaved():
    gone = {bs.train_jobs("small")[0].label}
    last = bs.points_at("small", STEPS[-1], _made(gone))
    assert (last.runs, last.runs_total) == (107, 108) and not last.complete
    assert len(last.points) == 107 * 4
    assert "frames" not in bs.claims_meta(last)


# ---------------------------------------------------------------- the claims layer
def _judge(cid: str, meta: dict, frames: dict | None = None) -> ledger_row.Row:
    frames = frames if frames is not None else {"points": bs.points_at("small", STEPS[0], _made()).points}
    store.save_page("fig-3.3", "small", frames, {"scale": "small", **meta})
    return ledger.judge(registry.spec(cid), "small", with_null=False)


def test_not_computed_k_of_n_while_runs_are_missing():
    meta = bs.claims_meta(bs.points_at("small", STEPS[-1]))
    row = _judge("3.3-negative-correlation", {"thesis_budget": meta})
    tb_ = row.thesis_budget
    assert tb_["verdict"] == report.NOT_COMPUTED and (tb_["runs"], tb_["runs_total"]) == (0, 108)
    assert tb_["line"] == "thesis's budget (4M steps): not computed (0 of 108 runs)"
    assert row.status != report.NOT_COMPUTED  # the small verdict is judged as before
    assert results.thesis_budget.cell(row.as_dict()["thesis_budget"]) == "not computed (0 of 108 runs)"
    derived = ledger.judge(registry.spec("3.3-not-valid-metric"), "small", with_null=False)
    assert derived.thesis_budget["verdict"] == report.NOT_COMPUTED and derived.thesis_budget["runs"] == 0


def test_a_page_saved_before_the_study_says_so():
    row = _judge("3.3-negative-correlation", {})
    assert row.thesis_budget["verdict"] == report.NOT_COMPUTED
    assert "carry no thesis-budget runs" in row.thesis_budget["note"]


@pytest.mark.parametrize("cid", [s.id for s in FIG33])
def test_the_verdict_is_the_same_frozen_v3_rule_on_the_studys_4m_runs(cid):
    """Judged on the study's 4M frames, each Fig 3.3 claim gets exactly the v3 statistical label (and v2's) it gets
    on a page whose own numbers are those frames: the same measure, level, margin, count rule and Holm family."""
    last = bs.points_at("small", STEPS[-1], _made())
    meta = {"thesis_budget": bs.claims_meta(last)}
    small = bs.points_at("small", STEPS[0], _made()).points  # the scale's own numbers: r > 0 here
    row = _judge(cid, meta, {"points": small})
    alone = _judge(cid, {}, {"points": last.points})
    got = row.thesis_budget
    assert got["verdict"] == alone.v3["status"] and got["v2_verdict"] == alone.v2_status
    assert json.dumps(got["primary"], sort_keys=True) == json.dumps(alone.primary, sort_keys=True)
    assert got["verdict"] != report.NOT_COMPUTED and got["n_seeds"] == alone.n_seeds
    assert (got["runs"], got["runs_total"], got["steps"]) == (108, 108, 4_000_000)


def test_the_headline_claim_reproduces_on_synthetic_4m_runs_and_the_json_carries_it():
    last = bs.points_at("small", STEPS[-1], _made())
    row = _judge("3.3-negative-correlation", {"thesis_budget": bs.claims_meta(last)})
    d = json.loads(json.dumps(row.as_dict()))
    assert d["verdict"] != d["thesis_budget"]["verdict"]  # the small numbers (r > 0) against the 4M ones (r < 0)
    assert d["thesis_budget"]["verdict"] == report.REPRODUCES
    assert d["thesis_budget"]["ours"].startswith("pooled r -")
    assert d["thesis_budget"]["line"].startswith("thesis's budget (4M steps, 108/108 runs): reproduces")
    v = next(v for v in page_verdicts.verdicts("fig-3.3", "small") if "3.3-negative-correlation" in v.headline)
    assert v.thesis_budget == d["thesis_budget"]["line"]


def test_claims_beyond_the_studys_pages_carry_none():
    row = ledger.judge(registry.spec("3.2-overfitting"), "small", with_null=False)
    assert row.thesis_budget == {} and row.as_dict()["thesis_budget"] is None


def test_the_pages_agree_with_the_studys_items():
    from thesis_repro.book.notebooks import page_id

    assert set(tb.PAGES) == {page_id(i) for i in bs.ITEMS}
    assert tb.THESIS_STEPS == bs.budget_settings("small")["timesteps"]


def test_results_md_has_the_thesis_budget_column():
    claims = [
        {
            "id": "a",
            "verdict": "reproduces",
            "thesis_budget": {"verdict": report.NOT_COMPUTED, "runs": 3, "runs_total": 108},
        },
        {"id": "b", "verdict": "inconclusive"},
    ]
    table = results.claims_table(claims).splitlines()
    assert table[0].endswith("| thesis's budget (4M steps) |")
    assert table[2].endswith("| not computed (3 of 108 runs) |") and table[3].endswith("| - |")


# ---------------------------------------------------------------- the tables that read the same runs
TABLES = [s for s in registry.specs() if s.page in ("table-3.4", "table-3.6") and "measure" in s.rule]


def test_a_table_counts_only_its_own_learners_runs():
    sac = next(j.label for j in bs.train_jobs("small") if j.config["algorithm"] == "sac")
    cache = _made({sac})
    t34, t36 = bs.page_meta("table-3.4", "small", cache), bs.page_meta("table-3.6", "small", cache)
    assert (t34["runs"], t34["runs_total"]) == (47, 48) and "frames" not in t34  # ppo, trpo, ddpg, sac x 3 x 4
    assert t36["runs"] == t36["runs_total"] == 6 * 3 * 4 and set(t36["frames"]) == {"aucs", "returns", "train"}
    assert {r["method"] for r in t36["frames"]["aucs"]} == bs.item_learners("table-3.6", "small")
    with pytest.raises(ValueError, match="reads no run of the thesis-budget study"):
        bs.page_meta("table-3.5", "small", cache)


@pytest.mark.parametrize("cid", [s.id for s in TABLES])
def test_a_table_claim_is_judged_by_its_frozen_rule_on_the_studys_runs(cid):
    s = registry.spec(cid)
    meta = bs.page_meta(s.page, "small", _made())
    frames = tb.frames_of(meta)
    store.save_page(s.page, "small", frames, {"scale": "small"})
    alone = ledger.judge(s, "small", with_null=False)
    store.save_page(s.page, "small", frames, {"scale": "small", "thesis_budget": meta})
    got = ledger.judge(s, "small", with_null=False).thesis_budget
    if alone.v3.get("status") in (report.NOT_RUN, report.NOT_COMPUTED) or not alone.primary:
        assert got["verdict"] in (report.NOT_RUN, report.INCONCLUSIVE, alone.v3.get("status"))
        return
    assert got["verdict"] == alone.v3["status"] and got["v2_verdict"] == alone.v2_status
    assert json.dumps(got["primary"], sort_keys=True) == json.dumps(alone.primary, sort_keys=True)


def test_the_pages_first_line_says_the_answer_at_the_thesis_budget():
    from thesis_repro.book import builder

    small = {"points": bs.points_at("small", STEPS[0], _made()).points}
    page_verdicts.judge_page("fig-3.3", "small", small, {"thesis_budget": bs.page_meta("3.3", "small")}, display=False)
    first = "".join(builder.verdicts_cell("fig-3.3", "small")["source"]).splitlines()[0]
    assert first.startswith("**At the thesis's budget (4M steps):** 3.3-negative-correlation not computed (0 of 108")
    page_verdicts.judge_page("fig-3.3", "small", small, {"thesis_budget": bs.page_meta("3.3", "small", _made())})
    first = "".join(builder.verdicts_cell("fig-3.3", "small")["source"]).splitlines()[0]
    assert first.startswith("**At the thesis's budget (4M steps, 108/108 runs):** 3.3-negative-correlation reproduces")
