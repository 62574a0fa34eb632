"""The claims layer: one verdict per thesis sentence, rules fixed in advance, statistics across training seeds.

Figures compute numbers (:mod:`thesis_repro.figures`); this layer judges them. It never imports the
figure layer: a notebook hands its per-seed frames to :func:`judge_page`, which saves them, and the ledger
(:func:`ledger`) re-judges every registered claim (``data/thesis/claims.yaml``) from the saved numbers.
The book's scoreboard and ``python -m thesis_repro claims`` read that one ledger.

* :mod:`.report`: the verdict words, and how a page prints, displays and saves its verdicts;
* :mod:`.analysis_4_kl`: the analysis page's own rule (its three verdicts);
* :mod:`.stats`: contrasts with 95 % CIs across seeds (``scipy.stats``), units, count rules, null draws;
* :mod:`.measures`: what each claim measures on a page's frames (a module per chapter);
* :mod:`.ledger`: the registry, saving / loading page numbers, judging, scoreboard;
* :mod:`.synthetic`: no-effect frames of every page schema (null calibration, tests);
* :mod:`.cli`: the command line.
"""

from thesis_repro.claims import ledger
from thesis_repro.claims.ledger import bolding_check, judge, judge_page, scoreboard, spec, specs

__all__ = ["bolding_check", "judge", "judge_page", "ledger", "scoreboard", "spec", "specs"]
