"""What every chapter's measures share: the measure registry, its two exceptions and the per-seed value.

A measure is ``fn(data, spec) -> {group: [Unit, ...]}`` registered with :func:`measure` under the name a claim's
``rule.measure`` gives (:data:`MEASURES`); :func:`per_seed` turns a frame's rows into one value per training seed.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd

from thesis_repro.claims.seeds import Seeded
from thesis_repro.claims.stats import Unit

Data = Mapping[str, pd.DataFrame]
Groups = dict[str, list[Unit]]
Measure = Callable[[Data, Mapping[str, Any]], Groups]

#: Every measure by name (``rule.measure`` in the registry).
MEASURES: dict[str, Measure] = {}


#: Measures whose one value per unit pools every training seed (a statistic of the seed means), with the frame
#: whose ``seed`` column counts them: no replication, so at most indicative however many seeds there are.
POOLED: dict[str, str] = {"mean_selection": "points"}


def pooled_seeds(name: str, frames: Mapping[str, pd.DataFrame]) -> int:
    """How many training seeds measure ``name`` pools into each unit's one value; 0 if it does not pool.

    >>> pooled_seeds("mean_selection", {"points": pd.DataFrame({"seed": [0, 0, 1, 2]})})
    3
    >>> pooled_seeds("correlation", {"points": pd.DataFrame({"seed": [0, 1]})})
    0
    """
    frame = frames.get(POOLED.get(name, ""))
    return 0 if frame is None or "seed" not in frame.columns else int(frame["seed"].nunique())


class NotRun(Exception):
    """The claim needs a learner / run this scale does not train."""


class Inconclusive(Exception):
    """The data cannot answer the claim (the reason is the message)."""


def measure(name: str) -> Callable[[Measure], Measure]:
    """Register a measure under ``name``."""

    def deco(fn: Measure) -> Measure:
        MEASURES[name] = fn
        return fn

    return deco


def per_seed(frame: pd.DataFrame, value: str = "value", **where: Any) -> Seeded:
    """One value per seed (mean inside the seed) of the rows matching ``where``, by increasing seed, each with its
    seed (:class:`~thesis_repro.claims.seeds.Seeded`)."""
    sel = np.ones(len(frame), dtype=bool)
    for k, v in where.items():
        sel &= (frame[k].isin(v) if isinstance(v, (list, tuple)) else frame[k] == v).to_numpy()
    sub = frame[sel]
    if sub.empty:
        return Seeded((), ())
    return from_series(sub.groupby("seed")[value].mean())


def from_series(s: pd.Series) -> Seeded:
    """A :class:`~thesis_repro.claims.seeds.Seeded` from a series indexed by training seed (sorted by seed)."""
    s = s.sort_index()
    return Seeded((float(x) for x in s.to_numpy(float)), (int(k) for k in s.index))


def _needs(frame: pd.DataFrame, col: str, names: Sequence[str]) -> None:
    missing = [n for n in names if n not in set(frame[col])]
    if missing:
        raise NotRun(f"{', '.join(missing)} not run at this scale")
