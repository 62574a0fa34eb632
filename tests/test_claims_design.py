"""Claims design v2: the freeze, bounded labels, margins, pooled tests, calibration both ways, the fixed rules."""

from __future__ import annotations

import dataclasses
import math
import pkgutil

import numpy as np
import pandas as pd
import pytest

from thesis_repro.claims import calibration as C
from thesis_repro.claims import design, registry, report
from thesis_repro.claims import measures as M
from thesis_repro.claims import stats as S
from thesis_repro.claims.judge import count_rule, judge_v2
from thesis_repro.claims.stats import Contrast, CountRule, Unit


# ---------------------------------------------------------------- the freeze
def test_the_frozen_design_holds():
    """Every rule and the judging code are as frozen in data/thesis/claims-design.json under this version."""
    assert design.frozen()["version"] == design.VERSION
    assert design.check_frozen() == []


def test_a_changed_rule_without_a_new_version_is_caught(monkeypatch):
    reg = registry.registry()
    spec = next(s for s in registry.specs() if s.id == "3.3-negative-correlation")
    changed = [dataclasses.replace(s, v2={**s.v2, "margin": 0.05}) if s.id == spec.id else s for s in registry.specs()]
    monkeypatch.setattr(registry, "specs", lambda: tuple(changed))
    assert design.check_frozen() == [
        "claim 3.3-negative-correlation: rule changed",
        "a v2 rule changed: the previous version is shown as frozen",
    ]
    assert reg is registry.registry()


def test_the_engine_hash_covers_every_measures_module():
    """A measure in a module the hash does not read could change without breaking the freeze."""
    hashed = {m.__name__ for m in design.ENGINE_MODULES}
    assert {f"{M.__name__}.{m.name}" for m in pkgutil.iter_modules(M.__path__)} == hashed
    assert {fn.__module__ for fn in M.MEASURES.values()} <= hashed


def test_wording_may_change_but_judging_code_may_not():
    def f(x):
        """One docstring."""
        return x + 1  # a comment

    def g(x):
        """Another docstring."""
        return x + 1

    def h(x):
        return x + 2

    assert design._tree(f).replace("'f'", "'g'") == design._tree(g)
    assert design._tree(g).replace("'g'", "'h'") != design._tree(h)


def test_every_rule_has_a_level_and_a_margin_with_its_basis():
    for s in registry.specs():
        if s.rule.get("derived") or s.rule.get("visual") or "page_verdict" in s.rule:
            continue
        assert design.level(s.v2) in design.LEVELS, s.id
        assert design.margin(s.v2) >= 0 and s.v2.get("margin_basis"), s.id
        assert s.v2.get("short") and s.v2.get("thesis_value"), s.id


def test_an_unknown_level_is_a_one_line_error():
    with pytest.raises(ValueError, match="valid: pooled, each, count"):
        design.level({"level": "mostly"})


# ---------------------------------------------------------------- labels and units
def test_a_bounded_interval_names_the_region_it_rules_out():
    rule = CountRule(0.675, 0.25)
    no = [Unit(f"n{i}", (Contrast("r", (0.7, 0.75, 0.8), sign=-1, kind="r"),)) for i in range(13)]
    und = [Unit(f"u{i}", (Contrast("r", (-0.9, 0.2, 0.9), sign=-1, kind="r"),)) for i in range(7)]
    assert rule.judge(no + und).status == report.INCONCLUSIVE  # v1: [0, 0.35] touches "partly"
    assert S.judge_count_v2(rule, no + und, 0.1).status == report.AT_MOST_PARTLY


def test_a_null_unit_can_be_shown_absent_with_a_margin():
    """A true effect of 0 measured tightly: v1 leaves it undecided, v2 says no (CI below the margin)."""
    c = Contrast("a - b", (100.0, 101.0, 99.0, 100.5), (100.0, 100.5, 99.5, 100.0))
    assert c.estimate().outcome == S.UNDECIDED
    assert S.outcome_v2(S.estimate_v2(c), S.unit_margin(c, 0.05)) == S.NO


def test_fisher_z_intervals_stay_inside_minus_one_to_one():
    c = Contrast("r", (-0.2, -0.9, -0.99), sign=-1, kind="r")
    assert c.estimate().hi > 1  # v1's t-interval on raw r
    e = S.estimate_v2(c)
    assert -1 <= e.lo <= e.est <= e.hi <= 1


def test_a_clearly_failing_group_is_not_hidden_by_an_undecided_one():
    assert S.combine_groups([report.DOES_NOT, report.INCONCLUSIVE]) == report.INCONCLUSIVE
    assert S.combine_bounded([report.DOES_NOT, report.INCONCLUSIVE]) == report.AT_MOST_PARTLY


def test_pooled_correlation_refutes_a_claimed_negative_correlation():
    """Fig 3.3's shape: 20 cells, 3 seeds, r clearly positive in most: pooled r through Fisher z says does not."""
    rng = np.random.default_rng(0)
    units = {
        "": [
            Unit(f"c{i}", (Contrast("r", tuple(np.tanh(1.0 + 0.4 * rng.standard_normal(3))), sign=-1, kind="r"),))
            for i in range(20)
        ]
    }
    v = judge_v2(units, "pooled", 0.1, {"": CountRule(0.675, 0.25)})
    assert v.status == report.DOES_NOT
    lo, hi = v.groups["all"]["pooled"]["ci"]
    assert hi < math.atanh(0.1)


def test_holm_makes_a_pooled_test_sharing_its_page_data_more_conservative():
    units = {"": [Unit("u", (Contrast("a - b", (1.2, 1.35, 1.3), (1.0, 1.0, 1.0)),))]}
    rule = {"": CountRule(0.5, 0.25)}
    alone = judge_v2(units, "pooled", 0.05, rule)
    p = alone.groups["all"]["pooled"]["p_yes"]
    assert 0.025 / 11 < p < 0.025 and alone.status == report.REPRODUCES
    crowded = judge_v2(units, "pooled", 0.05, rule, family=[0.9] * 10)
    assert crowded.status == report.INCONCLUSIVE
    assert S.holm([0.001, 0.02, 0.012]) == [True, True, True]


# ---------------------------------------------------------------- calibration both ways
def _shapes() -> dict[str, tuple[dict[str, list[Unit]], str, float, dict[str, CountRule]]]:
    rng = np.random.default_rng(1)

    def val(i: int, paired: bool = False) -> Contrast:
        a = tuple(100 + 10 * rng.standard_normal(3))
        b = tuple(100 + 10 * rng.standard_normal(3))
        return Contrast(f"a{i} - b{i}", a, b, paired=paired)

    r_units = [
        Unit(f"r{i}", (Contrast("r", tuple(np.tanh(0.3 * rng.standard_normal(3))), sign=-1, kind="r"),))
        for i in range(10)
    ]
    v_units = [Unit(f"v{i}", (val(i),)) for i in range(5)]
    p_units = [Unit(f"p{i}", (val(i, paired=True),)) for i in range(4)]
    share = [Unit("s", (Contrast("share", (1.0, 0.0, 1.0), proportion=True, ref=0.5, kind="share"),))]
    return {
        "pooled r": ({"": r_units}, "pooled", 0.1, {"": CountRule(0.675, 0.25)}),
        "pooled values": ({"": v_units}, "pooled", 0.05, {"": CountRule(0.5, 0.25)}),
        "each paired": ({"": p_units}, "each", 0.05, {"": count_rule(CountRule(0.75, 0.5), "each", {})}),
        "count values": ({"": v_units}, "count", 0.05, {"": CountRule(0.5, 0.25)}),
        "each share": ({"": share}, "each", 0.1, {"": count_rule(CountRule(1.0, None), "each", {})}),
    }


@pytest.mark.parametrize("shape", list(_shapes()))
def test_every_rule_shape_is_calibrated_both_ways(shape):
    groups, level, margin, rules = _shapes()[shape]
    got = C.calibrate(groups, level, margin, rules, draws=C.DRAWS)
    assert got["draws"] >= 1000
    bound = 0.05 + 2 * got["mc_se"]
    assert got["false_reproduces"] <= bound, got
    assert got["false_does_not"] <= bound, got


def test_power_finds_more_seeds_for_a_smaller_effect():
    groups, level, margin, rules = _shapes()["pooled values"]
    big = C.power(groups, level, margin, rules, {u.label: 0.5 for u in groups[""]}, draws=100)
    small = C.power(groups, level, margin, rules, {u.label: 0.1 for u in groups[""]}, draws=100)
    assert big["seeds_for_80"] is not None
    assert small["seeds_for_80"] is None or small["seeds_for_80"] >= big["seeds_for_80"]


# ---------------------------------------------------------------- the fixed rules (each fails under v1's)
def _returns(drop: float) -> pd.DataFrame:
    rows = []
    for seed, noise in enumerate((0.0, 1.0, -1.0)):
        rows.append({"env": "H", "method": "ppo", "test": "obs", "seed": seed, "sigma": 0.0, "return": 100 + noise})
        rows.append(
            {"env": "H", "method": "ppo", "test": "obs", "seed": seed, "sigma": 0.8, "return": 100 * (1 - drop) + noise}
        )
    return pd.DataFrame(rows)


@pytest.mark.parametrize("cid", ["3.4-summary-poor", "6-overfit-methods"])
def test_a_small_drop_under_noise_is_not_poor_generalisation(cid):
    s = registry.spec(cid)
    data = {"returns": _returns(0.10)}
    v1 = [u.outcome() for us in M.MEASURES["degrade"](data, s.rule).values() for u in us]
    v2 = [u.outcome() for us in M.MEASURES["degrade"](data, design.rule(s.rule, s.v2)).values() for u in us]
    assert v1 == [S.YES]  # v1: any drop counts
    assert v2 == [S.NO]  # v2: a 10 % drop is not a quarter of the return


def test_in_each_case_needs_every_unit():
    s = registry.spec("3.3-i-training-return")
    rule2 = design.rule(s.rule, s.v2)
    assert design.level(s.v2) == "each" and float(rule2["reproduces"]) == 1.0
    yes = Unit("y", (Contrast("a - b", (5.0, 5.1, 4.9), (1.0, 1.1, 0.9)),))
    no = Unit("n", (Contrast("a - b", (1.0, 1.1, 0.9), (5.0, 5.1, 4.9)),))
    units = [yes, yes, yes, no]
    assert CountRule(0.75, 0.5).judge(units).status == report.REPRODUCES  # 3 of 4, as v1 allowed
    assert S.judge_count_v2(count_rule(CountRule(0.75, 0.5), "each", rule2), units, 0.1).status != report.REPRODUCES


def test_one_reversing_pair_is_not_enough_when_a_third_learner_wins_everywhere():
    rows = []
    means = {"A": {"t1": 5, "t2": 1}, "B": {"t1": 1, "t2": 5}, "C": {"t1": 9, "t2": 9}}
    for m, per in means.items():
        for env, v in per.items():
            for seed, e in enumerate((0.0, 0.1, -0.1)):
                rows.append({"env": env, "test": "obs", "method": m, "seed": seed, "value": v + e})
    data = {"aucs": pd.DataFrame(rows)}
    s = registry.spec("3.4-no-consistent-winner")
    v1_units = M.MEASURES[s.rule["measure"]](data, {**s.rule, "methods": ["A", "B", "C"]})[""]
    v1_rule = CountRule(1, None, True, True)
    assert v1_rule.judge(v1_units).status == report.REPRODUCES  # A/B reverse: v1 passes
    rule2 = {**design.rule(s.rule, s.v2), "methods": ["A", "B", "C"]}
    units = M.MEASURES[rule2["measure"]](data, rule2)[""]
    assert [u.outcome() for u in units] == [S.YES, S.YES, S.NO]  # C is never beaten
    assert S.judge_count_v2(count_rule(v1_rule, "each", rule2), units, 0.05).status != report.REPRODUCES


def test_reach_to_bic_uses_clopper_pearson_on_seeds():
    s = registry.spec("5.4-reach-to-bic")
    summary = pd.DataFrame(
        {"strategy": "tensor", "source": "reach", "target": "bic", "seed": [0, 1, 2], "success_rate": [0.0, 0.4, 0.0]}
    )
    v1 = M.MEASURES["reach_bic"]({"summary": summary}, s.rule)[""][0].parts[0]
    v2 = M.MEASURES["reach_bic"]({"summary": summary}, design.rule(s.rule, s.v2))[""][0].parts[0]
    assert not v1.proportion and v1.estimate().lo < 0  # a t-interval on shares runs below 0
    assert v2.proportion and 0 <= S.estimate_v2(v2).lo <= S.estimate_v2(v2).hi <= 1
