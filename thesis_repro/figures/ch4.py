"""Chapter 4, Figures 4.1-4.7 (kl_avg, kl_exact vs params_avg, joint): job grids and tidy frames.

Every figure trains the thesis's kl_avg (Eq 4.11) and our kl_exact (the exact Eq 4.7 minimiser)
beside the baselines params_avg and joint; the claims layer (:mod:`thesis_repro.claims`) judges each claim
for each of the two aggregates, against params_avg and joint only.

Training runs are ``train`` jobs of :func:`thesis_repro.learners.train_config` built by :func:`run_config`
from a figure's settings; the config depends only on the run's identity (algorithm, condition, seed) and the
budget keys of the settings, so figures with the same settings (4.1, 4.3, 4.5, 4.6) share one cached run.
Evaluations are cached jobs too: wind sweeps, mass × friction grids and observation/action-noise sweeps of
the deterministic (mean-action) policy under testing seeds.

>>> conditions("4.1")[0]
{'panel': 'a', 'c_a': 0.001, 'wind': [-0.5, 0.5]}
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable, Mapping, Sequence
from collections.abc import Set as AbstractSet
from typing import Any

import numpy as np
import pandas as pd

from thesis_repro.core import thesis_numbers
from thesis_repro.core.backends import run_jobs
from thesis_repro.core.cache import Job
from thesis_repro.core.validation import check_choice
from thesis_repro.envs import make_env
from thesis_repro.evaluation import tables
from thesis_repro.evaluation.metrics import auc
from thesis_repro.figures import register_figure
from thesis_repro.learners import iteration_steps, load_policy, train_config

EVAL_KINDS: tuple[str, ...] = ("wind", "shift", "obs", "act")


def thesis_name(algo: str) -> str:
    """A learner as the thesis spells it (figures, tables and the claims' frames; configs use the ids): the id with
    underscores, so the readings of Eq 4.11 (``kl-avg-trpo`` -> ``kl_avg_trpo``) follow ``kl-avg`` -> ``kl_avg``.

    >>> thesis_name("params-avg"), thesis_name("joint")
    ('params_avg', 'joint')
    """
    return algo.replace("-", "_")


#: The thesis's method (the claims of chapter 4 are about it), as figures name it.
OURS = "kl_avg"


# ---------------------------------------------------------------- conditions, configs, runs
def conditions(figure: str, panels: Sequence[str] | None = None) -> list[dict[str, Any]]:
    """Training conditions (panel, c_a, wind range) of a chapter-4 figure, from the thesis table.

    ``panels`` keeps only those panels (ignored for single-panel figures); ``None`` keeps all.
    """
    rows = thesis_numbers.load("chapter4_conditions")
    rows = rows[rows["figure"] == figure]
    if rows.empty:
        raise ValueError(f"no chapter-4 conditions for figure {figure!r}")
    if panels is not None and len(rows) > 1:
        for p in panels:
            check_choice(p, list(rows["panel"]), f"panel of figure {figure}")
        rows = rows[rows["panel"].isin(list(panels))]
    return [
        {"panel": r.panel, "c_a": float(r.action_penalty), "wind": [float(r.wind_low), float(r.wind_high)]}
        for r in rows.itertuples()
    ]


def panel_title(cond: Mapping[str, Any]) -> str:
    """Panel title such as ``"c_a=0.001, ξ~U(-0.5,0.5)"``."""
    return f"c_a={cond['c_a']:g}, ξ~U({cond['wind'][0]:g},{cond['wind'][1]:g})"


def run_config(
    settings: Mapping[str, Any], algo: str, cond: Mapping[str, Any], seed: int, **overrides: Any
) -> dict[str, Any]:
    """The training config of one run; depends only on the run's identity and the budget keys of ``settings``
    (``overrides``: further settings of :func:`~thesis_repro.learners.train_config`, e.g. a pilot's ``stop_at``)."""
    # one env per domain: n_envs = N domains, n_steps = T steps per domain (learners.multidomain)
    extra = {k: settings[s] for k, s in (("n_envs", "n_domains"), ("n_steps", "steps_per_domain")) if s in settings}
    return train_config(
        algo,
        settings["env"],
        seed,
        int(settings["timesteps"]),
        c_a=cond["c_a"],
        wind=list(cond["wind"]),
        max_episode_steps=settings["max_episode_steps"],
        protocol=settings["protocol"],
        **extra,
        **overrides,
    )


def algo_names(settings: Mapping[str, Any]) -> list[str]:
    """The thesis's names of the figure's learners, in the settings' order (hue order of the plots).

    >>> algo_names({"algos": ["kl-avg", "params-avg", "joint", "kl-avg-trpo"]})
    ['kl_avg', 'params_avg', 'joint', 'kl_avg_trpo']
    """
    return [thesis_name(a) for a in settings["algos"]]


def runs(settings: Mapping[str, Any]) -> pd.DataFrame:
    """One row per (condition, algo, seed) of a figure: ``algo`` (thesis name), ``panel``, ``condition``,
    ``seed``, ``config``."""
    rows = []
    for cond in conditions(settings["figure"], settings["panels"]):
        for algo in settings["algos"]:
            for seed in range(int(settings["train_seeds"])):
                rows.append(
                    {
                        "algo": thesis_name(algo),
                        "panel": cond["panel"],
                        "condition": panel_title(cond),
                        "seed": seed,
                        "config": run_config(settings, algo, cond, seed),
                    }
                )
    return pd.DataFrame(rows)


def train_runs(settings: Mapping[str, Any], n_jobs: int | None = None) -> pd.DataFrame:
    """Train (or load) every run of :func:`runs`; adds the cached ``result`` column."""
    table = runs(settings)
    table["result"] = run_jobs([Job("train", c) for c in table["config"]], n_jobs=n_jobs, desc="ch4 training")
    return table


def curves_frame(runs: pd.DataFrame) -> pd.DataFrame:
    """Long frame of training curves: one row per (run, iteration) with return, length, entropy, mean KL."""
    parts = []
    for row in runs.itertuples():
        r = row.result
        n = len(r["curve_timesteps"])
        kl = np.asarray(r["curve_kl"], dtype=float) if "curve_kl" in r else np.full((n, 1), np.nan)
        parts.append(
            pd.DataFrame(
                {
                    "algo": row.algo,
                    "panel": row.panel,
                    "condition": row.condition,
                    "seed": row.seed,
                    "iteration": np.asarray(r["curve_timesteps"]) // iteration_steps(row.config),
                    "timesteps": r["curve_timesteps"],
                    "return": r["curve_return"],
                    "length": r["curve_length"],
                    "entropy": r["curve_entropy"],
                    "kl_to_aggregate": np.nanmean(kl, axis=1) if np.isfinite(kl).any() else np.full(len(kl), np.nan),
                }
            )
        )
    return pd.concat(parts, ignore_index=True)


# ---------------------------------------------------------------- evaluations
def mass_friction_grid(settings: Mapping[str, Any]) -> list[dict[str, float]]:
    """The ``{"body_mass": m, "friction": f}`` ratio settings of a heat map (mass × friction of the settings)."""
    return [
        {"body_mass": float(m), "friction": float(f)}
        for m, f in itertools.product(settings["mass_ratios"], settings["friction_ratios"])
    ]


def eval_jobs(runs: pd.DataFrame, kind: str, values: Iterable[Any], n_rollouts: int, seed: int = 0) -> list[Job]:
    """One evaluation job per run of ``runs`` under ``kind`` (wind | shift | obs | act) over ``values``."""
    check_choice(kind, EVAL_KINDS, "evaluation kind")
    values = list(values)
    if kind in ("obs", "act"):
        points: dict[str, Any] = {"perturbation": kind, "sigmas": [float(v) for v in values]}
    else:  # fixed wind ξ per point, or mass × friction ratios (no wind)
        points = {"perturbation": "none", "ratios": [{"wind": float(v)} if kind == "wind" else dict(v) for v in values]}
    return [
        Job(
            "evaluate",
            {
                "train": row.config,
                "test": {
                    **points,
                    "n_rollouts": int(n_rollouts),
                    "seed": int(seed),
                    "max_episode_steps": int(row.config["max_episode_steps"] or 1000),
                    "c_a": row.config["c_a"],
                },
            },
        )
        for row in runs.itertuples()
    ]


def evaluate_runs(
    runs: pd.DataFrame, kind: str, values: Iterable[Any], n_rollouts: int, seed: int = 0, n_jobs: int | None = None
) -> pd.DataFrame:
    """Evaluate every run of ``runs`` under ``kind``; long frame with one row per (run, value) (mean return)."""
    values = list(values)
    results = run_jobs(eval_jobs(runs, kind, values, n_rollouts, seed), n_jobs=n_jobs, desc=f"ch4 eval {kind}")
    rows = []
    for row, res in zip(runs.itertuples(), results, strict=True):
        for v, ret in zip(values, np.asarray(res["returns"]), strict=True):
            item = {
                "algo": row.algo,
                "panel": row.panel,
                "condition": row.condition,
                "seed": row.seed,
                "return": float(np.mean(ret)),
            }
            if kind == "shift":
                item.update(mass=float(v["body_mass"]), friction=float(v["friction"]))
            else:
                item["value"] = float(v)
            rows.append(item)
    return pd.DataFrame(rows)


# ---------------------------------------------------------------- job grids of the figures
def _values(kind: str, settings: Mapping[str, Any]) -> list[Any]:
    """The evaluation grid of ``kind`` from a figure's settings (``wind0``: wind off, Fig 4.2)."""
    if kind == "shift":
        return mass_friction_grid(settings)
    return {"wind": settings["winds"], "wind0": [0.0], "obs": settings["sigmas"], "act": settings["sigmas"]}[kind]


def _grid(*evals: str) -> Any:
    """Job grid: every training job, then for each kind of ``evals`` one evaluation job per run."""

    def grid(settings: Mapping[str, Any]) -> list[Job]:
        table = runs(settings)
        jobs = [Job("train", c) for c in table["config"]]
        for kind in evals:
            jobs += eval_jobs(table, kind.removesuffix("0"), _values(kind, settings), settings["test_rollouts"])
        return jobs

    return grid


_TRAIN = ("train",)
_BOTH = ("train", "evaluate")
register_figure("4.1", "Training curves of kl_avg, kl_exact, params_avg and joint under four conditions", _TRAIN)(
    _grid()
)
register_figure("4.2", "Key frames of a walking cycle, kl_avg and kl_exact vs params_avg", _BOTH)(_grid("wind0"))
register_figure("4.3", "Walker2d testing return vs wind speed", _BOTH)(_grid("wind"))
register_figure("4.4", "Hopper: testing return vs wind; mass × friction heat maps", _BOTH)(_grid("wind", "shift"))
register_figure("4.5", "Walker2d testing return over mass × friction", _BOTH)(_grid("shift"))
register_figure("4.6", "Testing return vs observation- and action-noise scale", _BOTH)(_grid("obs", "act"))
register_figure("4.7", "Policy entropy during training", _TRAIN)(_grid())


# ---------------------------------------------------------------- tables of the figures
def best_per_group(frame: pd.DataFrame, value: str, by: Sequence[str] = ("panel",), ours: str = OURS) -> pd.DataFrame:
    """Mean of ``value`` per (by..., algo), the best algorithm of each group and whether it is ``ours``.

    The algorithm columns are the frame's ``algo`` values; ``best`` and ``<ours>_best`` are added.
    """
    table = frame.groupby([*by, "algo"])[value].mean().unstack("algo")
    table.columns.name = None
    algos = list(table.columns)
    table["best"] = table[algos].idxmax(axis=1)
    table[f"{ours}_best"] = table["best"] == ours
    return table


def seed_table(
    frame: pd.DataFrame,
    value: str,
    by: Sequence[str] = ("panel",),
    seed: str = "seed",
    level: float = tables.CI_LEVEL,
) -> pd.DataFrame:
    """Per (by..., algo): the mean of ``value`` across training seeds and its ``level`` t-interval half-width.

    Each seed's rows (rollouts, grid cells, iterations) are averaged first, so the training seed is the unit
    of replication (:func:`~thesis_repro.evaluation.tables.seed_ci`); rows with a NaN ``value`` are ignored.
    Columns ``by + (algo, mean, half_width, n_seeds)``; one seed: ``half_width`` NaN (no interval).

    >>> f = pd.DataFrame({"panel": "a", "algo": "kl_avg", "seed": [0, 0, 1, 1, 2, 2],
    ...                   "return": [690.0, 710.0, 780.0, 820.0, 900.0, 900.0]})   # seed means 700, 800, 900
    >>> seed_table(f, "return").round(1).values.tolist()     # t(0.975, 2) * 100 / sqrt(3) = 248.4
    [['a', 'kl_avg', 800.0, 248.4, 3]]
    """
    keys = [*by, "algo"]
    ci = tables.seed_ci(frame.dropna(subset=[value]), value, keys, seed, level)
    half = (ci["ci_hi"] - ci["ci_lo"]) / 2
    return ci.assign(mean=ci["seed_mean"], half_width=half)[[*keys, "mean", "half_width", "n_seeds"]]


def compare_ci(
    frame: pd.DataFrame,
    value: str,
    by: Sequence[str] = ("panel",),
    seed: str = "seed",
    level: float = tables.CI_LEVEL,
    algos: Sequence[str] | None = None,
) -> pd.DataFrame:
    """:func:`best_per_group` across training seeds, for display: per (by..., algo) ``"mean ± half-width"`` of the
    ``level`` t-interval over per-seed means (:func:`seed_table`), and the ``best`` algorithm by that mean.

    Rows (``by``) keep their order of first appearance, algorithm columns too unless ``algos`` orders them
    (e.g. :func:`algo_names`; algorithms not in the frame are left out). One seed: ``"mean"`` only;
    seeds differing between cells: each cell ends with ``" (n seeds)"``. ``attrs["note"]`` says what the
    intervals are (:func:`~thesis_repro.evaluation.tables.ci_label`); print it under the table.

    >>> f = pd.DataFrame({"panel": "a", "algo": ["kl_avg"] * 6 + ["joint"] * 6, "seed": [0, 0, 1, 1, 2, 2] * 2,
    ...                   "return": [690.0, 710.0, 780.0, 820.0, 900.0, 900.0, *[500.0] * 6]})
    >>> t = compare_ci(f, "return")
    >>> t.loc["a"].tolist()
    ['800.0 ± 248.4', '500.0 ± 0.0', 'kl_avg']
    >>> t.attrs["note"]
    'mean ± half-width of the 95 % CI of the mean across 3 training seeds (t-interval over per-seed means)'
    >>> one = compare_ci(f[f.seed == 0], "return")
    >>> one.loc["a"].tolist(), one.attrs["note"]
    (['700.0', '500.0', 'kl_avg'], '1 training seed: no confidence interval')
    """
    cells = seed_table(frame, value, by, seed, level)
    n = cells["n_seeds"]
    mixed = len(n) > 0 and n.min() != n.max()
    text = cells.assign(
        cell=[
            tables.pm_text(m, h) + (f" ({int(k)})" if mixed and np.isfinite(m) else "")
            for m, h, k in cells[["mean", "half_width", "n_seeds"]].itertuples(index=False)
        ]
    )
    index = list(by) or ["all"]  # no grouping: one row "all"
    text, cells = (f.assign(all="all") if not by else f for f in (text, cells))
    present = list(dict.fromkeys(cells["algo"]))
    algos = present if algos is None else [a for a in algos if a in present]
    table = text.pivot_table(index=index, columns="algo", values="cell", aggfunc="first", sort=False)
    table = table.reindex(columns=algos).fillna("")
    table.columns.name = None
    if not by:
        table.index.name = None
    means = cells.pivot_table(index=index, columns="algo", values="mean", sort=False)
    table["best"] = means.reindex(index=table.index, columns=algos).idxmax(axis=1)
    label = tables.ci_label(n) if len(n) else "no runs"
    table.attrs["note"] = f"mean ± half-width of the {label}" if len(n) and n.max() > 1 else label
    return table


def late(curves: pd.DataFrame) -> pd.DataFrame:
    """Fig 4.1: the rows of the last third of the iterations (iteration > n - max(1, n // 3))."""
    n_it = int(curves["iteration"].max())
    return curves[curves["iteration"] > n_it - max(1, n_it // 3)]


def late_returns(curves: pd.DataFrame) -> pd.DataFrame:
    """Fig 4.1: mean training return over the last third of the iterations, per panel and algorithm."""
    return best_per_group(late(curves), "return")


def late_returns_ci(curves: pd.DataFrame) -> pd.DataFrame:
    """Fig 4.1: :func:`late_returns` across training seeds (:func:`compare_ci`): per seed the mean return over
    its last third of the iterations, then mean ± 95 % CI over seeds."""
    return compare_ci(late(curves), "return")


def aggregate_kl(curves: pd.DataFrame) -> pd.DataFrame:
    """Per learner (rows) and panel (columns): how far the sub-policies drift from the aggregate, the largest over
    training of their mean KL to it, as the median over seeds and the largest seed's ("0.02 (max 0.05)"); learners
    without an aggregate (joint) are left out.

    >>> c = pd.DataFrame({"algo": "kl_x", "panel": "a", "seed": [0, 0, 1, 1], "kl_to_aggregate": [0.01, 0.02, 3, 9]})
    >>> aggregate_kl(c).to_dict("index")
    {'kl_x': {'a': '4.5 (max 9)'}}
    """
    peak = curves.groupby(["algo", "panel", "seed"])["kl_to_aggregate"].max().dropna()
    text = peak.groupby(["algo", "panel"]).agg(lambda v: f"{v.median():.2g} (max {v.max():.2g})")
    return text.unstack("panel").rename_axis(index="learner", columns="panel")


def off_centre(heat: pd.DataFrame) -> pd.DataFrame:
    """Heat-map rows except the training dynamics (mass = friction = 1)."""
    return heat[~(np.isclose(heat["mass"], 1.0) & np.isclose(heat["friction"], 1.0))]


def noise_aucs(noise: pd.DataFrame, per_seed: bool = False) -> pd.DataFrame:
    """Fig 4.6: AUC (Eq 3.6) of the seed-mean return over σ, per noise type, panel and algorithm.

    ``per_seed``: the AUC of each training seed's own curve instead (a ``seed`` column; the input for
    :func:`compare_ci`, ``by=("noise", "panel")``).
    """
    keys = ["noise", "panel", "algo", *(["seed"] if per_seed else [])]
    curve = noise.groupby([*keys, "value"])["return"].mean().reset_index()
    rows = []
    for key, g in curve.groupby(keys):
        g = g.sort_values("value")
        rows.append(
            {
                **dict(zip(keys, key, strict=True)),
                "auc": float(auc(g["return"].to_numpy(), g["value"].tolist())),
            }
        )
    return pd.DataFrame(rows)


def best_seeds(runs: pd.DataFrame, last: int = 3) -> pd.DataFrame:
    """Fig 4.2: per algorithm, the run with the best mean return over its ``last`` iterations (index: algo)."""
    runs = runs.copy()
    runs["final_return"] = [
        float(np.nanmean(r["curve_return"][-last:])) if np.isfinite(r["curve_return"]).any() else -np.inf
        for r in runs["result"]
    ]
    return runs.loc[runs.groupby("algo")["final_return"].idxmax()].set_index("algo")


# ---------------------------------------------------------------- Figure 4.2: rendering
#: Offscreen rendering of Fig 4.2. Gymnasium 1.4 renders Walker2d/Hopper with a FREE camera whose
#: ``trackbodyid`` has no effect, so a walker leaves the frame after a few metres; the models' own
#: ``track`` camera (mode ``trackcom``) follows the centre of mass, as the thesis's frames do.
RENDER: dict[str, Any] = {"render_mode": "rgb_array", "width": 480, "height": 320, "camera_name": "track"}


def render_cycle(
    run_result: Any, env: str, c_a: float, n_frames: int = 5, steps: int = 300, seed: int = 0
) -> tuple[list[np.ndarray], list[int]]:
    """Key frames of one gait cycle of the trained policy at ξ = 0, rendered offscreen (``MUJOCO_GL``).

    The cycle period is the dominant period of the thigh-joint angle (FFT) over ``steps`` steps; the
    frames are ``n_frames`` evenly spaced steps of the last full cycle (fallback: of the whole episode).
    The camera follows the walker (:data:`RENDER`; its ``trackcom`` pose depends on the state alone). The
    episode is stepped twice with the same seed: once for the angles, then again rendering only the chosen
    steps (the replay must retrace the angles exactly, or this raises).
    """
    policy = load_policy(run_result)
    angles, _ = _gait_rollout(policy, env, c_a, steps, seed)
    idx = cycle_frames(np.asarray(angles), n_frames)
    again, frames = _gait_rollout(policy, env, c_a, steps, seed, render_at=set(idx))
    if again != angles:
        raise RuntimeError(f"render_cycle: the {env} replay with seed {seed} left the first rollout's trajectory")
    return [frames[i] for i in idx], idx


def _gait_rollout(
    policy: Any, env: str, c_a: float, steps: int, seed: int, render_at: AbstractSet[int] = frozenset()
) -> tuple[list[float], dict[int, np.ndarray]]:
    """One mean-action episode at ξ = 0: the thigh-joint angle after every step (step 0 = the reset) and the
    frames of the steps in ``render_at``."""
    e = make_env(env, ratios={"wind": 0.0}, c_a=c_a, max_episode_steps=steps, env_kwargs=RENDER)
    obs, _ = e.reset(seed=seed)
    angles, frames = [float(obs[2])], {}
    if 0 in render_at:
        frames[0] = e.render()
    for t in range(1, steps + 1):
        obs, _, term, trunc, _ = e.step(policy(obs[None])[0])
        angles.append(float(obs[2]))
        if t in render_at:
            frames[t] = e.render()
        if term or trunc:
            break
    e.close()
    return angles, frames


def cycle_frames(angles: np.ndarray, n_frames: int) -> list[int]:
    """Indices of ``n_frames`` evenly spaced steps over the last full period of ``angles`` (FFT period).

    >>> t = np.arange(101)
    >>> cycle_frames(np.sin(2 * np.pi * t / 20), 5)
    [80, 85, 90, 95, 100]
    """
    n = len(angles)
    period = n
    if n >= 16:
        a = np.asarray(angles, float) - np.mean(angles)
        spec = np.abs(np.fft.rfft(a))
        freqs = np.fft.rfftfreq(n)
        k = int(np.argmax(spec[1:]) + 1)
        period = int(round(1.0 / freqs[k])) if freqs[k] > 0 else n
    period = max(min(period, n - 1), n_frames)
    start = max(n - 1 - period, 0)
    return np.linspace(start, min(start + period, n - 1), n_frames).round().astype(int).tolist()
