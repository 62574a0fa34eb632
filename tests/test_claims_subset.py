"""The registered trained-runs sensitivity check: the same frozen rule on the runs `budgets` calls
trained, beside the primary verdict, with the units and runs that remain."""

from __future__ import annotations

import dataclasses
import io
import json
from contextlib import redirect_stdout

import numpy as np
import pandas as pd
import pytest

from thesis_repro.claims import cli, design, ledger, ledger_row, page_verdicts, registry, report, scoreboard, store
from thesis_repro.claims import synthetic as S
from thesis_repro.runs import budgets

#: The claims registered with the check (chosen by wording: see the registry's header comment).
CHECKED = {
    "3.3-negative-correlation",
    "3.3-pareto",
    "3.3-mean-selection",
    "3.3-least-robust",
    "3.3-ii-noisy-test",
    "3.3-iii-no-clear-benefit",
    "3.3-iv-degradation-ameliorated",
}
UNTRAINED = "ppo"  # the variant whose runs are still learning in :func:`_points`


def _points() -> pd.DataFrame:
    """Fig 3.3's per-seed points: the trained variants trade training return for testing AUC (r < 0 in every cell),
    one under-trained variant low on both pulls every cell's r positive."""
    rng = np.random.default_rng(0)
    p = S.frames(3, seed=1)["points"].copy()
    x = rng.uniform(1000.0, 3000.0, len(p))
    p["train_return"] = x
    p["auc"] = 5000.0 - x + rng.normal(0.0, 50.0, len(p))
    low = p["algo"] == UNTRAINED
    p.loc[low, "train_return"] = -20000.0
    p.loc[low, "auc"] = -20000.0
    return p.assign(trained=~low)


def _judge(cid: str, page: str, frames: dict[str, pd.DataFrame], scale: str = "small") -> ledger_row.Row:
    store.save_page(page, scale, frames, {"scale": scale})
    return ledger.judge(registry.spec(cid), scale, with_null=False)


def test_the_registered_claims_and_the_names_are_checked():
    assert {s.id for s in registry.specs() if s.subset} == CHECKED
    assert all(s.subset == "trained" for s in registry.specs() if s.subset)
    reg = registry.registry()
    bad = {"fig-3.3": {"claims": [{**reg["fig-3.3"]["claims"][0], "sensitivity_subset": "converged"}]}}
    with pytest.raises(ValueError, match="unknown sensitivity_subset 'converged'; valid: trained"):
        registry.parse_specs(bad)
    derived = next(c for c in reg["fig-3.3"]["claims"] if c["id"] == "3.3-not-valid-metric")
    parts = [c for c in reg["fig-3.3"]["claims"] if c["id"] != derived["id"]]
    with pytest.raises(ValueError, match="goes with the entry whose rule has a measure"):
        registry.parse_specs({"fig-3.3": {"claims": [*parts, {**derived, "sensitivity_subset": "trained"}]}})


def test_the_field_is_outside_the_frozen_rule_hashes(monkeypatch):
    """Adding or removing the check changes no claim's hash: the frozen design holds either way."""
    before = design.rule_hashes()
    flipped = [dataclasses.replace(s, subset="" if s.subset else "trained") for s in registry.specs()]
    monkeypatch.setattr(registry, "specs", lambda: tuple(flipped))
    assert design.rule_hashes() == before
    assert design.check_frozen() == []


def test_the_check_is_the_rule_on_the_trained_rows_only():
    """The check's verdict and statistic are those of the same rule on a page holding only the trained rows."""
    p = _points()
    row = _judge("3.3-least-robust", "fig-3.3", {"points": p})
    sub = row.subset
    alone = _judge("3.3-least-robust", "fig-3.3", {"points": p[p["trained"]].drop(columns="trained")})
    # the check is design v2's rule on the subset (the registered sensitivity analysis of seeds 0-5)
    assert sub["available"] and sub["verdict"] == alone.v2_status and sub["primary"] == alone.v2_primary
    assert alone.subset["available"] is False  # that page saved no column
    n_runs = p[["algo", "env", "seed"]].drop_duplicates().shape[0]
    assert (sub["runs"], sub["runs_total"]) == (n_runs - 5 * 3, n_runs)  # the untrained variant's 5 tasks x 3 seeds
    assert sub["units"] == sub["units_total"] == 20


def test_an_under_trained_variant_turning_the_pooled_correlation_is_shown():
    p = _points()
    row = _judge("3.3-negative-correlation", "fig-3.3", {"points": p})
    assert row.status == report.DOES_NOT  # the primary verdict keeps every run
    sub = row.subset
    assert sub["verdict"] == report.REPRODUCES and sub["primary"]["pooled"]["estimate"] > 0  # r < 0: sign -1 in z
    alone = _judge("3.3-negative-correlation", "fig-3.3", {"points": p[p["trained"]]})
    for key in ("estimate", "ci", "n_seeds", "units"):
        assert sub["primary"]["pooled"][key] == alone.primary["pooled"][key]
    assert sub["line"].startswith("sensitivity, trained runs only (90/105 runs, 20/20 units): reproduces · pooled r -")


def test_units_that_lose_their_runs_are_counted():
    """A cell whose seeds keep fewer than 3 trained variants has no correlation left: fewer units remain."""
    p = _points()
    p.loc[p["env"] == "Hopper", "trained"] = False
    sub = _judge("3.3-negative-correlation", "fig-3.3", {"points": p}).subset
    assert (sub["units"], sub["units_total"]) == (16, 20) and sub["runs"] == 90 - 6 * 3


def test_table33_claims_filter_every_frame_and_3_3_i_has_no_check():
    f = S.frames(3, seed=4)
    # seed 2 of the deterministic PPO is still learning
    late = {k: (f[k]["method"] == "ppo") & (f[k]["seed"] == 2) for k in ("aucs", "returns", "train")}
    ok = {k: f[k].assign(trained=~late[k]) for k in late}
    row = _judge("3.3-ii-noisy-test", "table-3.3", ok)
    alone = _judge("3.3-ii-noisy-test", "table-3.3", {k: v[v["trained"]] for k, v in ok.items()})
    assert row.subset["verdict"] == alone.status and row.subset["primary"] == alone.primary
    assert row.subset["runs_total"] - row.subset["runs"] == 5  # PPO seed 2 on each of the 5 tasks of `aucs`
    assert _judge("3.3-i-training-return", "table-3.3", ok).subset == {}
    none = {k: v.assign(trained=v["method"] != "ppo-mdl") for k, v in ok.items()}  # no trained PPO-MDL run
    sub = _judge("3.3-iii-no-clear-benefit", "table-3.3", none).subset
    assert sub["verdict"] == report.NOT_COMPUTED and sub["units"] == 0 < sub["units_total"]
    assert sub["note"] == "no unit remains: no trained run of ppo-mdl" and sub["note"] in sub["line"]


def test_a_page_saved_before_the_column_degrades_to_not_available():
    p = _points().drop(columns="trained")
    row = _judge("3.3-negative-correlation", "fig-3.3", {"points": p})
    want = "not available: page saved before the trained column (rebuild the page)"
    assert row.subset["available"] is False and row.subset["note"] == want
    assert row.subset["line"] == f"sensitivity, trained runs only: {want}"
    assert row.status == _judge("3.3-negative-correlation", "fig-3.3", {"points": _points()}).status


def test_json_verbose_and_page_carry_the_check():
    store.save_page("fig-3.3", "small", {"points": _points()}, {"scale": "small"})
    out = io.StringIO()
    with redirect_stdout(out):
        ids = ["3.3-negative-correlation", "3.3-not-valid-metric"]
        cli.main(["--scale", "small", "--json", "--no-null", "--ids", *ids])
    got = {c["id"]: c for c in json.loads(out.getvalue())["claims"]}
    sens = got["3.3-negative-correlation"]["sensitivity"]
    assert sens["subset"] == "trained" and sens["verdict"] == report.REPRODUCES
    assert {"primary", "units", "units_total", "runs", "runs_total", "line"} <= set(sens)
    assert got["3.3-not-valid-metric"]["sensitivity"] is None  # derived: its parts carry the check
    out = io.StringIO()
    with redirect_stdout(out):
        cli.main(["--scale", "small", "--verbose", "--no-null", "--ids", "3.3-negative-correlation"])
    assert "    sensitivity, trained runs only (90/105 runs, 20/20 units): reproduces" in out.getvalue()
    vs = {v.claim.split(" (thesis")[0]: v for v in page_verdicts.verdicts("fig-3.3", "small")}
    first = vs[registry.spec("3.3-negative-correlation").text].evidence.split("\n\n")[0]
    assert first.startswith("sensitivity, trained runs only (90/105 runs") and "\n" not in first
    assert vs[registry.spec("3.3-not-valid-metric").text].evidence.startswith("design v3 verdict:")
    assert "**Subset sensitivity**" in scoreboard.method([])


def test_smoke_judges_nothing():
    sub = _judge("3.3-negative-correlation", "fig-3.3", {"points": _points()}, scale="smoke").subset
    assert sub["verdict"] == report.NOT_JUDGED and sub["runs"] == 90


def test_mark_trained_is_conservative_and_leaves_other_frames_alone():
    runs_table = pd.DataFrame(
        {
            "algo": ["ppo", "ppo", "sac"],
            "env": ["Hopper"] * 3,
            "seed": [0, 0, 0],
            "verdict": ["trained", "fell from its peak", "trained"],
        }
    )
    f = pd.DataFrame({"algo": ["ppo", "sac", "trpo"], "env": "Hopper", "seed": 0, "x": 1.0})
    curve = pd.DataFrame({"seed": [0], "iteration": [1]})
    got = budgets.mark_trained({"points": f, "curve": curve}, runs_table)
    assert got["points"]["trained"].tolist() == [False, True, False]  # listed twice, once not trained; not judged
    assert got["curve"] is curve and "trained" not in f.columns
