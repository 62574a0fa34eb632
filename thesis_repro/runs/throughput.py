"""What a job costs: its learner family, its units of work, and each family's throughput (measured or shipped).

A job's work (:func:`work`) is env steps for training, an upper bound of env steps for an evaluation and
estimated simulated rollouts for chapter 5's arm jobs; its family (:func:`family`) names the rate that prices it.
The rates (:class:`Rates`, units per CPU-second) come from ``make bench`` (``build/bench/throughput.json``:
:func:`throughput_from_bench`, :func:`write_throughput`, :func:`load_rates`), else the documented
:data:`DEFAULT_RATES`; the generator's ETAs use the pace the shipped runs actually kept (:func:`shipped_rates`).
The cost plan (:mod:`thesis_repro.runs.costs`) adds them up.

>>> work(Job("train", {"algorithm": "ppo", "timesteps": 1000})), family(Job("train", {"algorithm": "ppo"}))
(1000.0, 'ppo')
"""

from __future__ import annotations

import json
import os
import platform
import statistics
from collections.abc import Mapping
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, NamedTuple

from thesis_repro import figures
from thesis_repro.core import paths
from thesis_repro.core.cache import Job, RunCache

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
#: the rates of ``python -m thesis_repro bench training multidomain evaluation arm`` (= ``make bench``) on the
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
    return paths.build_dir("bench") / "throughput.json"


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


def work_left(job: Job, cache: RunCache) -> float:
    """:func:`work` still to do for ``job`` in ``cache``: a training run's env steps past the newest checkpoint
    of its interrupted run (what resuming it trains), else all of its work.

    >>> work_left(Job("train", {"algorithm": "ppo", "timesteps": 1000}), RunCache(reference=False))
    1000.0
    """
    left = work(job)
    if job.kind in TRAINING_KINDS:
        from thesis_repro.learners.train import checkpoint_steps  # local: the listing stays importable without torch

        try:
            left = max(0.0, left - checkpoint_steps(cache.workdir(job)))
        except (OSError, ValueError):
            pass
    return left


def cost(job: Job) -> float:
    """Rough cost of a job for ordering: its env steps (``timesteps``), or CMA-ES evaluations, else 0."""
    c = job.config
    t = c.get("timesteps")
    if isinstance(t, int | float):
        return float(t)
    if isinstance(t, Mapping):
        return float(sum(v for v in t.values() if isinstance(v, int | float)))
    return float(c.get("generations", 0) or 0) * float(c.get("popsize", 1) or 1)


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
    """Steps (or rollouts) per CPU-second per family from the results of :func:`thesis_repro.core.bench.run_benchmarks`.

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
    doc["source"] = "make bench (python -m thesis_repro bench): units per CPU-second, one single-threaded process"
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


class _Pace(NamedTuple):
    """One shipped run's pace, as :func:`shipped_rates` weighs it."""

    pace: float
    mine: bool  # made on this machine's platform
    timed: bool  # recorded CPU time


def shipped_rates(
    root: str | Path | None = None,
    base: Rates | None = None,
    by_env: bool = False,
    machine: Mapping[str, Any] | None = None,
) -> Rates:
    """The pace the shipped training runs actually kept, per family: the median of each run's :func:`run_pace` (env
    steps per CPU-second of one run as the generator ran it, one run per core; per wall second for the runs made
    before CPU time was recorded) over the entries of ``<root>/train`` (default: the shipped layer). Families
    without a shipped run keep ``base``'s rate (default :func:`load_rates`). For an ETA of ``make reference-runs
    JOBS=2`` on a machine like the one that made them, not a benchmark: the pace of one family spans a factor ~3. With
    ``by_env``, also one rate per family and task under the key ``"<family>:<env>"`` (:func:`rate_key`), and one per
    chapter-5 arm kind (``"arm:arm-target"``: its work per wall second, ``provenance.json``'s ``wall_seconds``).

    With ``machine`` (this machine's :func:`~thesis_repro.core.provenance.platform_info`), a rate that at least
    :data:`MIN_LOCAL_RUNS` runs made on that platform give is their median alone: one CPU kept half another's pace
    on the same runs (chapter 4's Walker2d runs: Intel Xeon vs AMD EPYC), and a deadline (``--until``) must not
    start a run it cannot finish. A CPU pace comes first, though: where at least :data:`MIN_LOCAL_RUNS` runs recorded
    CPU time, their median alone (this CPU's, else every CPU's), since a wall pace reads the share of a core the run
    got, not the run (this Xeon's SAC runs, all wall-timed, read 148-456 steps per wall second; the CPU-timed ones
    on another CPU 389-575 per CPU-second). For
    the same reason a task whose runs give only a wall pace, in a family that has a CPU-timed rate, has no rate of
    its own: its jobs are priced at the family's (SAC's 160 wall steps/s on HalfCheetah against 469 per CPU-second).

    >>> r = shipped_rates(root="/nonexistent")
    >>> r.rates == load_rates().rates
    True
    """
    base = base or load_rates()
    folder = (Path(root) if root is not None else paths.reference()) / "train"
    here = json.loads(json.dumps(machine)) if machine is not None else None
    paces: dict[str, list[_Pace]] = {}
    arm = sorted(folder.parent.glob("arm-*/*")) if by_env else []  # chapter 5: work per wall second, by kind
    for entry in [*(sorted(folder.glob("*")) if folder.is_dir() else []), *arm]:
        try:
            cfg = json.loads((entry / "config.json").read_text())["config"]
            prov = json.loads((entry / "provenance.json").read_text())
            job = Job(entry.parent.name, cfg)
            trains = job.kind in TRAINING_KINDS
            pace = run_pace(prov["measured"]) if trains else work(job) / prov["wall_seconds"]
            timed = trains and bool(prov["measured"].get("steps_per_cpu_s"))
        except (OSError, ValueError, KeyError, TypeError, ZeroDivisionError):
            continue
        if pace > 0:
            keys = (family(job), rate_key(job)) if trains and by_env else (family(job),) if trains else (rate_key(job),)
            mine = here is not None and prov.get("platform") == here
            for key in keys:
                paces.setdefault(key, []).append(_Pace(pace, mine, timed))
    rates, sources = dict(base.rates), dict(base.sources)
    cpu_timed: set[str] = set()  # keys whose rate is CPU-seconds' pace
    for key, runs in paces.items():
        mine = [r for r in runs if r.mine]
        choices = (  # in order of preference: a CPU pace before a wall pace, then this CPU's runs before others'
            ([r for r in mine if r.timed], " on this CPU", ", CPU-timed"),
            ([r for r in runs if r.timed], "", ", CPU-timed"),
            (mine, " on this CPU", ""),
            (runs, "", ""),
        )
        runs, where, how = next(c for c in choices if len(c[0]) >= MIN_LOCAL_RUNS or c[0] is runs)
        if how:
            cpu_timed.add(key)
        rates[key] = float(statistics.median(r.pace for r in runs))
        sources[key] = f"{SHIPPED_PACE}{where}{how}, median of {len(runs)}"
    for key in [k for k in paces if ":" in k]:  # a task's wall pace only understates a CPU-timed family's rate
        if key not in cpu_timed and key.split(":")[0] in cpu_timed:
            del rates[key], sources[key]
    return Rates(rates, sources)


def run_pace(measured: Mapping[str, Any]) -> float:
    """A training run's pace from its ``provenance.json["measured"]``: env steps per CPU-second where it recorded
    them (``steps_per_cpu_s``), else per wall second (``steps_per_s``). The wall pace of a run that shared its core
    (with CI, a book build) reads up to 5x slow; its CPU pace does not.

    >>> run_pace({"steps_per_s": 1000.0, "steps_per_cpu_s": 4000.0}), run_pace({"steps_per_s": 1000.0})
    (4000.0, 1000.0)
    """
    return float(measured.get("steps_per_cpu_s") or measured["steps_per_s"])


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


def rates_note(rates: Rates) -> str:
    """Where the rates come from (the shipped runs' pace, the measured file, or the documented defaults)."""
    if any(s.startswith(SHIPPED_PACE) for s in rates.sources.values()):
        by_env = any(":" in k for k in rates.rates)
        local = any(s.startswith(f"{SHIPPED_PACE} on this CPU") for s in rates.sources.values())
        return (
            "rates: the shipped training runs' median pace per family (env steps per CPU-second of one run, one run "
            "per core, on the machines that made them: an ETA, not a benchmark)"
            + ("; per learner and task where shipped runs give one" if by_env else "")
            + ("; this CPU's runs alone where it made enough" if local else "")
        )
    measured = sorted(f for f, s in rates.sources.items() if s.startswith("measured"))
    if measured:
        return f"rates: {throughput_path()} ({', '.join(measured)}); defaults (throughput.DEFAULT_RATES) for the rest"
    return "rates: throughput.DEFAULT_RATES (documented defaults; run `make bench` to measure this machine's)"
