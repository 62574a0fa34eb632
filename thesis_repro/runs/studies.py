"""Every registered study's runs beside the figures': the keys ``runs --check`` and ``make verify`` count as
current though no page lists their learners yet.

* the thesis-budget study (:func:`thesis_repro.runs.budget_study.study_keys`);
* chapter 4's readings grid (:func:`thesis_repro.runs.pilots.readings_grid_jobs`): the readings that train and differ
  from params_avg in their pilots, on every chapter-4 item registered;
* with ``protocol``, the protocol studies (:func:`thesis_repro.runs.study.study_jobs`).

Evaluations count under their unbound and bound keys (bound: the shipped runs they evaluate).
"""

from __future__ import annotations

import json
from functools import lru_cache
from pathlib import Path

from thesis_repro.core import job_kinds, paths
from thesis_repro.core.cache import RunCache
from thesis_repro.runs import budget_study, pilots
from thesis_repro.runs.study import study_jobs

#: The pilot set whose summary names the readings that go to the grid.
READINGS_PILOTS = "ch4-readings"


def grid_keys(scale: str, layer: Path) -> set[str]:
    """The keys of chapter 4's readings grid at ``scale`` in ``layer`` (from the layer's own pilot summary; none
    without one), on the chapter-4 items the figure registry holds."""
    summary = layer / pilots.summary_path(READINGS_PILOTS).relative_to(paths.reference())
    if not summary.exists():
        return set()
    algos = pilots.grid_algos(json.loads(summary.read_text()))
    view = RunCache(layer, reference=False)
    keys: set[str] = set()
    for job in (q.job for q in pilots.readings_grid_jobs(scale, algos)):
        keys.add(job.key)
        if job_kinds.pins_dependencies(job.kind) and (bound := view.bind(job)) is not None:
            keys.add(bound.key)
    return keys


def keys(scale: str = "small", layer_root: str | Path | None = None, protocol: bool = False) -> set[str]:
    """The keys of every study's runs at ``scale`` in ``layer_root`` (default: the shipped layer)."""
    layer = Path(layer_root) if layer_root is not None else paths.reference()
    out = budget_study.study_keys(scale, layer) | grid_keys(scale, layer)
    return out | {j.key for j in study_jobs()} if protocol else out


@lru_cache(maxsize=8)
def _made(scale: str, roots: tuple[str, ...], folders: tuple[str, ...]) -> list[str]:
    """:func:`made_study_runs` for one state of the training folders (``roots`` and ``folders`` key the memo)."""
    cache = RunCache()
    return sorted(j.key for j in budget_study.train_jobs(scale) if cache.state(j) in ("cached", "shipped"))


def made_study_runs(scale: str) -> list[str]:
    """The keys of the thesis-budget study's training runs at ``scale`` that are made (in the local run cache or the
    shipped layer), sorted; recomputed only when a training folder appears or goes."""
    roots = (paths.runs_dir(), paths.reference())
    folders = tuple(sorted(f"{r}/{p.name}" for r in roots for p in (r / "train").glob("*")))
    return _made(scale, tuple(map(str, roots)), folders)
