"""Checks of the shipped layer: stale runs no figure makes any more, corrupt entries, the job behind an entry.

* :func:`check_shipped` (stale shipped runs, each with its fix), :func:`verify_shipped` and :func:`verify_local`
  (corrupt shipped and local entries) back ``python -m thesis_repro runs --check``;
* :func:`current_keys` (the keys the figures make at a scale), :func:`shipped_job` (the job an entry was made
  from), :func:`cheapest_shipped` and :func:`shipped_seconds` (the run the retrain check picks) back ``make
  verify`` and the provenance tests.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from thesis_repro import figures
from thesis_repro.core import job_kinds, paths
from thesis_repro.core.cache import Job, RunCache
from thesis_repro.core.paths import shown
from thesis_repro.runs.layer import corrupt, local_entries, shipped_entries
from thesis_repro.runs.needs import seed_count, target_seeds
from thesis_repro.runs.throughput import cost


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
            f"stale shipped run {shown(self.path)}: no figure's current {self.scale} config produces key {self.key} "
            f"({self.kind}); regenerate with `make reference-runs SCALE={self.scale}` and remove it with "
            f"`git rm -r {shown(self.path)}`"
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
                if job_kinds.pins_dependencies(j.kind) and (bound := shipped_view.bind(j)) is not None:
                    keys.add(bound.key)
    return keys


def target_keys(
    scale: str,
    kinds: Iterable[str] | None = None,
    figure_ids: Iterable[str] | None = None,
    layer_root: str | Path | None = None,
) -> set[str]:
    """:func:`current_keys` with each figure's training seeds taken to the confirmatory replication's target
    (:func:`~thesis_repro.runs.needs.target_seeds`): the runs shipped for the fresh seeds count as current (and are
    verified) before the scale table reads them."""
    keys: set[str] = set()
    for fid in figure_ids or figures.ids():
        keys |= current_keys(scale, kinds, [fid], layer_root, seeds=range(target_seeds(fid)))
    return keys


def shipped_job(path: str | Path) -> Job:
    """The :class:`Job` a shipped (or cached) entry was made from, rebuilt from its ``config.json``;
    ``ValueError`` if it no longer hashes to the entry's key (e.g. after a ``CACHE_VERSION`` bump)."""
    path = Path(path)
    meta = json.loads((path / "config.json").read_text())
    job = Job(meta["kind"], meta["config"])
    if job.key != meta["key"] or not path.name.endswith(f"__{job.key}"):
        raise ValueError(
            f"{shown(path)} no longer hashes to its key ({meta['key']} -> {job.key}); regenerate the shipped runs "
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
    is one of ``also`` (the protocol studies' runs: :func:`thesis_repro.runs.study.study_keys`). The confirmatory
    replication's seeds past the scale's own count, up to each item's target
    (:func:`~thesis_repro.runs.needs.target_seeds`),
    are current: they are shipped before the scale table counts them, and a page reads them once all are shipped.

    An empty list means every shipped run is still used; otherwise each :attr:`StaleRun.message` says how
    to regenerate.
    """
    keys = target_keys(scale, layer_root=layer_root) | set(also)
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
    """Local run-cache entries (``paths.runs_dir()`` unless ``root``) that fail their manifest, with the reason
    (the cache removes and recomputes such an entry when a figure next needs it)."""
    return {p: why for p in local_entries(root) if (why := corrupt(p)) is not None}
