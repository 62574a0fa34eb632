"""Claims design v3: seed-keyed statistics, linear margins, compound units, multiplicity, conjunctions, the gate.

Each fix of v2 has a test that fails on the v2 rule and passes on v3's.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from thesis_repro.claims import design, judge_v3, report
from thesis_repro.claims import stats as S
from thesis_repro.claims import stats_v3 as T
from thesis_repro.claims.calibration import calibrate, calibration_v3
from thesis_repro.claims.measures import ch4
from thesis_repro.claims.measures.common import Inconclusive
from thesis_repro.claims.seeds import Seeded, joined, series
from thesis_repro.claims.stats import Contrast, CountRule, Unit


def _seeded(rng: np.random.Generator, seeds: list[int], mu: float = 0.0, sd: float = 1.0) -> Seeded:
    return Seeded(mu + sd * rng.standard_normal(len(seeds)), seeds)


def _shuffled(x: Seeded, rng: np.random.Generator) -> Seeded:
    order = rng.permutation(len(x))
    return Seeded([x[i] for i in order], [x.seeds[i] for i in order])


# ---------------------------------------------------------------- seed-keyed statistics
@pytest.mark.parametrize("case", range(40))
def test_every_statistic_is_unchanged_by_seed_order_and_correctly_missing_when_seeds_drop(case):
    """Property: shuffling the seed order changes nothing; dropping seeds at random leaves exactly those seeds out
    (a paired test on the seeds both sides hold, a pooled test averaging each seed over the units holding it)."""
    rng = np.random.default_rng(case)
    seeds = list(range(6))
    units = []
    for u in range(4):
        a, b = _seeded(rng, seeds, 1.0 + u), _seeded(rng, seeds, 0.5 + u)
        paired = bool(u % 2)
        units.append(Unit(f"u{u}", (Contrast("a - b", a, b, paired=paired),)))
    shuffled = [
        Unit(u.label, (Contrast("a - b", _shuffled(c.a, rng), _shuffled(c.b, rng), paired=c.paired),))
        for u in units
        for c in u.parts
    ]
    for u, v in zip(units, shuffled, strict=True):
        assert T.contrast_test(u.parts[0], 0.1) == T.contrast_test(v.parts[0], 0.1)
    assert T.pooled_test(units, 0.1) == T.pooled_test(shuffled, 0.1)
    # drop random seeds from random sides
    dropped = []
    for u in units:
        c = u.parts[0]
        keep_a = sorted(rng.choice(seeds, size=int(rng.integers(3, 7)), replace=False))
        keep_b = sorted(rng.choice(seeds, size=int(rng.integers(3, 7)), replace=False))
        a = Seeded([series(c.a)[k] for k in keep_a], keep_a)
        b = Seeded([series(c.b)[k] for k in keep_b], keep_b)
        dropped.append(Unit(u.label, (Contrast("a - b", a, b, paired=c.paired),)))
    # the pooled per-seed values by hand: each unit's a - b at the seeds both sides hold, scaled by |mean(b)| over
    # b's other seeds
    by_seed: dict[int, list[float]] = {}
    for u in dropped:
        c = u.parts[0]
        keys, a, b = joined(c.a, c.b)
        for k, x, y in zip(keys, a, b, strict=True):
            sc = abs(float(np.mean([v for s, v in series(c.b).items() if s != k])))
            by_seed.setdefault(k, []).append((x - y) / sc)
    want = np.array([np.mean(by_seed[k]) for k in sorted(by_seed)])
    got = T.pooled_test(dropped, 0.1)
    assert got.n == want.size
    assert got.est == pytest.approx(float(want.mean()))
    paired = dropped[1].parts[0]
    keys, a, b = joined(paired.a, paired.b)
    assert T.contrast_test(paired, 0.0).n == len(keys)


def test_a_missing_seed_is_missing_not_a_shift_where_v2_shifted_it():
    """A unit without seed 0 (e.g. every variant at the ceiling there): v2 put seed 1's value in seed 0's slot."""
    a = Unit("a", (Contrast("r", Seeded((0.9, 0.1, 0.5), (0, 1, 2)), kind="r"),))
    b = Unit("b", (Contrast("r", Seeded((-0.9, -0.1), (1, 2)), kind="r"),))
    # by seed: seed 0 only a (0.9 -> z), seed 1: a 0.1 and b -0.9, seed 2: a 0.5 and b -0.1
    z = np.arctanh
    want = [z(0.9), (z(0.1) + z(-0.9)) / 2, (z(0.5) + z(-0.1)) / 2]
    assert T.pooled_test([a, b], 0.1).est == pytest.approx(float(np.mean(want)))
    assert S.pooled([a, b], 0.1).est != pytest.approx(float(np.mean(want)))  # v2: position-paired


def test_the_headlines_fresh_seed_interval_is_the_seed_aligned_one(shipped):
    from thesis_repro.claims import ledger, registry
    from thesis_repro.claims.confirmatory import fresh_frames
    from thesis_repro.claims.store import page_data

    s = registry.spec("3.3-negative-correlation")
    row = ledger.judge(s, "small")
    frames, _ = page_data(s, "small")
    pts = fresh_frames(frames)["points"]
    by_seed: dict[int, list[float]] = {}
    for (_env, _test, seed), g in pts.groupby(["env", "test", "seed"]):
        g = g.dropna(subset=["train_return", "auc"])
        if len(g) >= 3 and g["train_return"].std() > 0 and g["auc"].std() > 0:
            by_seed.setdefault(int(seed), []).append(float(np.arctanh(np.corrcoef(g["train_return"], g["auc"])[0, 1])))
    x = np.array([np.mean(by_seed[k]) for k in sorted(by_seed)])
    h = float(__import__("scipy").stats.t.ppf(0.975, x.size - 1)) * x.std(ddof=1) / math.sqrt(x.size)
    lo, hi = math.tanh(x.mean() - h), math.tanh(x.mean() + h)
    assert f"[{lo:+.2f}, {hi:+.2f}]" in row.confirmation.ours


# ---------------------------------------------------------------- the v2 rules each fix replaces
def test_a_margin_on_a_noisy_mean_is_tested_linearly_at_nominal_where_v2s_ratio_was_not():
    """'Drops by more than 25 %' pooled over many curves, each at exactly 25 %, with noisy σ = 0 returns: v2
    divided each seed's drop by the noisy mean (a biased ratio) and passed nulls above nominal."""
    rng = np.random.default_rng(0)

    def unit(i: int) -> Unit:
        b = 100 + 60 * rng.standard_normal(3)
        a = 0.75 * b + 20 * rng.standard_normal(3)
        c = Contrast("drop", Seeded(a, range(3)), Seeded(b, range(3)), sign=-1, paired=True, relative=True, margin=0.25)
        return Unit(f"curve {i}", (c,))

    groups = {"": [unit(i) for i in range(40)]}
    rules = {"": CountRule(0.5, 0.25)}
    v2 = calibrate(groups, "pooled", 0.0, rules, draws=400)
    v3 = calibration_v3(groups, "pooled", 0.0, rules, False, {}, draws=400)
    assert v2["false_reproduces"] > judge_v3.gate_limit(400)
    assert v3["false_reproduces"] <= judge_v3.gate_limit(400)


def test_a_unit_of_several_contrasts_at_the_margin_is_not_almost_always_does_not():
    """v2 took each seed's minimum over noisy contrasts (biased low): at the margin it said 'does not' ~always."""
    rng = np.random.default_rng(1)

    def unit(i: int) -> Unit:
        b = 100 + 10 * rng.standard_normal((3, 3))
        parts = tuple(Contrast(f"ppo - x{j}", Seeded(b[j] + 5, range(3)), Seeded(b[j], range(3))) for j in range(3))
        return Unit(f"row {i}", parts)

    groups = {"": [unit(i) for i in range(8)]}
    rules = {"": CountRule(0.5, 0.25)}
    v2 = calibrate(groups, "pooled", 0.05, rules, draws=300)
    v3 = calibration_v3(groups, "pooled", 0.05, rules, False, {}, draws=300)
    assert v2["false_does_not"] > 0.5
    assert v3["false_does_not"] <= judge_v3.gate_limit(300)


def test_twenty_null_units_rarely_give_a_yes_under_holm():
    """'Sometimes improves' from 1 of 20 units: v2 tested each at 5 %, so nulls gave a yes ~40 % of the time."""
    rng = np.random.default_rng(2)
    rule = CountRule(1, None, absolute=True)
    v2 = v3 = 0
    draws = 400
    for _ in range(draws):
        units = [
            Unit(f"r{i}", (Contrast("a - b", _seeded(rng, [0, 1, 2], 1.0), _seeded(rng, [0, 1, 2], 1.0)),))
            for i in range(20)
        ]
        v2 += S.judge_count_v2(rule, units, 0.05).status == report.REPRODUCES
        v3 += judge_v3.judge_v3({"": units}, "count", 0.05, {"": rule}, summaries=False).status == report.REPRODUCES
    assert v2 / draws > 0.2
    assert v3 / draws <= judge_v3.gate_limit(draws)


def test_one_part_of_a_conjunction_does_not_carry_the_claim():
    yes = Unit("return rises", (Contrast("up", Seeded((5.0, 5.2, 5.1), range(3)), Seeded((1.0, 1.1, 0.9), range(3))),))
    und = Unit("AUC falls", (Contrast("down", Seeded((1.0, 9.0, 3.0), range(3)), Seeded((2.0, 4.0, 6.0), range(3))),))
    rules = {"": CountRule(1.0, 0.5)}
    assert S.judge_count_v2(rules[""], [yes, und], 0.05).status == report.AT_LEAST_PARTLY
    assert judge_v3.judge_v3({"": [yes, und]}, "each", 0.05, rules, conjunction=True).status == report.INCONCLUSIVE


def test_a_test_shared_by_two_claims_counts_once_in_holms_family(shipped):
    from thesis_repro.claims import ledger, registry
    from thesis_repro.claims.store import one_pass

    with one_pass():
        s = registry.spec("3.6-entropy")
        v2 = ledger.family_p(s, "small")
        row = ledger.judge(s, "small")
    fam3 = row.primary["pooled"]["holm_family"]
    assert fam3 == len(v2)  # v2's family + its own test, less the duplicate of 3.6-promising's ppo-ent part


def test_a_unit_on_the_claims_side_but_below_its_margin_is_not_called_against_the_claim():
    c = Contrast("a - b", Seeded((1.09, 1.1, 1.11), range(3)), Seeded((1.0, 1.0, 1.0), range(3)), paired=True)
    t = T.contrast_test(c, 0.5)
    d = judge_v3._test_dict("a - b", t, 0.5)
    assert d["outcome"] == S.NO and d["below_margin"]
    from thesis_repro.claims.diagnosis import diagnose

    class J:
        units = [{"label": "u", "outcome": "no", "contrasts": [d]}]
        level = 0.95

    text = diagnose({"": J}, {})
    assert "below its margin" in text and "against the claim" not in text


def test_a_margin_stated_on_the_centre_is_a_fraction_of_the_centre():
    c = Contrast("centre - ring", Seeded((100.0, 110.0), range(2)), Seeded((10.0, 12.0), range(2)), scale_by="a")
    assert T.scale(c) == (105.0, 1.0)
    assert S.contrast_scale(c) == 11.0  # v2: the outer ring's mean, against its own margin basis


def test_a_diverged_run_never_enters_a_claim():
    def curves(diverged: set[tuple[str, int]]) -> pd.DataFrame:
        rows = []
        for algo in ("kl_avg", "joint"):
            for seed in range(3):
                late = -5.0 if (algo, seed) in diverged else 900.0
                for panel in "ab":
                    for it in range(9):
                        r = 1000.0 if it < 3 else late
                        rows.append({"algo": algo, "panel": panel, "seed": seed, "iteration": it, "return": r})
        return pd.DataFrame(rows).assign(entropy=1.0)

    kept = ch4.learned_curves(curves({("kl_avg", 0), ("joint", 2)}), "kl_avg")  # those two runs are left out
    pairs = set(zip(kept["algo"], kept["seed"], strict=True))
    assert pairs == {("kl_avg", 1), ("kl_avg", 2), ("joint", 0), ("joint", 1)}
    with pytest.raises(Inconclusive, match=ch4.DIVERGED):
        ch4.learned_curves(curves({("kl_avg", s) for s in range(3)}), "kl_avg")


# ---------------------------------------------------------------- the thesis's effect, the gate, the freeze
def test_the_thesiss_own_effect_is_tested():
    u = Unit("cell", (Contrast("r", Seeded((0.8, 0.7, 0.9, 0.85), range(4)), sign=-1, kind="r"),))
    got = T.thesis_excluded([u], {"cell": 0.43})
    assert got["excluded"] and got["ours_side"] == "larger" and got["thesis"] == pytest.approx(-0.43)
    assert T.thesis_excluded([u], {}) is None


def test_the_gate_relabels_a_rule_outside_its_calibration_or_that_cannot_be_settled():
    ok = {"false_reproduces": 0.03, "false_does_not": 0.02, "draws": 2000, "seeds_for_80": 6, "effect": "thesis"}
    assert judge_v3.gated(report.REPRODUCES, ok) == (report.REPRODUCES, "")
    assert judge_v3.gated(report.REPRODUCES, {**ok, "false_reproduces": 0.128})[0] == report.NOT_CALIBRATED
    assert judge_v3.gated(report.REPRODUCES, {**ok, "draws": 1000})[0] == report.NOT_CALIBRATED
    low = {**ok, "seeds_for_80": None, "power_at": 0.0}
    assert judge_v3.gated(report.INCONCLUSIVE, low)[0] == report.CANNOT_SETTLE
    assert judge_v3.gated(report.INCONCLUSIVE, {**low, "effect": "margin"})[0] == report.INCONCLUSIVE
    assert judge_v3.gated(report.NOT_RUN, {}) == (report.NOT_RUN, "")


@pytest.mark.xdist_group("snapshot-ledger")  # conftest.SNAPSHOT_LEDGER_GROUP: one judging for all
def test_no_plain_verdict_rests_on_a_rule_outside_the_calibration_gate(snapshot_ledger):
    """Over the real ledger (the shipped snapshot): every plain v3 label comes with a calibration over >= 2,000
    draws at the observed spread whose false R and false D are within the gate."""
    rows = snapshot_ledger
    plain = [r for r in rows if r.status in judge_v3.JUDGED and r.groups and not r.v3.get("derived")]
    assert len(plain) > 20
    for r in plain:
        c = r.calibration
        assert c.get("draws", 0) >= judge_v3.GATE_DRAWS, r.spec.id
        limit = judge_v3.gate_limit(c["draws"])
        assert c["false_reproduces"] <= limit and c["false_does_not"] <= limit, r.spec.id
    for r in rows:
        if r.status == report.NOT_CALIBRATED:
            assert r.v3.get("reason"), r.spec.id


def test_the_shipped_calibration_is_what_the_rule_gives(shipped):
    """One claim's v3 calibration recomputed here equals the shipped one (seeded draws: bit-for-bit)."""
    from thesis_repro.claims import calibration, ledger, registry
    from thesis_repro.claims.judge import count_rule
    from thesis_repro.claims.rules import rule_for, thesis_effects
    from thesis_repro.claims.store import page_data

    s = registry.spec("3.4-mass-vs-wind")
    shipped = ledger.judge(s, "small").calibration
    frames, _ = page_data(s, "small")
    rule3 = design.rule3(s.rule, s.v2, s.v3)
    lv, mg = design.level3(s.v2, s.v3), design.margin3(s.v2, s.v3)
    groups = {g: us for g, us in ledger._units(ledger._measure(frames, rule3)).items() if us}
    rules = {g: count_rule(rule_for(s, g, rule3)[0], lv, rule3) for g in groups}
    got = calibration.calibration_v3(groups, lv, mg, rules, False, thesis_effects(s, rule3))
    assert got == shipped


def test_v3_is_frozen_with_v2_kept_beside_it():
    lock = design.frozen()
    assert lock["version"] == "v3" and design.check_frozen() == []
    v2 = design.previous()
    assert v2["version"] == "v2" and v2["rules"] == design.rule_hashes("v2")
    assert design.engine_of("v2") == v2["engine"] != design.engine_of("v3")


@pytest.mark.xdist_group("snapshot-ledger")  # conftest.SNAPSHOT_LEDGER_GROUP: one judging for all
def test_v2_still_gives_its_registered_verdicts_on_seeds_0_to_5(snapshot_ledger):
    """Design v2's verdicts, recorded when v3 was made (by v2's own code), come out the same beside v3's."""
    import json
    from pathlib import Path

    record = json.loads((Path(__file__).parent / "data" / "claims-v2-verdicts.json").read_text())
    assert record["design"]["hash"] == design.previous()["hash"]
    got = {r.spec.id: r.v2_status or r.status for r in snapshot_ledger}
    assert got == record["verdicts"]


def test_pages_show_design_v2_s_verdict_beside_v3_s(tmp_path, monkeypatch):
    """A page's verdict list and its chapter's list give design v3's label with v2's beside it, in a few words."""
    from thesis_repro.book import builder as book

    monkeypatch.setenv("THESIS_REPRO_BUILD", str(tmp_path))
    line = "inconclusive · 3.3-x · l. 555 claim · thesis: r -0.43 · ours: r +0.79 [+0.50, +0.92]"
    moved = report.Verdict("3.3", "claim", report.INCONCLUSIVE, "e", line, v2=report.AT_LEAST_PARTLY)
    kept = report.Verdict("3.3", "other", report.REPRODUCES, "e", line.replace("inconclusive", "reproduces"))
    kept = report.Verdict(**{**kept.__dict__, "v2": report.REPRODUCES})
    report.report("fig-3.3", "small", [moved, kept], display=False)
    listed = book.chapter_summary("3", ["3.3"], "small")
    assert "**inconclusive** (v2: at least partly) · 3.3-x · l. 555 claim" in listed
    assert "**reproduces** (v2: same) · 3.3-x" in listed and "\n| " not in listed  # a list, not a table
    cell = book.verdicts_cell("fig-3.3", "small")["source"]
    assert "design v3" in cell and "(v2: at least partly)" in cell
    assert "*(design v2: at least partly)*" in moved._repr_markdown_()
