"""Chapter 3, Figures 3.2 and 3.3: job grids and tidy result tables (the claims layer judges them).

Arrays follow the kit's axis order ``(training seeds, tasks, algorithms, ...)``.

>>> import numpy as np
>>> tr = np.array([[[1.0, 5.0]], [[3.0, 4.0]]])   # (seeds=2, tasks=1, algos=2)
>>> auc = np.array([[[10.0, 20.0]], [[30.0, 40.0]]])
>>> best_seed(tr, auc).tolist()                     # seed with the best training return, per algo
[[30.0, 20.0]]
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd

from thesis_repro.core import thesis_numbers
from thesis_repro.core.backends import run_jobs
from thesis_repro.core.cache import Job, Result
from thesis_repro.core.validation import check_choice
from thesis_repro.evaluation import Benchmark, BenchmarkResult, benchmark_jobs, correlation, pareto_frontier
from thesis_repro.evaluation.jobs import check_test
from thesis_repro.figures import register_figure
from thesis_repro.learners import iteration_steps, n_iterations, train_config

SELECTIONS: tuple[str, ...] = ("best", "mean")


# ---------------------------------------------------------------- shared chapter-3 helpers
def best_seed(train_return: np.ndarray, values: np.ndarray) -> np.ndarray:
    """``values[s*, task, algo]`` where ``s*`` maximises the training return of that task and algorithm.

    The thesis (§3.3.1) represents each algorithm by "the learned policy with best training performance
    among multiple random seeds". Inputs ``(seeds, tasks, algos)``; output ``(tasks, algos)``.
    """
    tr, v = np.asarray(train_return, float), np.asarray(values, float)
    if tr.shape != v.shape or tr.ndim != 3:
        raise ValueError(f"need two (seeds, tasks, algos) arrays of one shape, got {tr.shape} and {v.shape}")
    idx = np.nanargmax(np.where(np.isnan(tr), -np.inf, tr), axis=0)
    return np.take_along_axis(v, idx[None], axis=0)[0]


def select(train_return: np.ndarray, values: np.ndarray, how: str = "best") -> tuple[np.ndarray, np.ndarray]:
    """Per (task, algo) training return and value, by the best-training seed or the mean over seeds."""
    check_choice(how, SELECTIONS, "selection")
    if how == "best":
        return best_seed(train_return, train_return), best_seed(train_return, values)
    return np.nanmean(train_return, axis=0), np.nanmean(values, axis=0)


def timesteps_for(timesteps: int | Mapping[str, int], env: str) -> int:
    """Training budget of ``env`` from an int or a per-env mapping (``default`` key allowed)."""
    if isinstance(timesteps, Mapping):
        if env in timesteps:
            return int(timesteps[env])
        if "default" in timesteps:
            return int(timesteps["default"])
        raise ValueError(f"no training budget for env {env!r} in {dict(timesteps)}")
    return int(timesteps)


def learner_timesteps(settings: Mapping[str, Any], algo: str) -> int | Mapping[str, int]:
    """Training budget of ``algo`` in an item: its ``algo_timesteps`` entry if any, else the item's ``timesteps``
    (an off-policy learner may reach the trained regime sooner; its budget is then measured on its own).

    >>> learner_timesteps({"timesteps": 200, "algo_timesteps": {"sac": 100}}, "sac")
    100
    >>> learner_timesteps({"timesteps": 200}, "ppo")
    200
    """
    per = settings.get("algo_timesteps") or {}
    return per[algo] if algo in per else settings["timesteps"]


# ---------------------------------------------------------------- Figure 3.2: overfitting during training
def training_return_at(train: Result | Mapping[str, Any], timesteps: Sequence[int], window: int = 100) -> np.ndarray:
    """Mean return of the last ``window`` training episodes finished by each of ``timesteps`` (NaN if none)."""
    ep_t = np.asarray(train["episode_timesteps"])
    ep_r = np.asarray(train["episode_returns"], float)
    out = []
    for t in timesteps:
        done = ep_r[ep_t <= t]
        out.append(float(done[-window:].mean()) if done.size else float("nan"))
    return np.array(out)


def snapshot_steps(cfg: Mapping[str, Any]) -> list[int]:
    """Env steps at which an on-policy training run saves its policy snapshots.

    Snapshots are taken at iteration starts once ``snapshot_every`` steps have passed since the last one
    (the first at step 0) and at the end (``ceil(timesteps / batch)`` iterations).

    >>> snapshot_steps({"class": "PPO", "n_envs": 2, "sb3": {"n_steps": 64}, "timesteps": 512, "snapshot_every": 200})
    [0, 256, 512]
    """
    batch, every = iteration_steps(cfg), int(cfg["snapshot_every"])
    if every <= 0:
        return []
    n_iter = n_iterations(cfg)
    out: list[int] = []
    for i in range(n_iter):
        t = i * batch
        if not out or t - out[-1] >= every:
            out.append(t)
    done = n_iter * batch
    return out if out[-1] == done else [*out, done]


def overfitting_configs(settings: Mapping[str, Any]) -> list[dict[str, Any]]:
    """Fig 3.2's training configs (one per seed, with policy snapshots)."""
    return [
        train_config(
            settings["algo"],
            settings["env"],
            seed,
            int(settings["timesteps"]),
            snapshot_every=int(settings["snapshot_every"]),
            protocol=settings["protocol"],
            **dict(settings["train_overrides"] or {}),
        )
        for seed in range(int(settings["train_seeds"]))
    ]


def overfitting_test(settings: Mapping[str, Any]) -> dict[str, Any]:
    """Fig 3.2's test block: observation noise over the σ grid of the scale table."""
    return check_test(
        {
            "perturbation": "obs",
            "sigmas": list(settings["sigmas"]),
            "n_rollouts": int(settings["test_rollouts"]),
            "max_episode_steps": int(settings["max_episode_steps"]),
        }
    )


def _snapshot_evals(cfg: Mapping[str, Any], test: Mapping[str, Any], steps: Sequence[int]) -> list[Job]:
    return [Job("evaluate", {"train": dict(cfg), "test": {**test, "snapshot": int(s)}}) for s in steps]


@register_figure("3.2", "Overfitting occurs in deep RL (PPO, Walker2d)")
def overfitting_jobs(settings: Mapping[str, Any]) -> list[Job]:
    """Train jobs (with snapshots), then one evaluation job per predicted snapshot."""
    cfgs, test = overfitting_configs(settings), overfitting_test(settings)
    evals = [j for c in cfgs for j in _snapshot_evals(c, test, snapshot_steps(c))]
    return [Job("train", c) for c in cfgs] + evals


def overfitting_curve(settings: Mapping[str, Any], n_jobs: int | None = None) -> pd.DataFrame:
    """Run (or load) Fig 3.2: one row per (seed, snapshot) with ``timesteps``, ``iteration``,
    ``train_return`` (last 100 training episodes) and ``test_auc`` (obs noise, Eq 3.6)."""
    cfgs, test = overfitting_configs(settings), overfitting_test(settings)
    trained = run_jobs([Job("train", c) for c in cfgs], n_jobs=n_jobs, desc="train (with snapshots)")
    rows = []
    for cfg, train in zip(cfgs, trained, strict=True):
        steps = [int(s) for s in train["snapshots"]]
        evals = run_jobs(
            _snapshot_evals(cfg, test, steps), n_jobs=n_jobs, desc=f"evaluate snapshots (seed {cfg['seed']})"
        )
        tr = training_return_at(train, steps)
        for s, r, e in zip(steps, tr, evals, strict=True):
            rows.append(
                {
                    "seed": cfg["seed"],
                    "timesteps": s,
                    "iteration": s / iteration_steps(cfg),
                    "train_return": r,
                    "test_auc": e["auc"],
                }
            )
    return pd.DataFrame(rows)


def curve_style(curve: pd.DataFrame, rows: int = 5) -> Any:
    """:func:`overfitting_curve` for display: its first and last ``rows`` rows as a ``Styler`` (1 decimal, no row
    numbers) whose caption says so; a training return that :func:`training_return_at` leaves NaN (no training
    episode finished by that snapshot, e.g. step 0) is shown as "–" and explained in the caption.

    >>> c = pd.DataFrame({"seed": 0, "timesteps": [0, 40960], "iteration": [0.0, 20.0],
    ...                   "train_return": [float("nan"), 239.24], "test_auc": [66.63, 317.9]})
    >>> html = curve_style(c).to_html()
    >>> all(x in html for x in (">–<", ">239.2<", "(all 2 rows)", "no training episode")), "239.240000" in html
    (True, False)
    """
    whole = len(curve) <= 2 * rows
    shown = curve if whole else pd.concat([curve.head(rows), curve.tail(rows)])
    which = f"all {len(curve)} rows" if whole else f"first and last {rows} of {len(curve)} rows"
    caption = f"Reproduced training return and testing AUC per training seed and snapshot ({which})"
    if curve["train_return"].isna().any():
        caption += "; train_return – : no training episode had finished by that snapshot (e.g. at step 0)"
    return shown.style.hide(axis="index").format(precision=1, na_rep="–").set_caption(caption)


# ---------------------------------------------------------------- Figure 3.3: training return vs testing AUC
def benchmark(
    algos: Sequence[str],
    envs: Sequence[str],
    seeds: Sequence[int],
    timesteps: int | Mapping[str, int],
    tests: Sequence[str],
    algo_timesteps: Mapping[str, int | Mapping[str, int]] | None = None,
    **kwargs: Any,
) -> Benchmark:
    """Like :func:`thesis_repro.evaluation.benchmark_jobs`, with a per-env and per-learner training budget.

    ``timesteps`` may be an int or ``{env: steps, "default": steps}``; ``algo_timesteps`` replaces it for the
    learners it names. Jobs keep the ``(seed, env, algo)`` order so :meth:`Benchmark.run` stacks them as
    ``(seeds, tasks, algos, ...)``.
    """
    per = algo_timesteps or {}
    parts = {
        (e, a): benchmark_jobs([a], [e], seeds, timesteps_for(per.get(a, timesteps), e), tests, **kwargs)
        for e in envs
        for a in algos
    }

    def order(get) -> list[Job]:  # noqa: ANN001
        return [get(parts[e, a])[si] for si in range(len(seeds)) for e in envs for a in algos]

    first = parts[envs[0], algos[0]]
    evals = {name: order(lambda b, n=name: b.eval_jobs[n]) for name in first.eval_jobs}
    train = order(lambda b: b.train_jobs)
    return Benchmark(list(algos), list(envs), [int(s) for s in seeds], first.tests, train, evals)


def variants(settings: Mapping[str, Any]) -> list[str]:
    """The variants an item runs at its scale: ``algos`` minus ``skip_algos`` (those the scale cannot afford).

    >>> variants({"algos": ["ppo", "sac"], "skip_algos": ["sac"]}), variants({"algos": ["ppo"]})
    (['ppo'], ['ppo'])
    """
    skip = set(settings.get("skip_algos") or ())
    return [a for a in settings["algos"] if a not in skip]


def not_run_note(settings: Mapping[str, Any]) -> str:
    """The sentence a page prints about the variants its scale skips (``""`` when it runs them all).

    >>> not_run_note({"algos": ["ppo", "ddpg", "sac"], "skip_algos": ["ddpg", "sac"], "scale": "small"})
    'Not run at scale small: ddpg, sac (2 of the 3 variants; scales.yaml `skip_algos`).'
    """
    skipped = [a for a in settings["algos"] if a not in variants(settings)]
    if not skipped:
        return ""
    n, where = len(settings["algos"]), "scales.yaml `skip_algos`"
    return f"Not run at scale {settings['scale']}: {', '.join(skipped)} ({len(skipped)} of the {n} variants; {where})."


def pareto_benchmark(settings: Mapping[str, Any]) -> Benchmark:
    """Fig 3.3's grid (every variant the scale runs × task × seed, tested under every test type)."""
    return benchmark(
        variants(settings),
        settings["envs"],
        list(range(int(settings["train_seeds"]))),
        settings["timesteps"],
        settings["tests"],
        algo_timesteps=settings.get("algo_timesteps"),
        sigmas=settings["sigmas"],
        n_rollouts=int(settings["test_rollouts"]),
        max_episode_steps=int(settings["max_episode_steps"]),
        train_overrides={**(settings["train_overrides"] or {}), "protocol": settings["protocol"]},
    )


@register_figure("3.3", "Training return does not reflect generalisation (Pareto frontier, correlation)")
def pareto_jobs(settings: Mapping[str, Any]) -> list[Job]:
    """Every training job of Fig 3.3, then every evaluation job."""
    bench = pareto_benchmark(settings)
    return [*bench.train_jobs, *(j for jobs in bench.eval_jobs.values() for j in jobs)]


def correlation_table(res: BenchmarkResult, how: str = "best") -> pd.DataFrame:
    """Fig 3.3(c): Pearson r of testing AUC vs training return across algorithms, per task and test type.

    Returns a tidy frame ``env, test, value, p, n`` (``value`` NaN where undefined: < 3 algorithms or no
    spread, as in a smoke run).
    """
    if res.train_return is None:
        raise ValueError("the benchmark result has no training returns")
    rows = []
    for test, auc in res.auc.items():
        tr, a = select(res.train_return, auc, how)
        for j, env in enumerate(res.envs):
            try:
                r, p = correlation(tr[j], a[j])
            except ValueError:
                r, p = float("nan"), float("nan")
            rows.append({"env": env, "test": test, "value": r, "p": p, "n": len(res.algos)})
    return pd.DataFrame(rows)


def points_table(res: BenchmarkResult, how: str = "best") -> pd.DataFrame:
    """Tidy ``env, test, algo, train_return, auc`` (one point per algorithm: Fig 3.3(a,b))."""
    rows = []
    for test, auc in res.auc.items():
        tr, a = select(res.train_return, auc, how)
        for j, env in enumerate(res.envs):
            for k, algo in enumerate(res.algos):
                rows.append({"env": env, "test": test, "algo": algo, "train_return": tr[j, k], "auc": a[j, k]})
    return pd.DataFrame(rows)


def seed_points(res: BenchmarkResult) -> pd.DataFrame:
    """Per-seed points for the claims layer: ``env, test, algo, seed, train_return, auc`` (no seed selection)."""
    rows = []
    for test, auc in res.auc.items():
        for s, seed in enumerate(res.seeds):
            for j, env in enumerate(res.envs):
                for k, algo in enumerate(res.algos):
                    rows.append(
                        {
                            "env": env,
                            "test": test,
                            "algo": algo,
                            "seed": seed,
                            "train_return": float(res.train_return[s, j, k]),
                            "auc": float(auc[s, j, k]),
                        }
                    )
    return pd.DataFrame(rows)


def correlation_wide(ours: pd.DataFrame) -> pd.DataFrame:
    """Fig 3.3(c) as ``env × (source, test)``: the thesis's coefficients beside ours (tasks run here)."""
    thesis = thesis_numbers.load("fig3_3c")
    envs = [e for e in thesis_numbers.ENVS if e in set(ours.env)]
    table = pd.concat([thesis.assign(source="thesis"), ours.assign(source="reproduced")])
    wide = table.pivot_table(index="env", columns=["source", "test"], values="value", dropna=False)
    cols = pd.MultiIndex.from_product([["thesis", "reproduced"], list(thesis_numbers.TESTS)])
    return wide.reindex(index=envs, columns=cols)


def frontier(points: pd.DataFrame) -> pd.DataFrame:
    """The Pareto-optimal rows of one panel's points (finite values only), by increasing training return."""
    ok = points[np.isfinite(points.train_return) & np.isfinite(points.auc)].reset_index(drop=True)
    if ok.empty:
        return ok
    return ok.iloc[pareto_frontier(ok.train_return, ok.auc)]


# ---------------------------------------------------------------- Fig 3.3 against training budget
#: The columns of a per-seed points frame at several training budgets (:func:`budget_correlations`' input).
BUDGET_POINTS = ("steps", "env", "test", "algo", "seed", "train_return", "auc")


def _r(x: np.ndarray, y: np.ndarray) -> float:
    """Pearson r of the finite pairs of ``x`` and ``y`` (NaN with fewer than 3 or no spread)."""
    ok = np.isfinite(x) & np.isfinite(y)
    try:
        return float(correlation(x[ok], y[ok])[0]) if ok.sum() >= 3 else float("nan")
    except ValueError:
        return float("nan")


def budget_correlations(points: pd.DataFrame) -> pd.DataFrame:
    """Fig 3.3(c) at each training budget: per ``steps`` and (task, test) cell, Pearson r of testing AUC vs training
    return across the variants, two ways: ``r`` the thesis's statistic (each variant's best-training seed, as
    :func:`correlation_table` with ``"best"``), ``r_seeds`` the seed-keyed one the page's pooled r reads (r per
    training seed, averaged through Fisher z), with ``algos`` (variants with a point) and ``seeds`` (training seeds
    whose r is defined). ``points`` has the columns :data:`BUDGET_POINTS` (a run missing at a budget has no rows).

    >>> pts = pd.DataFrame([{"steps": 1, "env": "E", "test": "obs", "algo": a, "seed": s, "train_return": tr + s,
    ...     "auc": au - s} for s in (0, 1) for a, tr, au in (("a", 1, 30), ("b", 2, 20), ("c", 3, 10))])
    >>> budget_correlations(pts).round(2).to_dict("records")
    [{'steps': 1, 'env': 'E', 'test': 'obs', 'r': -1.0, 'r_seeds': -1.0, 'algos': 3, 'seeds': 2}]
    """
    rows = []
    for (steps, env, test), cell in points.groupby(["steps", "env", "test"], sort=False):
        wide = cell.pivot_table(index="seed", columns="algo", values=["train_return", "auc"], aggfunc="mean")
        tr, au = wide["train_return"].to_numpy(float), wide["auc"].to_numpy(float)
        best = np.nanargmax(np.where(np.isnan(tr), -np.inf, tr), axis=0)
        pick = np.arange(tr.shape[1])
        per_seed = [_r(tr[i], au[i]) for i in range(tr.shape[0])]
        z = np.arctanh(np.clip([r for r in per_seed if np.isfinite(r)], -0.999999, 0.999999))
        rows.append(
            {
                "steps": int(steps),
                "env": env,
                "test": test,
                "r": _r(tr[best, pick], au[best, pick]),
                "r_seeds": float(np.tanh(z.mean())) if z.size else float("nan"),
                "algos": int(np.isfinite(tr).any(axis=0).sum()),
                "seeds": int(z.size),
            }
        )
    return pd.DataFrame(rows, columns=["steps", "env", "test", "r", "r_seeds", "algos", "seeds"])


def budget_summary(cells: pd.DataFrame) -> pd.DataFrame:
    """Per budget (``steps``) over the cells of :func:`budget_correlations`: ``negative`` (cells with the thesis's
    statistic r < 0) of ``cells`` (cells with r defined), ``mean_r`` (its mean) and ``pooled_r``, the seed-keyed r
    pooled through Fisher z over the cells (the point estimate of the page's pooled r).

    >>> cells = pd.DataFrame({"steps": [1, 1], "r": [-0.5, 0.2], "r_seeds": [-0.5, 0.5]})
    >>> budget_summary(cells).round(3).to_dict("records")
    [{'steps': 1, 'negative': 1, 'cells': 2, 'mean_r': -0.15, 'pooled_r': 0.0}]
    """
    rows = []
    for steps, g in cells.groupby("steps", sort=True):
        r = g["r"].to_numpy(float)
        z = np.arctanh(np.clip(g["r_seeds"].dropna().to_numpy(float), -0.999999, 0.999999))
        rows.append(
            {
                "steps": int(steps),
                "negative": int((r[np.isfinite(r)] < 0).sum()),
                "cells": int(np.isfinite(r).sum()),
                "mean_r": float(np.nanmean(r)) if np.isfinite(r).any() else float("nan"),
                "pooled_r": float(np.tanh(z.mean())) if z.size else float("nan"),
            }
        )
    return pd.DataFrame(rows, columns=["steps", "negative", "cells", "mean_r", "pooled_r"])


def thesis_negative(envs: Sequence[str] | None = None) -> tuple[int, int]:
    """(cells with r < 0, cells) of the thesis's Fig 3.3(c) (``data/thesis/fig3_3c.csv``), over ``envs`` if given.

    >>> thesis_negative(), thesis_negative(["Walker2d", "HalfCheetah", "Hopper"])
    ((18, 20), (12, 12))
    """
    t = thesis_numbers.load("fig3_3c")
    if envs is not None:
        t = t[t["env"].isin(list(envs))]
    return int((t["value"] < 0).sum()), int(len(t))
