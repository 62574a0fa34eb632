"""Protocol studies: measured comparisons of one training setting, across training seeds (issue 20).

``lr-schedule``: PPO with baselines ppo1's linear annealing (the thesis protocol) against a constant learning
rate and clip range, on InvertedDoublePendulum and Hopper at 1M env steps, 3 seeds each (one seed is not
enough: the same config and seed differs by ~20 % between two machines). Every run is an ordinary ``train``
job of the run cache (the annealed InvertedDoublePendulum runs ARE Fig 3.3's thesis-protocol PPO runs, same
keys), so they can be shipped and rechecked like any other.

    python -m thesis_repro.study lr-schedule [--jobs 2] [--ship] [--commit]   # train what is missing, then
    python -m thesis_repro.study lr-schedule --summary                        # the table, no training

>>> [j.config["lr_schedule"] for j in lr_schedule_jobs()][:2]
['linear', 'constant']
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

import numpy as np

from thesis_repro.cache import Job, RunCache
from thesis_repro.learners import train_config

#: The lr-schedule study: tasks with their budget, training seeds and the schedules compared.
LR_STUDY = {
    "envs": {"InvertedDoublePendulum": 1_000_000, "Hopper": 1_000_000},
    "seeds": (0, 1, 2),
    "schedules": ("linear", "constant"),
}


def lr_schedule_jobs() -> list[Job]:
    """One PPO training job per (task, seed, schedule), thesis protocol, no other override (Fig 3.3's configs)."""
    return [
        Job("train", train_config("ppo", env, seed, budget, protocol="thesis", lr_schedule=schedule))
        for env, budget in LR_STUDY["envs"].items()
        for seed in LR_STUDY["seeds"]
        for schedule in LR_STUDY["schedules"]
    ]


def summary(jobs: Sequence[Job], cache: RunCache | None = None) -> str:
    """Markdown table: final training return (mean of the last 100 episodes) and the peak of the training
    curve, mean ± sd over the seeds per task and schedule; runs neither cached nor shipped are counted out."""
    cache = cache or RunCache()
    rows: dict[tuple[str, str], list[tuple[float, float]]] = {}
    for job in jobs:
        res = cache.load(job)
        if res is None:
            continue
        curve = np.asarray(res["curve_return"], dtype=float)
        key = (job.config["env"], job.config["lr_schedule"])
        rows.setdefault(key, []).append((float(res["train_return"]), float(np.nanmax(curve))))
    n_seeds = len(LR_STUDY["seeds"])
    lines = [
        "| task (1M steps) | schedule | seeds | final training return | peak of the training curve |",
        "|---|---|---|---|---|",
    ]
    for env in LR_STUDY["envs"]:
        for schedule in LR_STUDY["schedules"]:
            vals = np.array(rows.get((env, schedule), []), dtype=float).reshape(-1, 2)
            if not len(vals):
                lines.append(f"| {env} | {schedule} | 0/{n_seeds} | not run | not run |")
                continue
            cells = [_mean_sd(vals[:, i]) for i in (0, 1)]
            lines.append(f"| {env} | {schedule} | {len(vals)}/{n_seeds} | {cells[0]} | {cells[1]} |")
    for env in LR_STUDY["envs"]:
        a, b = (np.array(rows.get((env, sch), []), dtype=float).reshape(-1, 2)[:, 0] for sch in LR_STUDY["schedules"])
        if len(a) >= 2 and len(b) >= 2:
            from scipy.stats import ttest_ind

            test = ttest_ind(a, b, equal_var=False)
            lo, hi = test.confidence_interval(0.95)
            first, second = LR_STUDY["schedules"]
            lines.append(
                f"\n{env}: final return {first} - {second} = {a.mean() - b.mean():,.0f} (Welch 95 % CI "
                f"{lo:,.0f} to {hi:,.0f}, p = {test.pvalue:.2f}, {len(a)} vs {len(b)} seeds)"
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
