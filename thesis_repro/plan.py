"""Cost plan of a figure (or the whole book) at a scale, printed before anything runs.

``python -m thesis_repro plan 3.3 --scale full [--cores N]`` (``make plan-3.3 SCALE=full``) and ``plan all``
count a figure's jobs (:func:`thesis_repro.figures.jobs`, deduplicated by key) per job kind and learner
family, their work, the throughput of each family, the core-hours and the wall time on N cores:

* **work**: env steps for ``train`` jobs (their ``timesteps``); for ``evaluate`` jobs the *upper bound*
  points × rollouts × ``max_episode_steps`` (episodes that terminate early are shorter); for the
  chapter-5 arm jobs an estimate of simulated rollouts (:func:`work`).
* **throughput** (units per CPU-second, one job per core, as the kit runs them): measured by ``make bench``,
  which writes ``build/bench/throughput.json`` (:func:`throughput_from_bench`, :func:`write_throughput`);
  a family it has not measured falls back to :data:`DEFAULT_RATES`, and the plan says which one it used.
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
import json
import os
import platform
import statistics
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from thesis_repro import figures, paths
from thesis_repro.cache import Job, RunCache

#: Job kinds whose runs come first (the training phase); every other kind is the second phase.
TRAINING_KINDS: tuple[str, ...] = figures.TRAINING_KINDS
#: Unit of work of each family.
UNITS: dict[str, str] = {"evaluate": "env steps", "arm": "rollouts"}
#: Learners measured by ``make bench`` under their own name (the multi-domain line); other multi-domain
#: learners (EPOpt, MAML-DG, Reptile-DG) use ``multidomain`` = the slowest of these.
MEASURED_LEARNERS: tuple[str, ...] = ("joint", "params-avg", "kl-avg", "kl-exact")
#: Training classes (``train_config(...)["class"]``) of the multi-domain learners.
MULTIDOMAIN_CLASSES: tuple[str, ...] = ("SubPolicyAggregation", "EPOpt", "MAMLDG", "ReptileDG")
#: Fallback throughput (units per CPU-second) of each family when ``build/bench/throughput.json`` lacks it:
#: the rates of ``python -m thesis_repro.bench training multidomain evaluation arm`` (= ``make bench``) on the
#: 2-core development machine on 2026-11-24 (Hopper; evaluation: the batched evaluator; arm: vectorised
#: rollouts), measured while other training shared the machine, rounded to 3 digits. ``trpo`` was not
#: benchmarked and takes PPO's rate (same rollouts, a cheaper update); ``multidomain`` (EPOpt, MAML-DG,
#: Reptile-DG) is the slowest measured multi-domain learner.
DEFAULT_RATES: dict[str, float] = {
    "ppo": 4030.0,
    "trpo": 4030.0,
    "sac": 526.0,
    "ddpg": 1430.0,
    "joint": 2820.0,
    "params-avg": 2740.0,
    "kl-avg": 2070.0,
    "kl-exact": 1990.0,
    "multidomain": 1990.0,
    "evaluate": 5630.0,
    "arm": 11300.0,
}
#: CMA-ES population assumed for an arm job whose ``popsize`` is ``None`` (CMA's default for ~20-40 parameters).
ARM_DEFAULT_POPSIZE = 16


def throughput_path() -> Path:
    """``build/bench/throughput.json`` (under ``THESIS_REPRO_BUILD`` if set)."""
    return paths.build("bench") / "throughput.json"


# ---------------------------------------------------------------- what a job costs
def family(job: Job) -> str:
    """Learner family whose throughput prices ``job``: ``ppo | trpo | sac | ddpg | joint | params-avg | kl-avg |
    multidomain`` for training, ``evaluate``, ``arm`` (chapter 5), else the job's kind.

    >>> family(Job("evaluate", {"train": {}, "test": {}}))
    'evaluate'
    """
    cfg = job.config
    if job.kind in TRAINING_KINDS:
        algo, cls = str(cfg.get("algorithm", "")), str(cfg.get("class", ""))
        if algo in MEASURED_LEARNERS:
            return algo
        if cls in MULTIDOMAIN_CLASSES:
            return "multidomain"
        return cls.lower() or "ppo"
    if job.kind.startswith("evaluate"):
        return "evaluate"
    if job.kind.startswith("arm-"):
        return "arm"
    return job.kind


def unit(fam: str) -> str:
    """Unit of work of family ``fam`` (``env steps`` unless :data:`UNITS` says otherwise)."""
    return UNITS.get(fam, "env steps")


def _timesteps(cfg: Mapping[str, Any]) -> float:
    t = cfg.get("timesteps", 0)
    return float(sum(t.values()) if isinstance(t, Mapping) else t or 0)


def work(job: Job) -> float:
    """Units of work of ``job``: env steps (training), an upper bound of env steps (evaluation), or estimated
    simulated rollouts (arm jobs: candidates per generation × generations × tasks).

    >>> work(Job("evaluate", {"train": {}, "test": {"sigmas": [0.0, 0.5], "n_rollouts": 2, "max_episode_steps": 50}}))
    200.0
    """
    cfg = job.config
    if job.kind in TRAINING_KINDS:
        return _timesteps(cfg)
    if job.kind.startswith("evaluate"):
        test = cfg.get("test", {})
        points = len(test.get("sigmas", test.get("ratios", [])))
        return float(points * int(test.get("n_rollouts", 20)) * int(test.get("max_episode_steps", 1000)))
    pop = float(cfg.get("popsize") or ARM_DEFAULT_POPSIZE)
    if job.kind in ("arm-source", "arm-competitor-source"):
        return pop * int(cfg.get("n_tasks", 1)) * (int(cfg.get("generations", 0)) + int(cfg.get("mtl_generations", 0)))
    if job.kind == "arm-target":
        return pop * int(cfg.get("n_targets", 1)) * int(cfg.get("rounds", 1)) * int(cfg.get("phase_generations", 0))
    if job.kind == "arm-curriculum":
        return float(int(cfg.get("n_tasks", 1)) * int(cfg.get("pretrain_trials", 0)) + int(cfg.get("bic_trials", 0)))
    if job.kind == "arm-solve":
        return pop * int(cfg.get("generations", 0))
    return _timesteps(cfg)


def cost(job: Job) -> float:
    """Rough cost of a job for ordering: its env steps (``timesteps``), or CMA-ES evaluations, else 0."""
    c = job.config
    t = c.get("timesteps")
    if isinstance(t, int | float):
        return float(t)
    if isinstance(t, Mapping):
        return float(sum(v for v in t.values() if isinstance(v, int | float)))
    return float(c.get("generations", 0) or 0) * float(c.get("popsize", 1) or 1)


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


# ---------------------------------------------------------------- throughput
@dataclass(frozen=True)
class Rates:
    """Throughput per family (units per CPU-second) and where each number came from."""

    rates: dict[str, float]
    sources: dict[str, str]

    def rate(self, fam: str) -> float:
        return self.rates.get(fam, 0.0)

    def source(self, fam: str) -> str:
        return self.sources.get(fam, "unknown")


def throughput_from_bench(results: Mapping[str, Mapping[str, Any] | None]) -> dict[str, float]:
    """Steps (or rollouts) per CPU-second per family from the results of :func:`thesis_repro.bench.run`.

    >>> throughput_from_bench({"training": {"ppo kit steps/s": 900.0}, "multidomain": {"joint steps/s": 700.0}})
    {'ppo': 900.0, 'joint': 700.0, 'multidomain': 700.0}
    """
    out: dict[str, float] = {}
    training = results.get("training") or {}
    for fam in ("ppo", "sac", "ddpg"):
        if f"{fam} kit steps/s" in training:
            out[fam] = float(training[f"{fam} kit steps/s"])
    md = results.get("multidomain") or {}
    for algo in MEASURED_LEARNERS:
        if f"{algo} steps/s" in md:
            out[algo] = float(md[f"{algo} steps/s"])
    if any(a in out for a in MEASURED_LEARNERS):
        out["multidomain"] = min(out[a] for a in MEASURED_LEARNERS if a in out)
    ev = results.get("evaluation") or {}
    if "batched_steps_per_s" in ev:
        out["evaluate"] = float(ev["batched_steps_per_s"])
    arm = results.get("arm") or {}
    if "vectorised_rollouts_per_s" in arm:
        out["arm"] = float(arm["vectorised_rollouts_per_s"])
    return out


def write_throughput(results: Mapping[str, Mapping[str, Any] | None], path: str | Path | None = None) -> Path | None:
    """Merge the families measured in ``results`` into ``build/bench/throughput.json``; ``None`` if none were.

    Families measured earlier and not now are kept with their own date.
    """
    measured = throughput_from_bench(results)
    if not measured:
        return None
    path = Path(path) if path is not None else throughput_path()
    doc: dict[str, Any] = {"rates": {}}
    if path.exists():
        try:
            doc = json.loads(path.read_text())
        except ValueError:
            doc = {"rates": {}}
    stamp = {"measured": datetime.now(UTC).isoformat(timespec="seconds"), "host": platform.node()}
    for fam, rate in measured.items():
        doc["rates"][fam] = {"per_cpu_second": rate, "unit": unit(fam), **stamp}
    doc["source"] = "make bench (python -m thesis_repro.bench): units per CPU-second, one single-threaded process"
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".tmp{os.getpid()}")
    tmp.write_text(json.dumps(doc, indent=1, sort_keys=True))
    os.replace(tmp, path)
    return path


def load_rates(path: str | Path | None = None) -> Rates:
    """Measured rates from ``build/bench/throughput.json`` where present, :data:`DEFAULT_RATES` elsewhere."""
    path = Path(path) if path is not None else throughput_path()
    rates = dict(DEFAULT_RATES)
    sources = dict.fromkeys(DEFAULT_RATES, "default")
    if path.exists():
        for fam, entry in json.loads(path.read_text()).get("rates", {}).items():
            rates[fam] = float(entry["per_cpu_second"])
            sources[fam] = f"measured {str(entry.get('measured', ''))[:10]}".strip()
    if sources["trpo"] == "default" and sources["ppo"] != "default":
        rates["trpo"], sources["trpo"] = rates["ppo"], "PPO's (not benchmarked)"
    return Rates(rates, sources)


#: Where :func:`shipped_rates` labels its numbers (and :func:`rates_note` recognises them).
SHIPPED_PACE = "shipped pace"


#: :func:`shipped_rates` with a ``machine``: the fewest runs made on it whose pace replaces every machine's.
MIN_LOCAL_RUNS = 2


def shipped_rates(
    root: str | Path | None = None,
    base: Rates | None = None,
    by_env: bool = False,
    machine: Mapping[str, Any] | None = None,
) -> Rates:
    """The pace the shipped training runs actually kept, per family: the median of ``measured.steps_per_s`` (env
    steps per WALL second of one run, as the generator ran it: two runs at a time on the 2-core machine, with
    whatever else it ran) over the entries of ``<root>/train`` (default: the shipped layer). Families without a
    shipped run keep ``base``'s rate (default :func:`load_rates`). For an ETA of ``make reference-runs JOBS=2`` on
    a machine like the one that made them, not a benchmark: the pace of one family spans a factor ~3-5. With
    ``by_env``, also one rate per family and task under the key ``"<family>:<env>"`` (:func:`rate_key`), and one per
    chapter-5 arm kind (``"arm:arm-target"``: its work per wall second, ``provenance.json``'s ``wall_seconds``).

    With ``machine`` (this machine's :func:`~thesis_repro.cache.platform_info`), a rate that at least
    :data:`MIN_LOCAL_RUNS` runs made on that platform give is their median alone: one CPU kept half another's pace
    on the same runs (chapter 4's Walker2d runs: Intel Xeon vs AMD EPYC), and a deadline (``--until``) must not
    start a run it cannot finish.

    >>> r = shipped_rates(root="/nonexistent")
    >>> r.rates == load_rates().rates
    True
    """
    base = base or load_rates()
    folder = (Path(root) if root is not None else paths.reference()) / "train"
    here = json.loads(json.dumps(machine)) if machine is not None else None
    paces: dict[str, list[float]] = {}
    local: dict[str, list[float]] = {}
    arm = sorted(folder.parent.glob("arm-*/*")) if by_env else []  # chapter 5: work per wall second, by kind
    for entry in [*(sorted(folder.glob("*")) if folder.is_dir() else []), *arm]:
        try:
            cfg = json.loads((entry / "config.json").read_text())["config"]
            prov = json.loads((entry / "provenance.json").read_text())
            job = Job(entry.parent.name, cfg)
            trains = job.kind in TRAINING_KINDS
            pace = float(prov["measured"]["steps_per_s"] if trains else work(job) / prov["wall_seconds"])
        except (OSError, ValueError, KeyError, TypeError, ZeroDivisionError):
            continue
        if pace > 0:
            keys = (family(job), rate_key(job)) if trains and by_env else (family(job),) if trains else (rate_key(job),)
            for key in keys:
                paces.setdefault(key, []).append(pace)
                if here is not None and prov.get("platform") == here:
                    local.setdefault(key, []).append(pace)
    rates, sources = dict(base.rates), dict(base.sources)
    for key, values in paces.items():
        mine = local.get(key, [])
        where = " on this CPU" if len(mine) >= MIN_LOCAL_RUNS else ""
        values = mine if where else values
        rates[key] = float(statistics.median(values))
        sources[key] = f"{SHIPPED_PACE}{where}, median of {len(values)}"
    return Rates(rates, sources)


def rate_key(job: Job) -> str:
    """The key of a job's own rate in :func:`shipped_rates` (``by_env=True``): a training job's per task, a chapter-5
    arm job's per kind (their units of work differ by kind).

    >>> rate_key(Job("train", {"algorithm": "sac", "class": "SAC", "env": "Hopper"})), rate_key(Job("arm-solve", {}))
    ('sac:Hopper', 'arm:arm-solve')
    """
    if job.kind not in TRAINING_KINDS:
        return f"{family(job)}:{job.kind}"
    return f"{family(job)}:{job.config.get('env')}"


def job_rate(job: Job, rates: Rates) -> float:
    """The rate that prices ``job``: its learner family's on its task where ``rates`` has one (:func:`rate_key`,
    :func:`shipped_rates` with ``by_env``), else its family's.

    >>> sac = Job("train", {"algorithm": "sac", "class": "SAC", "env": "Hopper"})
    >>> job_rate(sac, Rates({"sac": 500.0}, {})), job_rate(sac, Rates({"sac": 500.0, "sac:Hopper": 200.0}, {}))
    (500.0, 200.0)
    """
    return rates.rate(rate_key(job)) or rates.rate(family(job))


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


def training_seed(job: Job) -> int | None:
    """The training seed a job belongs to: a training run's ``seed``, an evaluation's policy's (its ``train``
    config), ``None`` for jobs without one (chapter 5's arm jobs carry their own ``seed`` and count as theirs).

    >>> training_seed(Job("train", {"seed": 2, "timesteps": 10}))
    2
    >>> training_seed(Job("evaluate", {"train": {"seed": 1}}))
    1
    """
    cfg = job.config
    for c in (cfg, cfg.get("train") if isinstance(cfg.get("train"), Mapping) else None):
        if c is not None and isinstance(c.get("seed"), int):
            return int(c["seed"])
    return None


#: The confirmatory replication (issue 46) makes chapters 3-4 to this many training seeds...
CONFIRMATORY_SEEDS = 6
#: ... and chapter 5's CMA-ES items to this many (they cost minutes per seed).
CH5_TARGET_SEEDS = 10


def target_seeds(figure_id: str) -> int:
    """The training seeds the confirmatory replication makes ``figure_id`` to (:data:`CONFIRMATORY_SEEDS`, or
    :data:`CH5_TARGET_SEEDS` for chapter 5).

    >>> target_seeds("table-3.3"), target_seeds("5.4")
    (6, 10)
    """
    return CH5_TARGET_SEEDS if figure_id.removeprefix("table-").startswith("5.") else CONFIRMATORY_SEEDS


def seed_count(figure_id: str, scale: str, seeds: set[int] | None) -> dict[str, Any]:
    """The override that makes ``figure_id`` plan every one of ``seeds`` past the scale's own seeds (the generator's
    and the plan's ``--seeds`` may plan them; the scale table itself never changes, so a page trains none of them
    until they are shipped): a larger ``train_seeds`` count, or for chapter 5's CMA-ES items, which list their
    ``seeds``, the list with the new ones added; ``{}`` if none is needed.

    >>> seed_count("3.3", "small", {3, 4, 5}), seed_count("5.6", "small", {4})
    ({'train_seeds': 6}, {'seeds': [0, 1, 2, 4]})
    >>> seed_count("5.6", "small", {1, 2})
    {}
    """
    if not seeds:
        return {}
    settings = figures.settings(figure_id, scale)
    listed = settings.get("seeds")
    if isinstance(listed, list):  # chapter 5 (its settings carry the scale's train_seeds too, unused)
        return {"seeds": sorted(set(listed) | set(seeds))} if not set(seeds) <= set(listed) else {}
    have = settings.get("train_seeds")
    return {"train_seeds": max(seeds) + 1} if have is not None and max(seeds) + 1 > int(have) else {}


def plan_jobs(name: str, jobs: Iterable[Job], scale: str, cores: int, rates: Rates | None = None) -> Plan:
    """:class:`Plan` of ``jobs`` (deduplicated by key), priced with ``rates`` (default :func:`load_rates`)."""
    rates = rates or load_rates()
    lines: dict[tuple[str, str], Line] = {}
    seeds: dict[int | None, tuple[int, float]] = {}
    for job in {j.key: j for j in jobs}.values():
        fam = family(job)
        ln = lines.setdefault((job.kind, fam), Line(job.kind, fam))
        w = work(job)
        ln.jobs += 1
        ln.work += w
        ln.durations.append(core_hours(w, job_rate(job, rates)))
        n, h = seeds.get(seed := training_seed(job), (0, 0.0))
        seeds[seed] = (n + 1, h + ln.durations[-1])
    order = sorted(lines.values(), key=lambda ln: (ln.kind not in TRAINING_KINDS, ln.kind, ln.family))
    return Plan(name, scale, cores, order, dict(sorted(seeds.items(), key=lambda kv: (kv[0] is None, kv[0] or 0))))


def seed_jobs(figure_id: str, scale: str, seeds: Iterable[int] | None = None, **overrides: Any) -> list[Job]:
    """The jobs of figure ``figure_id`` at ``scale``; with ``seeds``, only those of these training seeds
    (:func:`training_seed`; jobs without one are kept), planned past the scale's own count as the generator's
    ``--seeds`` does (:func:`seed_count`).

    >>> len(seed_jobs("3.3", "smoke", seeds=[0, 1, 2])) == 3 * len(seed_jobs("3.3", "smoke"))
    True
    """
    if seeds is None:
        return figures.jobs(figure_id, scale, **overrides)
    keep = {int(s) for s in seeds}
    jobs = figures.jobs(figure_id, scale, **{**seed_count(figure_id, scale, keep), **overrides})
    return [j for j in jobs if training_seed(j) is None or training_seed(j) in keep]


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
    return plan_jobs(fig.notebook_id, to_compute(jobs) if missing else jobs, scale, cores or os.cpu_count() or 1, rates)


def to_compute(jobs: Iterable[Job]) -> list[Job]:
    """The ``jobs`` neither cached nor shipped: what running them now would compute."""
    cache = RunCache()
    return [j for j in jobs if cache.state(j) not in ("cached", "shipped")]


def refuse_training(figure_id: str, scale: str, rates: Rates | None = None) -> int:
    """Before figure ``figure_id`` runs at ``scale`` without ``--train``: a ``ValueError`` naming what it would
    train and the cost when some of its training runs are neither shipped nor cached (a missing or moved shipped
    layer must not start hours of training silently); else the number of its training runs read from the local
    cache although a shipped copy exists, said on screen (0: none, or not a figure that trains)."""
    if figure_id not in figures.ids():
        return 0
    jobs = figures.training_jobs(figure_id, scale)
    missing = to_compute(jobs)
    if missing:
        p = plan_jobs(figure_id, missing, scale, os.cpu_count() or 1, rates)
        raise ValueError(
            f"figure {figure_id} at {scale} would train {len(missing)} of its {len(jobs)} runs "
            f"({p.env_steps:,.0f} env steps, {_num(p.core_hours)} core-hours): they are neither shipped in "
            f"{paths.reference()} nor cached; pass --train (make figure-{figure_id} TRAIN=1) to train them"
        )
    cache = RunCache()
    local = sum(cache.state(j) == "cached" and cache.shipped(j) is not None for j in jobs)
    if local:
        print(
            f"figure {figure_id}: {local} of its {len(jobs)} training runs come from the local cache "
            f"{paths.runs()}, not the shipped ones (`python -m thesis_repro runs {figure_id}` lists them)"
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
    if missing:
        per = {fid: to_compute(js) for fid, js in per.items()}
    plans = [plan_jobs(figures.get(f).notebook_id, js, scale, cores, rates) for f, js in per.items()]
    return plans, plan_jobs("book", (j for js in per.values() for j in js), scale, cores, rates)


# ---------------------------------------------------------------- printing
def _num(x: float) -> str:
    if x == float("inf"):
        return "unknown"
    return f"{x:,.0f}" if x >= 100 else f"{x:,.2g}" if x < 1 else f"{x:,.1f}"


def _hours(h: float) -> str:
    if h == float("inf"):
        return "unknown (no rate)"
    return f"{h:,.1f} h" if h < 48 else f"{h:,.0f} h ({h / 24:,.1f} days)"


def summary(p: Plan) -> str:
    """The plan's one-line total: jobs, training env steps, core-hours, wall time on its cores."""
    train, other = p.wall_hours()
    return (
        f"{p.name} ({p.scale}): {p.n_train:,} training jobs ({p.env_steps:,.0f} env steps), "
        f"{p.n_other:,} evaluation and other jobs; "
        f"{_num(p.core_hours)} core-hours; wall time on {p.cores} cores: {_hours(train + other)} "
        f"(training {_hours(train)}, then evaluation {_hours(other)})"
    )


def table(rows: Sequence[Mapping[str, str]], columns: Sequence[str] = ("kind", "label", "key", "state", "path")) -> str:
    """Plain-text table of ``rows`` (what ``python -m thesis_repro runs`` prints).

    >>> print(table([{"kind": "train", "label": "ppo__Hopper__s0", "key": "ab12", "state": "shipped", "path": "p"}]))
    kind   label            key   state    path
    train  ppo__Hopper__s0  ab12  shipped  p
    """
    widths = [max([len(c), *(len(str(r[c])) for r in rows)]) for c in columns]
    lines = ["  ".join(c.ljust(w) for c, w in zip(columns, widths, strict=True)).rstrip()]
    lines += ["  ".join(str(r[c]).ljust(w) for c, w in zip(columns, widths, strict=True)).rstrip() for r in rows]
    return "\n".join(lines)


def report(p: Plan, rates: Rates | None = None) -> str:
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
    return table(rows, cols) + "\n" + per_seed(p) + summary(p)


def per_seed(p: Plan) -> str:
    """One line: jobs and core-hours per training seed (empty when the plan has no seeded job), so a run of
    several seeds can be ordered seed by seed (``reference-runs --seeds 0`` first)."""
    if not any(s is not None for s in p.seeds):
        return ""
    parts = [f"{'other' if s is None else f's{s}'}: {n:,} jobs, {_num(h)} core-hours" for s, (n, h) in p.seeds.items()]
    return "per training seed: " + "; ".join(parts) + "\n"


def rates_note(rates: Rates) -> str:
    """Where the rates come from (the shipped runs' pace, the measured file, or the documented defaults)."""
    if any(s.startswith(SHIPPED_PACE) for s in rates.sources.values()):
        by_env = any(":" in k for k in rates.rates)
        local = any(s.startswith(f"{SHIPPED_PACE} on this CPU") for s in rates.sources.values())
        return (
            "rates: the shipped training runs' median pace per family (env steps per wall second of one run, two "
            "runs at a time on the machine that made them: an ETA, not a benchmark; 'core-hours' are then run-hours)"
            + ("; per learner and task where shipped runs give one" if by_env else "")
            + ("; this CPU's runs alone where it made enough" if local else "")
        )
    measured = sorted(f for f, s in rates.sources.items() if s.startswith("measured"))
    if measured:
        return f"rates: {throughput_path()} ({', '.join(measured)}); defaults (plan.DEFAULT_RATES) for the rest"
    return "rates: plan.DEFAULT_RATES (documented defaults; run `make bench` to measure this machine's)"
