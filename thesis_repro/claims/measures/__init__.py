"""What each claim measures: the page's per-seed numbers turned into units of contrasts (:mod:`..stats`).

A measure is ``fn(data, spec) -> {group: [Unit, ...]}``; ``data`` maps frame names to the per-seed frames a
notebook saved (:func:`thesis_repro.claims.page_verdicts.judge_page`), ``spec`` is the claim's registry entry.
Values are always one number per training seed (rollouts and episodes averaged inside the seed first).
A measure raises :class:`NotRun` when the scale did not train a learner the claim needs, and
:class:`Inconclusive` when the data cannot answer the claim (e.g. every kl_avg run diverged).

:mod:`.common` holds the registry (:data:`MEASURES`) and what every chapter shares; :mod:`.ch3`, :mod:`.ch4` and
:mod:`.ch5` each register one chapter's measures when imported (here, so ``MEASURES`` is whole).

>>> sorted(MEASURES)[:3]
['arpl', 'best_in', 'better']
"""

from thesis_repro.claims.measures import ch3, ch4, ch5  # noqa: F401 (importing a chapter registers its measures)
from thesis_repro.claims.measures.ch3 import NOISY
from thesis_repro.claims.measures.common import (
    MEASURES,
    POOLED,
    Data,
    Groups,
    Inconclusive,
    Measure,
    NotRun,
    measure,
    per_seed,
    pooled_seeds,
)

__all__ = [
    "MEASURES",
    "NOISY",
    "POOLED",
    "Data",
    "Groups",
    "Inconclusive",
    "Measure",
    "NotRun",
    "measure",
    "per_seed",
    "pooled_seeds",
]
