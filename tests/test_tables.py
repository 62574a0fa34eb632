"""Chapter-3 table statistics (thesis_repro.evaluation.tables) and the table/figure items built on them."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from thesis_repro import reference
from thesis_repro.evaluation import tables as T

RNG = np.random.default_rng(0)


def samples(env: str, test: str, method: str, values) -> pd.DataFrame:
    v = np.asarray(values, dtype=float).ravel()
    return pd.DataFrame({"env": env, "test": test, "method": method, "value": v})


# ---------------------------------------------------------------- settings read from the thesis data
def test_significance_level_and_n_come_from_the_thesis_settings():
    settings = reference.load("chapter3_settings").set_index("parameter")
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
    t = T.bold(reference.load("table3_4"), n=T.thesis_n())
    row = t[(t.env == "Walker2d") & (t.test == "dom")].set_index("method")["bold"]
    # SAC 2779.8 ± 443.8 best; TRPO 2648.4 ± 417.5: p ~ 9e-4 < 0.05 -> not bold
    assert row.to_dict() == {"ppo": False, "trpo": False, "ddpg": False, "sac": True}
    assert T.welch_p_from_stats(2779.8, 443.8, 240, 2648.4, 417.5, 240) < 0.05
    with pytest.raises(ValueError, match="pass n="):
        T.bold(reference.load("table3_4"))


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
    t = T.bold(reference.load("table3_6"), n=T.thesis_n())
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
    t = reference.load("table3_5")
    scaled = t.assign(mean=np.where(t.env == "InvertedDoublePendulum", t["mean"] * 10, t["mean"]))
    a, b = T.auc_change(t, "ppo"), T.auc_change(scaled, "ppo")
    assert np.allclose(a.change, b.change)
