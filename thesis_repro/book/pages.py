"""What a notebook page prints beside its numbers: where its runs come from and what it hands the claims layer.

The figure layer (:mod:`thesis_repro.figures`) computes numbers only and imports no run, claims or book module;
what a figure needs is asked of :mod:`thesis_repro.runs.needs`, below the generator. This module sits above all of
them, so imports run one way::

    figures -> (core, evaluation, learners, ...)
    runs    -> figures (needs, budgets, layer; never the generator on a page's path)
    claims  -> (never figures)
    pages   -> figures, runs.layer, runs.budgets

Every notebook calls ``pages.runs_summary(...)`` after its settings and ``pages.claim_meta(...)`` in its
verdict cell; pages whose claims carry the trained-runs sensitivity check (Fig 3.3, Table 3.3) pass their frames
through ``pages.claim_frames(...)``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import pandas as pd

from thesis_repro import figures
from thesis_repro.core.cache import RunCache
from thesis_repro.runs import budgets
from thesis_repro.runs import layer as runs


def runs_summary(figure_id: str, scale: str) -> str:
    """One line: where the runs of ``figure_id`` at ``scale`` come from (shipped / cached / to compute).

    Counts its training runs, or every job when the figure trains nothing (chapter 5's arm jobs).

    >>> runs_summary("4.1", "smoke")  # doctest: +ELLIPSIS
    'fig-4.1 (smoke): 8 training runs: 0 shipped, ... cached, ... to compute'
    """
    fig = figures.get(figure_id)
    every = fig.jobs(fig.settings(scale))
    training = [j for j in every if j.kind in figures.TRAINING_KINDS]
    return f"{fig.notebook_id} ({scale}): " + runs.summary(training or every)


def local_runs(figure_id: str, settings: Mapping[str, Any], cache: RunCache | None = None) -> dict[str, Any] | None:
    """How many of the figure's training runs (every job when it trains nothing; the runs that
    :func:`runs_summary` counts) are read from the local run cache instead of the shipped layer, and how many
    of those have a shipped copy they replace; ``None`` when none is local.

    ``{"local": 2, "replacing_shipped": 1, "of": 35, "noun": "training runs"}``
    """
    fig = figures.get(figure_id)
    every = fig.jobs(settings)
    training = [j for j in every if j.kind in figures.TRAINING_KINDS]
    cache = cache or RunCache()
    local = [j for j in training or every if cache.state(j) == "cached"]
    if not local:
        return None
    return {
        "local": len(local),
        "replacing_shipped": sum(cache.shipped(j) is not None for j in local),
        "of": len(training or every),
        "noun": "training runs" if training else "runs",
    }


def claim_meta(figure_id: str, settings: Mapping[str, Any]) -> dict[str, Any]:
    """What a page hands the claims layer beside its numbers: scale, seeds, the budget sentence, how many
    of its training runs are trained / still learning (:mod:`thesis_repro.runs.budgets`: half vs final budget) and,
    when some come from the local run cache rather than the shipped layer, how many (:func:`local_runs`; the
    verdicts' evidence names them).

    Chapter 5 counts its own ``seeds`` (a list); the thesis gives no seed count there, so the note names the
    kit's ``full`` count instead:

    >>> meta = claim_meta("5.3", figures.settings("5.3", "smoke"))
    >>> meta["figure"], meta["note"], "budgets" in meta
    ('5.3', 'scale smoke: 1 seed(s) (full: 6; the thesis gives no count)', False)
    """
    fig = figures.get(figure_id)
    full = fig.settings("full")
    if "seeds" in settings:
        note = (
            f"scale {settings['scale']}: {len(settings['seeds'])} seed(s) "
            f"(full: {len(full['seeds'])}; the thesis gives no count)"
        )
    else:
        note = f"scale {settings['scale']}: {settings['train_seeds']} training seed(s) (thesis: {full['train_seeds']})"
    if "timesteps" in settings:
        note = figures.budget_note(dict(settings, figure=settings.get("figure", figure_id)))
    out: dict[str, Any] = {"figure": fig.id, "note": note}
    if any(k in figures.TRAINING_KINDS for k in fig.kinds):
        table = budgets.table(settings["scale"], [fig.id])
        if len(table) and "verdict" in table:
            out["budgets"] = {
                "runs": int(len(table)),
                **{str(k): int(v) for k, v in table["verdict"].value_counts().items()},
            }
    local = local_runs(figure_id, settings)
    if local:
        out["local_runs"] = local
    return out


def claim_frames(figure_id: str, scale: str, frames: Mapping[str, pd.DataFrame]) -> dict[str, pd.DataFrame]:
    """A page's per-seed frames for the claims layer, each row marked ``trained`` when :mod:`thesis_repro.runs.budgets`
    calls its training run trained (:func:`~thesis_repro.runs.budgets.mark_trained`): the claims' registered
    ``sensitivity_subset: trained`` check judges the same rule on those rows only."""
    return budgets.mark_trained(frames, budgets.table(scale, [figures.get(figure_id).id]))


__all__ = ["claim_frames", "claim_meta", "local_runs", "runs_summary"]
