"""Chapter 5, Figures 5.3-5.6 (2-D arm: one BIC movement, transfer grid, competitors, curriculum).

Job grids are built here from a figure's settings; the algorithms (CMA-ES, transfer, competitors,
curriculum stages) stay in :mod:`thesis_repro.arm`. Figures 5.4 and 5.5 share their settings blocks, so
their source runs and the tensor target runs are computed once.

>>> s = {"families": ["reach", "bic"], "seeds": [0], "source": {"n_tasks": 3}, "target": {"n_targets": 2}}
>>> sources, rows = grid_jobs(s, ["scratch", "tensor"])
>>> len(sources), len(rows)     # sources shared by the two strategies; 2 x 2 pairs x 2 strategies
(2, 8)
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd

from thesis_repro import report
from thesis_repro.arm.baselines import COMPETITORS, STRATEGIES, TARGET_DEFAULTS, TRANSFER
from thesis_repro.arm.curriculum import CONDITIONS, CURRICULUM_DEFAULTS
from thesis_repro.arm.learn import source_config
from thesis_repro.arm.tasks import SIM_VERSION, ArmConfig
from thesis_repro.backends import run_jobs
from thesis_repro.cache import Job, Result
from thesis_repro.figures import register
from thesis_repro.validation import check_choice

#: Methods compared in Fig 5.5: our tensor transfer and the competitors.
FIG55_METHODS: tuple[str, ...] = ("tensor", *COMPETITORS)


# ---------------------------------------------------------------- Figure 5.3: one ball-in-cup movement
def solve_jobs(settings: Mapping[str, Any]) -> list[Job]:
    """One CMA-ES run on the single BIC task of the settings per seed (shaped cost)."""
    return [
        Job(
            "arm-solve",
            {
                "family": "bic",
                "task": list(settings["task"]),
                "n_basis": settings["n_basis"],
                "generations": settings["generations"],
                "sigma": settings["sigma"],
                "popsize": settings["popsize"],
                "shaped": True,
                "seed": int(seed),
                "sim_version": SIM_VERSION,
            },
        )
        for seed in settings["seeds"]
    ]


register("5.3", "A successful ball-in-cup movement (string taut / slack)", ["arm-solve"])(solve_jobs)


def catch_summary(results: Sequence[Result | Mapping[str, Any]], seeds: Sequence[int]) -> pd.DataFrame:
    """One row per seed: ``success``, ``cost`` (Eq 5.12), catch time [s], taut/slack alternation, first move right."""
    dt = ArmConfig().dt
    rows = []
    for seed, r in zip(seeds, results, strict=True):
        ok, hit = bool(r["success"]), int(r["hit_step"])
        taut = np.asarray(r["taut"])[:hit] if ok else np.asarray(r["taut"])
        rows.append(
            {
                "seed": int(seed),
                "success": ok,
                "cost": float(r["cost"]),
                "catch_time": hit * dt if ok else float("nan"),
                "taut_and_slack": bool(ok and taut.any() and (~taut).any()),
                "moves_right_first": bool(ok and np.asarray(r["ee"])[5, 0] > 0),
            }
        )
    return pd.DataFrame(rows)


def catch_verdict(summary: pd.DataFrame, settings: Mapping[str, Any]) -> list[report.Verdict]:
    """Fig 5.3: a learned BIC movement catches the ball after taut and slack string phases."""
    ok = summary[summary.success]
    times = ", ".join(f"{t:.2f}" for t in ok.catch_time)
    evidence = (
        f"reproduced: {len(ok)}/{len(summary)} CMA-ES runs caught the ball within {settings['generations']} "
        f"generations" + (f" (catch times {times} s)" if len(ok) else "") + f"; {int(ok.taut_and_slack.sum())} "
        f"alternate taut and slack string phases before the catch; {int(ok.moves_right_first.sum())} first move "
        "right as the thesis's movement does (thesis: one successful movement from demonstrations, shown as a "
        "figure; the discount γ^m of Eq 5.12 rewards early catches, so learned movements can be quicker flicks)"
    )
    holds = bool(ok.taut_and_slack.any())
    claim = "A learned movement catches the ball after taut and slack string phases (Fig 5.3)"
    return [report.Verdict("5.3", claim, report.status(holds, settings["scale"]), evidence)]


# ---------------------------------------------------------------- Figures 5.4 / 5.5: the transfer grid
def source_settings(settings: Mapping[str, Any], family: str, seed: int) -> dict[str, Any]:
    """The source config of ``family`` from a figure's settings (``settings["source"]``)."""
    return source_config(family, seed=seed, **settings["source"])


def grid_jobs(settings: Mapping[str, Any], strategies: Sequence[str]) -> tuple[list[Job], list[dict[str, Any]]]:
    """Source and target jobs for every (source, target, strategy, seed).

    ``settings`` has ``families``, ``seeds``, ``source`` (source overrides) and ``target`` (target
    overrides). Returns ``(source_jobs, rows)``; each row holds ``source``, ``target``, ``strategy``,
    ``seed`` and its ``job``. Source jobs are deduplicated (shared by the strategies that use them).
    """
    for s in strategies:
        check_choice(s, STRATEGIES, "strategy")
    sources: dict[str, Job] = {}
    rows = []
    for seed in settings["seeds"]:
        for src in settings["families"]:
            cfg = source_settings(settings, src, seed)
            for strategy in strategies:
                if strategy in COMPETITORS:
                    source = Job("arm-competitor-source", {**cfg, "policy": strategy})
                else:
                    source = Job("arm-source", cfg)
                sources.setdefault(source.key, source)
                for tgt in settings["families"]:
                    tcfg = {
                        **TARGET_DEFAULTS,
                        **settings["target"],
                        "source": cfg,
                        "target": tgt,
                        "strategy": strategy,
                        "seed": seed,
                    }
                    job = Job("arm-target", tcfg)
                    rows.append({"source": src, "target": tgt, "strategy": strategy, "seed": seed, "job": job})
    return list(sources.values()), rows


def _transfer_grid(strategies: Sequence[str]) -> Any:
    def grid(settings: Mapping[str, Any]) -> list[Job]:
        sources, rows = grid_jobs(settings, strategies)
        return [*sources, *(r["job"] for r in rows)]

    return grid


_ARM_KINDS = ("arm-source", "arm-competitor-source", "arm-target")
register("5.4", "Transfer strategies to BIC: learning curves; total cost and success", _ARM_KINDS[::2])(
    _transfer_grid(TRANSFER)
)
register("5.5", "Tensor transfer vs ELLA / RBF-ELLA / FCNN", _ARM_KINDS)(_transfer_grid(FIG55_METHODS))


def run_grid(
    settings: Mapping[str, Any], strategies: Sequence[str], n_jobs: int | None = None
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Run (or load) a transfer grid; returns ``(summary, curves)`` labelled "reproduced".

    ``summary``: one row per (source, target, strategy, seed) with ``pair``, ``success_rate`` and
    ``total_cost`` (mean over target tasks). ``curves``: long format ``trials``, ``cost``, ``success``
    (means over the target tasks) and ``cost_successful`` (mean over the targets that succeeded at the end,
    the thesis's convention for Fig 5.4a; NaN if none) per (source, target, strategy, seed).
    """
    src_jobs, rows = grid_jobs(settings, strategies)
    run_jobs(src_jobs, n_jobs=n_jobs, desc="arm sources")
    results = run_jobs([r["job"] for r in rows], n_jobs=n_jobs, desc="arm targets")
    summary, curves = [], []
    for row, res in zip(rows, results, strict=True):
        key = {k: row[k] for k in ("source", "target", "strategy", "seed")}
        summary.append(
            {
                **key,
                "pair": f"{row['source']}→{row['target']}",
                "success_rate": res["success_rate"],
                "total_cost": res["mean_total_cost"],
                "final_cost": float(np.mean(res["final_cost"])),
                "label": "reproduced",
            }
        )
        ok = np.asarray(res["final_success"]) > 0
        cost_ok = res["curve"][ok].mean(0) if ok.any() else np.full(res["curve"].shape[1], np.nan)
        curves.append(
            pd.DataFrame(
                {
                    **key,
                    "trials": res["trials"],
                    "cost": res["curve"].mean(0),
                    "cost_successful": cost_ok,
                    "success": res["success_curve"].mean(0),
                }
            )
        )
    return pd.DataFrame(summary), pd.concat(curves, ignore_index=True)


def strategy_means(summary: pd.DataFrame, strategies: Sequence[str]) -> pd.DataFrame:
    """Mean total cost and success rate per strategy over all pairs (rows in ``strategies`` order)."""
    return summary.groupby("strategy")[["total_cost", "success_rate"]].mean().reindex(list(strategies))


def pair_wins(summary: pd.DataFrame, methods: Sequence[str]) -> pd.Series:
    """% of (source, target) pairs each method wins (smallest mean total cost)."""
    per_pair = summary.groupby(["pair", "strategy"]).total_cost.mean().unstack()
    return (per_pair.idxmin(axis=1).value_counts(normalize=True) * 100).reindex(list(methods), fill_value=0.0)


def transfer_verdict(summary: pd.DataFrame, settings: Mapping[str, Any]) -> list[report.Verdict]:
    """Fig 5.4's three claims: scratch fails on BIC/Cast; cost tensor < matrix < direct; tensor succeeds most."""
    scale = settings["scale"]
    mean = strategy_means(summary, TRANSFER)
    hard = summary[summary.target.isin(["bic", "cast"]) & (summary.strategy == "scratch")]
    scratch_hard = float(hard.success_rate.mean()) if len(hard) else float("nan")
    order = list(mean.sort_values("total_cost").index)
    n_pairs = summary.pair.nunique()
    tensor_pairs = int(((summary.strategy == "tensor") & (summary.success_rate >= 0.5)).sum())
    best_success = mean.success_rate.idxmax()
    means = ", ".join(f"{s} {c:.3g} / {r:.2f}" for s, (c, r) in mean.iterrows())
    return [
        report.Verdict(
            "5.4",
            "(i) Learning from scratch mostly fails on BIC and Cast targets",
            report.status(None if hard.empty else scratch_hard < 0.5, scale),
            f"reproduced scratch success rate on BIC/Cast targets: {scratch_hard:.2f} (thesis: mostly fails)",
        ),
        report.Verdict(
            "5.4",
            "(ii) Total cost of learning: tensor < matrix < direct",
            report.status(
                order.index("tensor") < order.index("matrix") < order.index("direct"),
                scale,
                partly=order.index("tensor") < order.index("direct"),
            ),
            f"reproduced ordering by mean total cost: {' < '.join(order)} (mean total cost / success rate: {means})",
        ),
        report.Verdict(
            "5.4",
            "(iii) Tensor transfer has the highest success rate, high on most pairs",
            report.status(
                best_success == "tensor" and tensor_pairs > n_pairs / 2,
                scale,
                partly=best_success == "tensor" or tensor_pairs > n_pairs / 2,
            ),
            f"reproduced: highest mean success rate: {best_success}; tensor >= 50 % success on "
            f"{tensor_pairs}/{n_pairs} pairs",
        ),
    ]


def cast_to_bic(curves: pd.DataFrame, families: Sequence[str]) -> tuple[str, str, pd.DataFrame]:
    """Fig 5.5(a)'s pair (Cast → BIC, or the nearest families run) and its curves."""
    src = "cast" if "cast" in families else families[0]
    tgt = "bic" if "bic" in families else families[-1]
    return src, tgt, curves[(curves.source == src) & (curves.target == tgt)]


def competitor_verdict(
    summary: pd.DataFrame, curves: pd.DataFrame, settings: Mapping[str, Any]
) -> list[report.Verdict]:
    """Fig 5.5's claims: (a) on Cast → BIC tensor starts and ends best; (b) best average cost, most pairs won."""
    scale = settings["scale"]
    src, tgt, d = cast_to_bic(curves, settings["families"])
    start = d.groupby("strategy").cost.apply(lambda c: c.iloc[:5].mean()).reindex(list(FIG55_METHODS))
    end = d.groupby("strategy").cost.apply(lambda c: c.iloc[-5:].mean()).reindex(list(FIG55_METHODS))
    avg = strategy_means(summary, FIG55_METHODS).total_cost
    wins = pair_wins(summary, FIG55_METHODS)
    a = [start.idxmin() == "tensor", end.idxmin() == "tensor"]
    b = [avg.idxmin() == "tensor", bool(wins.idxmax() == "tensor" and wins["tensor"] > 50.0)]
    fmt = lambda s: ", ".join(f"{k} {v:.3g}" for k, v in s.items())  # noqa: E731
    return [
        report.Verdict(
            "5.5",
            f"(a) On {src} → {tgt} tensor transfer starts better and converges to a better cost",
            report.status(all(a), scale, partly=any(a)),
            f"reproduced mean cost of the first 5 generations: {fmt(start)}; of the last 5: {fmt(end)}",
        ),
        report.Verdict(
            "5.5",
            "(b) Tensor transfer has by far the best average total cost and wins most pairs",
            report.status(all(b), scale, partly=any(b)),
            f"reproduced average total cost: {fmt(avg)}; % of pairs won: {fmt(wins)}",
        ),
    ]


# ---------------------------------------------------------------- Figure 5.6: curriculum
def curriculum_jobs(settings: Mapping[str, Any]) -> list[dict[str, Any]]:
    """One row per (condition, seed) with its job, from a figure's settings."""
    keys = [k for k in CURRICULUM_DEFAULTS if k in settings and k != "seed"]
    rows = []
    for seed in settings["seeds"]:
        for condition in CONDITIONS:
            cfg = {**CURRICULUM_DEFAULTS, **{k: settings[k] for k in keys}, "condition": condition, "seed": seed}
            rows.append({"condition": condition, "seed": seed, "job": Job("arm-curriculum", cfg)})
    return rows


register("5.6", "Curriculum Reach → Throw → BIC vs no curriculum", ["arm-curriculum"])(
    lambda settings: [r["job"] for r in curriculum_jobs(settings)]
)


def run_curriculum(
    settings: Mapping[str, Any], n_jobs: int | None = None
) -> tuple[pd.DataFrame, pd.DataFrame, pd.DataFrame]:
    """Run (or load) Fig 5.6; returns ``(curves, final, pretraining)`` frames, labelled "reproduced".

    ``curves``: cost and success of the BIC population per trial; ``final``: success rate of the learned
    BIC policies per (condition, seed); ``pretraining``: cost and population success at the end of each
    pre-training stage.
    """
    rows = curriculum_jobs(settings)
    results = run_jobs([r["job"] for r in rows], n_jobs=n_jobs, desc="fig-5.6 curriculum")
    curves, final, pre = [], [], []
    for r, res in zip(rows, results, strict=True):
        key = {"condition": r["condition"], "seed": r["seed"]}
        curves.append(
            pd.DataFrame(
                {
                    **key,
                    "trials": res["trials"],
                    "cost": res["curve"],
                    "success": res["success_curve"],
                    "label": "reproduced",
                }
            )
        )
        final.append({**key, "final_success": float(res["success_rate"])})
        for k in res:
            if k.startswith("pretrain_") and k.endswith("_curve"):
                stage = k[len("pretrain_") : -len("_curve")]
                pre.append(
                    {
                        **key,
                        "stage": stage,
                        "cost": float(res[k][-1]),
                        "population_success": float(res[f"pretrain_{stage}_success"][-1]),
                    }
                )
    return pd.concat(curves, ignore_index=True), pd.DataFrame(final), pd.DataFrame(pre)


def curriculum_end(curves: pd.DataFrame) -> pd.DataFrame:
    """Mean cost and success over the last 10 % of BIC trials, per condition (mean over seeds)."""
    tail = curves.groupby(["condition", "seed"])[["cost", "success"]].apply(
        lambda d: d.iloc[-max(1, len(d) // 10) :].mean()
    )
    return tail.groupby("condition").mean().reindex(list(CONDITIONS))


def curriculum_verdict(
    curves: pd.DataFrame, final: pd.DataFrame, pretraining: pd.DataFrame, settings: Mapping[str, Any]
) -> list[report.Verdict]:
    """Fig 5.6: the curriculum beats no curriculum on BIC and solves it; NC fails (the thesis's premise)."""
    scale = settings["scale"]
    end = curriculum_end(curves)
    fin = final.groupby("condition").final_success.mean().reindex(list(CONDITIONS))
    cl, nc = end.loc["CL"], end.loc["NC"]
    better = bool(cl["cost"] < nc["cost"] and cl["success"] > nc["success"])
    nc_pre = pretraining[(pretraining.condition == "NC") & (pretraining.stage == "bic")].population_success.mean()
    return [
        report.Verdict(
            "5.6",
            "With the curriculum BIC is learned better than without (lower cost, higher success)",
            report.status(better, scale, partly=bool(cl["cost"] < nc["cost"] or cl["success"] > nc["success"])),
            f"reproduced, last 10 % of BIC trials: CL cost {cl['cost']:.3g} / success {cl['success']:.2f}, "
            f"NC cost {nc['cost']:.3g} / success {nc['success']:.2f}",
        ),
        report.Verdict(
            "5.6",
            "The curriculum solves BIC (final success of the learned policies >= 50 %)",
            report.status(bool(fin["CL"] >= 0.5), scale),
            f"reproduced final success rate: CL {fin['CL']:.2f}, NC {fin['NC']:.2f}",
        ),
        report.Verdict(
            "5.6",
            "Without the curriculum BIC is not learned (the thesis's premise)",
            report.status(bool(nc_pre <= 0.1 and fin["NC"] < 0.5), scale),
            f"reproduced: MTL on BIC alone reaches a population success rate of {nc_pre:.2f} during pre-training "
            f"and a final success rate of {fin['NC']:.2f}",
        ),
    ]
