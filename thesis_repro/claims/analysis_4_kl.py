"""The analysis page's own rule (``analysis-4-kl``): its three verdicts from the Eq 4.7 tables it computes.

The page (``notebooks/analysis-4-kl.py``) computes its numbers with :mod:`thesis_repro.mdl.kl_analysis`; this
module judges them. Its claims are the registry's ``page_verdict`` entries of ``analysis-4-kl``: the ledger reads
these verdicts, in this order, from ``build/<scale>/figures/analysis-4-kl.rule.json``, which the page's
``judge_page(..., page_rule=verdicts(...))`` saves before it judges and prints them as every page does.
"""

from __future__ import annotations

import pandas as pd

from thesis_repro.claims.report import Verdict, status

#: Page id of the verdicts (``build/<scale>/figures/analysis-4-kl.rule.json``).
PAGE = "analysis-4-kl"


def kl_verdicts(summary: pd.DataFrame, linear: pd.DataFrame, scale: str) -> list[Verdict]:
    """Verdicts of the page from :func:`~thesis_repro.mdl.kl_analysis.summarise_aggregates` (MLP problems) and
    :func:`~thesis_repro.mdl.kl_analysis.linear_gaussian` tables.

    Claim judged: the thesis's premise that Eq 4.10/4.11 moves the aggregate closer, in the KL of Eq 4.7,
    to the sub-policies than Eq 4.6 does (REPRODUCES if kl_avg beats params_avg on ≥ 75 % of problems,
    PARTLY if on ≥ 25 %); and, for the exact minimiser, whether Eq 4.7 CAN be lowered below params_avg.
    """
    lin = linear["eq47"]
    rows = []
    for name, label in (("kl_avg", "Eq 4.11 as the kit runs it (λ = 0.1)"), ("eq4.10", "undamped Eq 4.10")):
        frac = float(summary.loc[name, "beats_params_avg"])
        holds = frac >= 0.75
        st = status(holds, scale, partly=frac >= 0.25)
        rows.append(
            Verdict(
                PAGE,
                f"{label} aggregates closer to the sub-policies (lower Eq 4.7) than parameter averaging",
                st,
                f"reproduced: lower Eq 4.7 than params_avg on {frac:.0%} of {int(summary.loc[name, 'problems'])} "
                f"MLP problems (median Eq 4.7 {summary.loc[name, 'median_eq47_vs_avg']:.4g}x params_avg's, median "
                f"distance to the optimum {summary.loc[name, 'median_dist_ratio']:.2g}x params_avg's); "
                f"linear-Gaussian: Eq 4.7 = {lin['eq4.10']:.4g} (Eq 4.10) vs {lin['params_avg']:.4g} "
                f"(params_avg) vs {lin['closed form (Eq 4.7)']:.4g} (optimum); thesis: claimed, not measured",
            )
        )
    frac = float(summary.loc["kl_exact", "beats_params_avg"])
    ok = frac == 1.0 and abs(lin["kl_exact"] - lin["closed form (Eq 4.7)"]) <= 1e-6 * max(1.0, abs(lin["kl_exact"]))
    rows.append(
        Verdict(
            PAGE,
            "Eq 4.7 itself (minimised exactly, kl_exact) does lower the KL to the sub-policies below params_avg",
            status(ok, scale),
            f"reproduced: kl_exact below params_avg on {frac:.0%} of problems (median Eq 4.7 "
            f"{summary.loc['kl_exact', 'median_eq47_vs_avg']:.4g}x params_avg's), median excess over the optimum "
            f"{summary.loc['kl_exact', 'median_excess']:.2g} vs {summary.loc['params_avg', 'median_excess']:.2g} "
            f"(params_avg); reaches the linear-Gaussian closed form (Eq 4.7 {lin['kl_exact']:.6g} vs "
            f"{lin['closed form (Eq 4.7)']:.6g})",
        )
    )
    return rows
