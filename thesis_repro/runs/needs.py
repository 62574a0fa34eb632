"""Which jobs a figure needs, at which budget and seeds: pure questions, asked by the generator, the cost plan,
budgets and the pages alike.

:func:`needed` lists the jobs of some figures at a scale, deduplicated by key, each with the figures that use it, in
figure order; it reads the figure registry and the scale table only (no run cache, no cost, no generator), so a
page's metadata asks it without loading what trains or prices runs. :func:`seed_count` and :func:`seed_jobs` plan
the confirmatory replication's training seeds past a scale's own (:func:`target_seeds`).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from thesis_repro import figures
from thesis_repro.core.cache import Job


@dataclass
class Need:
    """One job some figures need: the job, the notebook ids that use it and the index of the first of them."""

    job: Job
    figures: list[str] = field(default_factory=list)
    first: int = 0


def job_algorithm(job: Job) -> str | None:
    """The learner a training job trains, or an evaluation evaluates (``None`` for other kinds)."""
    cfg = job.config.get("train", job.config)
    return cfg.get("algorithm") if isinstance(cfg, Mapping) else None


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


#: The confirmatory replication makes chapters 3-4 to this many training seeds...
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

    >>> seed_count("3.3", "smoke", {3, 4, 5}), seed_count("5.6", "smoke", {4})
    ({'train_seeds': 6}, {'seeds': [0, 4]})
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


def needed(
    scale: str,
    figure_ids: Iterable[str] | None = None,
    kinds: Iterable[str] = figures.TRAINING_KINDS,
    algos: Iterable[str] | None = None,
    seeds: Iterable[int] | None = None,
    item_seeds: Mapping[str, Iterable[int]] | None = None,
) -> list[Need]:
    """The jobs of ``kinds`` of every figure (or ``figure_ids``) at ``scale``, each once (by key) with the figures
    that use it, in figure order; with ``algos`` / ``seeds``, only the jobs of those learners / training seeds
    (``item_seeds``: per figure id, its own seeds instead), planned past the scale's own count (:func:`seed_count`).

    >>> [n.figures for n in needed("smoke", ["3.3"], kinds=("train",))][:1]
    [['fig-3.3']]
    """
    kinds = set(kinds)
    keep = None if algos is None else set(algos)
    seeds = None if seeds is None else [int(s) for s in seeds]
    out: dict[str, Need] = {}
    for i, fid in enumerate(figure_ids or figures.ids()):
        notebook_id = figures.get(fid).notebook_id
        wanted = item_seeds[fid] if item_seeds is not None and fid in item_seeds else seeds
        keep_seeds = None if wanted is None else {int(s) for s in wanted}
        for job in figures.jobs(fid, scale, **seed_count(fid, scale, keep_seeds)):
            if job.kind not in kinds or (keep is not None and job_algorithm(job) not in keep):
                continue
            if keep_seeds is None or training_seed(job) in keep_seeds:
                out.setdefault(job.key, Need(job, first=i)).figures.append(notebook_id)
    return list(out.values())
