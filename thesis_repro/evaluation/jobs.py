"""Cached evaluation jobs and figure-level benchmark grids (train jobs first, then evaluation jobs).

An evaluation config (the ``"evaluate"`` job) is ``{"train": <train_config(...)>, "test": <test block>}``;
the trained model comes from the run cache (the same train job is trained once and shared by every test).
The kind pins its training run (:func:`evaluate_dependencies`): the run cache adds ``"policy": <identity of
the training entry>`` (:func:`thesis_repro.core.cache.entry_identity`) before keying it, so an evaluation of
retrained weights is a new entry, and a fresh clone (shipped training runs) computes the same keys.
A test block is ``{"perturbation", "sigmas" | "ratios", "n_rollouts", "seed", "max_episode_steps",
"c_a", "snapshot" (optional), "env" (optional), "env_kwargs" (optional)}``:

* ``sigmas``: a noise grid of ``perturbation`` (obs | act | env | dom; Eq 3.6's AUC over it), or
* ``ratios``: a list of fixed env settings, one per point: factor ratios (``{"body_mass": 1.2, "friction":
  0.8}``, heat maps) and/or a fixed wind ξ in m/s² (``{"wind": -2.0}``, chapter 4's wind sweeps);
* ``c_a``: the action penalty of Eq 4.12 during testing; by default the training run's (so the reward is
  the one trained for); the training ``wind`` range is NOT applied: the test block says which wind blows.

Arrays of :class:`BenchmarkResult` have axes ``(training seeds, tasks, algorithms, points, rollouts)``
(points = sigmas, or ratio settings of a shift grid); ``auc``/``train_return`` drop the last two axes.

>>> bench = benchmark_jobs(["PPO"], ["Hopper"], [0, 1], 100_000, ["obs", "act"],
...                        sigmas=[0.0, 0.1, 0.2])  # doctest: +SKIP
>>> res = bench.run()  # doctest: +SKIP
>>> res.auc["obs"].shape  # (seeds, tasks, algorithms)  # doctest: +SKIP
(2, 1, 1)
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from thesis_repro.core.backends import run_jobs
from thesis_repro.core.cache import Job, Result, RunCache
from thesis_repro.core.validation import check_choice, check_nonneg
from thesis_repro.evaluation.evaluator import PERTURBATIONS, evaluate, evaluate_shift
from thesis_repro.evaluation.metrics import auc, expected_return, sigma_step
from thesis_repro.learners import load_policy, train_config

#: Job kinds of training and evaluation runs (``thesis_repro.core.job_kinds``).
TRAIN_KIND = "train"
EVAL_KIND = "evaluate"


def check_test(test: Mapping[str, Any]) -> dict[str, Any]:
    """Validate a test block and fill defaults (``seed=0``, ``max_episode_steps=1000``, ``n_rollouts=20``,
    ``c_a=None``: the training run's).

    >>> check_test({"perturbation": "none", "ratios": [{"wind": -1.0}], "c_a": 1.0})["c_a"]
    1.0
    >>> check_test({"perturbation": "obs"})
    Traceback (most recent call last):
    ...
    ValueError: a test needs exactly one of 'sigmas' (noise grid) or 'ratios' (systematic shifts)
    """
    t = {"seed": 0, "max_episode_steps": 1000, "n_rollouts": 20, "c_a": None, **dict(test)}
    check_choice(t.get("perturbation"), PERTURBATIONS, "perturbation")
    if ("sigmas" in t) == ("ratios" in t):
        raise ValueError("a test needs exactly one of 'sigmas' (noise grid) or 'ratios' (systematic shifts)")
    if "ratios" in t and t["perturbation"] != "none":
        raise ValueError("systematic-shift tests ('ratios') use perturbation 'none'")
    if t["c_a"] is not None:
        t["c_a"] = check_nonneg(t["c_a"], "c_a")
    return t


def evaluate_dependencies(config: Mapping[str, Any]) -> dict[str, Job]:
    """``{"policy": <the train job>}``: the run an evaluation loads (the ``evaluate`` kind's pinned dependency).

    >>> evaluate_dependencies({"train": {"algorithm": "ppo"}, "test": {}})["policy"].kind
    'train'
    """
    train = config.get("train")
    return {"policy": Job(TRAIN_KIND, train)} if isinstance(train, Mapping) else {}


def evaluate_job(config: dict[str, Any], workdir: Path) -> dict[str, Any]:
    """Job function: train (through the cache) or reuse the model of ``config["train"]``, evaluate ``["test"]``.

    Any kit learner's run (chapter 3 or 4) is evaluated the same way. Returns ``returns`` and ``lengths``
    ``(points, n_rollouts)``, ``expected_return`` ``(points,)``, ``auc`` (Eq. 3.6; ``None`` for shift grids or a
    single sigma) and ``train_return`` if the train job reports one. The training entry is loaded from the
    cache running this job; if ``config["policy"]`` names another entry identity, that is an error.
    """
    test = check_test(config["test"])
    train = RunCache.current().run(Job(TRAIN_KIND, config["train"]))
    if config.get("policy") is not None and train.identity != config["policy"]:
        raise RuntimeError(
            f"evaluation of policy {config['policy']} found training entry {train.path} with identity "
            f"{train.identity} (recomputed meanwhile?); rerun to evaluate the current one"
        )
    policy = load_policy(train, snapshot=test.get("snapshot"))
    env = test.get("env", config["train"]["env"])
    c_a = test["c_a"] if test["c_a"] is not None else config["train"].get("c_a")
    extra = {**(test.get("env_kwargs") or {}), **({"c_a": c_a} if c_a is not None else {})}
    kw = {
        "seed": int(test["seed"]),
        "max_episode_steps": int(test["max_episode_steps"]),
        "env_kwargs": extra or None,
        "return_lengths": True,
    }
    if "ratios" in test:
        out = evaluate_shift(policy, env, test["ratios"], int(test["n_rollouts"]), **kw)
        area = None
    else:
        out = evaluate(policy, env, test["perturbation"], test["sigmas"], int(test["n_rollouts"]), **kw)
        area = float(auc(expected_return(out.returns, axis=1), test["sigmas"])) if len(test["sigmas"]) > 1 else None
    tr = train.get("train_return")
    return {
        "returns": out.returns,
        "lengths": out.lengths,
        "expected_return": expected_return(out.returns, axis=1),
        "auc": area,
        "train_return": None if tr is None else float(np.mean(tr)),
    }


@dataclass
class BenchmarkResult:
    """Stacked results; axes ``(seeds, tasks, algos, points, rollouts)`` for ``returns``/``lengths``."""

    algos: list[str]
    envs: list[str]
    seeds: list[int]
    tests: dict[str, dict[str, Any]]
    returns: dict[str, np.ndarray] = field(default_factory=dict)
    lengths: dict[str, np.ndarray] = field(default_factory=dict)
    auc: dict[str, np.ndarray] = field(default_factory=dict)
    train_return: np.ndarray | None = None

    def points(self, test: str) -> list[Any]:
        """The x values of ``test``: its sigmas, or its ratio settings for a shift grid."""
        t = self.tests[test]
        return list(t["sigmas"]) if "sigmas" in t else list(t["ratios"])

    def frame(self, test: str) -> Any:
        """Tidy ``pandas.DataFrame`` of ``test``: one row per (seed, env, algo, point, rollout) with its return.

        The point column is ``sigma`` for noise tests and ``ratios`` (the dict, as text) for shift grids.
        """
        import pandas as pd  # only for the tidy frames: the job functions above do not need pandas

        r, ln = self.returns[test], self.lengths[test]
        col = "sigma" if "sigmas" in self.tests[test] else "ratios"
        pts = [p if col == "sigma" else str(p) for p in self.points(test)]
        idx = np.indices(r.shape).reshape(r.ndim, -1)
        return pd.DataFrame(
            {
                "seed": np.asarray(self.seeds)[idx[0]],
                "env": np.asarray(self.envs)[idx[1]],
                "algo": np.asarray(self.algos)[idx[2]],
                col: np.asarray(pts, dtype=object if col == "ratios" else float)[idx[3]],
                "rollout": idx[4],
                "return": r.reshape(-1),
                "length": ln.reshape(-1),
                "test": test,
            }
        )

    def auc_frame(self) -> Any:
        """Tidy ``pandas.DataFrame`` of every noise test's AUC: columns seed, env, algo, test, auc, train_return."""
        rows = []
        for test, a in self.auc.items():
            for (i, j, k), v in np.ndenumerate(a):
                tr = None if self.train_return is None else float(self.train_return[i, j, k])
                rows.append((self.seeds[i], self.envs[j], self.algos[k], test, float(v), tr))
        return pd.DataFrame(rows, columns=["seed", "env", "algo", "test", "auc", "train_return"])

    def by_algo(self, values: np.ndarray) -> dict[str, np.ndarray]:
        """``{algo: values[:, :, i]}`` — the (runs × tasks) matrices rliable-style aggregators expect."""
        return {a: values[:, :, i] for i, a in enumerate(self.algos)}


@dataclass
class Benchmark:
    """Train and evaluation jobs of a figure; :meth:`run` executes them (train first) and stacks results."""

    algos: list[str]
    envs: list[str]
    seeds: list[int]
    tests: dict[str, dict[str, Any]]
    train_jobs: list[Job]
    eval_jobs: dict[str, list[Job]]  # test name -> jobs in (seed, env, algo) order

    def run(self, n_jobs: int | None = None, progress: bool = True) -> BenchmarkResult:
        """Run missing jobs (cached ones are loaded) and return stacked arrays."""
        trained = run_jobs(self.train_jobs, n_jobs=n_jobs, progress=progress, desc="train")
        shape = (len(self.seeds), len(self.envs), len(self.algos))
        res = BenchmarkResult(self.algos, self.envs, self.seeds, self.tests)
        tr = [t.get("train_return") for t in trained]
        if all(v is not None for v in tr):
            res.train_return = np.array([float(np.mean(v)) for v in tr]).reshape(shape)
        for name, jobs in self.eval_jobs.items():
            out: list[Result] = run_jobs(jobs, n_jobs=n_jobs, progress=progress, desc=f"evaluate {name}")
            rets = np.stack([np.asarray(r["returns"]) for r in out])
            res.returns[name] = rets.reshape(*shape, *rets.shape[1:])
            res.lengths[name] = np.stack([np.asarray(r["lengths"]) for r in out]).reshape(res.returns[name].shape)
            if "sigmas" in self.tests[name] and len(self.tests[name]["sigmas"]) > 1:
                res.auc[name] = auc(expected_return(res.returns[name], axis=-1), self.tests[name]["sigmas"])
        return res


def benchmark_jobs(
    algos: Sequence[str],
    envs: Sequence[str],
    seeds: Sequence[int],
    timesteps: int,
    tests: Sequence[str | Mapping[str, Any]],
    *,
    sigmas: Sequence[float] | None = None,
    n_rollouts: int = 20,
    test_seed: int = 0,
    max_episode_steps: int = 1000,
    snapshot: Any = None,
    train_overrides: Mapping[str, Any] | None = None,
) -> Benchmark:
    """Train jobs (one per seed × task × algorithm) and evaluation jobs (one per train job × test).

    ``tests`` items are perturbation names (using ``sigmas``) or full test blocks with a ``"name"``
    (``{"name": "mass", "perturbation": "none", "ratios": [...]}``).
    """
    if not (algos and envs and seeds and tests):
        raise ValueError("algos, envs, seeds and tests must all be non-empty")
    blocks: dict[str, dict[str, Any]] = {}
    for t in tests:
        if isinstance(t, str):
            if sigmas is None:
                raise ValueError(f"test {t!r} is given by name, so pass sigmas=[...]")
            if len(sigmas) > 1:
                sigma_step(sigmas)
            t = {"name": t, "perturbation": t, "sigmas": list(sigmas)}
        t = dict(t)
        name = t.pop("name", t.get("perturbation"))
        t.setdefault("n_rollouts", n_rollouts)
        t.setdefault("seed", test_seed)
        t.setdefault("max_episode_steps", max_episode_steps)
        if snapshot is not None:
            t.setdefault("snapshot", snapshot)
        if name in blocks:
            raise ValueError(f"duplicate test name {name!r}")
        blocks[name] = check_test(t)
    train_cfgs = [
        train_config(a, e, int(s), int(timesteps), **dict(train_overrides or {}))
        for s in seeds
        for e in envs
        for a in algos
    ]
    train_jobs = [Job(TRAIN_KIND, c) for c in train_cfgs]
    eval_jobs = {name: [Job(EVAL_KIND, {"train": c, "test": b}) for c in train_cfgs] for name, b in blocks.items()}
    return Benchmark(list(algos), list(envs), [int(s) for s in seeds], blocks, train_jobs, eval_jobs)
