"""Where every figure's runs are, the shipped layer of reference runs, and the generator that fills it.

* :func:`rows` / :func:`table`: a figure's jobs with their kind, label, key, state (``cached`` in the
  local cache, ``shipped`` in ``data/reference``, ``corrupt`` = either of them failing its manifest, to be
  recomputed, ``partial`` = interrupted and resumable, ``missing``) and path — ``python -m thesis_repro
  runs 3.3 --scale small``; :func:`record` writes the same rows to ``build/<scale>/figures/fig-3.3.runs.json``
  after a notebook ran; :func:`summary` is the one line a notebook prints.
* :func:`export`: compact copy of a finished training entry into the shipped layer (policy weights,
  obs filter, curves, snapshots, config, provenance; never optimiser state, full SB3 models or replay
  buffers) with a fresh manifest.
* :func:`generate`: ``make reference-runs SCALE=small`` — trains the training jobs of every figure
  (cheapest first, resumable), exports each into the layer and optionally commits it as it lands.
* :func:`check_shipped` (stale shipped runs), :func:`verify_shipped` and :func:`verify_local` (corrupt
  shipped and local entries; ``runs --check``),
  :func:`max_abs_diff` (compare two runs' policies) and :func:`compare_retrain` (a retrain against the
  shipped run: bit-identical on the same platform, else the same outcome within :data:`OUTCOME_RTOL`) back
  the provenance tests.

>>> from thesis_repro.cache import Job
>>> summary([Job("square", {"x": 1}), Job("square", {"x": 2})], RunCache(reference=False))
'2 runs: 0 shipped, 0 cached, 2 to compute'
"""

from __future__ import annotations

import fnmatch
import json
import math
import os
import shutil
import subprocess
import time
from collections.abc import Callable, Collection, Iterable, Mapping, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass, field
from datetime import datetime, timedelta
from pathlib import Path
from typing import Any

import numpy as np

from thesis_repro import figures, paths
from thesis_repro import jobs as registry
from thesis_repro.backends import die_with_parent as _die_with_parent  # study.py imports it from here
from thesis_repro.backends import execute
from thesis_repro.backends import sigint_held as _sigint_held
from thesis_repro.backends import stop_pool as _stop_pool
from thesis_repro.cache import (
    UNSHIPPED,
    Job,
    Result,
    RunCache,
    entry_identity,
    find_entry,
    read_entry,
    sweep_tmp,
    write_manifest,
)
from thesis_repro.plan import Rates, job_rate, seed_count, shipped_rates, work
from thesis_repro.plan import table as table  # re-exported: the run listing's table (the CLI, verify)
from thesis_repro.plan import training_seed as job_seed  # the training seed of a job (an evaluation: its policy's)
from thesis_repro.provenance import numerics_env, platform_info, same_platform
from thesis_repro.validation import check_choice

#: States of a job in :func:`rows`.
STATES: tuple[str, ...] = ("cached", "shipped", "corrupt", "partial", "missing")
#: Artefacts never shipped (glob patterns on file or folder names): full SB3 models and VecNormalize
#: pickles (optimiser state, env references), replay buffers, resumable checkpoints, optimiser dumps.
#: (The cache's list: these files are not part of an entry's identity either.)
EXCLUDE: tuple[str, ...] = UNSHIPPED
#: Files a shipped entry of a kind must hold to be usable: a training run's policy (``load_policy(result)``),
#: an evaluation's values (rollout returns and lengths live in ``arrays.npz``).
REQUIRED: dict[str, tuple[str, ...]] = {
    "train": ("out/policy.pth", "out/learner.json"),
    "evaluate": ("result.json", "arrays.npz"),
}
#: Size a shipped run should stay under (snapshots included); larger ones are reported.
TARGET_BYTES = 1_000_000


def _rel(path: Path) -> str:
    try:
        return str(path.resolve().relative_to(paths.ROOT))
    except ValueError:
        return str(path)


# ---------------------------------------------------------------- findable runs
def corrupt(path: Path) -> str | None:
    """Why entry ``path`` fails its manifest (or cannot be read), ``None`` if it verifies."""
    try:
        read_entry(path)
    except Exception as err:  # noqa: BLE001 - any failure to read means the entry is unusable
        return str(err) or type(err).__name__
    return None


def job_state(job: Job, cache: RunCache, verify: bool = True) -> tuple[str, Path]:
    """State (one of :data:`STATES`) and folder of one job, without computing anything.

    With ``verify`` the entry the cache would read (local, else shipped) is checked against its manifest
    (every file hashed) and is ``corrupt`` if it fails: the cache will not use it but recompute the job.
    """
    state = cache.state(job, verify=verify)
    if state == "cached":
        path = cache.entry(job)
    elif state == "shipped":
        path = cache.shipped(job)
    elif state == "corrupt":
        path = cache.entry(job) if cache.entry(job).is_dir() else cache.shipped(job)
    elif state == "partial":
        path = cache.workdir(job)
    else:
        path = cache.entry(job)
    return state, Path(path)


def job_row(job: Job, cache: RunCache, verify: bool = True) -> dict[str, str]:
    """``kind``, ``label``, ``key``, ``state`` and ``path`` of one job (see :func:`job_state`; no computing)."""
    state, path = job_state(job, cache, verify)
    return {"kind": job.kind, "label": job.label, "key": job.key, "state": state, "path": _rel(path)}


def rows(figure_id: str, scale: str, cache: RunCache | None = None, verify: bool = True) -> list[dict[str, str]]:
    """One row per job figure ``figure_id`` runs at ``scale`` (training jobs first); ``verify``: see
    :func:`job_state`."""
    cache = cache or RunCache()
    return [job_row(job, cache, verify) for job in figures.jobs(figure_id, scale)]


def summary(jobs: Iterable[Job], cache: RunCache | None = None, verify: bool = False) -> str:
    """One line: how many of ``jobs`` are shipped, cached locally or still to compute.

    ``"35 training runs: 35 shipped, 0 cached, 0 to compute"`` (``runs`` when not all are training jobs;
    interrupted runs that will resume, and with ``verify`` corrupt entries, count as to compute and are named).
    """
    cache = cache or RunCache()
    jobs = list({j.key: j for j in jobs}.values())
    states = [job_state(j, cache, verify)[0] for j in jobs]
    noun = "training runs" if jobs and all(j.kind in figures.TRAINING_KINDS for j in jobs) else "runs"
    n = {s: states.count(s) for s in STATES}
    todo = n["partial"] + n["missing"] + n["corrupt"]
    noun = noun[:-1] if len(jobs) == 1 else noun
    text = f"{len(jobs)} {noun}: {n['shipped']} shipped, {n['cached']} cached, {todo} to compute"
    notes = [f"{n['partial']} interrupted, will resume"] if n["partial"] else []
    notes += [f"{n['corrupt']} corrupt, will be recomputed"] if n["corrupt"] else []
    return text + (f" ({'; '.join(notes)})" if notes else "")


def runs_json(figure_id: str, scale: str) -> Path:
    """``build/<scale>/figures/fig-X.Y.runs.json``."""
    return paths.figures(scale) / f"{figures.get(figure_id).notebook_id}.runs.json"


def record(figure_id: str, scale: str, cache: RunCache | None = None) -> Path | None:
    """Write the run rows of ``figure_id`` at ``scale`` to :func:`runs_json`; ``None`` if it is not a registered
    figure (nothing to record)."""
    try:
        figures.get(figure_id)
    except ValueError:
        return None
    cache = cache or RunCache()
    jobs = figures.jobs(figure_id, scale)
    training = [j for j in jobs if j.kind in figures.TRAINING_KINDS]
    doc = {
        "figure": figures.get(figure_id).notebook_id,
        "scale": scale,
        "summary": summary(training, cache) if training else summary(jobs, cache),
        "runs": [job_row(j, cache, verify=False) for j in jobs],  # the notebook has just read (verified) them
    }
    out = runs_json(figure_id, scale)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(f".tmp{os.getpid()}")
    tmp.write_text(json.dumps(doc, indent=1))
    os.replace(tmp, out)
    return out


# ---------------------------------------------------------------- the shipped layer
@dataclass(frozen=True)
class Exported:
    """A run copied into the shipped layer: its folder, size in bytes and the files left out."""

    path: Path
    bytes: int
    dropped: tuple[str, ...] = ()

    @property
    def megabytes(self) -> float:
        return self.bytes / 1e6


def _excluded(name: str) -> bool:
    return any(fnmatch.fnmatch(name, pat) for pat in EXCLUDE)


def _size(folder: Path) -> int:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())


def export(result: Result, layer_root: str | Path | None = None) -> Exported:
    """Compact copy of the finished entry ``result`` into the shipped layer (``paths.reference()`` by default).

    Keeps ``config.json``, ``provenance.json``, ``result.json``, ``arrays.npz`` and ``out/`` minus
    :data:`EXCLUDE`; writes a fresh manifest; replaces an older copy atomically. A training entry without
    the files evaluation needs (:data:`REQUIRED`) is a ``ValueError``.
    """
    layer = Path(layer_root) if layer_root is not None else paths.reference()
    src = Path(result.path)
    kind = json.loads((src / "config.json").read_text())["kind"]
    missing = [f for f in REQUIRED.get(kind, ()) if not (src / f).exists()]
    if missing:
        raise ValueError(f"cannot ship {src}: it lacks {', '.join(missing)} (what a figure loads from it)")
    dest = layer / kind / src.name
    if dest.resolve() == src.resolve():
        return Exported(dest, _size(dest))
    dropped: list[str] = []

    def ignore(folder: str, names: list[str]) -> list[str]:
        out = [n for n in names if _excluded(n)]
        dropped.extend(_rel(Path(folder) / n).split(f"{src.name}/", 1)[-1] for n in out)
        return out

    sweep_tmp(dest.parent)  # temporary copies of dead exports
    tmp = dest.parent / f".tmp-export-{src.name}-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    for name in ("config.json", "provenance.json", "result.json", "arrays.npz"):
        if (src / name).exists():
            shutil.copy2(src / name, tmp / name)
    if (src / "out").is_dir():
        shutil.copytree(src / "out", tmp / "out", ignore=ignore)
    write_manifest(tmp, json.loads((src / "manifest.json").read_text()).get("identity"))
    read_entry(tmp)  # the copy verifies before it replaces anything
    if dest.exists():
        shutil.rmtree(dest)
    os.replace(tmp, dest)
    return Exported(dest, _size(dest), tuple(sorted(dropped)))


def entries(root: str | Path) -> list[Path]:
    """Every committed entry folder (``<kind>/<label>__<key>``) under ``root`` (no workdirs, temporary folders
    or locks)."""
    root = Path(root)
    if not root.is_dir():
        return []
    return sorted(
        p
        for p in root.glob("*/*__*")
        if p.is_dir()
        and not p.name.startswith(".")
        and not p.parent.name.startswith(".")
        and not p.name.endswith(".partial")
    )


def shipped_entries(layer_root: str | Path | None = None) -> list[Path]:
    """Every entry folder (``<kind>/<label>__<key>``) of the shipped layer."""
    return entries(layer_root if layer_root is not None else paths.reference())


def local_entries(root: str | Path | None = None) -> list[Path]:
    """Every committed entry folder of the local run cache (``paths.runs()`` unless ``root``)."""
    return entries(root if root is not None else paths.runs())


@dataclass(frozen=True)
class StaleRun:
    """A shipped entry whose key no figure produces any more at ``scale``."""

    path: Path
    kind: str
    key: str
    scale: str

    @property
    def message(self) -> str:
        return (
            f"stale shipped run {_rel(self.path)}: no figure's current {self.scale} config produces key {self.key} "
            f"({self.kind}); regenerate with `make reference-runs SCALE={self.scale}` and remove it with "
            f"`git rm -r {_rel(self.path)}`"
        )


def current_keys(
    scale: str,
    kinds: Iterable[str] | None = None,
    figure_ids: Iterable[str] | None = None,
    layer_root: str | Path | None = None,
    seeds: Iterable[int] | None = None,
) -> set[str]:
    """Keys of every job (of ``kinds``, default all) of every figure (or ``figure_ids``) at ``scale``; with
    ``seeds``, of those training seeds too where the scale table counts fewer (:func:`seed_count`).

    A job of a pinned kind (an evaluation) counts under its key bound to the shipped entries of its dependencies
    (in ``layer_root``, default ``paths.reference()``), the key its shipped copy has, as well as unbound.
    """
    kinds = None if kinds is None else set(kinds)
    seeds = None if seeds is None else {int(s) for s in seeds}
    shipped_view = RunCache(layer_root if layer_root is not None else paths.reference(), reference=False)
    keys = set()
    for fid in figure_ids or figures.ids():
        for j in figures.jobs(fid, scale, **seed_count(fid, scale, seeds)):
            if kinds is None or j.kind in kinds:
                keys.add(j.key)
                if registry.pinned(j.kind) and (bound := shipped_view.bind(j)) is not None:
                    keys.add(bound.key)
    return keys


def shipped_job(path: str | Path) -> Job:
    """The :class:`Job` a shipped (or cached) entry was made from, rebuilt from its ``config.json``;
    ``ValueError`` if it no longer hashes to the entry's key (e.g. after a ``CACHE_VERSION`` bump)."""
    path = Path(path)
    meta = json.loads((path / "config.json").read_text())
    job = Job(meta["kind"], meta["config"])
    if job.key != meta["key"] or not path.name.endswith(f"__{job.key}"):
        raise ValueError(
            f"{_rel(path)} no longer hashes to its key ({meta['key']} -> {job.key}); regenerate the shipped runs "
            "with `make reference-runs SCALE=small`"
        )
    return job


def cheapest_shipped(
    kind: str = "train", layer_root: str | Path | None = None, keys: Iterable[str] | None = None
) -> Job | None:
    """The shipped ``kind`` job (with one of ``keys``, if given) that took the least measured wall time to make
    among those that record their platform and trained uninterrupted (:func:`shipped_seconds`); the others after
    them, by :func:`cost`; for the retrain-and-compare check, or ``None``. Wall time, not env steps: 200k DDPG
    steps cost ~6x 200k PPO steps."""
    keys = None if keys is None else set(keys)
    found = [
        (shipped_seconds(p), shipped_job(p))
        for p in shipped_entries(layer_root)
        if p.parent.name == kind and (keys is None or p.name.rsplit("__", 1)[1] in keys)
    ]

    def order(item: tuple[float, Job]) -> tuple[Any, ...]:
        seconds, job = item
        return (math.isnan(seconds), 0.0 if math.isnan(seconds) else seconds, cost(job), job.label, job.key)

    return min(found, key=order, default=(math.nan, None))[1]


def shipped_seconds(path: str | Path) -> float:
    """Measured wall time of a shipped (or cached) entry's job when it is a conclusive retrain target: its
    ``provenance.json`` records the platform and a ``measured.wall_time`` of a run that trained without
    interruption (``resumed_from`` 0). NaN otherwise, e.g. for entries made before the kit recorded these
    (their wall time may cover only the last session, and the platform rule cannot be applied)."""
    try:
        prov = json.loads((Path(path) / "provenance.json").read_text())
        measured = prov.get("measured") or {}
        if not prov.get("platform") or int(measured.get("resumed_from", -1)) != 0:
            return math.nan
        return float(measured["wall_time"])
    except (OSError, KeyError, ValueError, TypeError, AttributeError):
        return math.nan


def check_shipped(
    scale: str = "small", layer_root: str | Path | None = None, also: Iterable[str] = ()
) -> list[StaleRun]:
    """Shipped entries whose key is no longer produced by any figure's current config at ``scale`` (stale), nor
    is one of ``also`` (the protocol studies' runs: :func:`thesis_repro.study.study_keys`).

    An empty list means every shipped run is still used; otherwise each :attr:`StaleRun.message` says how
    to regenerate.
    """
    keys = current_keys(scale, layer_root=layer_root) | set(also)
    stale = []
    for path in shipped_entries(layer_root):
        key = path.name.rsplit("__", 1)[1]
        if key not in keys:
            stale.append(StaleRun(path, path.parent.name, key, scale))
    return stale


def verify_shipped(layer_root: str | Path | None = None) -> dict[Path, str]:
    """Shipped entries that fail their manifest (or cannot be read), with the reason."""
    return {p: why for p in shipped_entries(layer_root) if (why := corrupt(p)) is not None}


def verify_local(root: str | Path | None = None) -> dict[Path, str]:
    """Local run-cache entries (``paths.runs()`` unless ``root``) that fail their manifest, with the reason
    (the cache removes and recomputes such an entry when a figure next needs it)."""
    return {p: why for p in local_entries(root) if (why := corrupt(p)) is not None}


def _policy_arrays(result_or_path: Result | str | Path) -> dict[str, np.ndarray]:
    from thesis_repro.learners.policy_file import read_state_dict  # local: keep the listing importable without torch

    folder = Path(getattr(result_or_path, "out", result_or_path))
    if not (folder / "policy.pth").exists() and (folder / "out" / "policy.pth").exists():
        folder = folder / "out"
    arrays = {f"policy.{k}": v.numpy() for k, v in read_state_dict(folder / "policy.pth").items()}
    if (folder / "obs_norm.npz").exists():
        with np.load(folder / "obs_norm.npz", allow_pickle=False) as z:
            arrays.update({f"obs_norm.{k}": z[k] for k in ("mean", "var")})
    return arrays


def max_abs_diff(result_a: Result | str | Path, result_b: Result | str | Path) -> float:
    """Largest absolute difference between two training runs' policy weights and observation filters
    (``0.0``: bit-identical); ``ValueError`` if they do not have the same parameters."""
    a, b = _policy_arrays(result_a), _policy_arrays(result_b)
    if a.keys() != b.keys() or any(a[k].shape != b[k].shape for k in a):
        diff = sorted(a.keys() ^ b.keys()) or [k for k in a if a[k].shape != b[k].shape]
        raise ValueError(f"the two runs have different parameters: {', '.join(diff[:5])}")
    return max((float(np.max(np.abs(a[k].astype(np.float64) - b[k]))) for k in a if a[k].size), default=0.0)


#: A retrain on the platform that made the shipped run must give its weights to this tolerance.
WEIGHTS_ATOL = 1e-6
#: On another platform (other SIMD kernels, so other last bits, which RL amplifies) a retrain is another
#: sample of the same training procedure: its training return and its deterministic policy's testing return
#: must match the shipped run's within this relative tolerance.
OUTCOME_RTOL = 0.05


_RECOMPUTE = """
import json, sys
from thesis_repro.cache import Job, RunCache
spec = json.loads(sys.argv[1])
RunCache(spec["root"], reference=False).run(Job(spec["kind"], spec["config"]))
"""


def recompute(job: Job, root: str | Path, like: Result | str | Path) -> Result:
    """Compute ``job`` into the cache at ``root`` in a fresh process with the numerics ``like`` was made in
    (:func:`numerics_env`): how ``make verify`` and the retrain test check a shipped entry bit for bit."""
    import sys

    import thesis_repro

    env = {k: v for k, v in os.environ.items() if k not in thesis_repro.PORTABLE_NUMERICS}
    env.update(numerics_env(like))
    spec = json.dumps({"kind": job.kind, "config": dict(job.config), "root": str(root)})
    subprocess.run([sys.executable, "-c", _RECOMPUTE, spec], env=env, check=True)
    result = RunCache(root, reference=False).load(job)
    if result is None:  # pragma: no cover - the subprocess committed it or failed above
        raise RuntimeError(f"recompute of {job.label} left no entry in {root}")
    return result


@dataclass(frozen=True)
class RetrainCheck:
    """Outcome of :func:`retrain_verdict`: ``ok`` and a one-line ``message`` saying which rule applied."""

    ok: bool
    message: str


def retrain_verdict(
    label: str,
    same: bool | None,
    weights_diff: float,
    train_return: tuple[float, float],
    test_return: tuple[float, float] | None,
    rtol: float = OUTCOME_RTOL,
) -> RetrainCheck:
    """The rule of :func:`compare_retrain` on its numbers (``(shipped, fresh)`` pairs).

    Same platform: weights within :data:`WEIGHTS_ATOL`. Another or unrecorded platform: bit-identical
    weights pass too; otherwise both returns must agree within ``rtol`` of the larger magnitude.

    >>> retrain_verdict("r", True, 0.0, (990.0, 990.0), None).ok
    True
    >>> retrain_verdict("r", True, 0.3, (990.0, 991.0), None).message
    'r: same platform as the shipped run but weights differ by 0.3 > 1e-06 (training is not deterministic)'
    >>> retrain_verdict("r", None, 0.3, (993.6, 991.1), (1000.0, 1000.0)).ok
    True
    >>> retrain_verdict("r", False, 0.3, (993.6, 500.0), (1000.0, 1000.0)).ok
    False
    """

    def close(pair: tuple[float, float]) -> bool:
        a, b = pair
        return abs(a - b) <= rtol * max(abs(a), abs(b))

    if weights_diff <= WEIGHTS_ATOL:
        return RetrainCheck(True, f"{label}: bit-identical to the shipped run (max |dw| {weights_diff:.1e})")
    if same:
        return RetrainCheck(
            False,
            f"{label}: same platform as the shipped run but weights differ by {weights_diff:.3g} > "
            f"{WEIGHTS_ATOL:g} (training is not deterministic)",
        )
    where = "another platform" if same is False else "a platform the shipped run did not record"
    pairs = {"training return": train_return, **({"testing return": test_return} if test_return else {})}
    ok = all(close(p) for p in pairs.values())
    said = ", ".join(f"{k} {a:.2f} shipped vs {b:.2f} retrained" for k, (a, b) in pairs.items())
    rule = f"within {rtol:.0%}" if ok else f"NOT within {rtol:.0%}"
    return RetrainCheck(ok, f"{label}: retrained on {where} (weights differ by {weights_diff:.3g}); {said}: {rule}")


def compare_retrain(shipped: Result, fresh: Result, n_rollouts: int = 5, rtol: float = OUTCOME_RTOL) -> RetrainCheck:
    """Is ``fresh`` (a retrain from scratch) the shipped training run again? See :func:`retrain_verdict`.

    Across platforms both final policies are also tested on the unperturbed task (``n_rollouts`` testing
    seeds, the same for both) and their mean returns compared.
    """
    same = same_platform(shipped)
    diff = max_abs_diff(shipped, fresh)
    test = None
    if diff > WEIGHTS_ATOL and not same:
        from thesis_repro.evaluation import evaluate  # local: the listing stays importable without the envs
        from thesis_repro.learners import load_policy

        cfg = shipped_job(shipped.path).config
        env, steps = cfg["env"], cfg.get("max_episode_steps") or 1000
        a, b = (
            float(evaluate(load_policy(r), env, "none", [0.0], n_rollouts, max_episode_steps=steps).mean())
            for r in (shipped, fresh)
        )
        test = (a, b)
    train = (float(shipped["train_return"]), float(fresh["train_return"]))
    return retrain_verdict(shipped.path.name.rsplit("__", 1)[0], same, diff, train, test, rtol)


# ---------------------------------------------------------------- the reference-run generator
def cost(job: Job) -> float:
    """Rough cost of a job for ordering: its env steps (``timesteps``), or CMA-ES evaluations, else 0."""
    c = job.config
    t = c.get("timesteps")
    if isinstance(t, int | float):
        return float(t)
    if isinstance(t, Mapping):
        return float(sum(v for v in t.values() if isinstance(v, int | float)))
    return float(c.get("generations", 0) or 0) * float(c.get("popsize", 1) or 1)


@dataclass
class Planned:
    """One reference run to produce: its job, the figures that use it and its estimated cost."""

    job: Job
    figures: list[str] = field(default_factory=list)

    @property
    def cost(self) -> float:
        return cost(self.job)


def job_algorithm(job: Job) -> str | None:
    """The learner a training job trains, or an evaluation evaluates (``None`` for other kinds)."""
    cfg = job.config.get("train", job.config)
    return cfg.get("algorithm") if isinstance(cfg, Mapping) else None


def plan(
    scale: str,
    figure_ids: Iterable[str] | None = None,
    kinds: Iterable[str] = figures.TRAINING_KINDS,
    by_figure: bool = False,
    algos: Iterable[str] | None = None,
    seeds: Iterable[int] | None = None,
) -> list[Planned]:
    """The jobs of ``kinds`` of every figure (or ``figure_ids``) at ``scale``, deduplicated by key, cheapest
    first; with ``by_figure``, the first figure's jobs first (each figure's cheapest first), so that the
    figures finish in the order given; with ``algos`` / ``seeds``, only the jobs of those learners / seeds.
    Several ``seeds``: the first seed given of every figure first, then the other seeds figure by figure, each
    figure's in the order given (``--seeds 0 1 2``: seed 0 everywhere; then seeds 1 and 2 of the first figure,
    of the second, ...), so one resumable command completes seed 0, then one item's full seed count after
    another (an item can show its 3 seeds without waiting for every other item's seed 1)."""
    kinds = set(kinds)
    keep = None if algos is None else set(algos)
    seed_rank = None if seeds is None else {int(s): i for i, s in reversed(list(enumerate(seeds)))}
    keep_seeds = None if seed_rank is None else set(seed_rank)
    out: dict[str, Planned] = {}
    rank: dict[str, int] = {}
    for i, fid in enumerate(figure_ids or figures.ids()):
        notebook_id = figures.get(fid).notebook_id
        for job in figures.jobs(fid, scale, **seed_count(fid, scale, keep_seeds)):
            if job.kind not in kinds or (keep is not None and job_algorithm(job) not in keep):
                continue
            if keep_seeds is None or job_seed(job) in keep_seeds:
                out.setdefault(job.key, Planned(job)).figures.append(notebook_id)
                rank.setdefault(job.key, i if by_figure else 0)

    def order(p: Planned) -> tuple[Any, ...]:
        r = 0 if seed_rank is None else seed_rank.get(job_seed(p.job), len(seed_rank))  # type: ignore[arg-type]
        return (min(r, 1), rank[p.job.key], r, p.cost, p.job.kind, p.job.label, p.job.key)

    return sorted(out.values(), key=order)


def _bind_to_layer(planned: list[Planned], layer: Path, cache: RunCache, log: Callable[[str], None]) -> list[Planned]:
    """``planned`` with each job of a pinned kind bound to the shipped entries of its dependencies (the key its
    shipped copy gets, :meth:`RunCache.bind`); jobs whose dependency is not shipped, or differs in the local
    ``cache`` from the shipped one (the job would load the local one), are left out and counted in the log."""
    shipped_view = RunCache(layer, reference=False)
    out, unshipped, differ = [], 0, []
    for p in planned:
        bound = shipped_view.bind(p.job)
        if bound is None:
            unshipped += 1
            continue
        for dep in registry.dependencies(bound.kind, bound.config).values():
            local = find_entry(cache.root, dep)
            if local is not None and entry_identity(local) != entry_identity(find_entry(layer, dep)):
                differ.append(_rel(local))
                break
        else:
            out.append(Planned(bound, p.figures))
    if unshipped:
        what = "/".join(sorted({p.job.kind for p in planned}))
        log(f"{unshipped} {what} jobs skipped: the run they load is not shipped (ship it first)")
    for path in differ:
        log(f"skipped: the local {path} differs from its shipped copy (remove it to evaluate the shipped one)")
    return out


class _Followers:
    """Pinned jobs (evaluations) waiting for the runs they load: :meth:`ready` hands each out once, bound to the
    shipped entries of ``layer``, as soon as its every dependency is shipped (unless it is shipped itself)."""

    def __init__(self, planned: list[Planned], layer: Path, cache: RunCache | None) -> None:
        self.layer = layer
        self.cache = RunCache(cache.root if cache is not None else None, reference=layer)  # loads shipped policies
        self.waiting = {p.job.key: p for p in planned}

    def ready(self, landed: str | None) -> list[Planned]:
        """The waiting jobs that load the run with key ``landed`` (``None``: all) and can run now, bound."""
        out = []
        for key, p in list(self.waiting.items()):
            deps = {d.key for d in registry.dependencies(p.job.kind, p.job.config).values()}
            if landed is not None and landed not in deps:
                continue
            bound = _bind_to_layer([p], self.layer, self.cache, lambda _: None)
            if bound:
                del self.waiting[key]
                if find_entry(self.layer, bound[0].job) is None:
                    out.append(bound[0])
        return out


def wall_seconds(result: Result) -> float:
    """Measured wall time of a finished run, NaN if unknown: a training run's own ``wall_time`` (summed over
    the sessions of a resumed run; :meth:`~thesis_repro.cache.Result.measured`), else the ``provenance.json`` of the
    process that committed it."""
    try:
        wall = result.measured("wall_time")
        if wall is not None:
            return float(wall)
        return float(result.provenance["wall_seconds"])
    except (OSError, KeyError, ValueError, TypeError, AttributeError):
        return float("nan")


def git_commit(path: Path, message: str, attempts: int = 20) -> str:
    """``git add <path> && git commit -m <message> -- <path>`` in the repository; returns the new commit.

    Retries while another process holds the index lock (several people/agents commit in one tree).
    """
    rel = _rel(path)
    for attempt in range(attempts):
        add = subprocess.run(["git", "-C", str(paths.ROOT), "add", "--", rel], capture_output=True, text=True)
        com = None
        if add.returncode == 0:
            com = subprocess.run(
                ["git", "-C", str(paths.ROOT), "commit", "-q", "-m", message, "--", rel], capture_output=True, text=True
            )
            if com.returncode == 0:
                head = subprocess.run(
                    ["git", "-C", str(paths.ROOT), "rev-parse", "--short", "HEAD"], capture_output=True
                )
                return head.stdout.decode().strip()
        err = (com or add).stderr
        if "index.lock" not in err or attempt == attempts - 1:
            raise RuntimeError(f"git commit of {rel} failed: {err.strip()}")
        time.sleep(1 + attempt)
    raise AssertionError("unreachable")  # pragma: no cover


#: Seconds between the generator's progress lines while its runs train (checkpoints land every 100k steps).
HEARTBEAT_SECONDS = 300.0


def progress_line(
    jobs: Sequence[Job], cache: RunCache, elapsed: float, eta: Callable[[Job], float] | None = None
) -> str:
    """One line: how far each of ``jobs`` got (env steps of its newest checkpoint / its budget) and, with ``eta``
    (seconds still needed, :func:`eta_seconds`), about how long it has left.

    >>> progress_line([], RunCache(reference=False), 600.0)
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
    rate in ``rates`` (units per second, :func:`thesis_repro.plan.job_rate`: its learner's on its task where
    ``rates`` has one, else its family's); ``inf`` for a family without a rate.

    >>> ppo = Job("train", {"algorithm": "ppo", "env": "Hopper", "timesteps": 1000})
    >>> eta_seconds(ppo, RunCache(reference=False), Rates({"ppo": 100.0}, {}))
    10.0
    >>> eta_seconds(ppo, RunCache(reference=False), Rates({"ppo": 100.0, "ppo:Hopper": 50.0}, {}))
    20.0
    """
    left = work(job)
    if job.kind in figures.TRAINING_KINDS:
        from thesis_repro.learners.train import checkpoint_steps  # local: the listing stays importable without torch

        try:
            left = max(0.0, left - checkpoint_steps(cache.workdir(job)))
        except (OSError, ValueError):
            pass
    rate = job_rate(job, rates)
    return left / rate if rate > 0 else math.inf


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
    first job expected to end by then (:data:`DEADLINE_MARGIN` x ``eta`` seconds from now) and ``None`` once none
    fits."""

    def __init__(
        self, todo: Sequence[Planned], until: datetime | None, eta: Callable[[Job], float], log: Callable[[str], None]
    ) -> None:
        self.queue, self.until, self.eta, self.log = list(todo), until, eta, log
        if until is not None:
            log(f"--until {until:%Y-%m-%d %H:%M}: starting only jobs expected to end by then")

    def take(self) -> Planned | None:
        if not self.queue:
            return None
        if self.until is None:
            return self.queue.pop(0)
        left = (self.until - datetime.now()).total_seconds()
        for i, p in enumerate(self.queue):
            need = self.eta(p.job)
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
) -> list[Exported]:
    """Produce the shipped reference runs of ``scale`` (``make reference-runs``).

    Collects the jobs of ``kinds`` of every figure (deduplicated, cheapest first; with ``figure_ids``, figure
    by figure in that order), skips those already
    shipped with a verified entry, runs the rest through the local cache ``n_jobs`` at a time (an
    interrupted run resumes from its workdir checkpoint on the next call), exports each finished one into
    the layer and, with ``commit``, commits it as it lands; every ``heartbeat`` seconds without one landing it
    logs a :func:`progress_line`. Returns the exported runs.

    A job of a pinned kind (an evaluation, ``--kind evaluate``) is keyed by the shipped entries of its
    dependencies (the training run it evaluates), so a fresh clone finds it: it is computed against the shipped
    policy and skipped while that policy is not shipped, or while the local cache holds another version of it.
    With training and pinned kinds together (``--kind train evaluate``), each pinned job runs in this process
    as soon as the last run it loads is shipped (:class:`_Followers`), so an item's evaluations land with its
    last training run.

    With ``until`` (``--until 22:40``), a job starts only while it is expected to finish by then (``eta``, default
    :func:`eta_seconds`: the work left past its checkpoint at the shipped runs' pace): at the end of a session the
    generator takes the next job that fits instead of one that would be cut off, and stops starting jobs when none
    fits (an interrupted run resumes only on the machine that holds its checkpoints; a new one starts it again).
    """
    layer = Path(layer_root) if layer_root is not None else paths.reference()
    kinds = tuple(check_choice(k, sorted(registry.KINDS), "job kind") for k in kinds)
    pinned_kinds = tuple(k for k in kinds if registry.pinned(k))
    if pinned_kinds and len(pinned_kinds) < len(kinds):  # training and evaluation in one command: they follow
        kinds = tuple(k for k in kinds if k not in pinned_kinds)
        followers = _Followers(plan(scale, figure_ids, pinned_kinds, algos=algos, seeds=seeds), layer, cache)
    else:
        followers = None
    pinned = any(registry.pinned(k) for k in kinds)
    cache = cache or RunCache(reference=layer if pinned else False)  # evaluations load the shipped policies
    planned = plan(scale, figure_ids, kinds, by_figure=figure_ids is not None, algos=algos, seeds=seeds)
    if pinned:
        planned = _bind_to_layer(planned, layer, cache, log)
    todo, shipped = [], 0
    for p in planned:
        where = find_entry(layer, p.job)
        if where is not None:
            try:
                read_entry(where)
            except Exception as err:  # noqa: BLE001
                log(f"shipped run {_rel(where)} is corrupt ({err}); regenerating it")
            else:
                shipped += 1
                continue
        todo.append(p)
    total = sum(p.cost for p in todo)
    log(
        f"reference runs ({scale}): {len(planned)} {'/'.join(kinds)} jobs, {shipped} already shipped, "
        f"{len(todo)} to produce ({total:,.0f} env steps in all) -> {_rel(layer)}"
    )
    done: list[Exported] = []

    def land(i: int, p: Planned, result: Result) -> None:
        ex = export(result, layer)
        wall = wall_seconds(result)
        note = "" if ex.bytes <= TARGET_BYTES else f" (over the {TARGET_BYTES / 1e6:.0f} MB target)"
        tag = f"[{i}/{len(todo)}]" if i else "[follows]"
        line = f"{tag} {p.job.kind} {p.job.label}: {wall:.0f} s, shipped {ex.megabytes:.2f} MB{note}"
        if commit:
            msg = f"reference run: {p.job.label} ({p.job.kind}, key {p.job.key}, {wall:.0f} s)"
            line += f", committed {git_commit(ex.path, msg)}"
        log(line + f" -> {_rel(ex.path)}")
        done.append(ex)
        if followers is not None and not registry.pinned(p.job.kind):
            follow(followers.ready(p.job.key))

    def follow(ready: list[Planned]) -> None:
        for q in ready:  # in this process, single-threaded (RunCache.compute), beside the pool's workers
            land(0, q, followers.cache.run(q.job))

    def follow_shipped() -> None:  # the evaluations of the runs shipped before this command
        if followers is not None:
            follow(followers.ready(None))

    queue = _Deadline(todo, until, eta or _default_eta(cache), log)
    if n_jobs <= 1 or len(todo) <= 1:
        follow_shipped()
        i = 0
        while (p := queue.take()) is not None:
            i += 1
            state, used_by = cache.state(p.job), ", ".join(p.figures)
            log(f"[{i}/{len(todo)}] {p.job.kind} {p.job.label} ({p.cost:,.0f} steps; {state}) for {used_by}")
            land(i, p, cache.run(p.job))
    else:
        import multiprocessing as mp

        with ProcessPoolExecutor(
            max_workers=n_jobs, mp_context=mp.get_context("spawn"), initializer=_die_with_parent
        ) as ex:
            ref = str(cache.reference) if cache.reference is not None else False
            futures: dict[Future, Planned] = {}
            pending: set[Future] = set()

            def submit() -> None:  # keep n_jobs in flight, each the next job the deadline allows
                while len(pending) < n_jobs and (p := queue.take()) is not None:
                    with _sigint_held():  # the workers start (and stay) deaf to Ctrl-C: the generator ends them
                        fut = ex.submit(execute, p.job, str(cache.root), ref)
                    futures[fut] = p
                    pending.add(fut)

            order = "figure by figure, each cheapest first" if figure_ids is not None else "cheapest first"
            t0, landed = time.time(), 0  # the pool's jobs landed so far (``done`` also holds the evaluations)
            try:  # from here on, Ctrl-C ends the workers (outside it, leaving the pool would wait for every run)
                log(f"running {len(todo)} jobs, {n_jobs} at a time ({order})")
                submit()
                follow_shipped()  # while the workers train
                while pending:
                    finished, pending = wait(pending, timeout=heartbeat, return_when=FIRST_COMPLETED)
                    started = [futures[f].job for f in in_flight(futures, pending, n_jobs)]
                    running = [j for j in started if cache.workdir(j).exists()]  # workers still importing: none
                    if not finished and running:
                        log(progress_line(running, cache, time.time() - t0, queue.eta))
                    for fut in finished:
                        landed += 1
                        land(landed, futures[fut], fut.result())
                    submit()
            except KeyboardInterrupt:  # Ctrl-C: stop now (the interrupted runs resume from their checkpoints)
                _stop_pool(ex)
                raise
    queue.report()
    return done
