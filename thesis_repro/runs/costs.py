"""Cost plan of a figure (or the whole book) at a scale, printed before anything runs.

``python -m thesis_repro plan 3.3 --scale full [--cores N]`` (``make plan-3.3 SCALE=full``) and ``plan all``
count a figure's jobs (:func:`thesis_repro.figures.jobs`, deduplicated by key) per job kind and learner
family, their work, the throughput of each family, the core-hours and the wall time on N cores:

* **work**: env steps for ``train`` jobs (their ``timesteps``); for ``evaluate`` jobs the *upper bound*
  points × rollouts × ``max_episode_steps`` (episodes that terminate early are shorter); for the
  chapter-5 arm jobs an estimate of simulated rollouts (:func:`thesis_repro.runs.throughput.work`).
* **throughput** (units per CPU-second, one job per core, as the kit runs them): measured by ``make bench``,
  which writes ``build/bench/throughput.json``; a family it has not measured falls back to the documented
  defaults, and the plan says which one it used (:mod:`thesis_repro.runs.throughput`).
* **core-hours** = work / rate / 3600 (:func:`core_hours`); **wall time** on N cores = training phase then
  evaluation phase (the figures call ``run_jobs`` in that order), each phase scheduled longest job first on
  N cores (:func:`makespan`; never below the longest job, nor below core-hours / N).

The book total counts each run once (figures share runs by key), so it is less than the sum of the figures.

>>> core_hours(3_600_000, 1_000.0)
1.0
>>> makespan([3.0, 3.0, 2.0, 2.0, 2.0], cores=2)
7.0
"""

from __future__ import annotations

import heapq
import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from thesis_repro import figures
from thesis_repro.core import paths
from thesis_repro.core.cache import Job, RunCache
from thesis_repro.runs.needs import seed_jobs, training_seed
from thesis_repro.runs.throughput import TRAINING_KINDS, Rates, family, job_rate, load_rates, unit, work, work_left


# ---------------------------------------------------------------- arithmetic (pure)
def core_hours(units: float, rate: float) -> float:
    """CPU-core hours for ``units`` of work at ``rate`` units per CPU-second (``inf`` if the rate is unknown)."""
    return units / rate / 3600.0 if rate > 0 else float("inf")


def makespan(durations: Sequence[float], cores: int) -> float:
    """Wall time of running single-core jobs of ``durations`` on ``cores`` cores, longest first, each started
    on the core that frees up first (LPT list scheduling: within 4/3 of the optimum).

    >>> makespan([1.0] * 10, cores=4)
    3.0
    >>> makespan([5.0, 1.0, 1.0], cores=8)  # never below the longest job
    5.0
    """
    if cores < 1:
        raise ValueError(f"cores must be an integer >= 1, got {cores!r}")
    if not durations:
        return 0.0
    free = [0.0] * min(cores, len(durations))
    for d in sorted(durations, reverse=True):
        heapq.heapreplace(free, free[0] + d)
    return max(free)


# ---------------------------------------------------------------- plans
@dataclass
class Line:
    """One (kind, family) row of a plan."""

    kind: str
    family: str
    jobs: int = 0
    work: float = 0.0
    durations: list[float] = field(default_factory=list)  # core-hours of each job

    @property
    def core_hours(self) -> float:
        return sum(self.durations)

    @property
    def rate(self) -> float | None:
        """The line's effective rate (its work over its core-seconds; per-task rates make it a blend), ``None``
        without work or a finite price."""
        seconds = self.core_hours * 3600.0
        return self.work / seconds if self.work > 0 and 0 < seconds < float("inf") else None


@dataclass
class Plan:
    """Cost of a set of jobs (one figure, or the book) at one scale on ``cores`` cores."""

    name: str
    scale: str
    cores: int
    lines: list[Line]
    #: training seed -> (jobs, core-hours) of the jobs that belong to it (``None``: no training seed)
    seeds: dict[int | None, tuple[int, float]] = field(default_factory=dict)

    @property
    def training(self) -> list[Line]:
        return [ln for ln in self.lines if ln.kind in TRAINING_KINDS]

    @property
    def other(self) -> list[Line]:
        return [ln for ln in self.lines if ln.kind not in TRAINING_KINDS]

    @property
    def n_train(self) -> int:
        return sum(ln.jobs for ln in self.training)

    @property
    def n_other(self) -> int:
        return sum(ln.jobs for ln in self.other)

    @property
    def n_jobs(self) -> int:
        return self.n_train + self.n_other

    @property
    def env_steps(self) -> float:
        """Training env steps (the budget the scale table sets)."""
        return sum(ln.work for ln in self.training)

    @property
    def core_hours(self) -> float:
        return sum(ln.core_hours for ln in self.lines)

    def wall_hours(self, cores: int | None = None) -> tuple[float, float]:
        """(training phase, evaluation phase) wall hours on ``cores`` (default: the plan's)."""
        n = cores or self.cores
        train = makespan([d for ln in self.training for d in ln.durations], n)
        return train, makespan([d for ln in self.other for d in ln.durations], n)


def plan_jobs(
    name: str,
    jobs: Iterable[Job],
    scale: str,
    cores: int,
    rates: Rates | None = None,
    missing_in: RunCache | None = None,
) -> Plan:
    """:class:`Plan` of ``jobs`` (deduplicated by key), priced with ``rates`` (default :func:`load_rates`); with
    ``missing_in``, only those neither cached nor shipped in that cache (:func:`to_compute`), a training run
    interrupted there counted at its work past its newest checkpoint
    (:func:`~thesis_repro.runs.throughput.work_left`)."""
    jobs = jobs if missing_in is None else to_compute(jobs, missing_in)
    return _priced(name, jobs, scale, cores, rates or load_rates(), missing_in)


def _priced(name: str, jobs: Iterable[Job], scale: str, cores: int, rates: Rates, left: RunCache | None) -> Plan:
    """:func:`plan_jobs` of ``jobs`` already filtered: each at its work left in ``left``, or whole."""
    lines: dict[tuple[str, str], Line] = {}
    seeds: dict[int | None, tuple[int, float]] = {}
    for job in {j.key: j for j in jobs}.values():
        fam = family(job)
        ln = lines.setdefault((job.kind, fam), Line(job.kind, fam))
        w = work(job) if left is None else work_left(job, left)
        ln.jobs += 1
        ln.work += w
        ln.durations.append(core_hours(w, job_rate(job, rates)))
        n, h = seeds.get(seed := training_seed(job), (0, 0.0))
        seeds[seed] = (n + 1, h + ln.durations[-1])
    order = sorted(lines.values(), key=lambda ln: (ln.kind not in TRAINING_KINDS, ln.kind, ln.family))
    return Plan(name, scale, cores, order, dict(sorted(seeds.items(), key=lambda kv: (kv[0] is None, kv[0] or 0))))


def plan_figure(
    figure_id: str,
    scale: str,
    cores: int | None = None,
    rates: Rates | None = None,
    missing: bool = False,
    seeds: Iterable[int] | None = None,
    **overrides: Any,
) -> Plan:
    """:class:`Plan` of every job figure ``figure_id`` runs at ``scale``; ``overrides`` are settings of the
    scale table (e.g. ``envs=["Hopper"]``, ``algos=["ppo", "trpo"]`` for a subset), validated there. With
    ``missing``, only the jobs neither cached nor shipped (what running the figure now would compute); with
    ``seeds``, the jobs of those training seeds (:func:`seed_jobs`)."""
    fig = figures.get(figure_id)
    jobs = seed_jobs(figure_id, scale, seeds, **overrides)
    cores = cores or os.cpu_count() or 1
    return plan_jobs(fig.notebook_id, jobs, scale, cores, rates, RunCache() if missing else None)


def to_compute(jobs: Iterable[Job], cache: RunCache | None = None) -> list[Job]:
    """The ``jobs`` neither cached nor shipped in ``cache`` (default: the kit's): what running them now would
    compute."""
    cache = cache or RunCache()
    return [j for j in jobs if cache.state(j) not in ("cached", "shipped")]


def refuse_training(figure_id: str, scale: str, rates: Rates | None = None) -> int:
    """Before figure ``figure_id`` runs at ``scale`` without ``--train``: a ``ValueError`` naming what it would
    train and the cost when some of its training runs are neither shipped nor cached (a missing or moved shipped
    layer must not start hours of training silently); else the number of its training runs read from the local
    cache although a shipped copy exists, said on screen (0: none, or not a figure that trains)."""
    if figure_id not in figures.ids():
        return 0
    jobs = figures.training_jobs(figure_id, scale)
    cache = RunCache()
    p = plan_jobs(figure_id, jobs, scale, os.cpu_count() or 1, rates, missing_in=cache)
    if p.n_jobs:
        raise ValueError(
            f"figure {figure_id} at {scale} would train {p.n_jobs} of its {len(jobs)} runs "
            f"({p.env_steps:,.0f} env steps, {_num(p.core_hours)} core-hours): they are neither shipped in "
            f"{paths.reference()} nor cached; pass --train (make figure-{figure_id} TRAIN=1) to train them"
        )
    local = sum(cache.state(j) == "cached" and cache.shipped(j) is not None for j in jobs)
    if local:
        print(
            f"figure {figure_id}: {local} of its {len(jobs)} training runs come from the local cache "
            f"{paths.runs_dir()}, not the shipped ones (`python -m thesis_repro runs {figure_id}` lists them)"
        )
    return local


def plan_book(
    scale: str,
    cores: int | None = None,
    rates: Rates | None = None,
    missing: bool = False,
    seeds: Iterable[int] | None = None,
) -> tuple[list[Plan], Plan]:
    """One plan per figure and the book's plan (each run counted once); ``missing`` and ``seeds`` as in
    :func:`plan_figure`."""
    cores = cores or os.cpu_count() or 1
    rates = rates or load_rates()
    per = {fid: seed_jobs(fid, scale, seeds) for fid in figures.ids()}
    left = RunCache() if missing else None
    if left is not None:  # each figure's jobs checked once; the book's are their union
        per = {fid: to_compute(js, left) for fid, js in per.items()}
    plans = [_priced(figures.get(f).notebook_id, js, scale, cores, rates, left) for f, js in per.items()]
    return plans, _priced("book", (j for js in per.values() for j in js), scale, cores, rates, left)


# ---------------------------------------------------------------- printing
def _num(x: float) -> str:
    if x == float("inf"):
        return "unknown"
    return f"{x:,.0f}" if x >= 100 else f"{x:,.2g}" if x < 1 else f"{x:,.1f}"


def _hours(h: float) -> str:
    if h == float("inf"):
        return "unknown (no rate)"
    return f"{h:,.1f} h" if h < 48 else f"{h:,.0f} h ({h / 24:,.1f} days)"


def plan_summary(p: Plan) -> str:
    """The plan's one-line total: jobs, training env steps, core-hours, wall time on its cores."""
    train, other = p.wall_hours()
    return (
        f"{p.name} ({p.scale}): {p.n_train:,} training jobs ({p.env_steps:,.0f} env steps), "
        f"{p.n_other:,} evaluation and other jobs; "
        f"{_num(p.core_hours)} core-hours; wall time on {p.cores} cores: {_hours(train + other)} "
        f"(training {_hours(train)}, then evaluation {_hours(other)})"
    )


def text_table(
    rows: Sequence[Mapping[str, str]], columns: Sequence[str] = ("kind", "label", "key", "state", "path")
) -> str:
    """Plain-text table of ``rows`` (what ``python -m thesis_repro runs`` prints).

    >>> row = {"kind": "train", "label": "ppo__Hopper__s0", "key": "ab12", "state": "shipped", "path": "p"}
    >>> print(text_table([row]))
    kind   label            key   state    path
    train  ppo__Hopper__s0  ab12  shipped  p
    """
    widths = [max([len(c), *(len(str(r[c])) for r in rows)]) for c in columns]
    lines = ["  ".join(c.ljust(w) for c, w in zip(columns, widths, strict=True)).rstrip()]
    lines += ["  ".join(str(r[c]).ljust(w) for c, w in zip(columns, widths, strict=True)).rstrip() for r in rows]
    return "\n".join(lines)


def cost_report(p: Plan, rates: Rates | None = None) -> str:
    """Table of ``p``'s lines (kind, family, jobs, work, rate and its source, core-hours) and its summary."""
    rates = rates or load_rates()
    rows = [
        {
            "kind": ln.kind,
            "family": ln.family,
            "jobs": f"{ln.jobs:,}",
            "work": f"{ln.work:,.0f} {unit(ln.family)}",
            "per CPU-s": _num(ln.rate if ln.rate is not None else rates.rate(ln.family)),
            "rate from": rates.source(ln.family),
            "core-hours": _num(ln.core_hours),
        }
        for ln in p.lines
    ]
    cols = ("kind", "family", "jobs", "work", "per CPU-s", "rate from", "core-hours")
    return text_table(rows, cols) + "\n" + cost_per_seed(p) + plan_summary(p)


def cost_per_seed(p: Plan) -> str:
    """One line: jobs and core-hours per training seed (empty when the plan has no seeded job), so a run of
    several seeds can be ordered seed by seed (``reference-runs --seeds 0`` first)."""
    if not any(s is not None for s in p.seeds):
        return ""
    parts = [f"{'other' if s is None else f's{s}'}: {n:,} jobs, {_num(h)} core-hours" for s, (n, h) in p.seeds.items()]
    return "per training seed: " + "; ".join(parts) + "\n"
