"""The figure layer: registry, job grids (shared runs) and the tables of chapters 4 and 5 (no verdicts)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from thesis_repro import figures
from thesis_repro.core.cache import Job
from thesis_repro.figures import ch4, ch5

EXPECTED = ["3.2", "3.3", "4.1", "4.2", "4.3", "4.4", "4.5", "4.6", "4.7", "5.3", "5.4", "5.5", "5.6"]


def _keys(jobs: list[Job], kind: str | None = None) -> set[str]:
    return {j.key for j in jobs if kind is None or j.kind == kind}


# ---------------------------------------------------------------- registry
def test_registry_lists_every_figure_with_its_module():
    assert set(EXPECTED) <= set(figures.FIGURES)
    ids = figures.ids()
    assert [i for i in ids if i in EXPECTED] == EXPECTED  # catalogue order: chapter, then number
    assert all(i[:1].isdigit() for i in ids[: len([i for i in ids if i[:1].isdigit()])])  # tables after figures
    assert figures.get("fig-4.3") is figures.FIGURES["4.3"]
    assert figures.get("4.3").module == "thesis_repro.figures.ch4"
    assert figures.get("4.3").notebook_id == "fig-4.3"
    with pytest.raises(ValueError, match="unknown figure '9.9'; valid figures are: '3.2'"):
        figures.get("9.9")


@pytest.mark.parametrize("figure_id", EXPECTED)
def test_jobs_put_training_first_without_duplicates_and_use_declared_kinds(figure_id):
    fig = figures.get(figure_id)
    jobs = figures.jobs(figure_id, "smoke")
    kinds = [j.kind for j in jobs]
    assert jobs and len(_keys(jobs)) == len(jobs)
    n_train = sum(k in figures.TRAINING_KINDS for k in kinds)
    assert all(k in figures.TRAINING_KINDS for k in kinds[:n_train])
    assert set(kinds) <= set(fig.kinds)
    assert figures.training_jobs(figure_id, "smoke") == jobs[:n_train]


def test_register_rejects_a_second_grid_for_an_id_and_overrides_reach_the_settings():
    with pytest.raises(ValueError, match="already registered"):
        figures.register_figure("3.3", "again")(lambda s: [])
    base = figures.training_jobs("4.1", "smoke")
    more = figures.training_jobs("4.1", "smoke", train_seeds=2)
    assert len(more) == 2 * len(base) and _keys(base) < _keys(more)
    with pytest.raises(ValueError, match="valid settings of figure 4.1 are"):
        figures.jobs("4.1", "smoke", train_seed=2)


def test_thesis_budget_is_read_from_the_full_scale():
    assert figures.thesis_budget("3.3") == figures.settings("3.3", "full")["timesteps"]
    assert figures.thesis_budget("4.1") == figures.settings("4.1", "full")["timesteps"]


# ---------------------------------------------------------------- shared runs
@pytest.mark.parametrize("scale", ["smoke", "small"])
def test_chapter4_figures_share_training_runs(scale):
    train = {f: _keys(figures.training_jobs(f, scale)) for f in ("4.1", "4.3", "4.5", "4.6")}
    assert train["4.1"] == train["4.3"] == train["4.5"] == train["4.6"]
    assert not train["4.1"] & _keys(figures.training_jobs("4.7", scale))  # c_a = 0.1: its own runs


def test_chapter4_evaluations_train_through_the_same_key():
    jobs = figures.jobs("4.3", "smoke")
    train = _keys(jobs, "train")
    evals = [j for j in jobs if j.kind == "evaluate"]
    assert evals and {Job("train", j.config["train"]).key for j in evals} == train


def test_figures_5_4_and_5_5_share_sources_and_tensor_runs():
    a, b = figures.jobs("5.4", "smoke"), figures.jobs("5.5", "smoke")
    assert _keys(a, "arm-source") == _keys(b, "arm-source")
    tensor = {j.key for j in a if j.kind == "arm-target" and j.config["strategy"] == "tensor"}
    assert tensor and tensor <= _keys(b, "arm-target")


def test_fig_3_2_predicted_snapshots_match_the_evaluations():
    jobs = figures.jobs("3.2", "smoke")
    (train,) = [j for j in jobs if j.kind == "train"]
    steps = [j.config["test"]["snapshot"] for j in jobs if j.kind == "evaluate"]
    assert steps == figures.ch3.snapshot_steps(train.config)
    assert steps[0] == 0 and steps[-1] >= train.config["timesteps"]


# ---------------------------------------------------------------- chapter 4 tables
def test_conditions_come_from_the_thesis_table():
    conds = ch4.conditions("4.1")
    assert [c["panel"] for c in conds] == ["a", "b", "c", "d"]
    assert {(c["c_a"], c["wind"][1]) for c in conds} == {(0.001, 0.5), (0.001, 2.5), (1.0, 0.5), (1.0, 2.5)}
    assert [c["panel"] for c in ch4.conditions("4.1", ["a", "d"])] == ["a", "d"]
    assert ch4.conditions("4.7", ["a"])[0]["c_a"] == 0.1  # single-panel figures ignore the filter
    with pytest.raises(ValueError, match="valid panels of figure 4.1 are"):
        ch4.conditions("4.1", ["z"])


def _table() -> pd.DataFrame:
    frame = pd.DataFrame(
        {
            "panel": ["a"] * 3 + ["b"] * 3,
            "algo": ["kl_avg", "params_avg", "joint"] * 2,
            "return": [95.0, 100.0, 90.0, 120.0, 100.0, 110.0],
        }
    )
    return ch4.best_per_group(frame, "return")


def test_compare_marks_the_best_algorithm_per_panel():
    table = _table()
    assert table.loc["b", "best"] == "kl_avg" and not table.loc["a", "kl_avg_best"]
    assert table.loc["a", "best"] == "params_avg" and table.loc["b", "kl_avg_best"]
    assert table.loc["a", "kl_avg"] == 95.0


def _seeded(seed_means: dict[str, list[float]], spread: float = 10.0, rollouts: int = 4) -> pd.DataFrame:
    """Per algo and seed, ``rollouts`` rows around the seed's mean (symmetric, so the seed's mean is exact)."""
    offsets = np.linspace(-spread, spread, rollouts)
    return pd.DataFrame(
        [
            {"panel": "a", "algo": a, "seed": s, "rollout": r, "return": m + offsets[r]}
            for a, means in seed_means.items()
            for s, m in enumerate(means)
            for r in range(rollouts)
        ]
    )


def test_compare_ci_is_a_t_interval_over_per_seed_means():
    from scipy import stats

    means = {"kl_avg": [700.0, 820.0, 905.0], "joint": [400.0, 455.0, 610.0]}
    frame = _seeded(means, spread=300.0)  # large rollout spread: must not enter the interval
    num = ch4.seed_table(frame, "return").set_index("algo")
    for algo, v in means.items():
        m = np.mean(v)
        half = stats.t.ppf(0.975, len(v) - 1) * np.std(v, ddof=1) / np.sqrt(len(v))
        assert num.loc[algo, "mean"] == pytest.approx(m)
        assert num.loc[algo, "half_width"] == pytest.approx(half)
        assert num.loc[algo, "n_seeds"] == 3
    table = ch4.compare_ci(frame, "return")
    m, half = np.mean(means["kl_avg"]), stats.t.ppf(0.975, 2) * stats.sem(means["kl_avg"])
    assert table.loc["a", "kl_avg"] == f"{m:.1f} ± {half:.1f}"
    assert list(table.columns) == ["kl_avg", "joint", "best"] and table.loc["a", "best"] == "kl_avg"
    assert "95 % CI of the mean across 3 training seeds" in table.attrs["note"]
    ordered = ch4.compare_ci(frame, "return", algos=["joint", "params_avg", "kl_avg"])  # params_avg not run
    assert list(ordered.columns) == ["joint", "kl_avg", "best"] and ordered.loc["a", "joint"] == table.loc["a", "joint"]


def test_compare_ci_averages_rollouts_within_a_seed_first():
    frame = _seeded({"kl_avg": [500.0, 500.0, 500.0]}, spread=200.0)  # rollouts differ, seed means equal
    num = ch4.seed_table(frame, "return")
    assert num["half_width"].item() == 0.0 and num["mean"].item() == 500.0
    assert ch4.compare_ci(frame, "return").loc["a", "kl_avg"] == "500.0 ± 0.0"
    # unequal rollouts per seed: the mean is over seed means, not over all rows
    uneven = pd.concat([frame[frame["seed"] == 0].head(1), frame[frame["seed"] > 0]])
    uneven.loc[uneven.index[0], "return"] = 800.0
    assert ch4.seed_table(uneven, "return")["mean"].item() == pytest.approx((800.0 + 500.0 + 500.0) / 3)


def test_compare_ci_with_one_seed_gives_no_interval():
    frame = _seeded({"kl_avg": [700.0], "joint": [650.0]})
    num = ch4.seed_table(frame, "return")
    assert num["half_width"].isna().all() and (num["n_seeds"] == 1).all()
    table = ch4.compare_ci(frame, "return")
    assert table.loc["a"].tolist() == ["700.0", "650.0", "kl_avg"]
    assert table.attrs["note"] == "1 training seed: no confidence interval"
    # seeds differing between cells: each cell says how many
    mixed = ch4.compare_ci(_seeded({"kl_avg": [700.0, 720.0, 710.0]}).pipe(lambda f: pd.concat([f, frame])), "return")
    assert mixed.loc["a", "joint"] == "650.0 (1)" and mixed.loc["a", "kl_avg"].endswith("(3)")
    assert "1-3 training seeds" in mixed.attrs["note"]


def test_compare_ci_means_match_compare_with_equal_rollouts():
    frame = pd.concat(
        [_seeded({"kl_avg": [700.0, 820.0], "joint": [400.0, 900.0]}).assign(panel=p) for p in "ab"],
        ignore_index=True,
    )
    frame.loc[frame["panel"] == "b", "return"] *= 2
    num = ch4.best_per_group(frame, "return")
    table = ch4.compare_ci(frame, "return")
    for p in "ab":
        for algo in ("kl_avg", "joint"):
            assert table.loc[p, algo].startswith(f"{num.loc[p, algo]:.1f} ± ")
        assert table.loc[p, "best"] == num.loc[p, "best"]


def test_per_seed_noise_aucs_average_to_the_seed_mean_auc():
    noise = pd.DataFrame(
        {
            "noise": "obs",
            "panel": "a",
            "algo": "kl_avg",
            "seed": [0, 0, 0, 1, 1, 1],
            "value": [0.0, 0.5, 1.0] * 2,
            "return": [10.0, 6.0, 2.0, 14.0, 8.0, 6.0],
        }
    )
    per = ch4.noise_aucs(noise, per_seed=True)
    assert per["auc"].tolist() == pytest.approx([0.5 * (10 + 6 + 2), 0.5 * (14 + 8 + 6)])
    assert per["auc"].mean() == pytest.approx(ch4.noise_aucs(noise)["auc"].item())
    table = ch4.compare_ci(per, "auc", by=("noise", "panel"))
    assert table.loc[("obs", "a"), "kl_avg"] == "11.5 ± 31.8"  # seeds 9, 14: t(0.975, 1) * 2.5


def test_noise_aucs_follow_eq_3_6():
    noise = pd.DataFrame(
        {"noise": "obs", "panel": "a", "algo": "kl_avg", "value": [0.0, 0.5, 1.0], "return": [10.0, 6.0, 2.0]}
    )
    out = ch4.noise_aucs(noise)
    assert out["auc"].item() == pytest.approx(0.5 * (10 + 6 + 2))


def test_cycle_frames_span_the_last_period():
    t = np.arange(121)
    idx = ch4.cycle_frames(np.sin(2 * np.pi * t / 30), 4)
    assert idx[-1] == 120 and idx[-1] - idx[0] == 30 and len(idx) == 4


# ---------------------------------------------------------------- chapter 5
def test_grid_jobs_cover_all_pairs_and_share_sources():
    settings = {"families": ["reach", "bic"], "seeds": [0], "source": {"n_tasks": 3}, "target": {"n_targets": 2}}
    sources, rows = ch5.grid_jobs(settings, ["scratch", "tensor", "ella"])
    assert len(rows) == 2 * 2 * 3
    assert len(sources) == 2 * 2  # RBF sources shared by scratch/tensor, ELLA learns its own
    with pytest.raises(ValueError, match="valid strategies"):
        ch5.grid_jobs(settings, ["cp"])


def _transfer_summary() -> pd.DataFrame:
    rows = []
    for pair, tgt in (("reach→bic", "bic"), ("bic→cast", "cast")):
        for strategy, cost, success in (
            ("scratch", 9.0, 0.0),
            ("direct", 5.0, 0.2),
            ("matrix", 3.0, 0.4),
            ("tensor", 1.0, 0.9),
        ):
            rows.append(
                {"pair": pair, "target": tgt, "strategy": strategy, "total_cost": cost, "success_rate": success}
            )
    return pd.DataFrame(rows)


def test_strategy_means_and_pair_wins():
    summary = _transfer_summary()
    mean = ch5.strategy_means(summary, ["tensor", "matrix", "direct", "scratch"])
    assert list(mean.index) == ["tensor", "matrix", "direct", "scratch"]
    assert mean.loc["matrix", "total_cost"] == 3.0 and mean.loc["tensor", "success_rate"] == pytest.approx(0.9)
    summary.loc[(summary.strategy == "matrix") & (summary.pair == "bic→cast"), "total_cost"] = 0.5
    wins = ch5.pair_wins(summary, ["tensor", "matrix", "ella"])
    assert wins.to_dict() == {"tensor": 50.0, "matrix": 50.0, "ella": 0.0}


def test_seed_means_are_the_unit_of_the_ch5_error_bars():
    """Per seed, the mean over pairs; their mean over seeds is strategy_means (equal pairs per seed)."""
    summary = pd.concat([_transfer_summary().assign(seed=0), _transfer_summary().assign(seed=1)], ignore_index=True)
    summary.loc[summary.seed == 1, "total_cost"] += 2.0
    per_seed = ch5.strategy_seed_means(summary, ["tensor", "scratch"])
    assert per_seed[["strategy", "seed"]].values.tolist() == [
        ["tensor", 0],
        ["tensor", 1],
        ["scratch", 0],
        ["scratch", 1],
    ]
    assert per_seed.total_cost.tolist() == [1.0, 3.0, 9.0, 11.0]
    overall = ch5.strategy_means(summary, ["tensor", "scratch"])
    assert per_seed.groupby("strategy").total_cost.mean().to_dict() == overall.total_cost.to_dict()


def test_curriculum_end_averages_the_last_tenth_of_the_trials():
    curves = pd.DataFrame(
        {
            "condition": ["CL"] * 10 + ["NC"] * 10,
            "seed": 0,
            "cost": [5.0] * 9 + [1.0] + [2.0] * 10,
            "success": [0.0] * 9 + [0.8] + [0.0] * 10,
        }
    )
    end = ch5.curriculum_end(curves)
    assert end.loc["CL", "cost"] == 1.0 and end.loc["CL", "success"] == pytest.approx(0.8)
    assert end.loc["NC", "cost"] == 2.0 and end.loc["NC", "success"] == 0.0


def test_a_run_shared_by_two_figures_is_computed_once():
    from thesis_repro.core.backends import run_jobs

    small = {"panels": ["a"], "algos": ["joint"]}
    (first,) = run_jobs(figures.training_jobs("4.1", "smoke", **small), n_jobs=1, progress=False)
    (second,) = run_jobs(figures.training_jobs("4.3", "smoke", **small), n_jobs=1, progress=False)
    assert first.source == "computed" and second.source == "cached" and second.path == first.path


@pytest.mark.parametrize("figure_id", EXPECTED)
def test_notebooks_are_thin_and_end_with_the_shared_verdict(figure_id):
    from thesis_repro.core import paths

    fig = figures.get(figure_id)
    code = "\n".join(line for line in paths.notebook(figure_id).read_text().splitlines() if not line.startswith("#"))
    for literal in ("2048", "4096", "4e6", "4000000", "4_000_000", "Job(", "def "):
        assert literal not in code, f"{fig.notebook_id}: {literal!r} belongs in the library or the scale table"
    assert f'figures.settings("{figure_id}", SCALE)' in code
    assert f'pages.runs_summary("{figure_id}", SCALE)' in code
    last = paths.notebook(figure_id).read_text().strip().split("# %%")[-1]  # the verdict cell (claims layer)
    calls = (f'claims.judge_page(\n    "{fig.notebook_id}",', f'claims.judge_page("{fig.notebook_id}", SCALE, ')
    assert any(c in last for c in calls), last


def test_register_checks_the_job_kinds():
    with pytest.raises(ValueError, match="unknown job kind 'trian'; valid job kinds are"):
        figures.register_figure("_x", "typo", kinds=["trian"])
    assert "_x" not in figures.FIGURES


@pytest.mark.parametrize("figure_id", EXPECTED)
def test_every_figure_page_opens_with_the_thesis_caption_and_claims(figure_id):
    from thesis_repro.book import builder as book

    entry = book.claims()[figures.get(figure_id).notebook_id]  # the book inserts these under the title
    assert entry["caption"] and entry["claims"]
