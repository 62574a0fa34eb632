"""Protocol sensitivity in the claims ledger: a protocol study's measured effect (the thesis protocol's
lr-schedule study, :mod:`thesis_repro.runs.study`) in the "why" of the claims the registry declares it on."""

from __future__ import annotations

import ast
import inspect

import numpy as np
import pandas as pd
import pytest

from thesis_repro.claims import diagnosis, evidence, ledger, ledger_row, registry, report, scoreboard, store
from thesis_repro.claims import synthetic as S
from thesis_repro.core.cache import RunCache
from thesis_repro.runs import study

#: The study's result as measured (README / `python -m thesis_repro.runs.study lr-schedule --summary`).
FAKE = study.Sensitivity(
    study="lr-schedule",
    setting="lr schedule",
    learner="PPO",
    budget="1M steps",
    contrast="linear - constant",
    measure="final training return",
    effects=(
        study.Effect("InvertedDoublePendulum", 58.0, (-4964.0, 5080.0), 0.97, (3, 3)),
        study.Effect("Hopper", 122.0, (-613.0, 856.0), 0.67, (3, 3)),
    ),
)
EXPECTED = (
    "protocol sensitivity (lr schedule, PPO, 1M steps, 3 seeds; final training return, linear - constant): "
    "IDP +58 (95 % CI -4,964 to 5,080), Hopper +122 (-613 to 856): within seed spread"
)


def _ppo_behind_on_pendulums() -> pd.DataFrame:
    """Table 3.4's AUCs with PPO far below TRPO on the pendulums: 3.4-ppo-pendulums does not reproduce."""
    a = S.frames(3, seed=2)["aucs"]
    a = a[a["method"].isin(["ppo", "trpo"])].copy()
    low = (a["method"] == "ppo") & a["env"].str.startswith("Inverted")
    a.loc[low, "value"] -= 100.0
    return a


def _judge_table34() -> dict[str, ledger_row.Row]:
    store.save_page("table-3.4", "small", {"aucs": _ppo_behind_on_pendulums()}, {"scale": "small"})
    return {
        cid: ledger.judge(registry.spec(cid), "small", with_null=False)
        for cid in ("3.4-ppo-pendulums", "3.4-sac-walker")
    }


def test_sensitivity_text_appears_for_a_declared_claim(monkeypatch):
    monkeypatch.setitem(study.STUDIES, "lr-schedule", lambda: FAKE)
    assert diagnosis.sensitivity_text(FAKE) == EXPECTED
    rows = _judge_table34()
    row = rows["3.4-ppo-pendulums"]
    assert registry.spec("3.4-ppo-pendulums").sensitivity == ("lr-schedule",)
    assert row.status == report.DOES_NOT
    assert EXPECTED in row.diagnosis and "why: " in evidence.describe(row)
    js = row.as_dict()
    assert js["sensitivity_studies"] == ["lr-schedule"]
    (m,) = js["protocol_sensitivity"]
    assert m["within_seed_spread"] and m["effects"][0]["ci"] == [-4964.0, 5080.0]
    # a claim on the same page that declares no study gets no sensitivity, whatever its verdict
    assert "protocol sensitivity" not in rows["3.4-sac-walker"].diagnosis
    # a setting that moves a task beyond the seed spread is said so
    moved = study.Sensitivity(
        **{**FAKE.__dict__, "effects": (study.Effect("Hopper", 900.0, (100.0, 1700.0), 0.03, (3, 3)),)}
    )
    assert diagnosis.sensitivity_text(moved).endswith(
        "Hopper +900 (95 % CI 100 to 1,700): outside seed spread on Hopper (the CI excludes 0)"
    )


def test_one_seed_leaning_away_from_the_claim_still_shows_the_study(monkeypatch):
    """Indicative rows have no seed spread to report, but a lean towards 'does not' gets the measured protocol
    sensitivity (and no 'significantly against' from a single seed); a lean towards 'reproduces' gets no why."""
    monkeypatch.setitem(study.STUDIES, "lr-schedule", lambda: FAKE)
    a = _ppo_behind_on_pendulums()
    one = a[a["seed"] == 0]
    store.save_page("table-3.4", "small", {"aucs": one}, {"scale": "small"})
    row = ledger.judge(registry.spec("3.4-ppo-pendulums"), "small", with_null=False)
    assert row.status == report.INDICATIVE and "lean 'does not reproduce'" in row.note
    assert EXPECTED in row.diagnosis and "significantly against" not in row.diagnosis
    assert "median 95 % CI width" not in row.diagnosis
    flip = one.copy()
    flip.loc[flip["method"] == "ppo", "value"] += 1000.0  # PPO far ahead everywhere: the lean is 'reproduces'
    store.save_page("table-3.4", "small", {"aucs": flip}, {"scale": "small"})
    row = ledger.judge(registry.spec("3.4-ppo-pendulums"), "small", with_null=False)
    assert row.status == report.INDICATIVE and "lean 'reproduces'" in row.note and row.diagnosis == ""


def test_nothing_is_said_when_the_study_runs_are_missing(monkeypatch):
    """conftest points the run cache and the shipped layer at empty folders: no run, no sensitivity, no training."""

    def no_training(self, job):  # noqa: ANN001
        raise AssertionError(f"the ledger trained {job.label}")

    monkeypatch.setattr(RunCache, "run", no_training)
    monkeypatch.setattr(RunCache, "compute", no_training)
    assert study.lr_schedule_sensitivity() is None
    row = _judge_table34()["3.4-ppo-pendulums"]
    assert row.status == report.DOES_NOT and row.diagnosis  # still diagnosed (seed spread) ...
    assert "protocol sensitivity" not in row.diagnosis and row.sensitivity == []  # ... but silent on sensitivity
    assert "runs are not available" in diagnosis.sensitivity_method()


class _FakeCache:
    """Final training returns per (task, schedule, seed), as a run cache would load them (only some runs)."""

    def __init__(self, returns: dict[tuple[str, str], list[float]]):
        self.returns = returns

    def load(self, job):  # noqa: ANN001
        vals = self.returns.get((job.config["env"], job.config["lr_schedule"]), [])
        seed = job.config["seed"]
        if seed >= len(vals):
            return None
        return {"train_return": vals[seed], "curve_return": [vals[seed] / 2, vals[seed]]}


def test_the_sensitivity_is_computed_from_the_runs_with_the_summary_s_welch():
    """Ledger and ``--summary`` read one function; a task without 2 seeds per schedule is left out."""
    from scipy.stats import ttest_ind

    lin, const = [5868.0, 9054.0, 7629.0], [8897.0, 4621.0, 8861.0]
    cache = _FakeCache(
        {
            ("InvertedDoublePendulum", "linear"): lin,
            ("InvertedDoublePendulum", "constant"): const,
            ("Hopper", "linear"): [2000.0],  # one seed: no CI, not reported
            ("Hopper", "constant"): [1900.0, 1800.0],
        }
    )
    m = study.lr_schedule_sensitivity(cache)
    (e,) = m.effects
    ci = ttest_ind(lin, const, equal_var=False).confidence_interval(0.95)
    assert e.task == "InvertedDoublePendulum" and e.n == (3, 3)
    assert e.difference == pytest.approx(np.mean(lin) - np.mean(const)) and e.ci == pytest.approx((ci.low, ci.high))
    assert m.seeds == "3 seeds" and m.within_spread
    text = study.study_table(study.lr_schedule_jobs(), cache)
    assert f"= {e.difference:,.0f} (Welch 95 % CI {e.ci[0]:,.0f} to {e.ci[1]:,.0f}" in text
    assert "\nHopper:" not in text and "| Hopper (1M) | linear | 1/3 |" in text
    assert study.lr_schedule_sensitivity(_FakeCache({})) is None


def _registry(**extra) -> dict:
    claim = {"id": "x-claim", "text": "A sentence.", "lines": [1], "rule": {"measure": "better"}, **extra}
    return {"table-3.4": {"claims": [claim]}}


def test_the_registry_field_is_validated():
    (s,) = registry.parse_specs(_registry(sensitivity=["lr-schedule"]))
    assert s.sensitivity == ("lr-schedule",)
    assert registry.parse_specs(_registry())[0].sensitivity == ()
    valid = "valid: lr-schedule, reptile-outer-step, maml-outer-update$"
    with pytest.raises(ValueError, match=rf"unknown sensitivity study 'lr-shedule'; {valid}") as err:
        registry.parse_specs(_registry(sensitivity=["lr-shedule"]))
    assert "\n" not in str(err.value) and "x-claim" in str(err.value)
    with pytest.raises(ValueError, match="must be a list"):
        registry.parse_specs(_registry(sensitivity="lr-schedule"))


def test_the_registry_declares_lr_schedule_on_chapter_3_ppo_claims():
    declared = {s.id for s in registry.specs() if "lr-schedule" in s.sensitivity}
    assert declared == {
        "3.2-overfitting",
        "3.3-negative-correlation",
        "3.3-pareto",
        "3.3-mean-selection",
        "3.3-least-robust",
        "3.3-i-training-return",
        "3.4-ppo-pendulums",
    }
    assert all(registry.spec(cid).page.split("-")[1].startswith("3.") for cid in declared)


def test_the_method_section_explains_protocol_sensitivity(monkeypatch):
    monkeypatch.setitem(study.STUDIES, "lr-schedule", lambda: FAKE)
    text = scoreboard.method([])
    assert "**Protocol sensitivity**" in text and "`lr-schedule`, declared on 3.2-overfitting" in text
    assert "3.4-ppo-pendulums: " + EXPECTED in text


def test_study_imports_neither_claims_nor_figures():
    """Imports run one way: the claims layer may import the study, the study neither claims nor figures."""
    tree = ast.parse(inspect.getsource(study))
    names = [a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names]
    names += [n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)]
    names += [
        f"{n.module}.{a.name}" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module for a in n.names
    ]
    assert not [m for m in names if m.startswith(("thesis_repro.claims", "thesis_repro.figures"))]
