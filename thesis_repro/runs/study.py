"""Protocol studies: measured comparisons of one training setting, across training seeds (issues 20, 21).

Each study (:data:`SPECS`) trains one learner under two values of one setting, 3 seeds per task, as ordinary
``train`` jobs of the run cache (so they can be shipped and rechecked like any other). Where one value is the
protocol a figure uses, those runs ARE that figure's runs (same keys):

* ``lr-schedule``: PPO with baselines ppo1's linear annealing (the thesis protocol) against a constant learning
  rate and clip range, on InvertedDoublePendulum and Hopper at 1M env steps (the annealed InvertedDoublePendulum
  runs are Fig 3.3's thesis-protocol PPO runs). One seed is not enough: the same config and seed differs by
  ~20 % between two machines.
* ``reptile-outer-step``: PPO-Reptile-DG with Nichol et al.'s outer step π ← π + ε(π' − π), ε = 1 annealed as
  the lr (the Reptile paper's outer step size, annealed linearly to 0), against Alg 2 as the thesis writes it
  (one Adam step of lr β = 1e-3 on π − π' per iteration: the kit's Table 3.7 runs, which stay near an
  untrained policy's return), on InvertedPendulum, InvertedDoublePendulum and Hopper at Table 3.7's `small`
  budgets.
* ``maml-outer-update``: PPO-MAML-DG with Alg 1's outer update read literally (one Adam step of lr β on the
  mean post-adaptation gradient per iteration, i.e. per 2·N·T = 8,192 env steps) against the kit's reading (the
  same first-order objective optimised for PPO's epochs and minibatches: the kit's Table 3.7 runs), on
  InvertedPendulum at Table 3.7's `small` budget.

    python -m thesis_repro.runs.study lr-schedule [--jobs 2] [--ship] [--commit]   # train what is missing, then
    python -m thesis_repro.runs.study lr-schedule --summary                        # the table, no training

The claims ledger reads a study's result as a *protocol sensitivity* (:data:`STUDIES`, :func:`sensitivity`):
per task the difference of the compared settings with its Welch 95 % CI across seeds, computed from the
cached / shipped runs (never trained here; ``None`` when the runs are not available). This module imports
neither the claims layer nor the figures (the claims layer imports it).

>>> [j.config["lr_schedule"] for j in lr_schedule_jobs()][:2]
['linear', 'constant']
>>> [SPECS["reptile-outer-step"].value(j) for j in study_jobs("reptile-outer-step")][:2]
[1.0, None]
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass
from typing import Any

import numpy as np

from thesis_repro.core.cache import Job, RunCache


@dataclass(frozen=True)
class StudySpec:
    """One protocol study: ``learner`` (its id) trained on ``envs`` (task -> budget) for ``seeds`` under each of
    two ``values`` of the setting at ``path`` (a top-level config key, or ``sb3.<key>``; absent reads as
    ``default``); the contrast is ``values[0] - values[1]``. ``overrides`` are the other training settings
    (those of the figure whose runs one value shares)."""

    name: str
    learner: str
    learner_label: str
    setting: str
    path: str
    values: tuple[Any, Any]
    labels: tuple[str, str]
    envs: Mapping[str, int]
    seeds: tuple[int, ...] = (0, 1, 2)
    default: Any = None
    overrides: Mapping[str, Any] | None = None

    def value(self, job: Job) -> Any:
        """The studied setting of a job's config (``default`` when absent)."""
        holder: Any = job.config
        *parents, leaf = self.path.split(".")
        for part in parents:
            holder = holder.get(part, {})
        return holder.get(leaf, self.default)

    def label(self, value: Any) -> str:
        """The display name of one of :attr:`values`."""
        return self.labels[self.values.index(value)]

    @property
    def contrast(self) -> str:
        return f"{self.labels[0]} - {self.labels[1]}"

    def jobs(self) -> list[Job]:
        """One training job per (task, seed, value), thesis protocol, through the one ``train_config``."""
        from thesis_repro.learners import train_config  # at call time: importing this module stays cheap (claims)

        leaf, extra = self.path.split(".")[-1], dict(self.overrides or {})
        return [
            Job("train", train_config(self.learner, env, seed, budget, protocol="thesis", **{**extra, leaf: v}))
            for env, budget in self.envs.items()
            for seed in self.seeds
            for v in self.values
        ]


#: Table 3.7's `small` training settings (config/scales.yaml: its perturbation ``dom`` at σ 0.2) and budgets, which
#: the meta-learning studies share so that their kit-reading runs ARE Table 3.7's (same keys; tests/test_study.py).
TABLE_3_7_SETTINGS: Mapping[str, Any] = {"perturbation": "dom", "sigma": 0.2}
TABLE_3_7_BUDGETS: Mapping[str, int] = {
    "InvertedPendulum": 200_000,
    "InvertedDoublePendulum": 1_000_000,
    "Hopper": 2_000_000,
}

#: Every protocol study by name.
SPECS: dict[str, StudySpec] = {
    spec.name: spec
    for spec in (
        StudySpec(
            name="lr-schedule",
            learner="ppo",
            learner_label="PPO",
            setting="lr schedule",
            path="lr_schedule",
            values=("linear", "constant"),
            labels=("linear", "constant"),
            envs={"InvertedDoublePendulum": 1_000_000, "Hopper": 1_000_000},
        ),
        StudySpec(
            name="reptile-outer-step",
            learner="ppo-reptile-dg",
            learner_label="PPO-Reptile-DG",
            setting="Reptile-DG outer step",
            path="sb3.meta_step_size",
            values=(1.0, None),
            labels=("eps = 1 (Nichol et al.)", "Adam 1e-3 (Alg 2)"),
            envs=TABLE_3_7_BUDGETS,
            overrides=TABLE_3_7_SETTINGS,
        ),
        StudySpec(
            name="maml-outer-update",
            learner="ppo-maml-dg",
            learner_label="PPO-MAML-DG",
            setting="MAML-DG outer update",
            path="sb3.meta_update",
            values=("step", "ppo"),
            labels=("one Adam step (Alg 1 read literally)", "PPO epochs (kit)"),
            envs={"InvertedPendulum": TABLE_3_7_BUDGETS["InvertedPendulum"]},  # its cheapest task
            default="ppo",
            overrides=TABLE_3_7_SETTINGS,
        ),
    )
}


def study_jobs(name: str | None = None) -> list[Job]:
    """The training jobs of study ``name`` (all studies' when ``None``), deduplicated by key."""
    names = list(SPECS) if name is None else [_check(name)]
    jobs = {j.key: j for n in names for j in SPECS[n].jobs()}
    return list(jobs.values())


def lr_schedule_jobs() -> list[Job]:
    """One PPO training job per (task, seed, schedule), thesis protocol, no other override (Fig 3.3's configs)."""
    return SPECS["lr-schedule"].jobs()


def _check(name: str) -> str:
    if name not in SPECS:
        raise ValueError(f"unknown protocol study {name!r}; valid: {', '.join(SPECS)}")
    return name


#: Short task names for one-line texts (the ledger's "why").
SHORT = {"InvertedDoublePendulum": "IDP", "InvertedPendulum": "IP", "HalfCheetah": "HalfCheetah"}


@dataclass(frozen=True)
class Effect:
    """One task's difference of the study's two settings (``first - second``) in mean final training return,
    with its Welch 95 % CI and p across training seeds (``n`` seeds per setting)."""

    task: str
    difference: float
    ci: tuple[float, float]
    pvalue: float
    n: tuple[int, int]

    @property
    def within_spread(self) -> bool:
        """Whether the CI contains 0 (the settings are not distinguishable over these seeds)."""
        return self.ci[0] <= 0.0 <= self.ci[1]


@dataclass(frozen=True)
class Sensitivity:
    """A protocol study's result as the claims ledger reads it: what was varied, on which learner and budget,
    the measured quantity, and one :class:`Effect` per task with enough seeds."""

    study: str
    setting: str
    learner: str
    budget: str
    contrast: str
    measure: str
    effects: tuple[Effect, ...]

    @property
    def seeds(self) -> str:
        """``"3 seeds"`` (or ``"2-3 seeds"`` when tasks or settings differ)."""
        ns = sorted({n for e in self.effects for n in e.n})
        return f"{ns[0]} seeds" if len(ns) == 1 else f"{ns[0]}-{ns[-1]} seeds"

    @property
    def within_spread(self) -> bool:
        """Every task's CI contains 0."""
        return all(e.within_spread for e in self.effects)


def final_returns(
    jobs: Sequence[Job], cache: RunCache | None = None, spec: StudySpec | None = None
) -> dict[tuple[str, Any], np.ndarray]:
    """Per (task, setting value) of ``spec`` (default: the lr-schedule study): one row (final training return,
    peak of the training curve) per loaded seed. Runs neither cached nor shipped are left out (nothing is
    trained)."""
    spec = spec or SPECS["lr-schedule"]
    cache = cache or RunCache()
    rows: dict[tuple[str, Any], list[tuple[float, float]]] = {}
    for job in jobs:
        res = cache.load(job)
        if res is None:
            continue
        curve = np.asarray(res["curve_return"], dtype=float)
        key = (job.config["env"], spec.value(job))
        rows.setdefault(key, []).append((float(res["train_return"]), float(np.nanmax(curve))))
    return {k: np.array(v, dtype=float).reshape(-1, 2) for k, v in rows.items()}


def schedule_effects(returns: dict[tuple[str, Any], np.ndarray], spec: StudySpec | None = None) -> dict[str, Effect]:
    """Per task with >= 2 seeds of each value of ``spec`` (default: the lr-schedule study): first - second value
    in mean final training return, Welch 95 % CI across seeds (``scipy.stats.ttest_ind``, unequal variances).

    >>> r = {("Hopper", "linear"): np.array([[3.0, 0], [5.0, 0]])}
    >>> r[("Hopper", "constant")] = np.array([[1.0, 0], [3.0, 0]])
    >>> e = schedule_effects(r)["Hopper"]
    >>> e.difference, e.n, e.within_spread
    (2.0, (2, 2), True)
    """
    from scipy.stats import ttest_ind  # local: slow to import, and the claims layer imports this module

    spec = spec or SPECS["lr-schedule"]
    first, second = spec.values
    out = {}
    for env in spec.envs:
        a, b = (returns.get((env, v), np.empty((0, 2)))[:, 0] for v in (first, second))
        if len(a) < 2 or len(b) < 2:
            continue
        test = ttest_ind(a, b, equal_var=False)
        lo, hi = test.confidence_interval(0.95)
        out[env] = Effect(env, float(a.mean() - b.mean()), (float(lo), float(hi)), float(test.pvalue), (len(a), len(b)))
    return out


def study_sensitivity(name: str, cache: RunCache | None = None) -> Sensitivity | None:
    """Study ``name`` as a protocol sensitivity, from the cached / shipped runs; ``None`` when no task has >= 2
    seeds of each value available (nothing is trained)."""
    spec = SPECS[_check(name)]
    effects = schedule_effects(final_returns(spec.jobs(), cache, spec), spec)
    if not effects:
        return None
    budgets = sorted(set(spec.envs.values()))
    return Sensitivity(
        study=name,
        setting=spec.setting,
        learner=spec.learner_label,
        budget="/".join(f"{b / 1e6:g}M" for b in budgets) + " steps",
        contrast=spec.contrast,
        measure="final training return",
        effects=tuple(effects[env] for env in spec.envs if env in effects),
    )


def lr_schedule_sensitivity(cache: RunCache | None = None) -> Sensitivity | None:
    """The lr-schedule study as a protocol sensitivity (:func:`study_sensitivity`)."""
    return study_sensitivity("lr-schedule", cache)


#: Protocol studies the claims registry may name (``sensitivity: [lr-schedule]``): name -> its result.
STUDIES: dict[str, Callable[[], Sensitivity | None]] = {
    "lr-schedule": lr_schedule_sensitivity,
    "reptile-outer-step": lambda: study_sensitivity("reptile-outer-step"),
    "maml-outer-update": lambda: study_sensitivity("maml-outer-update"),
}


def sensitivity(name: str) -> Sensitivity | None:
    """The result of the study ``name`` (:data:`STUDIES`) from the runs available, or ``None``."""
    if name not in STUDIES:
        raise ValueError(f"unknown protocol study {name!r}; valid: {', '.join(STUDIES)}")
    return STUDIES[name]()


def study_table(jobs: Sequence[Job], cache: RunCache | None = None, spec: StudySpec | None = None) -> str:
    """Markdown table: final training return (mean of the last 100 episodes) and the peak of the training
    curve, mean ± sd over the seeds per task and setting value of ``spec`` (default: the lr-schedule study),
    then each task's Welch contrast (:func:`schedule_effects`, the numbers the claims ledger reads); runs
    neither cached nor shipped are counted out."""
    spec = spec or SPECS["lr-schedule"]
    rows = final_returns(jobs, cache, spec)
    n_seeds = len(spec.seeds)
    lines = [
        f"| task (budget) | {spec.setting} | seeds | final training return | peak of the training curve |",
        "|---|---|---|---|---|",
    ]
    for env, budget in spec.envs.items():
        for v in spec.values:
            vals = rows.get((env, v), np.empty((0, 2)))
            task = f"{env} ({budget / 1e6:g}M)"
            if not len(vals):
                lines.append(f"| {task} | {spec.label(v)} | 0/{n_seeds} | not run | not run |")
                continue
            cells = [_mean_sd(vals[:, i]) for i in (0, 1)]
            lines.append(f"| {task} | {spec.label(v)} | {len(vals)}/{n_seeds} | {cells[0]} | {cells[1]} |")
    for env, e in schedule_effects(rows, spec).items():
        lo, hi = e.ci
        lines.append(
            f"\n{env}: final return {spec.contrast} = {e.difference:,.0f} (Welch 95 % CI "
            f"{lo:,.0f} to {hi:,.0f}, p = {e.pvalue:.2f}, {e.n[0]} vs {e.n[1]} seeds)"
        )
    return "\n".join(lines)


def _mean_sd(x: np.ndarray) -> str:
    """``mean ± sd`` (sample sd, ddof 1) with the values, or the single value.

    >>> _mean_sd(np.array([1.0, 3.0]))
    '2 ± 1 (1, 3)'
    """
    vals = ", ".join(f"{v:,.0f}" for v in x)
    if len(x) == 1:
        return f"{x[0]:,.0f} (1 seed)"
    return f"{x.mean():,.0f} ± {x.std(ddof=1):,.0f} ({vals})"


def produce(
    jobs: Sequence[Job], n_jobs: int = 1, ship: bool = False, commit: bool = False, spec: StudySpec | None = None
) -> None:
    """Train the jobs that are neither cached nor shipped, ``n_jobs`` at a time; export (and commit) each."""
    # local: only the generator needs runs (which imports the figure layer); the claims layer imports this module
    from thesis_repro.core.backends import die_with_parent, execute
    from thesis_repro.runs.layer import export, git_commit, wall_seconds

    spec = spec or SPECS["lr-schedule"]
    leaf = spec.path.split(".")[-1]
    cache = RunCache()
    todo = [j for j in jobs if cache.state(j) not in ("cached", "shipped")]
    print(f"{spec.name} study: {len(jobs)} runs, {len(todo)} to train, {n_jobs} at a time", flush=True)

    def land(job: Job, res) -> None:  # noqa: ANN001 - a cache Result
        setting = f"{leaf}={spec.value(job)}"
        line = f"{job.label} {setting}: train_return {res['train_return']:.1f}"
        if ship:
            ex = export(res)
            line += f", shipped {ex.megabytes:.2f} MB"
            if commit:
                msg = f"reference run: {job.label} {setting} (train, key {job.key}, "
                msg += f"{wall_seconds(res):.0f} s; {spec.name} study)"
                line += f", committed {git_commit(ex.path, msg)}"
        print(line, flush=True)

    if n_jobs <= 1:
        for job in todo:
            land(job, cache.run(job))
        return
    with ProcessPoolExecutor(
        max_workers=n_jobs, mp_context=mp.get_context("spawn"), initializer=die_with_parent
    ) as pool:
        futures = {pool.submit(execute, job, str(cache.root), True): job for job in todo}
        pending, t0 = set(futures), time.time()
        while pending:
            finished, pending = wait(pending, timeout=600, return_when=FIRST_COMPLETED)
            if not finished:
                print(f"... {len(pending)} runs left after {time.time() - t0:.0f} s", flush=True)
            for fut in finished:
                land(futures[fut], fut.result())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m thesis_repro.runs.study", description=__doc__.split("\n")[0])
    parser.add_argument("study", choices=list(SPECS))
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--ship", action="store_true", help="export each finished run into data/reference")
    parser.add_argument("--commit", action="store_true", help="git-commit each shipped run (implies --ship)")
    parser.add_argument("--summary", action="store_true", help="print the table only (no training)")
    args = parser.parse_args(argv)
    if args.jobs < 1:
        parser.error(f"--jobs must be >= 1, got {args.jobs}")
    spec = SPECS[args.study]
    jobs = spec.jobs()
    if not args.summary:
        produce(jobs, args.jobs, ship=args.ship or args.commit, commit=args.commit, spec=spec)
    print(study_table(jobs, spec=spec))
    return 0


if __name__ == "__main__":
    sys.exit(main())
