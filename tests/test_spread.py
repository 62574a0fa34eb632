"""Seed spread of the training return beside published numbers (``budgets --spread``), and the book
page's block that shows it (``book/runs.md``): every row of that block is recomputed here from the shipped runs,
restricted to its seeds."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from thesis_repro.cli.commands import main
from thesis_repro.core import paths, thesis_numbers
from thesis_repro.learners import train_config
from thesis_repro.runs import budgets
from thesis_repro.runs.study import lr_schedule_jobs

#: The page holding the block, the block and the command that regenerates it (the test checks that the page names it).
PAGE = paths.ROOT / "book" / "runs.md"
BEGIN, END = "<!-- spread:begin -->", "<!-- spread:end -->"
AT, PROTOCOL = 1_000_000, "thesis"
COMMAND = (
    f"python -m thesis_repro budgets --scale small --spread --protocol {PROTOCOL} --at {AT} "
    "--algos ppo trpo ddpg sac --shipped-only"
)


def _frame(**groups: list[tuple[int, float, float]]) -> pd.DataFrame:
    rows = []
    for env, runs in groups.items():
        for seed, final, at in runs:
            rows.append(
                {"protocol": "thesis", "algorithm": "ppo", "env": env, "setting": "", "timesteps": 1_000_000}
                | {"seed": seed, "key": f"k{env}{seed}", "final": final, "at_return": at}
            )
    return pd.DataFrame(rows)


def test_mean_and_sample_sd_across_seeds():
    finals, ats = [1000.0, 1500.0, 2600.0], [900.0, 1400.0, 2000.0]
    frame = _frame(Hopper=[(2, finals[2], ats[2]), (0, finals[0], ats[0]), (1, finals[1], ats[1])])
    row = budgets.aggregate_seeds(frame).iloc[0]
    assert row["seeds"] == (0, 1, 2) and row["n"] == 3
    assert row["final_mean"] == pytest.approx(np.mean(finals)) == pytest.approx(1700.0)
    assert row["final_sd"] == pytest.approx(np.std(finals, ddof=1)) == pytest.approx(np.sqrt(670000.0))
    assert row["at_mean"] == pytest.approx(1433.3333333) and row["at_sd"] == pytest.approx(np.std(ats, ddof=1))


def test_one_seed_has_no_sd_and_a_missing_value_stays_missing():
    frame = _frame(Walker2d=[(0, 3000.0, 2500.0)], Hopper=[(0, 2000.0, np.nan), (1, 2200.0, 2100.0)])
    out = budgets.aggregate_seeds(frame).set_index("env")
    assert out.loc["Walker2d", "n"] == 1 and out.loc["Walker2d", "final_mean"] == 3000.0
    assert np.isnan(out.loc["Walker2d", "final_sd"]) and np.isnan(out.loc["Walker2d", "at_sd"])
    assert np.isnan(out.loc["Hopper", "at_mean"]) and out.loc["Hopper", "final_mean"] == 2100.0  # not the mean of one
    text = budgets.render_spread(budgets.aggregate_seeds(frame), at=AT, published=thesis_numbers.published())
    assert (
        "| ppo | Walker2d | thesis | 0 | 1M | 3,000 (1 seed) | 2,500 (1 seed) | 2,288 ± 572 (CleanRL, v4, 1M) |" in text
    )
    assert "| ppo | Hopper | thesis | 0, 1 | 1M | 2,100 ± 141 | - | 2,383 ± 272 (CleanRL, v4, 1M) |" in text


def test_two_runs_of_one_seed_in_a_row_are_an_error():
    with pytest.raises(ValueError, match="several runs of one seed"):
        budgets.aggregate_seeds(_frame(Hopper=[(0, 1.0, 1.0), (0, 2.0, 2.0)]))


def test_unknown_protocol_is_a_one_line_error_naming_the_valid_ones(capsys):
    with pytest.raises(ValueError) as err:
        budgets.spread(budgets.seed_runs("small", protocol="kit-v2"))
    assert "\n" not in str(err.value) and "'thesis'" in str(err.value)
    assert main(["budgets", "--spread", "--protocol", "kit-v2"]) == 2
    assert main(["budgets", "--at", "1000000"]) == 2  # --at without --spread
    assert main(["budgets", "--spread", "--at", "0"]) == 2
    assert main(["budgets", "--spread", "--algos", "ppo-17"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 4 and all(line.startswith("error: ") for line in lines)
    assert "valid protocols are: 'thesis'" in lines[0]


def test_published_loader_returns_cleanrl_ppo_rows():
    table = thesis_numbers.published()
    assert set(table["kind"]) == {"published"}
    clean = table[table["source"] == "CleanRL"].set_index("env")
    assert set(clean["algo"]) == {"ppo"} and set(clean["steps"]) == {1_000_000} and set(clean["env_version"]) == {"v4"}
    assert clean[["mean", "std"]].to_dict("index") == {
        "HalfCheetah": {"mean": 1442.64, "std": 46.03},
        "Walker2d": {"mean": 2287.95, "std": 571.78},
        "Hopper": {"mean": 2382.86, "std": 271.74},
        "InvertedPendulum": {"mean": 963.09, "std": 22.20},
    }
    zoo = table[table["algo"] == "sac"]
    assert len(zoo) == 3 and zoo["std"].isna().all() and set(zoo["steps"]) == {1_000_000}
    assert budgets.published_cell("ppo-16", "Hopper", table) == ""  # a variant is not the published learner


def test_protocol_and_setting_of_a_config():
    thesis = train_config("ppo", "Hopper", 0, 1000, protocol="thesis")
    assert budgets.config_protocols(thesis) == ("thesis",)
    assert budgets.config_protocols(train_config("trpo", "Hopper", 0, 1000)) == ("thesis",)
    assert budgets.config_protocols({k: v for k, v in thesis.items() if k != "lr_schedule"}) == ()
    assert budgets.config_setting(thesis, "thesis") == ""
    wind = train_config("joint", "Walker2d", 0, 1000, c_a=1.0, wind=[-2.5, 2.5])
    assert budgets.config_setting(wind, "thesis") == "c_a=1.0, wind=[-2.5, 2.5]"


class _FakeCache:
    """Loads made-up curves for some jobs (``{key: result}``), nothing for the others."""

    def __init__(self, results: dict[str, dict]):
        self.results = results

    def load(self, job):
        return self.results.get(job.key)


def test_final_and_at_returns_read_from_the_curves():
    jobs = [j for j in lr_schedule_jobs() if j.config["env"] == "Hopper" and j.config["lr_schedule"] == "linear"]
    t = np.arange(1, 2001) * 500  # an episode every 500 steps up to 1M
    results = {}
    for i, job in enumerate(jobs[:2]):
        results[job.key] = {"episode_timesteps": t, "episode_returns": t / 1000.0 + i, "timesteps_done": 1_001_472}
    runs = budgets.seed_runs("small", protocol="thesis", at=600_000, cache=_FakeCache(results))
    assert sorted(runs["seed"]) == [0, 1] and set(runs["setting"]) == {""} and set(runs["protocol"]) == {"thesis"}
    first = runs.set_index("seed").loc[0]
    assert first["final"] == pytest.approx(np.mean(t[t > 900_000] / 1000.0))  # the last 10 % of the budget
    assert first["at_return"] == pytest.approx(np.mean(t[(t <= 600_000)][-100:] / 1000.0))  # last 100 by 600k
    assert budgets.seed_runs("small", at=600_000, cache=_FakeCache(results), algos=["trpo"]).empty
    late = budgets.seed_runs("small", protocol="thesis", at=2_000_000, cache=_FakeCache(results))
    assert late["at_return"].isna().all()  # the runs never got to 2M steps
    row = budgets.spread(budgets.seed_runs("small", protocol="thesis", at=600_000, cache=_FakeCache(results))).iloc[0]
    assert row["seeds"] == (0, 1) and row["final_sd"] == pytest.approx(np.sqrt(0.5))


# ---------------------------------------------------------------- the book page's block
def _readme_block() -> tuple[str, list[str]]:
    text = PAGE.read_text()
    assert text.count(BEGIN) == 1 and text.count(END) == 1, f"{PAGE.name} needs one {BEGIN} ... {END} block"
    block = text.split(BEGIN, 1)[1].split(END, 1)[0]
    return text, [line for line in block.strip().splitlines() if line.startswith("|")]


def _parse(line: str) -> dict:
    cells = [c.strip() for c in line.strip().strip("|").split("|")]
    learner, task, protocol, seeds, steps = cells[:5]
    algorithm, _, setting = learner.partition(" ")
    return {
        "algorithm": algorithm,
        "setting": setting[1:-1] if setting else "",
        "env": task,
        "protocol": protocol,
        "seeds": tuple(int(s) for s in seeds.split(",")),
        "steps": steps,
    }


def test_book_spread_block_is_recomputed_from_the_shipped_runs(monkeypatch):
    monkeypatch.setenv("THESIS_REPRO_REFERENCE", str(paths.ROOT / "data" / "reference"))  # the real shipped layer
    text, lines = _readme_block()
    assert COMMAND in text, f"{PAGE.name} must name the command that regenerates its spread block"
    header, rows = lines[:2], lines[2:]
    assert rows, "the spread block has no rows"
    per_run = budgets.seed_runs("small", protocol=PROTOCOL, at=AT, cache=budgets.shipped_cache())
    published = thesis_numbers.published()
    empty = budgets.aggregate_seeds(per_run.iloc[:0])
    assert header == budgets.render_spread(empty, at=AT, published=published).splitlines()
    labels = per_run["timesteps"].map(budgets.steps_label)
    for line in rows:
        row = _parse(line)
        mine = per_run[
            (per_run["algorithm"] == row["algorithm"])
            & (per_run["env"] == row["env"])
            & (per_run["setting"] == row["setting"])
            & (per_run["protocol"] == row["protocol"])
            & (labels == row["steps"])
        ]
        assert mine["timesteps"].nunique() <= 1, f"ambiguous spread row: {line}"
        mine = mine[mine["seed"].isin(row["seeds"])]
        assert tuple(sorted(mine["seed"])) == row["seeds"], f"spread row not (all) shipped: {line}"
        recomputed = budgets.render_spread(budgets.aggregate_seeds(mine), at=AT, published=published).splitlines()[2]
        assert recomputed == line.strip(), f"spread row in {PAGE.name} is stale; rerun `{COMMAND}`"
    keys = [tuple(v for k, v in _parse(line).items() if k != "seeds") for line in rows]
    assert len(set(keys)) == len(keys), "a setting has two rows in the spread block"
