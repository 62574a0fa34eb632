"""The thesis-budget study: Fig 3.3's variants at the thesis's own training budget, evaluated along the way.

Every verdict of the book is measured at ``small``'s budgets (2M env steps for the PPO family and TRPO on the
locomotion tasks, 1M for SAC and DDPG), the thesis trained for 4e6 (Appendix A). The study trains Fig 3.3's nine
variants on Walker2d, HalfCheetah and Hopper, training seeds 0-3, for the thesis's budget from scratch (the PPO
family anneals its learning rate to its own budget), with everything else at the scale's Fig 3.3 settings
(rollouts, σ grid, test types, protocol): the budget is the only change. Each run saves a compact policy snapshot
after each of ``evaluate_at`` env steps (``snapshot_at``: policy and observation filter, never optimiser state),
and every test of Fig 3.3 evaluates each snapshot and the final policy. The settings are the scale table's hidden
entry ``_thesis-budget`` (:data:`SETTINGS_ID`); the study's runs have keys of their own, so no page trains them
and no existing run's key changes.

* :func:`train_jobs` / :func:`budget_eval_jobs` / :func:`budget_jobs`: the study's job list; :func:`points`: the
  budgets it evaluates (env steps, and the snapshot each reads); :func:`benchmark_at`: the Fig 3.3 grid at one of
  them, for the pages and the claims layer.
* :func:`ordered`: the generator's order: the two Pareto panels' tasks first, then the others; within a task,
  the items that read its runs (Fig 3.3, Tables 3.4 and 3.6) ranked by claims settled per core-hour
  (:func:`thesis_repro.runs.order.rank`), each item's runs cheapest first, then by seed; every run is still trained
  to the full budget.
* :func:`budget_points` / :func:`points_at`: Fig 3.3's per-seed points at each budget from the runs made so far (read
  from the cache and the shipped layer only: nothing trains), with ``k of n runs``; :func:`r_by_budget`: r against
  training budget per cell and pooled; :func:`claims_meta` / :func:`page_meta`: what Fig 3.3's and Tables 3.4 and
  3.6's pages hand the claims layer (:mod:`thesis_repro.claims.thesis_budget` judges the 4M numbers).
* :func:`budget_schedule` and :func:`prefix_checks`: where a learner has no budget-dependent schedule (SAC,
  DDPG and TRPO as configured), the snapshot at the ``small`` budget is the shipped ``small`` run of the same
  seed, bit for bit (``python -m thesis_repro verify --study thesis-budget``).

``python -m thesis_repro plan thesis-budget [--missing] [--rates shipped]`` prices it;
``make thesis-budget UNTIL=HH:MM`` (``reference-runs --study thesis-budget``) makes it, resumably.

>>> [j.label for j in train_jobs("smoke")]
['ppo__Hopper__s0', 'sac__Hopper__s0']
>>> [(p.steps, p.snapshot) for p in points(train_jobs("smoke")[0].config)]
[(128, 128), (256, None)]
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from thesis_repro import figures
from thesis_repro.core import job_kinds, paths, scales
from thesis_repro.core.cache import Job, Result, RunCache
from thesis_repro.core.validation import check_choice
from thesis_repro.evaluation import Benchmark, auc, benchmark_jobs, expected_return
from thesis_repro.figures.ch3 import (
    BUDGET_POINTS,
    budget_correlations,
    budget_summary,
    learner_timesteps,
    timesteps_for,
    training_return_at,
    variants,
)
from thesis_repro.learners.config import rollout_steps, snapshot_at_steps, train_config
from thesis_repro.runs.costs import core_hours
from thesis_repro.runs.generator import Queued
from thesis_repro.runs.order import Claim, Item, rank
from thesis_repro.runs.throughput import Rates, job_rate, work

#: The study's name on the command line (``plan thesis-budget``, ``reference-runs --study thesis-budget``).
NAME = "thesis-budget"
#: Every study of this kind, by name (one today).
STUDIES: tuple[str, ...] = (NAME,)
#: Its entry in the scale table (hidden: not a figure).
SETTINGS_ID = "_thesis-budget"
#: The items whose pages read the study's runs: Fig 3.3 (its cells, the Pareto panels) and the tables that read
#: the same learners on the same tasks.
ITEMS: tuple[str, ...] = ("3.3", "table-3.4", "table-3.6")
#: The first version of the claims design the study may be judged under: it is frozen before the first run.
DESIGN_VERSION = 3


def check_study(name: str) -> str:
    """``name`` if it names a study, else a ``ValueError`` listing them.

    >>> check_study("thesis-budgets")
    Traceback (most recent call last):
    ...
    ValueError: unknown budget study 'thesis-budgets'; valid budget studies are: 'thesis-budget'
    """
    return check_choice(name, STUDIES, "budget study")


def budget_settings(scale: str) -> dict[str, Any]:
    """The study's resolved settings at ``scale`` (the scale table's :data:`SETTINGS_ID` entry)."""
    return scales.figure_settings(SETTINGS_ID, scale)


def task_order(s: Mapping[str, Any]) -> list[str]:
    """The study's tasks in the generator's order: the Pareto panels' tasks (Fig 3.3's ``panels``) first, in panel
    order, then the others as listed.

    >>> panels = [["Walker2d", "act"], ["HalfCheetah", "obs"]]
    >>> task_order({"envs": ["Hopper", "HalfCheetah", "Walker2d"], "panels": panels})
    ['Walker2d', 'HalfCheetah', 'Hopper']
    """
    envs = list(s["envs"])
    first = [t for t, _ in s.get("panels") or () if t in envs]
    return list(dict.fromkeys([*first, *envs]))


def train_config_of(s: Mapping[str, Any], algo: str, env: str, seed: int) -> dict[str, Any]:
    """One run's training config: Fig 3.3's at the scale (protocol, overrides) with the study's budget and
    snapshots; a learner's ``algo_overrides`` replace ``train_overrides`` (the smoke block's off-policy settings)."""
    per = dict(s.get("algo_overrides") or {})
    overrides = dict(per[algo] if algo in per else s.get("train_overrides") or {})
    return train_config(
        algo,
        env,
        int(seed),
        int(s["timesteps"]),
        protocol=s["protocol"],
        snapshot_at=[int(t) for t in s["evaluate_at"]],
        **overrides,
    )


def train_jobs(scale: str) -> list[Job]:
    """The study's training jobs, in (task :func:`task_order`, learner, seed) order."""
    s = budget_settings(scale)
    seeds = range(int(s["train_seeds"]))
    return [Job("train", train_config_of(s, a, e, sd)) for e in task_order(s) for a in variants(s) for sd in seeds]


@dataclass(frozen=True)
class Point:
    """A budget at which the study evaluates a run: ``steps`` (env steps trained) and the ``snapshot`` that holds
    its policy (``None``: the run's final policy)."""

    steps: int
    snapshot: int | None


def points(cfg: Mapping[str, Any]) -> list[Point]:
    """The budgets at which a study run is evaluated: each snapshot (:func:`snapshot_at_steps`), then the final
    policy at the env steps the run ends at."""
    every = rollout_steps(cfg)
    done = -(-int(cfg["timesteps"]) // every) * every
    return [*(Point(t, t) for t in snapshot_at_steps(cfg)), Point(done, None)]


def _tests(s: Mapping[str, Any]) -> Benchmark:
    """A one-run benchmark grid whose test blocks are the study's (Fig 3.3's tests at the scale)."""
    algo, env = variants(s)[0], task_order(s)[0]
    return benchmark_jobs(
        [algo],
        [env],
        [0],
        int(s["timesteps"]),
        s["tests"],
        sigmas=s["sigmas"],
        n_rollouts=int(s["test_rollouts"]),
        max_episode_steps=int(s["max_episode_steps"]),
        train_overrides={"protocol": s["protocol"]},
    )


def budget_eval_jobs(scale: str, train: Iterable[Job] | None = None) -> list[Job]:
    """One evaluation job per study run (or per job of ``train``), test and :func:`points` entry, in run order."""
    s = budget_settings(scale)
    blocks = _tests(s).tests
    out = []
    for job in train if train is not None else train_jobs(scale):
        for p in points(job.config):
            for block in blocks.values():
                test = dict(block) if p.snapshot is None else {**block, "snapshot": p.snapshot}
                out.append(Job("evaluate", {"train": dict(job.config), "test": test}))
    return out


def budget_jobs(scale: str) -> list[Job]:
    """Every job of the study: the training runs, then their evaluations."""
    train = train_jobs(scale)
    return [*train, *budget_eval_jobs(scale, train)]


def benchmark_at(scale: str, steps: int) -> Benchmark:
    """The study's Fig 3.3 grid (learners x tasks x seeds, every test) evaluated at the budget point ``steps``
    (one of the :func:`points`' ``steps`` of the runs; for the PPO family and TRPO the first iteration boundary at
    or after the requested budget), as a :class:`~thesis_repro.evaluation.Benchmark`. Its ``run()`` reports each
    run's final training return; the return at ``steps`` is :func:`thesis_repro.figures.ch3.training_return_at`."""
    s = budget_settings(scale)
    algos, envs, seeds = variants(s), task_order(s), list(range(int(s["train_seeds"])))
    blocks = _tests(s).tests
    cfgs = [train_config_of(s, a, e, sd) for sd in seeds for e in envs for a in algos]
    wanted = []
    for cfg in cfgs:
        at = [p for p in points(cfg) if p.steps >= steps]
        if not at:
            raise ValueError(f"{NAME}: no point at {steps:,} env steps; the runs end at {points(cfg)[-1].steps:,}")
        wanted.append(at[0])
    evals = {
        name: [
            Job("evaluate", {"train": c, "test": block if p.snapshot is None else {**block, "snapshot": p.snapshot}})
            for c, p in zip(cfgs, wanted, strict=True)
        ]
        for name, block in blocks.items()
    }
    return Benchmark(algos, envs, seeds, blocks, [Job("train", c) for c in cfgs], evals)


def budgets(scale: str) -> list[int]:
    """The budgets (env steps) the study evaluates at: ``evaluate_at`` and the run's budget.

    >>> budgets("small")
    [1000000, 2000000, 3000000, 4000000]
    """
    s = budget_settings(scale)
    return [*(int(t) for t in s["evaluate_at"]), int(s["timesteps"])]


# ---------------------------------------------------------------- the generator's order
def item_learners(figure_id: str, scale: str) -> set[str]:
    """The learners item ``figure_id`` shows at ``scale`` (its scale-table variants)."""
    return set(variants(figures.settings(figure_id, scale)))


def ordered(
    scale: str, rates: Rates, claims: Sequence[Claim] = (), kinds: Iterable[str] = ("train", "evaluate")
) -> list[Queued]:
    """The study's jobs of ``kinds`` in the generator's order: task by task (:func:`task_order`: the Pareto
    panels' tasks first); within a task, the :data:`ITEMS` that read its runs ranked by the ``claims`` each settles
    at the study's seeds per core-hour (:func:`thesis_repro.runs.order.rank`, costs priced with ``rates``; without
    claims: cheapest item first), each item's runs not yet placed cheapest first, then by seed; each run's
    evaluations right after it. The order decides only what runs first: every job is in the list."""
    kinds = set(kinds)
    s = budget_settings(scale)
    train = train_jobs(scale)
    evals: dict[str, list[Job]] = {}
    for e in budget_eval_jobs(scale, train):
        evals.setdefault(Job("train", e.config["train"]).key, []).append(e)
    price = {j.key: core_hours(work(j), job_rate(j, rates)) for j in train}
    target = int(s["train_seeds"])
    out: list[Queued] = []
    for env in task_order(s):
        on_task = [j for j in train if j.config["env"] == env]
        items = [
            Item(f, target, {j.key: price[j.key] for j in on_task if j.config["algorithm"] in item_learners(f, scale)})
            for f in ITEMS
        ]
        placed: set[str] = set()
        for r in rank(items, claims):
            runs = [j for j in on_task if j.key not in placed and j.config["algorithm"] in item_learners(r.item, scale)]
            for j in sorted(runs, key=lambda j: (price[j.key], j.config["seed"], j.label)):
                placed.add(j.key)
                if "train" in kinds:
                    out.append(Queued(j, [NAME]))
                if "evaluate" in kinds:
                    out.extend(Queued(e, [NAME]) for e in evals.get(j.key, []))
    return out


def study_keys(scale: str, layer_root: str | Path | None = None) -> set[str]:
    """The keys of the study's jobs at ``scale``: training runs, and evaluations unbound and bound to the shipped
    runs they evaluate (the keys their shipped copies have), so ``runs --check`` counts them as current."""
    view = RunCache(layer_root if layer_root is not None else paths.reference(), reference=False)
    keys = set()
    for j in budget_jobs(scale):
        keys.add(j.key)
        if job_kinds.pins_dependencies(j.kind) and (bound := view.bind(j)) is not None:
            keys.add(bound.key)
    return keys


def check_design(frozen: Mapping[str, str], required: int = DESIGN_VERSION) -> None:
    """A ``ValueError`` unless the frozen claims design (:func:`thesis_repro.core.provenance.claims_design`) is version
    ``required`` or later: the study is judged under a design frozen before its first run.

    >>> check_design({"version": "v3", "hash": "ab"})
    >>> check_design({"version": "v2", "hash": "ab"})  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    ValueError: the thesis-budget study is judged under claims design v3 or later, ...: freeze v3 first
    """
    text = str(frozen.get("version") or "")
    try:
        version = int(text.lstrip("v"))
    except ValueError:
        version = -1
    if version < required:
        raise ValueError(
            f"the {NAME} study is judged under claims design v{required} or later, frozen before its first run; the "
            f"frozen design is {text or 'none'} (data/thesis/claims-design.json): freeze v{required} first"
        )


# ---------------------------------------------------------------- the free integrity check
def budget_schedule(cfg: Mapping[str, Any]) -> str | None:
    """Why a training config's updates depend on its budget, ``None`` if they do not: the PPO family's
    ``lr_schedule: linear`` anneals the learning rate and clip range to the run's own budget; a learning rate,
    clip range or entropy schedule given as an SB3 schedule string would too. SAC, DDPG and TRPO as configured
    (constant rates, fixed entropy coefficient, no schedule) have none.

    >>> budget_schedule(train_config("ppo", "Hopper", 0, 1000))
    'lr_schedule linear: the learning rate and clip range anneal to the run budget'
    >>> [budget_schedule(train_config(a, "Hopper", 0, 1000)) for a in ("sac", "ddpg", "trpo")]
    [None, None, None]
    """
    if cfg.get("lr_schedule", "constant") != "constant":
        return f"lr_schedule {cfg['lr_schedule']}: the learning rate and clip range anneal to the run budget"
    for key in ("learning_rate", "clip_range", "clip_range_vf", "ent_coef"):
        value = cfg["sb3"].get(key)
        if isinstance(value, str) and value.startswith(("lin_", "linear")):
            return f"sb3.{key} {value}: a schedule over the run budget"
    return None


def twin_budget(cfg: Mapping[str, Any], scale: str = "small") -> int:
    """The budget of the Fig 3.3 run at ``scale`` of a study run's learner and task (its ``algo_timesteps``)."""
    return timesteps_for(learner_timesteps(figures.settings("3.3", scale), cfg["algorithm"]), cfg["env"])


def small_twin(cfg: Mapping[str, Any], budget: int) -> dict[str, Any]:
    """The config of the run a study run shares its first ``budget`` env steps with: the same learner, task, seed
    and settings at that budget, without snapshots (for ``budget`` = :func:`twin_budget`, Fig 3.3's run)."""
    twin = {**{k: v for k, v in cfg.items() if k != "snapshot_at"}, "timesteps": int(budget)}
    return json.loads(json.dumps(twin))


@dataclass(frozen=True)
class PrefixCheck:
    """One study run against its ``small`` twin: ``status`` is ``identical``, ``DIFFERENT``, or why it was not
    compared (``budget-dependent``, ``not made``, ``no snapshot``, ``other platform``); ``detail`` says more."""

    label: str
    status: str
    detail: str

    @property
    def failed(self) -> bool:
        return self.status == "DIFFERENT"


def _episodes(res: Result, up_to: int) -> np.ndarray:
    t = np.asarray(res["episode_timesteps"])
    keep = t <= up_to
    return np.stack([t[keep], np.asarray(res["episode_returns"])[keep], np.asarray(res["episode_lengths"])[keep]])


def prefix_check(job: Job, cache: RunCache, budget: int) -> PrefixCheck:
    """Is study run ``job``'s snapshot at the ``small`` budget the shipped (or cached) ``small`` run of the same
    seed (:func:`small_twin` at ``budget``), bit for bit (policy weights, observation filter, every training episode
    up to then)? Only for learners
    without a budget-dependent schedule (:func:`budget_schedule`) and runs made on the platform and in the
    numerics of the twin (:func:`thesis_repro.core.provenance.same_making`; pinned numerics agree on any x86-64
    CPU, so a run made on another CPU than this one is checked too)."""
    from thesis_repro import NUMERICS_ENV
    from thesis_repro.core.provenance import numerics_env, same_making
    from thesis_repro.runs.retrain_check import max_abs_diff

    why = budget_schedule(job.config)
    if why is not None:
        return PrefixCheck(job.label, "budget-dependent", why)
    twin_job = Job("train", small_twin(job.config, budget))
    twin, run = cache.load(twin_job), cache.load(job)
    if twin is None or run is None:
        which = "study run" if run is None else f"small run {twin_job.label} ({twin_job.key})"
        return PrefixCheck(job.label, "not made", f"the {which} is neither cached nor shipped")
    done = int(twin["timesteps_done"])
    snap = Path(run.path) / "out" / "snapshots" / f"step_{done:09d}"
    if not (snap / "policy.pth").exists():
        return PrefixCheck(job.label, "no snapshot", f"no snapshot at {done:,} env steps in {run.path}")
    if same_making(twin, run) is False:
        made = {numerics_env(r)[NUMERICS_ENV] for r in (twin, run)}
        why = "in other numerics than its twin" if len(made) > 1 else "natively, on another platform than its twin"
        return PrefixCheck(job.label, "other platform", f"made {why}: not comparable bit for bit")
    diff = max_abs_diff(twin, snap)
    a, b = _episodes(twin, done), _episodes(run, done)
    same_eps = a.shape == b.shape and bool(np.array_equal(a, b))
    if diff == 0.0 and same_eps:
        same = f"at {done:,} steps = {twin_job.label} ({twin_job.key}), bit for bit"
        return PrefixCheck(job.label, "identical", same)
    eps = "the same" if same_eps else f"{a.shape[1]} vs {b.shape[1]} or other"
    return PrefixCheck(job.label, "DIFFERENT", f"at {done:,} steps: weights differ by {diff:.3g}; episodes {eps}")


def prefix_checks(scale: str = "small", cache: RunCache | None = None) -> list[PrefixCheck]:
    """:func:`prefix_check` of every study run at ``scale`` against Fig 3.3's run at ``scale`` (none is trained
    here)."""
    cache = cache or RunCache()
    return [prefix_check(j, cache, twin_budget(j.config, scale)) for j in train_jobs(scale)]


# ---------------------------------------------------------------- the shipped layer's size
@dataclass(frozen=True)
class SizeEstimate:
    """Expected bytes the study adds to the shipped layer, from the shipped ``small`` twins of its runs:
    ``train`` per run label (an upper bound: the twin's training curves and episodes scaled by the budget ratio,
    later episodes being longer, plus one copy of its policy files per snapshot), ``evaluate`` in all (the twin's
    mean evaluation entry per evaluation job), ``missing`` the runs without a shipped twin (not counted)."""

    train: dict[str, int]
    evaluate: int
    n_evaluate: int
    missing: tuple[str, ...]

    @property
    def total(self) -> int:
        return sum(self.train.values()) + self.evaluate


def _files(entry: Path) -> dict[str, int]:
    return {str(p.relative_to(entry)): p.stat().st_size for p in entry.rglob("*") if p.is_file()}


def size_estimate(scale: str = "small", layer_root: str | Path | None = None) -> SizeEstimate:
    """:class:`SizeEstimate` of the study at ``scale`` from the twins shipped in ``layer_root`` (default the layer)."""
    from thesis_repro.core.cache import find_entry

    layer = Path(layer_root) if layer_root is not None else paths.reference()
    train, missing, ev_bytes, n_ev = {}, [], 0, 0
    evals_per_run = {}
    for e in budget_eval_jobs(scale):
        k = Job("train", e.config["train"]).key
        evals_per_run[k] = evals_per_run.get(k, 0) + 1
    twin_evals = {}
    for entry in sorted((layer / "evaluate").glob("*")) if (layer / "evaluate").is_dir() else []:
        label = entry.name.rsplit("__", 1)[0]
        twin_evals.setdefault(label.rsplit("__", 1)[0], []).append(sum(_files(entry).values()))
    for job in train_jobs(scale):
        twin = Job("train", small_twin(job.config, twin_budget(job.config, scale)))
        entry = find_entry(layer, twin)
        if entry is None:
            missing.append(job.label)
            continue
        files = _files(Path(entry))
        ratio = int(job.config["timesteps"]) / int(twin.config["timesteps"])
        outs = sum(v for k, v in files.items() if k.startswith("out/") and "/snapshots/" not in k)
        arrays = files.get("arrays.npz", 0)
        rest = sum(files.values()) - outs - arrays
        train[job.label] = int(rest + ratio * arrays + outs * (1 + len(snapshot_at_steps(job.config))))
        sizes = twin_evals.get(job.label, [])
        if sizes:
            ev_bytes += int(np.mean(sizes) * evals_per_run[job.key])
            n_ev += evals_per_run[job.key]
    return SizeEstimate(train, ev_bytes, n_ev, tuple(missing))


def size_line(est: SizeEstimate) -> str:
    """One line of :class:`SizeEstimate`: MB in all, per training run (median, max) and for the evaluations.

    >>> size_line(SizeEstimate({"a": 300_000, "b": 500_000}, 1_000_000, 16, ()))
    'expected shipped size: 1.8 MB (2 training runs 0.8 MB: median 400 kB, max 500 kB per run; 16 evaluations 1.0 MB)'
    """
    per = sorted(est.train.values())
    med = float(np.median(per)) if per else 0.0
    text = (
        f"expected shipped size: {est.total / 1e6:,.1f} MB ({len(per)} training runs {sum(per) / 1e6:,.1f} MB: "
        f"median {med / 1e3:,.0f} kB, max {max(per, default=0) / 1e3:,.0f} kB per run; {est.n_evaluate:,} "
        f"evaluations {est.evaluate / 1e6:,.1f} MB)"
    )
    return text + (f"; {len(est.missing)} runs without a shipped twin not counted" if est.missing else "")


# ---------------------------------------------------------------- Fig 3.3 at each budget, from the runs made so far
#: The columns of :attr:`BudgetPoints.returns`.
RETURN_COLUMNS = ("env", "algo", "test", "sigma", "seed", "return")


@dataclass(frozen=True)
class BudgetPoints:
    """The study's per-seed Fig 3.3 points at one budget, from the runs made so far: ``points`` (columns
    :data:`thesis_repro.figures.ch3.BUDGET_POINTS`; a run counts once its training entry and its evaluation under
    every test at that budget exist), ``runs`` of ``runs_total`` made, and the testing ``returns`` per σ."""

    steps: int
    points: pd.DataFrame
    runs: int
    runs_total: int
    #: the testing returns behind each AUC (``env, algo, test, sigma, seed, return``: mean over testing rollouts)
    returns: pd.DataFrame = field(default_factory=lambda: pd.DataFrame(columns=list(RETURN_COLUMNS)))
    #: every run the budget needs, as (learner, task, seed)
    expected: tuple[tuple[str, str, int], ...] = ()

    @property
    def complete(self) -> bool:
        return self.runs == self.runs_total

    @property
    def coverage(self) -> str:
        """``k of n runs`` (the words a page and the claims say)."""
        return f"{self.runs} of {self.runs_total} runs"


def points_at(scale: str, steps: int, cache: RunCache | None = None) -> BudgetPoints:
    """:class:`BudgetPoints` of :func:`benchmark_at` ``(scale, steps)`` read from the run cache and the shipped layer
    only: nothing is trained or evaluated. The training return is the mean of the run's last 100 training episodes
    finished by the budget point (:func:`~thesis_repro.figures.ch3.training_return_at`; at the last point the
    run's own ``train_return``), the AUC that of the evaluation of the point's snapshot (Eq 3.6)."""
    cache = cache or RunCache()
    bench = benchmark_at(scale, steps)
    rows: list[dict[str, Any]] = []
    rets: list[dict[str, Any]] = []
    made = 0
    for i, job in enumerate(bench.train_jobs):
        cfg = job.config
        at = next(p for p in points(cfg) if p.steps >= steps)
        train = cache.load(job)
        evals = {name: cache.load(jobs[i]) for name, jobs in bench.eval_jobs.items()}
        if train is None or any(e is None for e in evals.values()):
            continue
        made += 1
        tr = float(training_return_at(train, [at.steps])[0])
        for name, ev in evals.items():
            sig = bench.tests[name]["sigmas"]
            per_sigma = expected_return(np.asarray(ev["returns"], float), axis=-1)
            value = float(auc(per_sigma, sig))
            key = {"env": cfg["env"], "algo": cfg["algorithm"], "test": name, "seed": int(cfg["seed"])}
            rets += [{**key, "sigma": float(x), "return": float(r)} for x, r in zip(sig, per_sigma, strict=True)]
            rows.append(
                {
                    "steps": int(steps),
                    "env": cfg["env"],
                    "test": name,
                    "algo": cfg["algorithm"],
                    "seed": int(cfg["seed"]),
                    "train_return": tr,
                    "auc": value,
                }
            )
    points_frame = pd.DataFrame(rows, columns=list(BUDGET_POINTS))
    returns = pd.DataFrame(rets, columns=list(RETURN_COLUMNS))
    expected = tuple((j.config["algorithm"], j.config["env"], int(j.config["seed"])) for j in bench.train_jobs)
    return BudgetPoints(int(steps), points_frame, made, len(bench.train_jobs), returns, expected)


class _Loaded:
    """A cache's :meth:`~thesis_repro.core.cache.RunCache.load`, each entry read once (a training run serves every
    budget)."""

    def __init__(self, cache: Any):
        self.cache, self.seen = cache, {}

    def load(self, job: Job) -> Any:
        if job.key not in self.seen:
            self.seen[job.key] = self.cache.load(job)
        return self.seen[job.key]


def budget_points(scale: str, cache: RunCache | None = None) -> list[BudgetPoints]:
    """:func:`points_at` at every budget of the study (:func:`budgets`), from the runs made so far."""
    loaded = _Loaded(cache or RunCache())
    return [points_at(scale, b, loaded) for b in budgets(scale)]


def r_by_budget(at: Sequence[BudgetPoints]) -> tuple[pd.DataFrame, pd.DataFrame]:
    """r against training budget: per budget and Fig 3.3 cell (:func:`~thesis_repro.figures.ch3.budget_correlations`)
    and per budget (:func:`~thesis_repro.figures.ch3.budget_summary`, with ``runs`` and ``runs_total``)."""
    frames = [b.points for b in at if len(b.points)]
    pts = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame(columns=list(BUDGET_POINTS))
    cells = budget_correlations(pts)
    summary = budget_summary(cells).set_index("steps")
    summary = summary.reindex([b.steps for b in at])
    summary["runs"] = [b.runs for b in at]
    summary["runs_total"] = [b.runs_total for b in at]
    summary["negative"] = summary["negative"].fillna(0).astype(int)
    summary["cells"] = summary["cells"].fillna(0).astype(int)
    return cells, summary.rename_axis("steps").reset_index()


def table_frames(at: BudgetPoints, methods: Sequence[str]) -> dict[str, pd.DataFrame]:
    """The study's numbers at one budget in a chapter-3 table page's schema
    (:func:`thesis_repro.figures.ch3_tables.seed_frames`), for the table's ``methods`` only: ``aucs`` (env, test,
    method, seed, value), ``returns`` (env, method, test, sigma, seed, return) and ``train`` (env, method, seed,
    value: the training return at the budget)."""
    keep = list(methods)
    pts = at.points[at.points["algo"].isin(keep)].rename(columns={"algo": "method"})
    aucs = pts[["env", "test", "method", "seed", "auc"]].rename(columns={"auc": "value"})
    rets = at.returns[at.returns["algo"].isin(keep)].rename(columns={"algo": "method"})
    rets = rets[["env", "method", "test", "sigma", "seed", "return"]]
    train = pts.drop_duplicates(["env", "method", "seed"])[["env", "method", "seed", "train_return"]]
    train = train.rename(columns={"train_return": "value"})
    return {"aucs": aucs.reset_index(drop=True), "returns": rets.reset_index(drop=True), "train": train}


def claims_meta(last: BudgetPoints, methods: Sequence[str] | None = None) -> dict[str, Any]:
    """What a page hands the claims layer about the study (its meta key ``thesis_budget``): the study, the budget,
    how many of the runs it needs are made and, once all are, the study's per-seed frames at that budget in the
    page's own schema (Fig 3.3's ``points``; a table page's, :func:`table_frames`, when it names its ``methods``),
    so the same frozen rules judge them."""
    out: dict[str, Any] = {"study": NAME, "steps": last.steps, "runs": last.runs, "runs_total": last.runs_total}
    if methods is not None:  # only the runs of the page's learners count
        made = set(zip(last.points["algo"], last.points["env"], last.points["seed"].astype(int), strict=True))
        needed = [r for r in last.expected if r[0] in set(methods)]
        out.update(runs=sum(r in made for r in needed), runs_total=len(needed))
    if out["runs"] == out["runs_total"]:
        frames = {"points": last.points} if methods is None else table_frames(last, methods)
        out["frames"] = {k: json.loads(f.to_json(orient="records")) for k, f in frames.items()}
    return out


def page_meta(figure_id: str, scale: str, cache: RunCache | None = None) -> dict[str, Any]:
    """:func:`claims_meta` of item ``figure_id`` (one of :data:`ITEMS`) at the study's last budget, from the runs made
    so far: Fig 3.3's points, or a table's frames for its learners (:func:`item_learners`) and their runs only."""
    if figure_id not in ITEMS:
        raise ValueError(f"{figure_id!r} reads no run of the {NAME} study; its items are: {', '.join(ITEMS)}")
    last = points_at(scale, budgets(scale)[-1], cache)
    return claims_meta(last, None if figure_id == "3.3" else sorted(item_learners(figure_id, scale)))


def steps_words(steps: int) -> str:
    """An env-step budget in a few characters: ``4M`` from a million up, else with thousands separators.

    >>> steps_words(4_000_000), steps_words(2_500_000), steps_words(256)
    ('4M', '2.5M', '256')
    """
    return f"{steps / 1e6:g}M" if steps >= 1_000_000 else f"{steps:,}"


def budget_headline(last: BudgetPoints, summary: pd.DataFrame, thesis: tuple[int, int]) -> str:
    """One sentence of numbers (the verdict is the claims layer's): Fig 3.3's correlation at the study's last budget
    beside the thesis's count of negative cells, or that the study's runs are not all computed yet (k of n).

    >>> s = pd.DataFrame({"steps": [4_000_000], "negative": [2], "cells": [12], "pooled_r": [0.61]})
    >>> budget_headline(BudgetPoints(4_000_000, pd.DataFrame(), 12, 108), s, (18, 20))
    "At the thesis's budget (4M steps) the study's runs are not all computed yet (12 of 108 runs)."
    >>> budget_headline(BudgetPoints(4_000_000, pd.DataFrame(), 108, 108), s, (18, 20))
    "At the thesis's budget (4M steps, 108 runs): r < 0 in 2/12 cells (thesis: 18/20), pooled r +0.61."
    """
    if not last.complete:
        where = f"At the thesis's budget ({steps_words(last.steps)} steps)"
        return f"{where} the study's runs are not all computed yet ({last.coverage})."
    row = summary[summary["steps"] == last.steps].iloc[0]
    return (
        f"At the thesis's budget ({steps_words(last.steps)} steps, {last.runs} runs): r < 0 in {int(row['negative'])}/"
        f"{int(row['cells'])} cells (thesis: {thesis[0]}/{thesis[1]}), pooled r {float(row['pooled_r']):+.2f}."
    )
