"""The confirmatory replication: every claim's primary verdict judges seeds 0-5, and beside it the confirmatory check
judges the fresh
seeds 3-5 alone with the same frozen rule; a confirmatory verdict that leans the other way is flagged in the
ledger row, ``claims --json`` and the page's verdict line."""

from __future__ import annotations

import json

import pandas as pd
import pytest

from tests.test_claims_seeds import SCALE, effect_frames
from thesis_repro.claims import confirmatory as C
from thesis_repro.claims import ledger, registry, report, scoreboard, store

pytestmark = pytest.mark.xdist_group("claims-seeds")

#: Seeds 0-2 show the claimed effect clearly; seeds 3-5 the same, or its mirror image.
AGREE = (0.97, 1.0, 1.03, 0.98, 1.01, 1.02)
OPPOSE = (0.97, 1.0, 1.03, -0.98, -1.01, -1.02)
PAGE = "fig-3.4"  # its claims are judged here, from its own frames only


def _judge(tmp_path_factory, factors, name):
    with pytest.MonkeyPatch.context() as mp:
        for var in ("THESIS_REPRO_BUILD", "THESIS_REPRO_DATA", "THESIS_REPRO_REFERENCE"):
            mp.setenv(var, str(tmp_path_factory.mktemp(f"{var.lower()}-{name}")))
        store.save_page(PAGE, SCALE, effect_frames(factors)[PAGE], {"scale": SCALE})
        with store.one_pass():
            return {s.id: ledger.judge(s, SCALE, with_null=False) for s in registry.specs() if s.page == PAGE}


@pytest.fixture(scope="module")
def rows(tmp_path_factory):
    return {n: _judge(tmp_path_factory, f, n) for n, f in (("agree", AGREE), ("oppose", OPPOSE), ("design", AGREE[:3]))}


def test_three_seeds_have_no_confirmatory_verdict(rows):
    assert all(r.confirmation is None for r in rows["design"].values())
    counts = scoreboard.as_json(list(rows["design"].values()), SCALE)["confirmatory_counts"]
    assert set(counts) == {scoreboard.NOT_YET}


@pytest.fixture(scope="module")
def holding(rows):
    """The page's claims that reproduce on six seeds with the effect in every seed."""
    # the statistical label: these numbers are synthetic, never calibrated (the gate is tested apart)
    ids = [i for i, r in rows["agree"].items() if r.v3.get("status", r.status) == report.REPRODUCES]
    assert ids, {i: r.v3.get("status", r.status) for i, r in rows["agree"].items()}
    return ids


def test_fresh_seeds_that_agree_confirm_the_primary_verdict(rows, holding):
    for cid in holding:
        row = rows["agree"][cid]
        c = row.confirmation
        assert row.n_seeds == 6 and c is not None and c.seeds == (3, 4, 5)
        assert C.SIDE[c.status] == 1 and not c.disagrees
        assert c.line().startswith(f"fresh seeds 3-5: {c.status}")


def test_fresh_seeds_that_lean_the_other_way_are_flagged(rows, holding):
    claim = holding[0]
    row = rows["oppose"][claim]
    c = row.confirmation
    assert c is not None and C.SIDE[c.status] == -1  # the fresh seeds alone: the effect runs the other way
    assert c.disagrees == (C.SIDE.get(row.status, 0) > 0) and ("DISAGREES" in c.line()) == c.disagrees
    d = json.loads(json.dumps(scoreboard.as_json(list(rows["oppose"].values()), SCALE), allow_nan=False))
    (js,) = [x for x in d["claims"] if x["id"] == claim]
    assert js["confirmatory"]["verdict"] == c.status and js["confirmatory"]["seeds"] == [3, 4, 5]
    assert js["confirmatory"]["disagrees"] == c.disagrees
    assert (claim in d["confirmatory_disagree"]) == c.disagrees
    assert sum(d["confirmatory_counts"].values()) == len(d["claims"])
    assert C.did_not_hold(js) and f"`{claim}`" in C.fresh_summary(d["claims"]).split("did not hold up")[1]


def test_the_confirmatory_check_reads_only_the_fresh_seeds():
    frames = {"a": pd.DataFrame({"seed": [0, 1, 2, 3, 4, 5], "v": range(6)}), "b": pd.DataFrame({"v": [1]})}
    got = C.fresh_frames(frames)
    assert got["a"]["seed"].tolist() == [3, 4, 5] and got["b"].equals(frames["b"])
    assert C.fresh_frames({"a": frames["a"][frames["a"]["seed"] != 4]}) is None


@pytest.mark.parametrize(
    ("primary", "fresh", "flag"),
    [
        (report.REPRODUCES, report.DOES_NOT, True),
        (report.AT_LEAST_PARTLY, report.AT_MOST_PARTLY, True),
        (report.DOES_NOT, report.AT_LEAST_PARTLY, True),
        (report.REPRODUCES, report.INCONCLUSIVE, False),
        (report.REPRODUCES, report.PARTLY, False),
        (report.DOES_NOT, report.AT_MOST_PARTLY, False),
    ],
)
def test_disagreement_is_a_lean_the_other_way(primary, fresh, flag):
    assert C.disagrees(primary, fresh) is flag


def test_the_terminal_shows_the_fresh_seeds_verdict_under_each_claim_and_counts_them(rows, holding):
    """`claims --scale small`: a claim judged on the fresh seeds too has its confirmatory line under its headline,
    and the counts on the fresh seeds alone follow the ledger's; with no fresh seed anywhere, neither is printed."""
    from thesis_repro.claims.cli import ledger_lines

    text = ledger_lines(list(rows["agree"].values()))
    under = text[text.index(next(t for t in text if f"· {holding[0]} ·" in t)) + 1]
    assert under == f"    {rows['agree'][holding[0]].confirmation.line()}"
    assert text[-1].startswith("on the fresh seeds alone (confirmatory, the same frozen rules): ")
    plain = ledger_lines(list(rows["design"].values()))
    assert not any("fresh seeds" in t for t in plain) and plain[-1].startswith("distinct thesis claims: ")
