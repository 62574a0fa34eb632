"""Protocol studies: measured comparisons of one training setting, across training seeds (issue 20).

``lr-schedule``: PPO with baselines ppo1's linear annealing (the thesis protocol) against a constant learning
rate and clip range, on InvertedDoublePendulum and Hopper at 1M env steps, 3 seeds each (one seed is not
enough: the same config and seed differs by ~20 % between two machines). Every run is an ordinary ``train``
job of the run cache (the annealed InvertedDoublePendulum runs ARE Fig 3.3's thesis-protocol PPO runs, same
keys), so they can be shipped and rechecked like any other.

    python -m thesis_repro.study lr-schedule [--jobs 2] [--ship] [--commit]   # train what is missing, then
    python -m thesis_repro.study lr-schedule --summary                        # the table, no training

The claims ledger reads a study's result as a *protocol sensitivity* (:data:`STUDIES`, :func:`sensitivity`):
per task the difference of the compared settings with its Welch 95 % CI across seeds, computed from the
cached / shipped runs (never trained here; ``None`` when the runs are not available). This module imports
neither the claims layer nor the figures (the claims layer imports it).

>>> [j.config["lr_schedule"] for j in lr_schedule_jobs()][:2]
['linear', 'constant']
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass

import numpy as np

from thesis_repro.cache import Job, RunCache

#: The lr-schedule study: tasks with their budget, training seeds and the schedules compared.
LR_STUDY = {
    "envs": {"InvertedDoublePendulum": 1_000_000, "Hopper": 1_000_000},
    "seeds": (0, 1, 2),
    "schedules": ("linear", "constant"),
}


def lr_schedule_jobs() -> list[Job]:
    """One PPO training job per (task, seed, schedule), thesis protocol, no other override (Fig 3.3's configs)."""
    from thesis_repro.learners import train_config  # at call time: importing this module stays cheap (claims)

    return [
        Job("train", train_config("ppo", env, seed, budget, protocol="thesis", lr_schedule=schedule))
        for env, budget in LR_STUDY["envs"].items()
        for seed in LR_STUDY["seeds"]
        for schedule in LR_STUDY["schedules"]
    ]


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


def final_returns(jobs: Sequence[Job], cache: RunCache | None = None) -> dict[tuple[str, str], np.ndarray]:
    """Per (task, schedule): one row (final training return, peak of the training curve) per loaded seed.
    Runs neither cached nor shipped are left out (nothing is trained)."""
    cache = cache or RunCache()
    rows: dict[tuple[str, str], list[tuple[float, float]]] = {}
    for job in jobs:
        res = cache.load(job)
        if res is None:
            continue
        curve = np.asarray(res["curve_return"], dtype=float)
        key = (job.config["env"], job.config["lr_schedule"])
        rows.setdefault(key, []).append((float(res["train_return"]), float(np.nanmax(curve))))
    return {k: np.array(v, dtype=float).reshape(-1, 2) for k, v in rows.items()}


def schedule_effects(returns: dict[tuple[str, str], np.ndarray]) -> dict[str, Effect]:
    """Per task with >= 2 seeds of each schedule: first - second schedule (:data:`LR_STUDY`) in mean final
    training return, Welch 95 % CI across seeds (``scipy.stats.ttest_ind``, unequal variances).

    >>> r = {("Hopper", "linear"): np.array([[3.0, 0], [5.0, 0]])}
    >>> r[("Hopper", "constant")] = np.array([[1.0, 0], [3.0, 0]])
    >>> e = schedule_effects(r)["Hopper"]
    >>> e.difference, e.n, e.within_spread
    (2.0, (2, 2), True)
    """
    from scipy.stats import ttest_ind

    first, second = LR_STUDY["schedules"]
    out = {}
    for env in LR_STUDY["envs"]:
        a, b = (returns.get((env, sch), np.empty((0, 2)))[:, 0] for sch in (first, second))
        if len(a) < 2 or len(b) < 2:
            continue
        test = ttest_ind(a, b, equal_var=False)
        lo, hi = test.confidence_interval(0.95)
        out[env] = Effect(env, float(a.mean() - b.mean()), (float(lo), float(hi)), float(test.pvalue), (len(a), len(b)))
    return out


def lr_schedule_sensitivity(cache: RunCache | None = None) -> Sensitivity | None:
    """The lr-schedule study as a protocol sensitivity, from the cached / shipped runs; ``None`` when no task
    has >= 2 seeds of each schedule available (nothing is trained)."""
    effects = schedule_effects(final_returns(lr_schedule_jobs(), cache))
    if not effects:
        return None
    budgets = sorted(set(LR_STUDY["envs"].values()))
    first, second = LR_STUDY["schedules"]
    return Sensitivity(
        study="lr-schedule",
        setting="lr schedule",
        learner="PPO",
        budget="/".join(f"{b / 1e6:g}M" for b in budgets) + " steps",
        contrast=f"{first} - {second}",
        measure="final training return",
        effects=tuple(effects[env] for env in LR_STUDY["envs"] if env in effects),
    )


#: Protocol studies the claims registry may name (``sensitivity: [lr-schedule]``): name -> its result.
STUDIES: dict[str, Callable[[], Sensitivity | None]] = {"lr-schedule": lr_schedule_sensitivity}


def sensitivity(name: str) -> Sensitivity | None:
    """The result of the study ``name`` (:data:`STUDIES`) from the runs available, or ``None``."""
    if name not in STUDIES:
        raise ValueError(f"unknown protocol study {name!r}; valid: {', '.join(STUDIES)}")
    return STUDIES[name]()


def summary(jobs: Sequence[Job], cache: RunCache | None = None) -> str:
    """Markdown table: final training return (mean of the last 100 episodes) and the peak of the training
    curve, mean ± sd over the seeds per task and schedule, then each task's Welch contrast
    (:func:`schedule_effects`, the numbers the claims ledger reads); runs neither cached nor shipped are
    counted out."""
    rows = final_returns(jobs, cache)
    n_seeds = len(LR_STUDY["seeds"])
    lines = [
        "| task (1M steps) | schedule | seeds | final training return | peak of the training curve |",
        "|---|---|---|---|---|",
    ]
    for env in LR_STUDY["envs"]:
        for schedule in LR_STUDY["schedules"]:
            vals = rows.get((env, schedule), np.empty((0, 2)))
            if not len(vals):
                lines.append(f"| {env} | {schedule} | 0/{n_seeds} | not run | not run |")
                continue
            cells = [_mean_sd(vals[:, i]) for i in (0, 1)]
            lines.append(f"| {env} | {schedule} | {len(vals)}/{n_seeds} | {cells[0]} | {cells[1]} |")
    first, second = LR_STUDY["schedules"]
    for env, e in schedule_effects(rows).items():
        lo, hi = e.ci
        lines.append(
            f"\n{env}: final return {first} - {second} = {e.difference:,.0f} (Welch 95 % CI "
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


def produce(jobs: Sequence[Job], n_jobs: int = 1, ship: bool = False, commit: bool = False) -> None:
    """Train the jobs that are neither cached nor shipped, ``n_jobs`` at a time; export (and commit) each."""
    from thesis_repro.backends import execute
    from thesis_repro.runs import _die_with_parent, export, git_commit, wall_seconds

    cache = RunCache()
    todo = [j for j in jobs if cache.state(j) not in ("cached", "shipped")]
    print(f"lr-schedule study: {len(jobs)} runs, {len(todo)} to train, {n_jobs} at a time", flush=True)

    def land(job: Job, res) -> None:  # noqa: ANN001 - a cache Result
        line = f"{job.label} lr_schedule={job.config['lr_schedule']}: train_return {res['train_return']:.1f}"
        if ship:
            ex = export(res)
            line += f", shipped {ex.megabytes:.2f} MB"
            if commit:
                msg = f"reference run: {job.label} lr_schedule={job.config['lr_schedule']} (train, key {job.key}, "
                msg += f"{wall_seconds(res):.0f} s; lr-schedule study)"
                line += f", committed {git_commit(ex.path, msg)}"
        print(line, flush=True)

    if n_jobs <= 1:
        for job in todo:
            land(job, cache.run(job))
        return
    import multiprocessing as mp

    with ProcessPoolExecutor(
        max_workers=n_jobs, mp_context=mp.get_context("spawn"), initializer=_die_with_parent
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
    parser = argparse.ArgumentParser(prog="python -m thesis_repro.study", description=__doc__.split("\n")[0])
    parser.add_argument("study", choices=["lr-schedule"])
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--ship", action="store_true", help="export each finished run into data/reference")
    parser.add_argument("--commit", action="store_true", help="git-commit each shipped run (implies --ship)")
    parser.add_argument("--summary", action="store_true", help="print the table only (no training)")
    args = parser.parse_args(argv)
    if args.jobs < 1:
        parser.error(f"--jobs must be >= 1, got {args.jobs}")
    jobs = lr_schedule_jobs()
    if not args.summary:
        produce(jobs, args.jobs, ship=args.ship or args.commit, commit=args.commit)
    print(summary(jobs))
    return 0


if __name__ == "__main__":
    sys.exit(main())
