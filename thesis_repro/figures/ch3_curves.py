"""Chapter 3, Figures 3.4-3.8: testing-return curves (3.4 top, 3.7, 3.8), heat maps over domain shifts (3.4
bottom) and normalised-AUC bars (3.5, 3.6), thesis beside reproduced; the claims layer
(:mod:`thesis_repro.claims`) judges the per-seed frames.

The runs, evaluation jobs and cells are those of :mod:`thesis_repro.figures.ch3_tables` (every chapter-3 item
shares them); this module adds the heat-map jobs, the heat-map and bar numbers and the plots.

>>> shift_value("Walker2d", "body_mass", -0.2), round(shift_value("Walker2d", "wind", 0.2), 3)
(0.8, 1.962)
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping
from typing import Any

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
import seaborn as sns

from thesis_repro.core.backends import run_jobs
from thesis_repro.core.cache import Job
from thesis_repro.core.validation import check_choice
from thesis_repro.envs.factors import FACTORS, MIN_RATIO, WIND_SCALE
from thesis_repro.envs.registry import short_name
from thesis_repro.evaluation import tables
from thesis_repro.evaluation.jobs import check_test
from thesis_repro.figures import register_figure
from thesis_repro.figures.ch3_tables import (
    Results,
    benchmarks,
    grid,
    identity,
    item_envs,
    learners,
    skipped,
    thesis_cells,
)


# ---------------------------------------------------------------- job grids (shared with the tables)
def shift_value(env: str, factor: str, shift: float) -> float:
    """Value of ``factor`` at a systematic shift of ``shift`` σ-units: ratio ``max(1 + d, MIN_RATIO)``, or for
    the wind ``d · WIND_SCALE`` m/s² (the units of §3.2.2's sampling, see :mod:`thesis_repro.envs.factors`).

    >>> shift_value("Walker2d", "body_mass", -0.2), round(shift_value("Walker2d", "wind", 0.2), 3)
    (0.8, 1.962)
    """
    task = short_name(env)
    f = FACTORS[task][check_choice(factor, list(FACTORS[task]), f"factor of {task}")]
    return max(1.0 + float(shift), MIN_RATIO) if f.relative else float(shift) * WIND_SCALE


def heat_cells(settings: Mapping[str, Any]) -> list[dict[str, float]]:
    """The heat-map grid of Fig 3.4 (bottom): every (row shift, column shift) of the two ``heat_factors``."""
    f_row, f_col = settings["heat_factors"]
    env = settings["env"]
    shifts = [float(d) for d in settings["heat_shifts"]]
    return [
        {f_row: shift_value(env, f_row, a), f_col: shift_value(env, f_col, b)}
        for a, b in itertools.product(shifts, shifts)
    ]


def heat_jobs(settings: Mapping[str, Any]) -> list[Job]:
    """One evaluation job per training run of Fig 3.4 over the whole heat-map grid (no noise)."""
    test = check_test(
        {
            "perturbation": "none",
            "ratios": heat_cells(settings),
            "n_rollouts": int(settings["test_rollouts"]),
            "max_episode_steps": int(settings["max_episode_steps"]),
        }
    )
    return [Job("evaluate", {"train": j.config, "test": test}) for b in benchmarks(settings) for j in b.train_jobs]


def curve_grid(settings: Mapping[str, Any]) -> list[Job]:
    """Figs 3.5-3.8: the chapter-3 grid of their learners (:func:`thesis_repro.figures.ch3_tables.grid`)."""
    return grid(settings)


def fig34_grid(settings: Mapping[str, Any]) -> list[Job]:
    """Fig 3.4: :func:`grid` plus the heat-map evaluations."""
    return grid(settings) + heat_jobs(settings)


for _id, _title in [
    ("3.5", "Change in normalised testing AUC when training with noise vs PPO"),
    ("3.6", "Change in normalised testing AUC: single-domain variants vs PPO, multi-domain vs PPO-MDL"),
    ("3.7", "Generalisation curves of the four basic learners on all five tasks"),
    ("3.8", "Generalisation curves of the selected learners on all five tasks"),
]:
    register_figure(_id, _title)(curve_grid)
register_figure("3.4", "Walker2d: return vs testing noise and heat maps over domain shifts (basic learners)")(
    fig34_grid
)


def run_heat(settings: Mapping[str, Any], n_jobs: int | None = None) -> pd.DataFrame:
    """Fig 3.4 heat maps: ``env, method, seed, rollout, <row factor>, <col factor>, row_shift, col_shift, return``."""
    jobs = heat_jobs(settings)
    done = run_jobs(jobs, n_jobs=n_jobs, desc="evaluate shifts")
    f_row, f_col = settings["heat_factors"]
    shifts = [float(d) for d in settings["heat_shifts"]]
    pairs = list(itertools.product(shifts, shifts))
    parts = []
    for job, res in zip(jobs, done, strict=True):
        r = np.asarray(res["returns"], dtype=float)  # (cells, rollouts)
        ci, ri = np.indices(r.shape).reshape(2, -1)
        cells = job.config["test"]["ratios"]
        parts.append(
            pd.DataFrame(
                {
                    **identity(job.config["train"]),
                    "rollout": ri,
                    f_row: [cells[c][f_row] for c in ci],
                    f_col: [cells[c][f_col] for c in ci],
                    "row_shift": [pairs[c][0] for c in ci],
                    "col_shift": [pairs[c][1] for c in ci],
                    "return": r.reshape(-1),
                }
            )
        )
    return pd.concat(parts, ignore_index=True)


def heat_seeds(heat: pd.DataFrame) -> pd.DataFrame:
    """Per-seed heat-map cells for the claims layer: ``method, seed, row_shift, col_shift, return`` (mean over
    testing rollouts inside the seed)."""
    by = ["method", "seed", "row_shift", "col_shift"]
    return heat.groupby(by, as_index=False, sort=False)["return"].mean()


# ---------------------------------------------------------------- Fig 3.4: heat-map summary
def heat_summary(heat: pd.DataFrame) -> pd.DataFrame:
    """Per learner: mean return at the training domain (centre) and drops along each factor's axis.

    ``drop_row`` / ``drop_col``: centre minus the mean return at the largest shifts (both signs) of the row /
    column factor with the other at 0; ``drop_ring``: centre minus the mean over the outermost ring.
    """
    rows = []
    for method, h in heat.groupby("method", sort=False):
        m = h.groupby(["row_shift", "col_shift"])["return"].mean()
        d = max(abs(h["row_shift"]).max(), abs(h["col_shift"]).max())
        centre = m.get((0.0, 0.0), np.nan)
        axis_row = m[[(x, 0.0) for x in (-d, d) if (x, 0.0) in m.index]].mean()
        axis_col = m[[(0.0, y) for y in (-d, d) if (0.0, y) in m.index]].mean()
        ring = m[[i for i in m.index if max(abs(i[0]), abs(i[1])) == d]].mean()
        rows.append(
            {
                "method": method,
                "centre": centre,
                "drop_row": centre - axis_row,
                "drop_col": centre - axis_col,
                "drop_ring": centre - ring,
            }
        )
    return pd.DataFrame(rows)


def heat_summary_ci(heat: pd.DataFrame) -> pd.DataFrame:
    """:func:`heat_summary` across training seeds: per learner each column's mean over seeds of the per-seed
    summary, with its 95 % t-interval (``"mean [lo, hi] (n)"``, ``"mean (1 seed)"``; the seed is the unit).

    >>> h = pd.DataFrame({"method": "ppo", "seed": [0, 0, 1, 1], "row_shift": [0.0, 0.4] * 2, "col_shift": 0.0,
    ...                   "return": [1000.0, 600.0, 900.0, 300.0]})
    >>> heat_summary_ci(h)[["method", "centre", "drop_row"]].values.tolist()
    [['ppo', '950 [315, 1585] (2)', '500 [-771, 1771] (2)']]
    """
    per_seed = [heat_summary(h).assign(seed=seed) for seed, h in heat.groupby("seed", sort=True)]
    frame = pd.concat(per_seed, ignore_index=True)
    cols = [c for c in frame.columns if c not in ("method", "seed")]

    def cell(v: pd.Series) -> str:  # "" where no seed has the value (e.g. a grid without that axis)
        return tables.fmt_ci(*tables.t_interval(v)) if np.isfinite(v.to_numpy(float)).any() else ""

    rows = [{"method": m, **{c: cell(g[c]) for c in cols}} for m, g in frame.groupby("method", sort=False)]
    return pd.DataFrame(rows, columns=["method", *cols])


def heat_summary_labels(settings: Mapping[str, Any]) -> dict[str, str]:
    """Display names of the :func:`heat_summary` columns: the drops name the heat maps' row and column factors
    (``settings["heat_factors"]``) and the largest shift of the grid (σ units, as the heat maps' axes).

    >>> heat_summary_labels({"heat_factors": ["body_mass", "wind"], "heat_shifts": [-0.4, 0.0, 0.4]})["drop_row"]
    'drop at body_mass ±0.4'
    """
    f_row, f_col = settings["heat_factors"]
    d = f"{max(abs(float(x)) for x in settings['heat_shifts']):g}"
    return {
        "method": "learner",
        "centre": "centre (training domain)",
        "drop_row": f"drop at {f_row} ±{d}",
        "drop_col": f"drop at {f_col} ±{d}",
        "drop_ring": "drop over the outer ring",
    }


def heat_summary_style(summary: pd.DataFrame, settings: Mapping[str, Any], caption: str = "") -> Any:
    """:func:`heat_summary` or :func:`heat_summary_ci` for display: a ``Styler`` with the columns of
    :func:`heat_summary_labels`, no row numbers, returns to 1 decimal and ``caption``.

    >>> s = {"heat_factors": ["body_mass", "wind"], "heat_shifts": [-0.4, 0.0, 0.4]}
    >>> t = pd.DataFrame({"method": ["ppo"], "centre": [1512.84], "drop_row": [705.6], "drop_col": [1411.4],
    ...                   "drop_ring": [1319.7]})
    >>> html = heat_summary_style(t, s, "Heat maps").to_html()
    >>> all(x in html for x in (">drop at wind ±0.4<", ">1512.8<", "Heat maps")), "1512.840000" in html
    (True, False)
    """
    table = summary.rename(columns=heat_summary_labels(settings))
    return table.style.hide(axis="index").format(precision=1).set_caption(caption)


# ---------------------------------------------------------------- Figs 3.5, 3.6: normalised AUC change
#: Panels of the bar figures: (panel, baseline, thesis table whose columns are compared with the baseline).
BAR_PANELS: dict[str, list[tuple[str, str, str]]] = {
    "3.5": [("", "ppo", "table3_5")],
    "3.6": [("a", "ppo", "table3_6"), ("b", "ppo-mdl", "table3_7")],
}


#: Interval columns of the reproduced bars (NaN for the thesis's bars: it gives no per-seed numbers).
BAR_CI = ["ci_lo", "ci_hi", "n_seeds"]


def thesis_label(item: str) -> str:
    """How the page labels the thesis's bars of Fig ``item``: the kit derives them from the thesis's tables with its
    own normalisation (the thesis prints no bar values).

    >>> thesis_label("3.5"), thesis_label("3.6")
    ('thesis (derived from Table 3.5)', 'thesis (derived from Tables 3.6-3.7)')
    """
    names = [name.removeprefix("table").replace("_", ".") for _, _, name in BAR_PANELS[item]]
    if len(names) == 1:
        return f"thesis (derived from Table {names[0]})"
    return f"thesis (derived from Tables {names[0]}-{names[-1]})"


def bars_text(b: pd.DataFrame, item: str) -> pd.DataFrame:
    """The bars of :func:`bars` as a table for the page: rows panel × method, columns source × test (the thesis's
    bars labelled by :func:`thesis_label`, over its tests: the long label spans them), changes to 3 decimals."""
    labels = {"thesis": thesis_label(item), "reproduced": "reproduced"}
    return (
        b.assign(source=b["source"].map(labels))
        .pivot_table(index=["panel", "method"], columns=["source", "test"], values="change", sort=False)
        .round(3)
    )


def bars(
    item: str, ours: pd.DataFrame, settings: Mapping[str, Any], samples: pd.DataFrame | None = None
) -> pd.DataFrame:
    """Bars of Fig 3.5/3.6: change in normalised AUC vs the panel's baseline, mean over the tasks run, for the
    thesis (from its tables) and reproduced: ``panel, baseline, test, method, change, n_envs, source`` and
    :data:`BAR_CI`.

    With ``samples`` (the per-rollout ``aucs`` of :class:`~thesis_repro.figures.ch3_tables.Results`), the
    reproduced bars carry the 95 % CI across training seeds of the per-seed change
    (:func:`~thesis_repro.evaluation.tables.seed_change_ci`; NaN bounds with one seed); without, NaN.
    """
    how = check_choice(settings["normalisation"], tables.NORMALISATIONS, "normalisation")
    envs = item_envs(settings)
    parts = []
    for panel, base, name in BAR_PANELS[item]:
        thesis = thesis_cells(name)
        methods = [m for m in dict.fromkeys(thesis["method"]) if m != "ppo" or base == "ppo"]
        for source, cells in (("thesis", thesis[thesis["env"].isin(envs)]), ("reproduced", ours)):
            sub = cells[cells["method"].isin(methods)]
            if base not in set(sub["method"]):
                continue
            b = tables.mean_change(tables.auc_change(sub, base, how))
            if source == "reproduced" and samples is not None and len(samples):
                s = samples[samples["method"].isin(methods) & samples["env"].isin(envs)]
                ci = tables.seed_change_ci(s, base, how)[["test", "method", *BAR_CI]]
                b = b.merge(ci, on=["test", "method"], how="left")
            parts.append(b.assign(panel=panel, baseline=base, source=source))
    cols = ["panel", "baseline", "test", "method", "change", "n_envs", "source", *BAR_CI]
    if not parts:
        return pd.DataFrame(columns=cols)
    out = pd.concat(parts, ignore_index=True)
    for c in BAR_CI:
        if c not in out.columns:
            out[c] = np.nan
    return out[cols]


#: The column of :func:`bars_ci_text`.
BAR_CI_COLUMN = "reproduced change [95 % CI] (seeds)"


def bars_ci_text(b: pd.DataFrame) -> pd.DataFrame:
    """The reproduced bars with their interval, ``"change [lo, hi] (n seeds)"``: one row per panel, method and
    test, one column (a small table for the page: an interval per cell needs more width than a column per test
    leaves at a laptop's width)."""
    r = b[b["source"] == "reproduced"]
    cells = [tables.fmt_ci(*x, digits=3) for x in r[["change", *BAR_CI]].itertuples(index=False)]
    return r.assign(**{BAR_CI_COLUMN: cells}).set_index(["panel", "method", "test"])[[BAR_CI_COLUMN]]


def bar_note(b: pd.DataFrame) -> str:
    """What the error bars of :func:`plot_bars` are (from the bars' ``n_seeds``)."""
    n = b.loc[b["source"] == "reproduced", "n_seeds"].dropna()
    if n.empty or n.max() < 2:
        return "no error bars: 1 training seed at this scale (thesis bars: no per-seed numbers)"
    return f"error bars (reproduced): {tables.ci_label(n)}"


# ---------------------------------------------------------------- plots
def curve_seeds(res: Results) -> pd.DataFrame:
    """Per training seed the mean testing return over its rollouts: ``env, method, test, sigma, seed, return``
    (the points behind each line of :func:`plot_curves`)."""
    by = ["env", "method", "test", "sigma"]
    return tables.seed_means(res.returns, "return", by)


def plot_curves(res: Results, settings: Mapping[str, Any], title: str) -> plt.Figure:
    """Testing return vs σ: rows tasks, columns tests, lines learners. A line is the mean over training seeds of
    each seed's mean over its testing rollouts; the band the 95 % t-interval of that mean across seeds
    (:func:`~thesis_repro.evaluation.tables.t_errorbar`; none with one seed), as the title says."""
    envs, tests = item_envs(settings), list(settings["tests"])
    fig, axes = plt.subplots(len(envs), len(tests), figsize=(3.3 * len(tests), 2.6 * len(envs) + 0.8), squeeze=False)
    order = learners(settings)
    per_seed = curve_seeds(res)
    n_seeds = per_seed.groupby(["env", "method", "test", "sigma"])["seed"].nunique()
    for i, env in enumerate(envs):
        for j, test in enumerate(tests):
            ax = axes[i, j]
            d = per_seed[(per_seed["env"] == env) & (per_seed["test"] == test)]
            sns.lineplot(
                d,
                x="sigma",
                y="return",
                hue="method",
                hue_order=order,
                errorbar=tables.t_errorbar,
                marker="o",
                ax=ax,
                legend=(i == 0 and j == 0),
            )
            ax.set_title(f"{env} — {test}", fontsize=9)
            ax.set(xlabel="σ (Σ for dom)" if i == len(envs) - 1 else "", ylabel="testing return" if j == 0 else "")
    miss = skipped(settings)
    tail = f" (not run at this scale: {', '.join(miss)})" if miss else ""
    band = f"band: {tables.ci_label(n_seeds)}" if n_seeds.max() > 1 else "no band: 1 training seed"
    fig.suptitle(
        f"{title} — reproduced, scale={settings['scale']}{tail}\nline: mean over training seeds; {band}", fontsize=10
    )
    fig.tight_layout()
    return fig


def plot_heat(heat: pd.DataFrame, settings: Mapping[str, Any]) -> plt.Figure:
    """Fig 3.4 (bottom): mean return over the shift grid per learner, training domain at (0, 0)."""
    f_row, f_col = settings["heat_factors"]
    order = [m for m in learners(settings) if m in set(heat["method"])]
    fig, axes = plt.subplots(1, len(order), figsize=(3.4 * len(order), 3.0), squeeze=False)
    vmin, vmax = heat.groupby(["method", "row_shift", "col_shift"])["return"].mean().agg(["min", "max"])
    for ax, m in zip(axes[0], order, strict=True):
        mat = heat[heat["method"] == m].groupby(["row_shift", "col_shift"])["return"].mean().unstack("col_shift")
        sns.heatmap(
            mat.sort_index(ascending=False),
            ax=ax,
            cmap="viridis",
            vmin=vmin,
            vmax=vmax,
            annot=True,
            fmt=".0f",
            annot_kws={"fontsize": 6},
            cbar=ax is axes[0, -1],
        )
        ax.set(title=f"{m} (reproduced)", xlabel=f"{f_col} shift (σ units)", ylabel=f"{f_row} shift (σ units)")
    fig.suptitle(f"Fig 3.4 (bottom) — {settings['env']}, scale={settings['scale']}", fontsize=10)
    fig.tight_layout()
    return fig


def plot_bars(b: pd.DataFrame, title: str, item: str | None = None) -> plt.Figure:
    """Bars of Figs 3.5/3.6: one column per panel × test, thesis beside reproduced per learner; error bars on the
    reproduced bars: their 95 % CI across training seeds (:data:`BAR_CI`; none with one seed), as the title says.
    With ``item`` the legend labels the thesis's bars by :func:`thesis_label`."""
    keys = list(b[["panel", "test"]].drop_duplicates().itertuples(index=False, name=None))
    fig, axes = plt.subplots(1, len(keys), figsize=(2.9 * len(keys), 3.6), squeeze=False, sharey=True)
    sources, width = ["thesis", "reproduced"], 0.4
    colours = dict(zip(sources, sns.color_palette(n_colors=2), strict=True))
    for ax, (panel, test) in zip(axes[0], keys, strict=True):
        d = b[(b["panel"] == panel) & (b["test"] == test)]
        methods = list(dict.fromkeys(d["method"]))
        x = np.arange(len(methods))
        for k, source in enumerate(sources):
            r = d[d["source"] == source].set_index("method").reindex(methods)
            pos = x + (k - 0.5) * width
            label = thesis_label(item) if source == "thesis" and item else source
            ax.bar(pos, r["change"], width, color=colours[source], label=label)
            ok = np.isfinite(r["ci_lo"].astype(float)) & np.isfinite(r["ci_hi"].astype(float))
            if ok.any():  # the interval as computed (its centre, the mean of the per-seed changes, is the bar)
                lo, hi = r["ci_lo"][ok].to_numpy(float), r["ci_hi"][ok].to_numpy(float)
                mid, half = (lo + hi) / 2, (hi - lo) / 2
                ax.errorbar(pos[ok.to_numpy()], mid, yerr=half, fmt="none", ecolor="k", elinewidth=1, capsize=2)
        ax.set_xticks(x, methods)
        if ax is axes[0, -1]:
            ax.legend(fontsize=7)
        ax.axhline(0, color="k", lw=0.8)
        base = d["baseline"].iloc[0] if len(d) else ""
        ax.set_title(f"({panel}) {test} vs {base}" if panel else f"{test} vs {base}", fontsize=9)
        ax.set(xlabel="", ylabel="change in normalised AUC")
        ax.tick_params(axis="x", rotation=60, labelsize=7)
    fig.suptitle(f"{title}\n{bar_note(b)}", fontsize=10)
    fig.tight_layout()
    return fig
