"""Chapter 4's claims judged once per reading of the thesis's update (design v3's ``READING_CLAIMS``): every
reading gets a verdict with numbers or says why not, a diverged run never enters a claim, and the chapter's page
opens with the answer."""

from __future__ import annotations

import pandas as pd
import pytest

from thesis_repro.claims import design, judge_v3, ledger, readings, registry, report, store
from thesis_repro.claims.measures.ch4 import DIVERGED
from thesis_repro.mdl import readings as mdl_readings


@pytest.fixture(scope="module")
def reading_rows():
    from thesis_repro.core import paths

    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("THESIS_REPRO_REFERENCE", str(paths.ROOT / "data" / "reference"))
        readings.outcomes.cache_clear()  # read from the real layer, whatever an earlier test's layer gave
        with store.one_pass():
            return [ledger.judge(registry.spec(c), "small").as_dict() for c in design.READING_CLAIMS]


def test_every_reading_claim_has_a_verdict_per_reading(reading_rows):
    """Each of 4.1-4.7 and contribution 4 carries one entry per reading: *diverged, not judged* only where the
    reading diverged (its pilot, when it has no grid run; else every grid run the claim reads, by Fig 4.7's rule),
    params_avg's runs where it reduces to params_avg, and a plain label only with a calibration inside the gate."""
    outcomes = readings.outcomes()
    assert set(outcomes) == set(mdl_readings.reading_ids())
    assert outcomes["kl-avg-tr"] == readings.PILOT_DIVERGED and outcomes["kl-avg-ls"] == readings.PARAMS_AVG
    for row in reading_rows:
        got = {e["reading"]: e for e in row["readings"]}
        assert list(got) == list(outcomes), row["id"]
        for algo, e in got.items():
            if e["verdict"] == DIVERGED:
                assert algo == "kl-avg" or outcomes[algo] == readings.PILOT_DIVERGED, (row["id"], algo)
            if outcomes[algo] == readings.PILOT_DIVERGED:  # not trained on the grid, or judged on its grid runs
                assert e["verdict"] == DIVERGED or e["judged_on"] == readings.column(algo), (row["id"], algo)
            if e["verdict"] == DIVERGED and e["judged_on"]:  # every grid run of it diverged (Fig 4.7's rule)
                assert e["note"].startswith(DIVERGED), (row["id"], algo)
            if outcomes[algo] == readings.PARAMS_AVG:
                assert e["judged_on"] == "params_avg" and e["verdict"] != DIVERGED, (row["id"], algo)
            if e["verdict"] in judge_v3.JUDGED:
                cal = e["calibration"]
                limit = judge_v3.gate_limit(cal["draws"])
                assert cal["draws"] >= judge_v3.GATE_DRAWS, (row["id"], algo)
                assert max(cal["false_reproduces"], cal["false_does_not"]) <= limit, (row["id"], algo)
                assert e["ours"], (row["id"], algo)  # a verdict with numbers
        assert got["kl-exact"]["judged_on"] == "kl_exact"
        for e in row["readings"]:  # a reading judged on params_avg's runs counts those runs, not none
            if e["judged_on"] == "params_avg" and e["verdict"] in judge_v3.JUDGED:
                assert e["diverged_runs"][1] > 0, (row["id"], e["reading"])


def test_a_diverged_run_never_enters_a_claim(shipped):
    """Fig 4.7's entropy claim per reading: a kl_exact run made to diverge leaves the claim with one seed fewer,
    and its entry counts and names the run it left out; every run diverged reads *diverged, not judged*."""
    s = registry.spec("4.7-entropy")
    frames, _ = store.page_data(s, "small")

    def judged(bad_seeds: list[int]) -> dict:
        out = {}
        for k, f in frames.items():
            f = f.copy()
            if "return" in f.columns:
                hit = (f["algo"] == "kl_exact") & f["seed"].isin(bad_seeds)
                late = f["iteration"] > f["iteration"].max() * 2 / 3
                f.loc[hit & late, "return"] = -1000.0
            out[k] = f
        return {e["reading"]: e for e in ledger.judge_readings(s, "small", False, out)}

    seeds = sorted(set(frames["curves"]["seed"]))
    clean, one = judged([])["kl-exact"], judged(seeds[:1])["kl-exact"]
    assert clean["n_seeds"] == len(seeds) and clean["diverged_runs"] == [0, len(seeds)]
    assert one["n_seeds"] == len(seeds) - 1 and one["diverged_runs"] == [1, len(seeds)]
    assert readings.dropped_note(1, len(seeds)) in one["note"]  # the page says how many runs it left out
    assert judged(seeds)["kl-exact"]["verdict"] == DIVERGED


def test_a_reading_that_reduces_to_params_avg_is_judged_on_its_runs():
    frames = {"curves": pd.DataFrame({"algo": ["params_avg", "joint"], "seed": [0, 0], "return": [1.0, 2.0]})}
    got = readings.as_reading(frames, "kl_diag")["curves"]
    assert got[got["algo"] == "kl_diag"]["return"].tolist() == [1.0]
    v = readings.spec_for(registry.spec("4.3-wind"), "kl-diag")
    assert v.rule["ours"] == "kl_diag" and design.rule3(v.rule, v.v2, v.v3)["drop_diverged"] is True


def test_the_chapter_4_answer_names_every_reading(reading_rows):
    line = readings.answer(reading_rows)
    assert line.startswith("**") and "kl-avg-tr" in line and "kl-avg-trpo" in line
    assert readings.answer([]) == ""
    fake = [
        {
            "id": "4.3-wind",
            "readings": [readings.entry("kl-avg-ls", readings.PARAMS_AVG, "params_avg", report.REPRODUCES)],
        }
    ]
    assert readings.answer(fake).startswith("**Yes")
