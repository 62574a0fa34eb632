"""The reference-run generator: ``make reference-runs SCALE=small`` fills the shipped layer.

:func:`generate` trains the training jobs of every figure (:func:`job_queue`: cheapest first, or item by item;
resumable), exports each into the layer (:func:`thesis_repro.runs.layer.export`) and optionally commits it as it lands
(:func:`~thesis_repro.runs.layer.git_commit`); with ``--until`` it starts only jobs expected to end in time
(:func:`eta_seconds`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Collection, Iterable, Mapping, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, wait
from dataclasses import dataclass, field
from datetime import datetime, timedelta
from pathlib import Path
from typing import Any

from thesis_repro import figures
from thesis_repro.core import job_kinds, paths
from thesis_repro.core.backends import backend, job_pool
from thesis_repro.core.cache import (
    Job,
    Result,
    RunCache,
    adopt_identity,
    entry_identity,
    find_entry,
    read_entry,
    same_computation,
)
from thesis_repro.core.paths import shown
from thesis_repro.core.provenance import platform_info
from thesis_repro.core.validation import check_choice, one_line
from thesis_repro.runs.layer import TARGET_BYTES, Exported, export, git_commit, wall_seconds
from thesis_repro.runs.needs import needed, training_seed
from thesis_repro.runs.throughput import Rates, cost, job_rate, shipped_rates, work_left


@dataclass
class Queued:
    """One reference run to produce: its job, the figures that use it and its estimated cost."""

    job: Job
    figures: list[str] = field(default_factory=list)

    @property
    def cost(self) -> float:
        return cost(self.job)


#: How :func:`job_queue` orders several items and seeds (``reference-runs --order``, whose ``claims`` is ``item`` with
#: the
#: items ranked by :mod:`thesis_repro.runs.order`).
ORDERS: tuple[str, ...] = ("seed-first", "item")


def job_queue(
    scale: str,
    figure_ids: Iterable[str] | None = None,
    kinds: Iterable[str] = figures.TRAINING_KINDS,
    by_figure: bool = False,
    algos: Iterable[str] | None = None,
    seeds: Iterable[int] | None = None,
    order: str = "seed-first",
    item_seeds: Mapping[str, Iterable[int]] | None = None,
) -> list[Queued]:
    """The jobs of ``kinds`` of every figure (or ``figure_ids``) at ``scale``, deduplicated by key, cheapest
    first; with ``by_figure``, the first figure's jobs first (each figure's cheapest first), so that the
    figures finish in the order given; with ``algos`` / ``seeds``, only the jobs of those learners / seeds
    (``item_seeds``: per figure id, its own seeds instead, such as chapter 5's to 10 seeds).

    Several ``seeds``, ``order="seed-first"``: the first seed given of every figure first, then the other seeds
    figure by figure, each figure's in the order given (``--seeds 0 1 2``: seed 0 everywhere; then seeds 1 and 2
    of the first figure, of the second, ...), so one resumable command completes seed 0, then one item's full
    seed count after another. ``order="item"`` (implies ``by_figure``): item by item, every requested seed of a
    figure (seed by seed, each seed's jobs cheapest first) before the next figure's, so that a page that reads
    the new seeds only once all of them are shipped gets them as early as it can; a job two figures share
    belongs to the first."""
    check_choice(order, ORDERS, "generator order")
    by_figure = by_figure or order == "item"
    seeds = None if seeds is None else [int(s) for s in seeds]
    seed_rank = {} if seeds is None else {s: i for i, s in reversed(list(enumerate(seeds)))}
    needs = needed(scale, figure_ids, kinds, algos, seeds, item_seeds)
    rank = {n.job.key: n.first if by_figure else 0 for n in needs}

    def position(p: Queued) -> tuple[Any, ...]:
        seed = training_seed(p.job) or 0
        r = seed_rank.get(seed, len(seed_rank) + seed) if seeds is not None else 0  # an item's own seeds: after
        first = () if order == "item" else (min(r, 1),)
        return (*first, rank[p.job.key], r, p.cost, p.job.kind, p.job.label, p.job.key)

    return sorted((Queued(n.job, n.figures) for n in needs), key=position)


def _bind_to_layer(
    planned: list[Queued], layer: Path, cache: RunCache, log: Callable[[str], None], count_unshipped: bool = True
) -> list[Queued]:
    """``planned`` with each job of a pinned kind bound to the shipped entries of its dependencies (the key its
    shipped copy gets, :meth:`RunCache.bind`); jobs whose dependency is not shipped, or differs in the local
    ``cache`` from the shipped one (the job would load the local one), are left out and logged (the ones not
    shipped yet as a count, unless ``count_unshipped`` is false)."""
    shipped_view = RunCache(layer, reference=False)
    out, unshipped, differ = [], 0, []
    for p in planned:
        bound = shipped_view.bind(p.job)
        if bound is None:
            unshipped += 1
            continue
        for dep in job_kinds.dependencies(bound.kind, bound.config).values():
            local, shipped = find_entry(cache.root, dep), find_entry(layer, dep)
            if local is not None and not same_computation(local, shipped):
                differ.append(shown(local))
                break
            if local is not None and entry_identity(local) != entry_identity(shipped):
                adopt_identity(local, entry_identity(shipped))  # shipped compact with an identity of its own
        else:
            out.append(Queued(bound, p.figures))
    if unshipped and count_unshipped:
        what = "/".join(sorted({p.job.kind for p in planned}))
        log(f"{unshipped} {what} jobs skipped: the run they load is not shipped (ship it first)")
    for path in differ:
        log(f"skipped: the local {path} differs from its shipped copy (remove it to evaluate the shipped one)")
    return out


def _of_kinds(planned: Iterable[Queued], kinds: Collection[str]) -> list[Queued]:
    """The jobs of ``kinds`` in ``planned``, in its order, each once."""
    out: dict[str, Queued] = {}
    for p in planned:
        if p.job.kind in kinds:
            out.setdefault(p.job.key, p)
    return list(out.values())


class _Followers:
    """Pinned jobs (evaluations) waiting for the runs they load: :meth:`ready` hands each out once, bound to the
    shipped entries of ``layer``, as soon as its every dependency is shipped (unless it is shipped itself)."""

    def __init__(
        self, planned: list[Queued], layer: Path, cache: RunCache | None, log: Callable[[str], None] = print
    ) -> None:
        self.layer, self.log = layer, log
        self.cache = RunCache(cache.root if cache is not None else None, reference=layer)  # loads shipped policies
        self.waiting = {p.job.key: p for p in planned}

    def ready(self, landed: str | None) -> list[Queued]:
        """The waiting jobs that load the run with key ``landed`` (``None``: all) and can run now, bound."""
        out = []
        for key, p in list(self.waiting.items()):
            deps = {d.key for d in job_kinds.dependencies(p.job.kind, p.job.config).values()}
            if landed is not None and landed not in deps:
                continue
            bound = _bind_to_layer([p], self.layer, self.cache, self.log, count_unshipped=False)
            if bound:
                del self.waiting[key]
                if find_entry(self.layer, bound[0].job) is None:
                    out.append(bound[0])
        return out


#: Seconds between the generator's progress lines while its runs train (checkpoints land every 100k steps).
HEARTBEAT_SECONDS = 300.0


def jobs_progress_line(
    jobs: Sequence[Job], cache: RunCache, elapsed: float, eta: Callable[[Job], float] | None = None
) -> str:
    """One line: how far each of ``jobs`` got (env steps of its newest checkpoint / its budget) and, with ``eta``
    (seconds still needed, :func:`eta_seconds`), about how long it has left.

    >>> jobs_progress_line([], RunCache(reference=False), 600.0)
    '  ... 10 min: nothing training'
    """
    from thesis_repro.learners.train import checkpoint_steps  # local: the listing stays importable without torch

    parts = []
    for job in jobs:
        try:
            steps = f"{checkpoint_steps(cache.workdir(job)):,}"
        except (OSError, ValueError):  # a kind that checkpoints otherwise
            steps = "?"
        left = eta(job) if eta is not None else math.nan
        parts.append(
            f"{job.label} {steps}/{cost(job):,.0f} steps" + (f", ~{left / 60:.0f} min left" if left < math.inf else "")
        )
    what = "training " + "; ".join(parts) + " (newest checkpoints)" if parts else "nothing training"
    return f"  ... {elapsed / 60:.0f} min: {what}"


def in_flight(submitted: Iterable[Future], pending: Collection[Future], n_jobs: int) -> list[Future]:
    """The futures of ``submitted`` (in submission order) that ``n_jobs`` pool workers are running now.

    A process pool also marks the jobs waiting in its call queue as running (up to ``n_jobs + 1`` beyond
    those its workers hold), and the workers take jobs in submission order, so the running ones are the first
    ``n_jobs`` pending futures that say so (a queued job's stale workdir, left by an earlier interrupted
    session, must not make it look running).

    >>> from concurrent.futures import Future
    >>> fs = [Future() for _ in range(4)]
    >>> for f in fs[1:]:
    ...     _ = f.set_running_or_notify_cancel()
    >>> in_flight(fs, set(fs), 2) == fs[1:3]
    True
    """
    return [f for f in submitted if f in pending and f.running()][:n_jobs]


#: ``--until``: a job starts only if this many times its expected duration (:func:`eta_seconds`) ends by then: the
#: pace of one family spans a factor ~3 on one machine.
DEADLINE_MARGIN = 1.25

#: ``--until``: how many of this command's latest trainings :func:`core_share` averages over.
SHARE_WINDOW = 4


def core_share(result: Result) -> float | None:
    """The share of a core a finished training kept in its last session (its env steps per wall second over its env
    steps per CPU-second), at most 1; ``None`` for a run that measured neither (an evaluation, an older entry).

    The shipped rates of the families the confirmatory plan trains are paces per CPU-second: a run that keeps 0.75
    of a core (a book building beside the generator) takes 1/0.75 times as long on the wall clock. A family priced at
    its wall pace (chapter 4's multi-domain learners, :func:`thesis_repro.runs.throughput.shipped_rates`) already
    carries
    the shares its runs kept, so for it the deadline errs toward starting fewer jobs.
    """
    wall, cpu = result.measured("steps_per_s"), result.measured("steps_per_cpu_s")
    try:
        share = float(wall) / float(cpu)
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    return min(1.0, share) if share > 0 and math.isfinite(share) else None


def parse_until(text: str, now: datetime | None = None) -> datetime:
    """The next local clock time ``HH:MM`` after ``now`` (today, else tomorrow): when ``--until`` stops starting jobs.

    >>> parse_until("22:40", now=datetime(2026, 11, 26, 20, 0)).isoformat()
    '2026-11-26T22:40:00'
    >>> parse_until("01:30", now=datetime(2026, 11, 26, 20, 0)).isoformat()  # past midnight: tomorrow
    '2026-11-27T01:30:00'
    >>> parse_until("soon")
    Traceback (most recent call last):
    ValueError: --until takes a clock time HH:MM (such as 22:40), got 'soon'
    """
    try:
        clock = datetime.strptime(text, "%H:%M").time()
    except (TypeError, ValueError):
        raise ValueError(f"--until takes a clock time HH:MM (such as 22:40), got {text!r}") from None
    now = now or datetime.now()
    at = datetime.combine(now.date(), clock)
    return at if at > now else at + timedelta(days=1)


def eta_seconds(job: Job, cache: RunCache, rates: Rates) -> float:
    """Wall seconds ``job`` is expected to still take: its work past its newest checkpoint (a resumed run) at its
    rate in ``rates`` (units per second, :func:`thesis_repro.runs.throughput.job_rate`: its learner's on its task where
    ``rates`` has one, else its family's); ``inf`` for a family without a rate.

    >>> ppo = Job("train", {"algorithm": "ppo", "env": "Hopper", "timesteps": 1000})
    >>> eta_seconds(ppo, RunCache(reference=False), Rates({"ppo": 100.0}, {}))
    10.0
    >>> eta_seconds(ppo, RunCache(reference=False), Rates({"ppo": 100.0, "ppo:Hopper": 50.0}, {}))
    20.0
    """
    rate = job_rate(job, rates)
    return work_left(job, cache) / rate if rate > 0 else math.inf


def _default_eta(cache: RunCache) -> Callable[[Job], float]:
    """:func:`eta_seconds` at the pace the shipped runs kept, per learner family and task, on this CPU where it made
    enough of them (read once, when a deadline first asks)."""
    rates: list[Rates] = []

    def eta(job: Job) -> float:
        if not rates:
            rates.append(shipped_rates(by_env=True, machine=platform_info()))
        return eta_seconds(job, cache, rates[0])

    return eta


class _Deadline:
    """The generator's queue of jobs to start, in order; with a deadline (``until``), :meth:`take` hands out the
    first job expected to end by then (:data:`DEADLINE_MARGIN` x ``eta`` seconds from now, over the share of a core
    this command's latest trainings kept, :meth:`observe`) and ``None`` once none fits."""

    def __init__(
        self, todo: Sequence[Queued], until: datetime | None, eta: Callable[[Job], float], log: Callable[[str], None]
    ) -> None:
        self.queue, self.until, self.eta, self.log = list(todo), until, eta, log
        self.shares: list[float] = []
        if until is not None:
            log(f"--until {until:%Y-%m-%d %H:%M}: starting only jobs expected to end by then")

    def observe(self, result: Result) -> None:
        """Note the share of a core a landed training kept (:func:`core_share`)."""
        share = core_share(result)
        if share is not None:
            self.shares = [*self.shares, share][-SHARE_WINDOW:]

    @property
    def share(self) -> float:
        """The mean share of a core of the latest :data:`SHARE_WINDOW` trainings landed, 1 before any has."""
        return sum(self.shares) / len(self.shares) if self.shares else 1.0

    def take(self) -> Queued | None:
        if not self.queue:
            return None
        if self.until is None:
            return self.queue.pop(0)
        left = (self.until - datetime.now()).total_seconds()
        for i, p in enumerate(self.queue):
            need = self.eta(p.job) / self.share
            if DEADLINE_MARGIN * need <= left:
                if i:
                    self.log(f"  --until: {i} longer job(s) wait; starting {p.job.label} (~{need / 60:.0f} min)")
                return self.queue.pop(i)
        return None

    def report(self) -> None:
        """Log what the deadline left for the next run of the same command."""
        if self.until is not None and self.queue:
            self.log(
                f"--until {self.until:%H:%M}: {len(self.queue)} job(s) left, none expected to end in time; "
                "run the same command again to continue"
            )


def generate(
    scale: str = "small",
    figure_ids: Iterable[str] | None = None,
    kinds: Iterable[str] = figures.TRAINING_KINDS,
    commit: bool = False,
    n_jobs: int = 1,
    layer_root: str | Path | None = None,
    cache: RunCache | None = None,
    log: Callable[[str], None] = print,
    heartbeat: float = HEARTBEAT_SECONDS,
    algos: Iterable[str] | None = None,
    seeds: Iterable[int] | None = None,
    until: datetime | None = None,
    eta: Callable[[Job], float] | None = None,
    order: str = "seed-first",
    item_seeds: Mapping[str, Iterable[int]] | None = None,
    jobs: Sequence[Queued] | None = None,
) -> list[Exported]:
    """Produce the shipped reference runs of ``scale`` (``make reference-runs``).

    Collects the jobs of ``kinds`` of every figure (:func:`job_queue`: deduplicated, cheapest first; with
    ``figure_ids``,
    figure by figure in that order; ``order="item"``: every requested seed of an item before the next item;
    ``item_seeds``: an item's own seeds), skips those already
    shipped with a verified entry, runs the rest through the local cache ``n_jobs`` at a time, in local worker
    processes or as Ray tasks (``THESIS_REPRO_BACKEND=ray``: :func:`~thesis_repro.core.backends.job_pool`; an
    interrupted run resumes from its workdir checkpoint on the next call), exports each finished one into
    the layer and, with ``commit``, commits it as it lands; every ``heartbeat`` seconds without one landing it
    logs a :func:`jobs_progress_line`. Returns the exported runs.

    A job of a pinned kind (an evaluation, ``--kind evaluate``) is keyed by the shipped entries of its
    dependencies (the training run it evaluates), so a fresh clone finds it: it is computed against the shipped
    policy and skipped while that policy is not shipped, or while the local cache holds another version of it.
    With training and pinned kinds together (``--kind train evaluate``), each pinned job runs in this process
    as soon as the last run it loads is shipped (:class:`_Followers`), so an item's evaluations land with its
    last training run.

    With ``until`` (``--until 22:40``), a job starts only while it is expected to finish by then (``eta``, default
    :func:`eta_seconds`: the work left past its checkpoint at the shipped runs' pace, over the share of a core this
    command's latest trainings kept, :func:`core_share`): at the end of a session the
    generator takes the next job that fits instead of one that would be cut off, and stops starting jobs when none
    fits (an interrupted run resumes only on the machine that holds its checkpoints; a new one starts it again).

    ``jobs`` replaces the figures' jobs by a list made elsewhere, in its own order (a study's,
    :func:`thesis_repro.runs.budget_study.ordered`): its jobs of ``kinds`` are made as the figures' would be.
    """
    layer = Path(layer_root) if layer_root is not None else paths.reference()
    kinds = tuple(check_choice(k, sorted(job_kinds.KINDS), "job kind") for k in kinds)
    pinned_kinds = tuple(k for k in kinds if job_kinds.pins_dependencies(k))
    if pinned_kinds and len(pinned_kinds) < len(kinds):  # training and evaluation in one command: they follow
        kinds = tuple(k for k in kinds if k not in pinned_kinds)
        only = {"algos": algos, "seeds": seeds, "order": order, "item_seeds": item_seeds}
        waiting = (
            _of_kinds(jobs, pinned_kinds) if jobs is not None else job_queue(scale, figure_ids, pinned_kinds, **only)
        )
        followers = _Followers(waiting, layer, cache, log)
    else:
        followers = None
    pinned = any(job_kinds.pins_dependencies(k) for k in kinds)
    cache = cache or RunCache(reference=layer if pinned else False)  # evaluations load the shipped policies
    by_figure = figure_ids is not None
    if jobs is not None:
        planned = _of_kinds(jobs, kinds)
    else:
        planned = job_queue(scale, figure_ids, kinds, by_figure, algos, seeds, order, item_seeds)
    if pinned:
        planned = _bind_to_layer(planned, layer, cache, log)
    todo, shipped = [], 0
    for p in planned:
        where = find_entry(layer, p.job)
        if where is not None:
            try:
                read_entry(where)
            except Exception as err:  # noqa: BLE001
                log(f"shipped run {shown(where)} is corrupt ({err}); regenerating it")
            else:
                shipped += 1
                continue
        todo.append(p)
    total = sum(p.cost for p in todo)
    log(
        f"reference runs ({scale}): {len(planned)} {'/'.join(kinds)} jobs, {shipped} already shipped, "
        f"{len(todo)} to produce ({total:,.0f} env steps in all) -> {shown(layer)}"
    )
    done: list[Exported] = []

    def land(i: int, p: Queued, result: Result) -> None:
        ex = export(result, layer)
        wall = wall_seconds(result)
        note = "" if ex.bytes <= TARGET_BYTES else f" (over the {TARGET_BYTES / 1e6:.0f} MB target)"
        tag = f"[{i}/{len(todo)}]" if i else "[follows]"
        line = f"{tag} {p.job.kind} {p.job.label}: {wall:.0f} s, shipped {ex.megabytes:.2f} MB{note}"
        if commit:
            msg = f"reference run: {p.job.label} ({p.job.kind}, key {p.job.key}, {wall:.0f} s)"
            line += f", committed {git_commit(ex.path, msg)}"
        log(line + f" -> {shown(ex.path)}")
        done.append(ex)
        queue.observe(result)
        if followers is not None and not job_kinds.pins_dependencies(p.job.kind):
            follow(followers.ready(p.job.key))

    failed: list[str] = []

    def follow(ready: list[Queued]) -> None:
        for q in ready:  # in this process, single-threaded (RunCache.compute), beside the pool's workers
            try:
                result = followers.cache.run(q.job)
            except Exception as err:  # noqa: BLE001 - one evaluation must not stop the trainings in flight
                log(f"[follows] {q.job.kind} {q.job.label} FAILED, left for the next run: {one_line(err, 300)}")
                failed.append(q.job.label)
                continue
            land(0, q, result)

    def follow_shipped() -> None:  # the evaluations of the runs shipped before this command
        if followers is not None:
            follow(followers.ready(None))

    queue = _Deadline(todo, until, eta or _default_eta(cache), log)
    if backend() == "local" and (n_jobs <= 1 or len(todo) <= 1):
        follow_shipped()
        i = 0
        while (p := queue.take()) is not None:
            i += 1
            state, used_by = cache.state(p.job), ", ".join(p.figures)
            log(f"[{i}/{len(todo)}] {p.job.kind} {p.job.label} ({p.cost:,.0f} steps; {state}) for {used_by}")
            land(i, p, cache.run(p.job))
    else:
        with job_pool(n_jobs, cache) as pool:  # local worker processes, or Ray tasks (THESIS_REPRO_BACKEND=ray)
            futures: dict[Future, Queued] = {}
            pending: set[Future] = set()

            def submit() -> None:  # keep n_jobs in flight, each the next job the deadline allows
                while len(pending) < n_jobs and (p := queue.take()) is not None:
                    fut = pool.submit(p.job)
                    futures[fut] = p
                    pending.add(fut)

            how = "figure by figure, each cheapest first" if figure_ids is not None else "cheapest first"
            how = "item by item, every seed of an item before the next" if order == "item" else how
            how = "in the study's order" if jobs is not None else how
            t0, landed = time.time(), 0  # the pool's jobs landed so far (``done`` also holds the evaluations)
            try:  # from here on, Ctrl-C ends the workers (outside it, leaving the pool would wait for every run)
                log(f"running {len(todo)} jobs, {n_jobs} at a time ({how})")
                submit()
                follow_shipped()  # while the workers train
                while pending:
                    finished, pending = wait(pending, timeout=heartbeat, return_when=FIRST_COMPLETED)
                    started = [futures[f].job for f in in_flight(futures, pending, n_jobs)]
                    running = [j for j in started if cache.workdir(j).exists()]  # workers still importing: none
                    if not finished and running:
                        log(jobs_progress_line(running, cache, time.time() - t0, queue.eta))
                    for fut in finished:
                        landed += 1
                        land(landed, futures[fut], fut.result())
                    submit()
            except KeyboardInterrupt:  # Ctrl-C: stop now (the interrupted runs resume from their checkpoints)
                pool.stop()
                raise
    queue.report()
    if failed:
        log(f"{len(failed)} evaluation(s) failed and were left for the next run: {', '.join(failed)}")
    return done
