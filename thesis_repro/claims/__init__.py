"""The claims layer: one verdict per thesis sentence, rules fixed in advance, statistics across training seeds.

Figures compute numbers (:mod:`thesis_repro.figures`); this layer judges them. It never imports the
figure layer: a notebook hands its per-seed frames to :func:`judge_page`, which saves them, and the ledger
(:func:`thesis_repro.claims.ledger.ledger`) re-judges every registered claim (``data/thesis/claims.yaml``) from
the saved numbers. The book's scoreboard and ``python -m thesis_repro claims`` read that one ledger.

Its modules, bottom up (each imports only those above it in this list, and the layers below claims):

* :mod:`.report`: the verdict words, and how a page prints, displays and saves its verdicts;
* :mod:`.registry`: the claims of ``data/thesis/claims.yaml``, one :class:`~.registry.Spec` each;
* :mod:`.stats`, :mod:`.judge`: contrasts with 95 % CIs across seeds, units, count rules; design v2's judging of
  a claim's units (both frozen, with :mod:`.measures`, by :mod:`.design`'s hash);
* :mod:`.measures`: what each claim measures on a page's frames (a module per chapter);
* :mod:`.design`: the pre-registered design v2 (level, margin, rule) and its freeze;
* :mod:`.calibration`, :mod:`.sensitivity`, :mod:`.confirmatory`: false-verdict rates and power, the registered
  subset checks, the verdict on the fresh seeds alone;
* :mod:`.thesis_budget`: the same frozen rule on the thesis-budget study's runs at the thesis's 4e6 steps, beside the
  verdict (*not computed (k of n runs)* until they are made);
* :mod:`.snapshot`, :mod:`.store`: the shipped claims snapshot; the numbers each page saves, read back;
* :mod:`.rules`: a claim's count rule and its threshold from the thesis's own numbers;
* :mod:`.ledger_row`: one ledger row, its JSON form and its headline;
* :mod:`.evidence`, :mod:`.diagnosis`: a row's evidence in words; why a claim does not (fully) reproduce;
* :mod:`.ledger`: every claim judged from the saved numbers;
* :mod:`.scoreboard`, :mod:`.page_verdicts`: the whole ledger in words; what a notebook's last call does;
* :mod:`.analysis_4_kl`: the analysis page's own rule (its three verdicts);
* :mod:`.synthetic`: no-effect frames of every page schema (null calibration, tests);
* :mod:`.results`, :mod:`.cli`: ``RESULTS.md`` and the README's results; the command line.
"""

from thesis_repro.claims.page_verdicts import bolding_check, judge_page

__all__ = ["bolding_check", "judge_page"]
