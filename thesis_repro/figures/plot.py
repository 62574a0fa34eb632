"""Plotting helpers shared by the figure notebooks (matplotlib / seaborn); no numbers are computed here.

>>> import pandas as pd
>>> heat = pd.DataFrame({"mass": [1.0, 1.0, 2.0, 2.0], "friction": [1.0, 2.0, 1.0, 2.0], "return": [1.0, 2, 3, 4]})
>>> heat_matrix(heat).values.tolist()     # rows: mass (descending), columns: friction
[[3.0, 4.0], [1.0, 2.0]]
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
import seaborn as sns
from matplotlib.transforms import Bbox

from thesis_repro.core import paths
from thesis_repro.evaluation import tables


def save(fig: plt.Figure, scale: str, name: str, dpi: int = 100) -> None:
    """Save ``fig`` as ``build/<scale>/figures/<name>.png`` and print the path."""
    out = paths.figures_dir(scale) / f"{name}.png"
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=dpi)
    print("saved", out)


def panel_grid(n: int, ncols: int = 4, panel: tuple[float, float] = (4.0, 3.6)) -> tuple[plt.Figure, list[plt.Axes]]:
    """A figure of ``n`` panels of size ``panel`` (inches), at most ``ncols`` to a row (a row of seven panels is
    wider than any page); the unused axes of the last row are hidden.

    >>> fig, axes = panel_grid(7)
    >>> len(axes), fig.get_size_inches().tolist()
    (7, [16.0, 7.2])
    >>> plt.close(fig)
    """
    cols = min(n, ncols)
    rows = -(-n // cols)
    fig, grid = plt.subplots(rows, cols, figsize=(panel[0] * cols, panel[1] * rows), squeeze=False)
    flat = list(grid.ravel())
    for ax in flat[n:]:
        ax.set_visible(False)
    return fig, flat[:n]


#: Label offsets tried in turn (points; right/above first), each with its horizontal and vertical alignment.
_LABEL_SPOTS = (
    ((3, 3), "left", "bottom"),
    ((3, -3), "left", "top"),
    ((-3, 3), "right", "bottom"),
    ((-3, -3), "right", "top"),
    ((0, 6), "center", "bottom"),
    ((0, -6), "center", "top"),
    ((3, 12), "left", "bottom"),
    ((3, -12), "left", "top"),
    ((-3, 12), "right", "bottom"),
    ((-3, -12), "right", "top"),
)


def label_points(ax: plt.Axes, xs: Sequence[float], ys: Sequence[float], labels: Sequence[str], **kw: Any) -> list:
    """Label each point next to it, at the first of a few offsets whose text box overlaps no label placed
    before and no other point's marker (the first offset if none is free); kwargs go to ``ax.annotate``.
    Returns the annotations.

    >>> fig, ax = plt.subplots()
    >>> notes = label_points(ax, [1.0, 1.0], [1.0, 1.0], ["ppo-ent", "trpo"])    # the same spot
    >>> a, b = (n.get_window_extent(fig.canvas.get_renderer()) for n in notes)
    >>> bool(a.overlaps(b))
    False
    >>> plt.close(fig)
    """
    kw.setdefault("fontsize", 7)
    fig = ax.figure
    renderer = fig.canvas.get_renderer()
    placed: list[Any] = []
    notes = []
    xy = ax.transData.transform(np.column_stack([np.asarray(xs, float), np.asarray(ys, float)]))
    r = 4 * fig.dpi / 72  # a default scatter marker's radius, in pixels
    markers = [Bbox.from_extents(px - r, py - r, px + r, py + r) for px, py in xy]
    for i, (x, y, text) in enumerate(zip(xs, ys, labels, strict=True)):
        others = placed + markers[:i] + markers[i + 1 :]
        note = None
        for offset, ha, va in _LABEL_SPOTS:
            if note is not None:
                note.remove()
            note = ax.annotate(text, (x, y), xytext=offset, textcoords="offset points", ha=ha, va=va, **kw)
            box = note.get_window_extent(renderer)
            if not any(box.overlaps(b) for b in others):
                break
        else:
            note.remove()
            note = ax.annotate(text, (x, y), xytext=(3, 3), textcoords="offset points", **kw)
            box = note.get_window_extent(renderer)
        placed.append(box)
        notes.append(note)
    return notes


def heat_matrix(heat: pd.DataFrame, value: str = "return") -> pd.DataFrame:
    """Mean ``value`` as a mass (rows, descending) × friction (columns) matrix."""
    return heat.groupby(["mass", "friction"])[value].mean().unstack("friction").sort_index(ascending=False)


def heatmap(ax: plt.Axes, heat: pd.DataFrame, title: str, **kwargs: Any) -> None:
    """A mass × friction heat map of the testing return on ``ax`` (kwargs go to ``sns.heatmap``)."""
    sns.heatmap(heat_matrix(heat), ax=ax, cmap="viridis", **kwargs)
    ax.set(title=title, xlabel="friction ratio", ylabel="mass ratio")
    ax.title.set_fontsize(9)


def seed_band(data: pd.DataFrame, keys: Sequence[str], seed: str = "seed") -> str:
    """What the band of a line plot over per-seed rows is, for its title: the 95 % t-interval across training
    seeds (:func:`~thesis_repro.evaluation.tables.t_errorbar`), or none with one seed per point (``keys``: the
    columns of a point, e.g. panel, algo, x).

    >>> d = pd.DataFrame({"algo": "a", "x": [0, 0, 0], "seed": [0, 1, 2], "return": [1.0, 2, 3]})
    >>> seed_band(d, ["algo", "x"])
    'band: 95 % CI of the mean across 3 training seeds (t-interval over per-seed means)'
    >>> seed_band(d[d.seed == 0], ["algo", "x"])
    'no band: 1 training seed'
    """
    n = data.groupby(list(keys))[seed].nunique()
    return f"band: {tables.ci_label(n)}" if len(n) and n.max() > 1 else "no band: 1 training seed"


def seed_cells(data: pd.DataFrame, keys: Sequence[str], seed: str = "seed") -> str:
    """What each cell of a heat map over per-seed rows is, for its title: the mean across how many training seeds
    (each seed's row already its mean over testing rollouts); ``keys``: the columns of a cell, e.g. panel, algo,
    mass, friction. A range if cells differ.

    >>> d = pd.DataFrame({"algo": "a", "mass": 1.0, "seed": [0, 1, 2], "return": [1.0, 2, 3]})
    >>> seed_cells(d, ["algo", "mass"])
    'cells: mean across 3 training seeds (no interval shown)'
    >>> seed_cells(d[d.seed == 0], ["algo", "mass"])
    'cells: 1 training seed'
    """
    n = data.groupby(list(keys))[seed].nunique()
    if not len(n) or n.max() < 2:
        return "cells: 1 training seed"
    seeds = f"{n.max()}" if n.min() == n.max() else f"{n.min()}-{n.max()}"
    return f"cells: mean across {seeds} training seeds (no interval shown)"


def lines_by_panel(
    data: pd.DataFrame,
    conds: Sequence[Mapping[str, Any]],
    x: str,
    rows: Sequence[tuple[str, str]],
    hue_order: Sequence[str],
    title: Any = None,
    shade_wind: bool = False,
    **kwargs: Any,
) -> tuple[plt.Figure, np.ndarray]:
    """One column per training condition, one row per ``(column, ylabel)`` of ``rows``; lines by algorithm.

    ``title(cond, row_index)`` gives each axis title; ``shade_wind`` shades each condition's training wind
    range; kwargs go to ``sns.lineplot`` (e.g. ``marker="o"``). ``data`` has one row per training seed and
    point, so the band is by default the 95 % t-interval across seeds (``errorbar=tables.t_errorbar``; say so
    in the title with :func:`seed_band`).
    """
    kwargs.setdefault("errorbar", tables.t_errorbar)
    fig, axes = plt.subplots(len(rows), len(conds), figsize=(4 * len(conds), 3.2 * len(rows) + 0.3), squeeze=False)
    for j, cond in enumerate(conds):
        sub = data[data["panel"] == cond["panel"]]
        for i, (y, ylabel) in enumerate(rows):
            ax = axes[i, j]
            sns.lineplot(
                data=sub, x=x, y=y, hue="algo", hue_order=list(hue_order), ax=ax, legend=(i == 0 and j == 0), **kwargs
            )
            if shade_wind:
                ax.axvspan(*cond["wind"], color="grey", alpha=0.15)
            ax.set_title(title(cond, i) if title else "", fontsize=9)
            ax.set_ylabel(ylabel)
    return fig, axes


def ball_in_cup(ax: plt.Axes, rollout: Mapping[str, Any], title: str, cup_radius: float) -> None:
    """Fig 5.3: cup path, string and ball every 0.04 s up to the catch (red: string taut, green: slack)."""
    ee, ball, taut = np.asarray(rollout["ee"]), np.asarray(rollout["ball"]), np.asarray(rollout["taut"])
    m = int(rollout["hit_step"]) if bool(rollout["success"]) else len(ee) - 1
    for k in range(0, m + 1, 2):
        c = "tab:red" if taut[k] else "tab:green"
        ax.plot([ee[k, 0], ball[k, 0]], [ee[k, 1], ball[k, 1]], color=c, lw=0.6, alpha=0.7)
        ax.plot(ball[k, 0], ball[k, 1], "o", color=c, ms=2.5)
    ax.plot(ee[: m + 1, 0], ee[: m + 1, 1], "k-", lw=1.5, label="cup (end-effector) path")
    ax.plot(0, 0, "ks", ms=5, label="start")
    x, y, r = ee[m, 0], ee[m, 1], cup_radius
    ax.plot([x - r, x - r * 0.7, x + r * 0.7, x + r], [y, y - 0.04, y - 0.04, y], "b-", lw=2, label="cup")
    ax.set_aspect("equal")
    ax.set_title(title, fontsize=9)
    ax.set_xlabel("x (m)")


def r_by_budget_lines(
    ax: plt.Axes, cells: pd.DataFrame, summary: pd.DataFrame, thesis: tuple[int, int], title: str = ""
) -> None:
    """r against training budget (:func:`thesis_repro.figures.ch3.budget_correlations` and ``budget_summary``): one
    thin line per (task, test) cell (the thesis's statistic), the pooled r in black, each budget's ``k/n`` runs on
    the axis (one tick per budget) and the thesis's share of negative cells in the title. A cell with no r at any
    budget yet (too few of its runs made) is left out of the lines and the legend."""
    steps = [int(s) for s in summary["steps"]]
    at = {s: i for i, s in enumerate(steps)}
    has_r = {(e, t) for e, t, r in zip(cells["env"], cells["test"], cells["r"], strict=True) if np.isfinite(r)}
    drawn = cells.loc[[(e, t) in has_r for e, t in zip(cells["env"], cells["test"], strict=True)]]
    for (env, test), g in drawn.groupby(["env", "test"], sort=False):
        g = g.sort_values("steps")
        ax.plot([at[s] for s in g["steps"]], g["r"], marker=".", lw=0.8, alpha=0.6, label=f"{env}/{test}")
    ax.plot(range(len(steps)), summary["pooled_r"], "k-o", lw=2, label="pooled r (seed-keyed)")
    ax.axhline(0.0, color="grey", lw=0.8)
    ax.set(xlabel="training budget (env steps)", ylabel="r (testing AUC vs training return)", ylim=(-1.05, 1.05))
    words = [f"{s / 1e6:g}M" if s >= 1_000_000 else f"{s:,}" for s in steps]
    runs = zip(words, summary["runs"], summary["runs_total"], strict=True)
    ax.set_xticks(range(len(steps)), [f"{w}\n{k}/{n} runs" for w, k, n in runs])
    ax.set_xlim(-0.3, len(steps) - 0.7)
    neg = [f"{a}/{b}" if b else "-" for a, b in zip(summary["negative"], summary["cells"], strict=True)]
    ax.set_title(title or f"r < 0 in {', '.join(neg)} cells by budget (thesis: {thesis[0]}/{thesis[1]})", fontsize=10)
    if len(drawn):
        ax.legend(fontsize=7, ncol=2, loc="center left", bbox_to_anchor=(1.0, 0.5))
    else:
        ax.text(0.5, 0.5, "no study run computed yet", ha="center", va="center", transform=ax.transAxes)
