"""The figure layer: one registry from a figure/table id to its job grid, its module and its settings.

Each chapter module (:mod:`~thesis_repro.figures.ch3`, :mod:`~thesis_repro.figures.ch4`,
:mod:`~thesis_repro.figures.ch5`, ...) registers its items with :func:`register_figure`; a registered item knows
every :class:`~thesis_repro.core.cache.Job` it runs for given settings (training jobs first), so the run listing
(``python -m thesis_repro runs 3.3``), the reference-run generator and the tests can enumerate a figure's
runs without executing its notebook. Settings always come from the one scale table
(:func:`thesis_repro.core.scales.figure_settings`).

Imports run one way: :mod:`thesis_repro.runs.layer` and :mod:`thesis_repro.runs.budgets` import this
registry, so no figure module imports them (nor the claims layer), not even at call time; what a notebook
page prints about its runs and hands the claims layer lives in :mod:`thesis_repro.book.pages`
(``tests/test_layers.py`` enforces both).

>>> from thesis_repro import figures
>>> figures.get("fig-3.3").module
'thesis_repro.figures.ch3'
>>> [j.kind for j in figures.training_jobs("3.3", "smoke")][:2]
['train', 'train']
>>> figures.get("9.9")  # doctest: +ELLIPSIS
Traceback (most recent call last):
...
ValueError: unknown figure '9.9'; valid figures are: ...
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from thesis_repro.core import job_kinds, scales
from thesis_repro.core.cache import Job
from thesis_repro.core.validation import check_choice

#: Job kinds whose runs are *training* runs (shipped as reference runs at ``small``).
TRAINING_KINDS: tuple[str, ...] = ("train",)

JobGrid = Callable[[Mapping[str, Any]], list[Job]]


@dataclass(frozen=True)
class Figure:
    """One registered figure or table.

    ``id`` is the notebook id (``"3.3"``, ``"table-3.4"``, ``"analysis-4-kl"``), ``module`` the library
    module holding its logic, ``grid`` the function ``settings -> list[Job]`` (training jobs first) and
    ``kinds`` the job kinds it runs; ``settings_id`` names its entry in ``scales.yaml`` (default: ``id``).
    """

    id: str
    title: str
    module: str
    grid: JobGrid
    kinds: tuple[str, ...] = ("train", "evaluate")
    settings_id: str | None = None

    def jobs(self, settings: Mapping[str, Any]) -> list[Job]:
        """Every job of this figure for resolved ``settings``, training jobs first, without duplicates."""
        out: dict[str, Job] = {}
        for job in self.grid(settings):
            out.setdefault(job.key, job)
        jobs = list(out.values())
        return sorted(jobs, key=lambda j: j.kind not in TRAINING_KINDS)

    def settings(self, scale: str, **overrides: Any) -> dict[str, Any]:
        """Resolved settings of this figure at ``scale`` (:func:`thesis_repro.core.scales.figure_settings`)."""
        return scales.figure_settings(self.settings_id or self.id, scale, **overrides)

    @property
    def notebook_id(self) -> str:
        """``fig-3.3`` for figures, the id itself for tables and analyses (file stem and verdict name)."""
        return f"fig-{self.id}" if self.id[:1].isdigit() else self.id


#: Every registered figure/table, by id.
FIGURES: dict[str, Figure] = {}


def register_figure(
    figure_id: str,
    title: str,
    kinds: Iterable[str] = ("train", "evaluate"),
    settings_id: str | None = None,
) -> Callable[[JobGrid], JobGrid]:
    """Decorator registering ``grid(settings) -> list[Job]`` as the job grid of ``figure_id``.

    >>> @register_figure("_doc", "toy figure", kinds=["square"], settings_id="_example")
    ... def _grid(settings):
    ...     return [Job("square", {"x": settings["train_seeds"]})]
    >>> [j.config for j in jobs("_doc", "smoke")]
    [{'x': 1}]
    >>> _ = FIGURES.pop("_doc")
    """

    kinds = tuple(check_choice(k, list(job_kinds.KINDS), "job kind") for k in kinds)

    def deco(grid: JobGrid) -> JobGrid:
        if figure_id in FIGURES and FIGURES[figure_id].grid is not grid:
            raise ValueError(f"figure {figure_id!r} is already registered by {FIGURES[figure_id].module}")
        FIGURES[figure_id] = Figure(figure_id, title, grid.__module__, grid, kinds, settings_id)
        return grid

    return deco


def _normalise(figure_id: str) -> str:
    return figure_id[4:] if figure_id.startswith("fig-") else figure_id


def get(figure_id: str) -> Figure:
    """The registered figure ``figure_id`` (``"3.3"`` or ``"fig-3.3"``); ``ValueError`` listing ids if unknown."""
    return FIGURES[check_choice(_normalise(figure_id), list(FIGURES), "figure")]


def settings(figure_id: str, scale: str, **overrides: Any) -> dict[str, Any]:
    """Resolved settings of ``figure_id`` at ``scale`` (the one settings call of a notebook)."""
    return get(figure_id).settings(scale, **overrides)


def jobs(figure_id: str, scale: str, **overrides: Any) -> list[Job]:
    """Every job figure ``figure_id`` runs at ``scale`` (training jobs first), settings from the scale table."""
    fig = get(figure_id)
    return fig.jobs(fig.settings(scale, **overrides))


def training_jobs(figure_id: str, scale: str, **overrides: Any) -> list[Job]:
    """The training jobs (kinds :data:`TRAINING_KINDS`) of ``figure_id`` at ``scale``."""
    return [j for j in jobs(figure_id, scale, **overrides) if j.kind in TRAINING_KINDS]


def ids() -> list[str]:
    """Registered ids in catalogue order (chapter, then number; tables and analyses after figures)."""

    def key(fid: str) -> tuple:
        nums = [int(p) if p.isdigit() else 0 for p in fid.split("-")[-1].split(".")]
        return (not fid[:1].isdigit(), *nums, fid)

    return sorted(FIGURES, key=key)


def thesis_budget(figure_id: str) -> int:
    """The thesis's training budget (env steps) of a figure's runs: its ``full`` scale ``timesteps``.

    The ``full`` scale holds the thesis's own settings (Appendix A: 4e6 steps), so this is read, not typed.
    """
    t = get(figure_id).settings("full")["timesteps"]
    return int(t["default"] if isinstance(t, Mapping) else t)


def budget_note(settings: Mapping[str, Any], n_algos: int | None = None, extra: str = "") -> str:
    """One sentence: a scale's training budget, seeds and test rollouts beside the thesis's (read from the scale
    table), and the training protocol.

    >>> budget_note(settings("4.1", "smoke"), extra="~1 iteration")  # doctest: +NORMALIZE_WHITESPACE
    'scale smoke: 128 env steps per run (thesis: 4,000,000), 1 training seed(s) (thesis: 6),
    training protocol thesis, ~1 iteration.'
    >>> budget_note(settings("table-3.3", "small")).split(" (thesis")[0]
    'scale small: 2,000,000 env steps per run'
    """
    figure = settings["figure"]
    ours = settings["timesteps"]
    if isinstance(ours, Mapping) and isinstance(settings.get("env"), str):  # one task: its own budget only
        ours = ch3.timesteps_for(ours, settings["env"])
    ours_text = ", ".join(f"{k}: {v:,}" for k, v in ours.items()) if isinstance(ours, Mapping) else f"{ours:,}"
    full = get(figure).settings("full")
    thesis, seeds = thesis_budget(figure), full["train_seeds"]
    parts = [
        f"scale {settings['scale']}: {ours_text} env steps per run (thesis: {thesis:,})",
        f"{settings['train_seeds']} training seed(s) (thesis: {seeds})",
    ]
    if "test_rollouts" in settings and "evaluate" in get(figure).kinds:
        parts.append(f"{settings['test_rollouts']} test rollouts (thesis: {full['test_rollouts']})")
    if "protocol" in settings:
        parts.append(f"training protocol {settings['protocol']}")
    if n_algos is not None:
        parts.append(f"{n_algos} variants")
    if extra:
        parts.append(extra)
    return ", ".join(parts) + "."


# Chapter modules register their items on import (add a new module's import here).
from thesis_repro.figures import ch3, ch3_curves, ch3_tables, ch4, ch5  # noqa: E402

__all__ = [
    "FIGURES",
    "TRAINING_KINDS",
    "Figure",
    "budget_note",
    "ch3",
    "ch3_curves",
    "ch3_tables",
    "ch4",
    "ch5",
    "get",
    "ids",
    "jobs",
    "register_figure",
    "settings",
    "thesis_budget",
    "training_jobs",
]
