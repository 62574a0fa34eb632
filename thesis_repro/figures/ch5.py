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

from thesis_repro.arm.baselines import COMPETITORS, STRATEGIES, TARGET_DEFAULTS, TRANSFER
from thesis_repro.arm.curriculum import CONDITIONS, CURRICULUM_DEFAULTS
from thesis_repro.arm.learn import source_config
from thesis_repro.arm.tasks import SIM_VERSION, ArmConfig
from thesis_repro.core.backends import run_jobs
from thesis_repro.core.cache import Job, Result
from thesis_repro.core.validation import check_choice
from thesis_repro.figures import register_figure

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


register_figure("5.3", "A successful ball-in-cup movement (string taut / slack)", ["arm-solve"])(solve_jobs)


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
register_figure("5.4", "Transfer strategies to BIC: learning curves; total cost and success", _ARM_KINDS[::2])(
    _transfer_grid(TRANSFER)
)
register_figure("5.5", "Tensor transfer vs ELLA / RBF-ELLA / FCNN", _ARM_KINDS)(_transfer_grid(FIG55_METHODS))


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


def strategy_seed_means(summary: pd.DataFrame, strategies: Sequence[str]) -> pd.DataFrame:
    """Per training seed, each strategy's mean total cost and success rate over all pairs: columns
    ``strategy, seed, total_cost, success_rate`` (the unit of replication for the figures' 95 % CI bars).

    >>> s = pd.DataFrame({"strategy": ["a", "a", "a", "a"], "seed": [0, 0, 1, 1], "pair": ["p", "q", "p", "q"],
    ...                   "total_cost": [1.0, 3.0, 5.0, 7.0], "success_rate": [0.0, 1.0, 1.0, 1.0]})
    >>> strategy_seed_means(s, ["a"]).values.tolist()
    [['a', 0, 2.0, 0.5], ['a', 1, 6.0, 1.0]]
    """
    means = summary.groupby(["strategy", "seed"])[["total_cost", "success_rate"]].mean()
    return means.reindex(list(strategies), level="strategy").reset_index()


def pair_wins(summary: pd.DataFrame, methods: Sequence[str]) -> pd.Series:
    """% of (source, target) pairs each method wins (smallest mean total cost)."""
    per_pair = summary.groupby(["pair", "strategy"]).total_cost.mean().unstack()
    return (per_pair.idxmin(axis=1).value_counts(normalize=True) * 100).reindex(list(methods), fill_value=0.0)


def cast_to_bic(curves: pd.DataFrame, families: Sequence[str]) -> tuple[str, str, pd.DataFrame]:
    """Fig 5.5(a)'s pair (Cast → BIC, or the nearest families run) and its curves."""
    src = "cast" if "cast" in families else families[0]
    tgt = "bic" if "bic" in families else families[-1]
    return src, tgt, curves[(curves.source == src) & (curves.target == tgt)]


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


register_figure("5.6", "Curriculum Reach → Throw → BIC vs no curriculum", ["arm-curriculum"])(
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
