"""Chapter-3 table statistics (thesis_repro.evaluation.tables) and the table/figure items built on them."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from thesis_repro.core import thesis_numbers
from thesis_repro.evaluation import tables as T

RNG = np.random.default_rng(0)


def samples(env: str, test: str, method: str, values) -> pd.DataFrame:
    v = np.asarray(values, dtype=float).ravel()
    return pd.DataFrame({"env": env, "test": test, "method": method, "value": v})


# ---------------------------------------------------------------- settings read from the thesis data
def test_significance_level_and_n_come_from_the_thesis_settings():
    settings = thesis_numbers.load("chapter3_settings").set_index("parameter")
    assert T.significance_level() == float(settings.loc["welch_p_value", "value"]) == 0.05
    assert T.thesis_n() == int(settings.loc["n_train_seeds", "value"]) * int(settings.loc["n_test_seeds", "value"])
    assert "647" in settings.loc["welch_p_value", "ref"]  # the caption sentence is cited by line


# ---------------------------------------------------------------- mean ± std over seeds × rollouts
def test_mean_std_pools_seeds_and_rollouts_with_ddof_1():
    x = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 9.0]])  # (seeds, rollouts)
    m, s, n = T.mean_std(x)
    assert (m, n) == (4.0, 6)
    assert s == pytest.approx(np.sqrt(((x - 4.0) ** 2).sum() / 5))
    assert T.mean_std([np.nan, 2.0, 4.0])[:2] == (3.0, pytest.approx(np.sqrt(2.0)))
    assert np.isnan(T.mean_std([7.0])[1])
    with pytest.raises(ValueError, match="at least one finite"):
        T.mean_std([np.nan])


def test_cells_groups_samples_per_env_test_method():
    a, b = RNG.normal(10, 2, 12), RNG.normal(5, 1, 8)
    s = pd.concat([samples("Hopper", "obs", "ppo", a), samples("Hopper", "obs", "sac", b)])
    c = T.cells(s).set_index("method")
    assert c.loc["ppo", "mean"] == pytest.approx(a.mean()) and c.loc["ppo", "n"] == 12
    assert c.loc["sac", "std"] == pytest.approx(b.std(ddof=1))
    with pytest.raises(ValueError, match="lacks columns"):
        T.cells(s.drop(columns="test"))


# ---------------------------------------------------------------- Welch's t-test against SciPy
@pytest.mark.parametrize("shift", [0.0, 0.3, 1.0, 3.0])
def test_welch_p_equals_scipy_and_the_from_stats_form(shift):
    a, b = RNG.normal(0, 1, 30), RNG.normal(shift, 2.5, 17)
    p = stats.ttest_ind(a, b, equal_var=False).pvalue
    assert T.welch_p(a, b) == pytest.approx(p, rel=1e-12)
    ma, sa, na = T.mean_std(a)
    mb, sb, nb = T.mean_std(b)
    assert T.welch_p_from_stats(ma, sa, na, mb, sb, nb) == pytest.approx(p, rel=1e-9)


def test_welch_p_on_a_hand_computed_example():
    # a: mean 3, var 2.5, n 5; b: mean 5.25, var 26.75/3, n 4 -> Welch t and Welch-Satterthwaite df
    a, b = [1.0, 2.0, 3.0, 4.0, 5.0], [2.0, 4.0, 6.0, 9.0]
    va, vb = 2.5 / 5, (26.75 / 3) / 4
    t = (3.0 - 5.25) / np.sqrt(va + vb)
    df = (va + vb) ** 2 / (va**2 / 4 + vb**2 / 3)
    assert T.welch_p(a, b) == pytest.approx(2 * stats.t.sf(abs(t), df), rel=1e-12)


def test_welch_p_degenerate_samples():
    assert T.welch_p([1.0, 1.0, 1.0], [1.0, 1.0]) == 1.0
    assert T.welch_p([1.0, 1.0, 1.0], [2.0, 2.0]) == 0.0
    assert np.isnan(T.welch_p([1.0], [2.0, 3.0]))
    assert np.isnan(T.welch_p_from_stats(1.0, float("nan"), 1, 2.0, 1.0, 5))


# ---------------------------------------------------------------- bolding rule
def test_bold_row_is_best_plus_not_significantly_different():
    n = [240, 240, 240, 240]
    m = [1000.0, 990.0, 900.0, np.nan]
    s = [100.0, 100.0, 100.0, 100.0]
    # 990 vs 1000: p ~ 0.27 -> bold; 900 vs 1000: p ~ 1e-25 -> not bold; NaN (not run) never bold
    assert T.bold_row(m, s, n).tolist() == [True, True, False, False]
    p = T.welch_p_from_stats(1000.0, 100.0, 240, 990.0, 100.0, 240)
    assert T.bold_row(m, s, n, alpha=p * 1.01).tolist() == [True, False, False, False]
    assert T.bold_row([np.nan, np.nan], [1.0, 1.0], [5, 5]).tolist() == [False, False]
    with pytest.raises(ValueError, match="1-D of one length"):
        T.bold_row([1.0, 2.0], [1.0], [3, 3])


def test_bold_on_samples_matches_per_pair_scipy_tests():
    draws = {"a": RNG.normal(10, 1, 40), "b": RNG.normal(9.8, 1, 40), "c": RNG.normal(5, 1, 40)}
    s = pd.concat([samples("W", "act", k, v) for k, v in draws.items()])
    b = T.bold(T.cells(s)).set_index("method")["bold"]
    top = max(draws, key=lambda k: draws[k].mean())
    for k, v in draws.items():
        expect = k == top or stats.ttest_ind(draws[top], v, equal_var=False).pvalue >= 0.05
        assert b[k] == expect


def test_thesis_bolding_derived_with_n_240():
    t = T.bold(thesis_numbers.load("table3_4"), n=T.thesis_n())
    row = t[(t.env == "Walker2d") & (t.test == "dom")].set_index("method")["bold"]
    # SAC 2779.8 ± 443.8 best; TRPO 2648.4 ± 417.5: p ~ 9e-4 < 0.05 -> not bold
    assert row.to_dict() == {"ppo": False, "trpo": False, "ddpg": False, "sac": True}
    assert T.welch_p_from_stats(2779.8, 443.8, 240, 2648.4, 417.5, 240) < 0.05
    with pytest.raises(ValueError, match="pass n="):
        T.bold(thesis_numbers.load("table3_4"))


def test_bold_agreement_counts():
    thesis = pd.DataFrame(
        {
            "env": "H",
            "test": ["obs"] * 3 + ["act"] * 3,
            "method": list("xyz") * 2,
            "mean": [3.0, 2.0, 1.0, 1.0, 2.0, 3.0],
            "bold": [True, True, False, False, False, True],
        }
    )
    ours = thesis.assign(mean=[3.0, 1.0, 2.0, 3.0, 2.0, 1.0], bold=[True, False, False, True, False, False])
    a = T.bold_agreement(ours, thesis)
    assert a == {"cells": 6, "same": 3, "bold_both": 1, "bold_thesis": 3, "bold_ours": 2, "rows": 2, "best_same": 1}
    with pytest.raises(ValueError, match="run bold"):
        T.bold_agreement(ours.drop(columns="bold"), thesis)


def test_bold_agreement_with_itself_is_total():
    t = T.bold(thesis_numbers.load("table3_6"), n=T.thesis_n())
    a = T.bold_agreement(t, t)
    assert a["same"] == a["cells"] == 120 and a["best_same"] == a["rows"] == 20


# ---------------------------------------------------------------- normalised AUC change (Figs 3.5, 3.6)
def test_auc_change_relative_to_baseline_and_to_the_row_max():
    t = pd.DataFrame(
        {
            "env": ["A"] * 3 + ["B"] * 3,
            "test": "obs",
            "method": ["ppo", "x", "y"] * 2,
            "mean": [100.0, 120.0, 80.0, 1000.0, 500.0, 2000.0],
        }
    )
    rel = T.auc_change(t, "ppo").set_index(["env", "method"])["change"]
    assert rel.to_dict() == {("A", "x"): 0.2, ("A", "y"): -0.2, ("B", "x"): -0.5, ("B", "y"): 1.0}
    mx = T.auc_change(t, "ppo", how="max").set_index(["env", "method"])["change"]
    assert mx[("A", "x")] == pytest.approx(20 / 120) and mx[("B", "y")] == pytest.approx(1000 / 2000)
    bars = T.mean_change(T.auc_change(t, "ppo")).set_index("method")
    assert bars.loc["x", "change"] == pytest.approx((0.2 - 0.5) / 2) and bars.loc["y", "n_envs"] == 2
    with pytest.raises(ValueError, match="unknown normalisation"):
        T.auc_change(t, "ppo", how="zscore")
    with pytest.raises(ValueError, match="baseline 'sac' is not in the table"):
        T.auc_change(t, "sac")


def test_auc_change_is_scale_free_per_task():
    t = thesis_numbers.load("table3_5")
    scaled = t.assign(mean=np.where(t.env == "InvertedDoublePendulum", t["mean"] * 10, t["mean"]))
    a, b = T.auc_change(t, "ppo"), T.auc_change(scaled, "ppo")
    assert np.allclose(a.change, b.change)


# ================================================================ the chapter-3 items (figures.ch3_tables / ch3_curves)
from thesis_repro import figures
from thesis_repro.claims import report  # noqa: E402
from thesis_repro.core import paths  # noqa: E402
from thesis_repro.figures import ch3_curves as C  # noqa: E402
from thesis_repro.figures import ch3_tables as F  # noqa: E402

ITEMS = ["table-3.3", "table-3.4", "table-3.5", "table-3.6", "table-3.7", "3.4", "3.5", "3.6", "3.7", "3.8"]


def keys(item: str, scale: str, train_only: bool = False, **overrides) -> set[str]:
    jobs = figures.training_jobs(item, scale, **overrides) if train_only else figures.jobs(item, scale, **overrides)
    return {j.key for j in jobs}


def test_every_item_is_registered_with_a_notebook_and_settings_at_every_scale():
    for item in ITEMS:
        fig = figures.get(item)
        assert fig.module in ("thesis_repro.figures.ch3_tables", "thesis_repro.figures.ch3_curves")
        assert paths.notebook(item if item.startswith("table") else item).exists()
        for scale in ("smoke", "small", "full"):
            s = F.checked_settings(item, scale)
            assert set(F.learners(s)) | set(F.skipped(s)) == set(s["algos"])


def test_items_share_runs_with_fig_3_3_and_each_other():
    """A learner on a task is one run for the whole chapter. Compared at one seed count (3): seed s is one run."""

    def at3(item: str, train_only: bool = False) -> set[str]:
        return keys(item, "small", train_only, train_seeds=3)

    # every table-3.6 job (train and evaluate) is one of Fig 3.3's at small; Table 3.4's PPO/TRPO runs too
    assert at3("table-3.6") <= at3("3.3")
    assert at3("table-3.4", train_only=True) <= at3("3.3", train_only=True)
    # Table 3.3's Walker2d evaluations are Table 3.5's; Fig 3.7 is Table 3.4's grid; Fig 3.4 adds heat maps only
    assert at3("table-3.3") <= at3("table-3.5")
    assert at3("3.7") == at3("table-3.4")
    assert at3("3.4", train_only=True) <= at3("table-3.4", train_only=True)
    assert at3("3.8") <= at3("table-3.5") | at3("table-3.6") | at3("table-3.7")


def test_budgets_are_fig_3_3s():
    """Every chapter-3 item trains with Fig 3.3's budgets; at small an item whose fresh seeds are shipped reads
    the confirmatory seed count instead of Fig 3.3's."""
    from thesis_repro.runs.needs import CONFIRMATORY_SEEDS

    for item in ITEMS:
        for scale in ("smoke", "small", "full"):
            s, ref = F.checked_settings(item, scale), figures.settings("3.3", scale)
            for key in ("timesteps", "test_rollouts", "max_episode_steps", "train_overrides"):
                assert s[key] == ref[key], (item, scale, key)
            seeds = (ref["train_seeds"], CONFIRMATORY_SEEDS) if scale == "small" else (ref["train_seeds"],)
            assert s["train_seeds"] in seeds, (item, scale)


def test_settings_errors_name_the_valid_choices():
    with pytest.raises(ValueError, match="skip_algos"):
        F.checked_settings("table-3.4", "small", skip_algos=["td3"])
    with pytest.raises(ValueError, match="unknown factor of Walker2d 'mass'; valid factors of Walker2d are"):
        C.shift_value("Walker2d", "mass", 0.2)
    with pytest.raises(ValueError, match="unknown normalisation"):
        C.bars("3.5", F.thesis_cells(), F.checked_settings("3.5", "small", normalisation="zscore"))
    with pytest.raises(ValueError, match="unknown chapter-3 item 'table-9.9'"):
        F.compare("table-9.9", F.thesis_cells(), F.checked_settings("table-3.4", "small"))


# ---------------------------------------------------------------- the thesis's own numbers as ours
def thesis_as_ours(item: str, s: dict) -> pd.DataFrame:
    t = F.thesis_cells(F.THESIS_TABLES.get(item))
    return t[t.method.isin(s["algos"]) & t.env.isin(F.item_envs(s))]


@pytest.mark.parametrize("item", ["table-3.4", "table-3.5", "table-3.6", "table-3.7"])
def test_the_thesis_numbers_as_ours_agree_with_the_thesis_bolding(item):
    s = F.checked_settings(item, "full")
    a = F.compare(item, thesis_as_ours(item, s), s).agreement
    assert a["rows"] == a["best_same"] == 20 and a["same"] == a["cells"]


def test_unaffordable_learners_keep_the_thesis_numbers():
    s = F.checked_settings("table-3.4", "small", skip_algos=["ddpg", "sac"])  # a scale that could not afford them
    assert F.skipped(s) == ["ddpg", "sac"]
    ours = thesis_as_ours("table-3.4", s)
    ours = ours[ours.method.isin(F.learners(s))]
    comp = F.compare("table-3.4", ours, s)
    text, mask = comp.text()
    assert (text[("sac", "reproduced")] == report.NOT_RUN).all()
    assert text.loc[("Walker2d", "obs"), ("sac", "thesis")] == "1565.4 ± 544.9"
    assert bool(mask.loc[("Walker2d", "obs"), ("sac", "thesis")])  # the thesis's bold survives
    assert "font-weight: bold" in comp.style("t").to_html()
    text = F.describe_budget(s, width=60)
    assert "Not run at this scale (thesis numbers shown): ddpg, sac" in " ".join(text.split())
    assert max(map(len, text.splitlines())) <= 60 < len(text)  # wrapped for the book page


# ---------------------------------------------------------------- running: tidy frames from (fake) job results
def fake_run_jobs(jobs, **_):
    out = []
    for job in jobs:
        cfg = job.config
        if job.kind == "train":
            base = 100.0 * (cfg["seed"] + 1) + len(cfg["algorithm"])
            out.append({"episode_returns": np.arange(5.0) + base, "train_return_episodes": 3})
        else:
            tr, test = cfg["train"], cfg["test"]
            n_points = len(test.get("sigmas", test.get("ratios")))
            base = 1000.0 + 10 * len(tr["algorithm"]) + 100 * tr["seed"]
            r = base - 50.0 * np.arange(n_points)[:, None] + np.arange(test["n_rollouts"])[None, :]
            out.append({"returns": r})
    return out


def test_run_assembles_per_rollout_aucs_cells_and_training_episodes(monkeypatch):
    monkeypatch.setattr(F, "run_jobs", fake_run_jobs)
    s = F.checked_settings("table-3.5", "smoke", train_seeds=2, sigmas=[0.0, 0.2, 0.4], test_rollouts=3)
    res = F.run(s)
    n_envs, n_algos = len(s["envs"]), len(s["algos"])
    assert len(res.aucs) == n_envs * n_algos * 2 * 4 * 3  # envs × learners × seeds × tests × rollouts
    a = res.aucs.query("method == 'ppo' and seed == 1 and test == 'obs' and rollout == 2").value.unique()
    base = 1000.0 + 30 + 100  # len("ppo") = 3, seed 1
    assert a == pytest.approx([0.2 * ((base + 2) + (base - 50 + 2) + (base - 100 + 2))])
    cells = F.our_cells(res).set_index(["env", "test", "method"])
    ppo = res.aucs.query("method == 'ppo' and test == 'act' and env == 'Hopper'").value
    assert cells.loc[("Hopper", "act", "ppo"), "mean"] == pytest.approx(ppo.mean())
    assert cells.loc[("Hopper", "act", "ppo"), "std"] == pytest.approx(ppo.std(ddof=1))
    assert cells.loc[("Hopper", "act", "ppo"), "n"] == 6  # 2 seeds × 3 rollouts
    ep = res.episodes.query("method == 'ppo' and seed == 0 and env == 'Hopper'").value.tolist()
    assert ep == [105.0, 106.0, 107.0]  # the last train_return_episodes episodes


def test_table33_cells_and_its_sigma_grid(monkeypatch):
    monkeypatch.setattr(F, "run_jobs", fake_run_jobs)
    s = F.checked_settings("table-3.3", "smoke", train_seeds=2)
    a, b = F.table33(F.run(s), s)
    assert a.noise_type.tolist() == ["none", "obs", "act", "env", "mdl"]
    assert a.train_sigma.tolist() == [0.0, 0.2, 0.2, 0.2, 0.2]
    row = b[(b.noise_type == "act") & np.isclose(b.sigma_te, 0.2) & (b.train_sigma == 0.2)].iloc[0]
    # ppo-actnoise (12 chars): returns 1120 + 100 seed - 50 (σ index 1) + rollout, seeds {0, 1} × rollouts {0, 1}
    assert row["mean"] == pytest.approx(1120 + 50 - 50 + 0.5) and row["n"] == 4
    texts = F.table33_text((a, b))
    assert texts[1].loc[("obs", 0.0), (0.0, "thesis")] == "3723.9 ± 321.3"
    partial = F.table33_text((a.iloc[:2], b))[0]  # the thesis has no σ_tr = 0.2 cell for "none": stays empty
    assert partial.loc["none", (0.2, "reproduced")] == "" and partial.loc["act", (0.2, "reproduced")] == report.NOT_RUN
    s_bad = F.checked_settings("table-3.3", "smoke", sigmas=[0.0, 0.5])
    with pytest.raises(ValueError, match="lacks"):
        F.table33(F.run(s_bad), s_bad)


# ---------------------------------------------------------------- figure statistics
def test_bars_derived_from_the_thesis_tables_by_hand():
    s = F.checked_settings("3.5", "full")
    b = C.bars("3.5", F.thesis_cells(), s)
    th = thesis_numbers.load("table3_5").pivot_table(index=["env", "test"], columns="method", values="mean")
    obs = th.xs("obs", level="test")
    expect = ((obs["ppo-mdl"] - obs["ppo"]) / obs["ppo"]).mean()
    got = b.query("source == 'thesis' and method == 'ppo-mdl' and test == 'obs'").change.item()
    assert got == pytest.approx(expect)
    b6 = C.bars("3.6", F.thesis_cells(), F.checked_settings("3.6", "full"))
    assert set(b6.query("panel == 'b'").method) == {"ppo-epopt", "ppo-maml-dg", "ppo-reptile-dg"}
    assert set(b6.query("panel == 'b'").baseline) == {"ppo-mdl"}


def test_heat_grid_and_summary():
    s = F.checked_settings("3.4", "small")
    cells = C.heat_cells(s)
    assert len(cells) == len(s["heat_shifts"]) ** 2
    assert {"body_mass": 1.0, "wind": 0.0} in cells
    assert {"body_mass": pytest.approx(0.6), "wind": pytest.approx(0.4 * 9.81)} in cells
    d = np.array(s["heat_shifts"])
    rows = [
        {"method": m, "row_shift": a, "col_shift": c, "return": k * (100 - 50 * abs(a) - 10 * abs(c))}
        for m, k in (("ppo", 1.0), ("trpo", 2.0))
        for a in d
        for c in d
    ]
    summary = C.heat_summary(pd.DataFrame(rows)).set_index("method")
    assert summary.loc["ppo", "drop_row"] == pytest.approx(20.0) and summary.loc["ppo", "drop_col"] == pytest.approx(
        4.0
    )
    assert summary.loc["trpo", "centre"] == 200.0


def test_budget_sentence_names_only_the_items_tasks():
    one = " ".join(F.describe_budget(F.checked_settings("3.4", "small")).split())
    assert "scale small: 2,000,000 env steps per run (thesis: 4,000,000)" in one and "InvertedPendulum" not in one
    assert "InvertedPendulum: 200,000" in " ".join(F.describe_budget(F.checked_settings("table-3.4", "small")).split())
