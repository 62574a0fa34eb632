"""Chapter-3 figure logic (Figs 3.2, 3.3): job grids and the numbers the notebooks plot.

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

from thesis_repro.cache import Job, Result, run_jobs
from thesis_repro.evaluation import BenchmarkResult, correlation
from thesis_repro.evaluation.jobs import EVAL_FN, TRAIN_FN, check_test
from thesis_repro.learners import train_config

SELECTIONS = ("best", "mean")


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
    if how == "best":
        return best_seed(train_return, train_return), best_seed(train_return, values)
    if how == "mean":
        return np.nanmean(train_return, axis=0), np.nanmean(values, axis=0)
    raise ValueError(f"unknown selection {how!r}; valid selections are: {', '.join(map(repr, SELECTIONS))}")


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


def timesteps_for(timesteps: int | Mapping[str, int], env: str) -> int:
    """Training budget of ``env`` from an int or a per-env mapping (``default`` key allowed)."""
    if isinstance(timesteps, Mapping):
        if env in timesteps:
            return int(timesteps[env])
        if "default" in timesteps:
            return int(timesteps["default"])
        raise ValueError(f"no training budget for env {env!r} in {dict(timesteps)}")
    return int(timesteps)


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


def overfitting_jobs(
    algo: str,
    env: str,
    seeds: Sequence[int],
    timesteps: int,
    snapshot_every: int,
    test: Mapping[str, Any],
    n_jobs: int | None = None,
    overrides: Mapping[str, Any] | None = None,
) -> tuple[list[Result], list[list[Job]]]:
    """Train runs with policy snapshots, then one evaluation job per snapshot (all through the cache)."""
    cfgs = [
        train_config(algo, env, int(s), int(timesteps), snapshot_every=int(snapshot_every), **dict(overrides or {}))
        for s in seeds
    ]
    trained = run_jobs([Job(TRAIN_FN, c) for c in cfgs], n_jobs=n_jobs, desc="train (with snapshots)")
    block = check_test(test)
    evals = [
        [Job(EVAL_FN, {"train": c, "test": {**block, "snapshot": int(s)}}) for s in t["snapshots"]]
        for c, t in zip(cfgs, trained, strict=True)
    ]
    return trained, evals


def overfitting_summary(iterations: np.ndarray, train_return: np.ndarray, test_auc: np.ndarray) -> dict[str, Any]:
    """Did testing AUC peak before the end while training return kept rising? (the claim of Fig 3.2).

    ``overfits`` is True when the final AUC is at least 10 % below its peak and the final training
    return is at least that at the AUC peak.
    """
    it, tr, auc = (np.asarray(a, float) for a in (iterations, train_return, test_auc))
    k = int(np.nanargmax(auc))
    drop = float((auc[k] - auc[-1]) / abs(auc[k])) if auc[k] != 0 else 0.0
    overfits = bool(k < len(auc) - 1 and drop >= 0.10 and tr[-1] >= tr[k])
    return {
        "peak_iteration": float(it[k]),
        "peak_auc": float(auc[k]),
        "final_auc": float(auc[-1]),
        "auc_drop_from_peak": drop,
        "train_return_at_peak": float(tr[k]),
        "final_train_return": float(tr[-1]),
        "overfits": overfits,
    }


def benchmark(
    algos: Sequence[str],
    envs: Sequence[str],
    seeds: Sequence[int],
    timesteps: int | Mapping[str, int],
    tests: Sequence[str],
    **kwargs: Any,
):
    """Like :func:`thesis_repro.evaluation.benchmark_jobs`, with a per-env training budget.

    ``timesteps`` may be an int or ``{env: steps, "default": steps}``; jobs keep the
    ``(seed, env, algo)`` order so :meth:`Benchmark.run` stacks them as ``(seeds, tasks, algos, ...)``.
    """
    from thesis_repro.evaluation import Benchmark, benchmark_jobs

    parts = {e: benchmark_jobs(algos, [e], seeds, timesteps_for(timesteps, e), tests, **kwargs) for e in envs}
    n_a = len(algos)

    def order(get) -> list[Job]:  # noqa: ANN001
        return [get(parts[e])[si * n_a + ai] for si in range(len(seeds)) for e in envs for ai in range(n_a)]

    first = parts[envs[0]]
    evals = {name: order(lambda b, n=name: b.eval_jobs[n]) for name in first.eval_jobs}
    train = order(lambda b: b.train_jobs)
    return Benchmark(list(algos), list(envs), [int(s) for s in seeds], first.tests, train, evals)
