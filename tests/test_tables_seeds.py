"""Confidence intervals across training seeds: the statistic (thesis_repro.evaluation.tables), checked
by hand against ``scipy.stats.t.interval``, and the chapter-3 tables, bars and curves that show it — the
multi-seed path on synthetic 3-seed frames, the one-seed path (no interval, no crash)."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
import pytest  # noqa: E402
from matplotlib.collections import PolyCollection  # noqa: E402
from scipy import stats  # noqa: E402

from thesis_repro.evaluation import tables as T  # noqa: E402
from thesis_repro.figures import ch3_curves as C  # noqa: E402
from thesis_repro.figures import ch3_tables as F  # noqa: E402
from thesis_repro.figures import plot  # noqa: E402

# 3 seeds × 4 rollouts of one cell; seed means 101.5, 121.5, 96.5 (rollouts 0..3 add 0..3, mean 1.5)
SEED_OFFSETS = {0: 100.0, 1: 120.0, 2: 95.0}


def tiny(offsets=SEED_OFFSETS, method="ppo", env="Hopper", test="obs", rollouts=4) -> pd.DataFrame:
    return pd.DataFrame(
        [
            {"env": env, "test": test, "method": method, "seed": s, "rollout": r, "value": off + r}
            for s, off in offsets.items()
            for r in range(rollouts)
        ]
    )


def by_hand(seed_means: list[float], level: float = 0.95) -> tuple[float, float, float]:
    x = np.asarray(seed_means)
    n = x.size
    sem = x.std(ddof=1) / np.sqrt(n)
    lo, hi = stats.t.interval(level, n - 1, loc=x.mean(), scale=sem)
    q = stats.t.ppf(0.5 + level / 2, n - 1)  # the same interval written out: mean ± t_{n-1} · s / √n
    assert (lo, hi) == pytest.approx((x.mean() - q * sem, x.mean() + q * sem))
    return float(x.mean()), float(lo), float(hi)


# ---------------------------------------------------------------- the statistic
def test_t_interval_equals_scipy_by_hand():
    m, lo, hi, n = T.t_interval([101.5, 121.5, 96.5])
    assert n == 3
    assert (m, lo, hi) == pytest.approx(by_hand([101.5, 121.5, 96.5]))
    assert T.t_interval([1.0, np.nan, 3.0])[3] == 2  # non-finite values dropped
    assert T.t_interval([5.0, 5.0, 5.0]) == (5.0, 5.0, 5.0, 3)  # no spread: a zero-width interval, not NaN
    m1, lo1, hi1, n1 = T.t_interval([812.0])
    assert (m1, n1) == (812.0, 1) and np.isnan(lo1) and np.isnan(hi1)
    assert T.t_errorbar([101.5, 121.5, 96.5]) == pytest.approx(by_hand([101.5, 121.5, 96.5])[1:])
    with pytest.raises(ValueError, match="at least one finite"):
        T.t_interval([np.nan])


def test_seed_ci_averages_rollouts_inside_each_seed_then_intervals_over_seeds():
    s = tiny()
    c = T.seed_ci(s).iloc[0]
    m, lo, hi = by_hand([101.5, 121.5, 96.5])
    assert (c.seed_mean, c.ci_lo, c.ci_hi) == pytest.approx((m, lo, hi)) and c.n_seeds == 3
    # the seed, not the rollout, is the unit: more rollouts per seed (same seed means) give the same interval
    more = T.seed_ci(tiny(rollouts=4).pipe(lambda d: pd.concat([d, d]))).iloc[0]
    assert (more.ci_lo, more.ci_hi, more.n_seeds) == pytest.approx((lo, hi, 3))
    # the thesis-format cell pools seeds × rollouts: same mean, n = 12, and its std is a different number
    cell = T.cells(s).iloc[0]
    assert cell["mean"] == pytest.approx(m) and cell["n"] == 12


def test_seed_ci_one_seed_has_no_interval_and_cells_stay_separate():
    two = pd.concat([tiny({0: 100.0}), tiny(method="trpo")])
    c = T.seed_ci(two).set_index("method")
    assert c.loc["ppo", "n_seeds"] == 1 and c.loc["ppo", "seed_mean"] == 101.5
    assert np.isnan(c.loc["ppo", "ci_lo"]) and np.isnan(c.loc["ppo", "ci_hi"])
    assert c.loc["trpo", "n_seeds"] == 3 and np.isfinite(c.loc["trpo", "ci_lo"])
    assert T.fmt_ci(*c.loc["ppo", ["seed_mean", "ci_lo", "ci_hi", "n_seeds"]]) == "102 (1 seed)"
    with pytest.raises(ValueError, match="lacks columns"):
        T.seed_ci(two.drop(columns="seed"))
    assert T.ci_label(c["n_seeds"]).startswith("95 % CI of the mean across 1-3 training seeds")
    assert T.ci_label([1, 1]) == "1 training seed: no confidence interval"


def two_env_samples() -> pd.DataFrame:
    """ppo (baseline) and x on two tasks, 3 seeds × 2 rollouts; AUCs differ per seed."""
    base = {("A", 0): 100.0, ("A", 1): 110.0, ("A", 2): 90.0, ("B", 0): 50.0, ("B", 1): 40.0, ("B", 2): 60.0}
    x = {("A", 0): 130.0, ("A", 1): 150.0, ("A", 2): 95.0, ("B", 0): 55.0, ("B", 1): 50.0, ("B", 2): 75.0}
    rows = []
    for method, table in (("ppo", base), ("x", x)):
        for (env, seed), v in table.items():
            rows += [{"env": env, "test": "obs", "method": method, "seed": seed, "value": v + d} for d in (-1.0, 1.0)]
    return pd.DataFrame(rows)


@pytest.mark.parametrize("how", ["baseline", "max"])
def test_seed_change_ci_by_hand_and_centred_on_the_pooled_bar(how):
    s = two_env_samples()
    pooled = T.mean_change(T.auc_change(T.cells(s), "ppo", how)).change.item()
    ci = T.seed_change_ci(s, "ppo", how).iloc[0]
    # by hand: normaliser per task from the pooled means, seed s of x against seed s of ppo, mean over tasks
    scale = {"A": 100.0, "B": 50.0} if how == "baseline" else {"A": 125.0, "B": 60.0}
    per_seed = [
        np.mean([(130 - 100) / scale["A"], (55 - 50) / scale["B"]]),
        np.mean([(150 - 110) / scale["A"], (50 - 40) / scale["B"]]),
        np.mean([(95 - 90) / scale["A"], (75 - 60) / scale["B"]]),
    ]
    m, lo, hi = by_hand(per_seed)
    assert (ci.seed_mean, ci.ci_lo, ci.ci_hi, ci.n_seeds) == pytest.approx((m, lo, hi, 3))
    assert ci.seed_mean == pytest.approx(pooled)  # the interval sits on the bar the figure draws
    one = T.seed_change_ci(s[s.seed == 1], "ppo", how).iloc[0]
    scale1 = {"A": 110.0, "B": 40.0} if how == "baseline" else {"A": 150.0, "B": 50.0}  # seed 1's own pooled
    assert one.n_seeds == 1 and np.isnan(one.ci_lo) and np.isnan(one.ci_hi)
    assert one.seed_mean == pytest.approx(np.mean([40 / scale1["A"], 10 / scale1["B"]]))
    with pytest.raises(ValueError, match="baseline 'td3'"):
        T.seed_change(s, "td3")


# ---------------------------------------------------------------- chapter-3 pages on fake job results
def fake_run_jobs(jobs, **_):
    """Deterministic results whose seeds differ irregularly (so intervals have width)."""
    out = []
    for job in jobs:
        cfg = job.config
        if job.kind == "train":
            base = 100.0 * (1 + (cfg["seed"] * 7) % 5) + len(cfg["algorithm"])
            out.append({"episode_returns": np.arange(6.0) + base, "train_return_episodes": 3})
        else:
            tr, test = cfg["train"], cfg["test"]
            n_points = len(test.get("sigmas", test.get("ratios")))
            base = 1000.0 + 10 * len(tr["algorithm"]) + 60 * ((tr["seed"] * 7) % 5)
            r = base - 50.0 * np.arange(n_points)[:, None] + np.arange(test["n_rollouts"])[None, :]
            out.append({"returns": r})
    return out


@pytest.fixture
def fake_jobs(monkeypatch):
    monkeypatch.setattr(F, "run_jobs", fake_run_jobs)


@pytest.mark.parametrize("seeds", [3, 1])
def test_table_pages_show_the_seed_interval_beside_the_thesis_format(fake_jobs, seeds):
    s = F.checked_settings("table-3.4", "smoke", train_seeds=seeds, sigmas=[0.0, 0.2, 0.4], test_rollouts=3)
    res = F.run(s)
    ci = F.our_ci(res)
    comp = F.compare("table-3.4", F.our_cells(res), s, ci=ci)
    env, test = ci[["env", "test"]].iloc[0]
    text, _ = comp.text()
    assert "±" in text.loc[(env, test), ("ppo", "reproduced")] or seeds == 1  # thesis-format cells unchanged
    ct = comp.ci_text()
    assert list(ct.index.names) == ["env", "test"] and list(ct.columns) == F.learners(s)
    assert list(ct.index) == [r for r in text.index if r in set(ct.index)]  # the thesis's row order
    assert set(ct.index.get_level_values("env")) == set(s["envs"])  # only the rows run (smoke: not Walker2d)
    row = ci.query("env == @env and test == @test and method == 'ppo'").iloc[0]
    per_seed = res.aucs.query("env == @env and test == @test and method == 'ppo'").groupby("seed").value.mean()
    html = comp.ci_style("t").to_html()
    if seeds == 3:
        m, lo, hi = by_hand(per_seed.tolist())
        assert (row.seed_mean, row.ci_lo, row.ci_hi) == pytest.approx((m, lo, hi))
        assert ct.loc[(env, test), "ppo"] == f"{m:.0f} [{lo:.0f}, {hi:.0f}] (3)"
        assert "95 % CI of the mean across 3 training seeds" in html
    else:
        assert ct.loc[(env, test), "ppo"] == f"{per_seed.item():.0f} (1 seed)"
        assert "1 training seed: no confidence interval" in html
    assert max(len(c) for c in ct.to_numpy().ravel()) <= 24  # compact cells
    with pytest.raises(ValueError, match="no intervals"):
        F.compare("table-3.4", F.our_cells(res), s).ci_text()


def test_table33_cells_carry_the_seed_interval(fake_jobs):
    s = F.checked_settings("table-3.3", "smoke", train_seeds=3)
    res = F.run(s)
    a, b = F.table33(res, s)
    ep = res.episodes[(res.episodes.method == "ppo") & (res.episodes.env == s["env"])].groupby("seed").value.mean()
    row = a[a.noise_type == "none"].iloc[0]
    assert (row.seed_mean, row.ci_lo, row.ci_hi, row.n_seeds) == pytest.approx((*by_hand(ep.tolist()), 3))
    assert row["n"] == 9  # 3 seeds × 3 episodes pooled in the thesis-format cell
    ca, cb = F.table33_ci_text((a, b))
    assert ca.loc["none", 0.0].endswith("(3)") and ca.loc["none", 0.2] == ""
    assert cb.loc[("obs", 0.0), 0.0].endswith("(3)")
    html = F.ci_text_style(cb, b, "t").to_html()
    assert ">0.2<" in html and "0.200000" not in html and "across 3 training seeds" in html
    one = F.run(F.checked_settings("table-3.3", "smoke", train_seeds=1))
    ca1, _ = F.table33_ci_text(F.table33(one, F.checked_settings("table-3.3", "smoke", train_seeds=1)))
    assert ca1.loc["none", 0.0].endswith("(1 seed)")


@pytest.mark.parametrize("seeds", [3, 1])
def test_bars_carry_the_seed_interval_and_draw_error_bars_only_with_seeds(fake_jobs, seeds):
    s = F.checked_settings("3.5", "smoke", train_seeds=seeds, sigmas=[0.0, 0.2, 0.4], test_rollouts=2)
    res = F.run(s)
    b = C.bars("3.5", F.our_cells(res), s, samples=res.aucs)
    ours, thesis = b[b.source == "reproduced"], b[b.source == "thesis"]
    assert thesis[C.BAR_CI].isna().all().all()
    assert (ours.n_seeds == seeds).all()
    assert ours.ci_lo.notna().all() == (seeds > 1) and ours.ci_lo.isna().all() == (seeds == 1)
    if seeds > 1:  # the interval sits on the bar: its centre is the mean of the per-seed changes
        assert ((ours.ci_lo + ours.ci_hi) / 2).to_numpy() == pytest.approx(ours.change.to_numpy())
    fig = C.plot_bars(b, "Fig 3.5")
    n_errorbars = sum(len(ax.containers) - 2 for ax in fig.axes)  # 2 bar containers per axis, + 1 per errorbar set
    title = fig._suptitle.get_text()
    plt.close(fig)
    if seeds > 1:
        assert n_errorbars == len(fig.axes) and "95 % CI of the mean across 3 training seeds" in title
    else:
        assert n_errorbars == 0 and "no error bars: 1 training seed" in title
    text = C.bars_ci_text(b)
    assert text.to_numpy().ravel()[0].endswith("(3)" if seeds > 1 else "(1 seed)")
    assert C.bars("3.5", F.our_cells(res), s)[C.BAR_CI].isna().all().all()  # without samples: no interval


@pytest.mark.parametrize("seeds", [3, 1])
def test_curves_are_seed_means_with_a_seed_interval_band(fake_jobs, seeds):
    s = F.checked_settings("3.7", "smoke", train_seeds=seeds, sigmas=[0.0, 0.2, 0.4], test_rollouts=2)
    res = F.run(s)
    per_seed = C.curve_seeds(res)
    assert len(per_seed) == len(res.returns) // 2  # one point per seed: the rollouts are averaged inside it
    fig = C.plot_curves(res, s, "Fig 3.7")
    title = fig._suptitle.get_text()
    ax = fig.axes[0]
    bands = [c for c in ax.collections if isinstance(c, PolyCollection) and len(c.get_paths())]
    widths = [np.ptp(p.vertices[:, 1]) for c in bands for p in c.get_paths()]
    plt.close(fig)
    if seeds > 1:
        assert "band: 95 % CI of the mean across 3 training seeds" in title and max(widths) > 0
    else:
        assert "no band: 1 training seed" in title and not any(w > 0 for w in widths)


def test_chapter4_line_plots_default_to_the_seed_band():
    rows = [
        {"panel": "a", "algo": a, "seed": s, "iteration": i, "return": 10.0 * i + s * (2 + k)}
        for k, a in enumerate(["kl_avg", "joint"])
        for s in range(3)
        for i in range(4)
    ]
    d = pd.DataFrame(rows)
    fig, axes = plot.lines_by_panel(d, [{"panel": "a"}], "iteration", [("return", "r")], ["kl_avg", "joint"])
    bands = [c for c in axes[0, 0].collections if isinstance(c, PolyCollection) and len(c.get_paths())]
    assert len(bands) == 2  # a t-interval band per learner (seaborn's default would bootstrap)
    plt.close(fig)
    assert plot.seed_band(d, ["algo", "iteration"]).startswith("band: 95 % CI of the mean across 3 training seeds")
    assert plot.seed_band(d[d.seed == 0], ["algo", "iteration"]) == "no band: 1 training seed"
