"""The thesis-budget study (:mod:`thesis_repro.runs.budget_study`): its job list, its order, the keys it leaves alone,
its one-line errors, the snapshots its runs save and the bit-identity of a budget-free learner's prefix."""

from __future__ import annotations

import json

import pytest
import torch as th

from tests.interrupt import Interrupt
from thesis_repro import figures
from thesis_repro.cli.commands import main
from thesis_repro.core import paths
from thesis_repro.core.cache import Job, RunCache, find_entry
from thesis_repro.learners import train_config, train_job
from thesis_repro.learners.config import snapshot_at_steps
from thesis_repro.learners.policy_file import read_state_dict
from thesis_repro.runs import budget_study as bs
from thesis_repro.runs import costs as plan
from thesis_repro.runs.order import Claim
from thesis_repro.runs.throughput import Rates

VARIANTS = ["ppo", "trpo", "ddpg", "sac", "ppo-16", "ppo-scn", "ppo-scn-16", "ppo-ent", "ppo-arpl"]
RATES = Rates({"ppo": 4000.0, "trpo": 4000.0, "sac": 450.0, "ddpg": 1400.0, "evaluate": 5000.0}, {})


@pytest.fixture(scope="module")
def train() -> list[Job]:
    return bs.train_jobs("small")


def test_the_study_is_fig_3_3s_nine_variants_on_three_tasks_four_seeds_at_the_thesis_budget(train):
    assert len(train) == 9 * 3 * 4 == len({j.key for j in train})
    assert {j.config["algorithm"] for j in train} == set(VARIANTS)
    assert {j.config["env"] for j in train} == {"Walker2d", "HalfCheetah", "Hopper"}
    assert {j.config["seed"] for j in train} == {0, 1, 2, 3}
    assert {j.config["timesteps"] for j in train} == {figures.thesis_budget("3.3")} == {4_000_000}
    assert {tuple(j.config["snapshot_at"]) for j in train} == {(1_000_000, 2_000_000, 3_000_000)}


def test_the_budget_is_the_only_change_from_fig_3_3s_small_runs(train):
    """Each study run without its snapshots, at Fig 3.3's small budget, is one of Fig 3.3's shipped small runs."""
    small = {j.key for j in figures.training_jobs("3.3", "small")}
    for j in train:
        twin = Job("train", bs.small_twin(j.config, bs.twin_budget(j.config)))
        assert twin.key in small, j.label
        assert j.key not in small


def test_each_run_is_evaluated_after_1_2_3_and_4m_steps_under_every_fig_3_3_test(train):
    evals = bs.budget_eval_jobs("small", train)
    assert len(evals) == 108 * 4 * 4
    fig = {json.dumps(j.config["test"], sort_keys=True) for j in figures.jobs("3.3", "small") if j.kind == "evaluate"}
    assert len(fig) == 4
    for e in evals:
        test = {k: v for k, v in e.config["test"].items() if k != "snapshot"}
        assert json.dumps(test, sort_keys=True) in fig
    by_class = {}
    for j in train:
        by_class.setdefault(j.config["class"], [p.steps for p in bs.points(j.config)])
    assert by_class["SAC"] == by_class["DDPG"] == [1_000_000, 2_000_000, 3_000_000, 4_000_000]
    assert by_class["PPO"] == [1_001_472, 2_000_896, 3_000_320, 4_001_792]  # the first iteration at or after
    assert by_class["TRPO"] == [1_000_448, 2_000_896, 3_000_320, 4_000_768]
    assert bs.budgets("small") == [1_000_000, 2_000_000, 3_000_000, 4_000_000]
    assert bs.benchmark_at("small", 2_000_000).eval_jobs["obs"][0].config["test"]["snapshot"] in (2_000_000, 2_000_896)


def test_no_existing_run_key_changes():
    """Configs without snapshots carry no ``snapshot_at`` key, and every Fig 3.3 small training run is still shipped
    under its key (the shipped layer holds the keys made before the study existed)."""
    assert "snapshot_at" not in train_config("sac", "Hopper", 0, 1_000_000)
    assert train_config("sac", "Hopper", 0, 10, snapshot_at=None) == train_config("sac", "Hopper", 0, 10)
    layer = paths.ROOT / "data" / "reference"  # the real shipped layer (the fixtures point the kit elsewhere)
    missing = [j.label for j in figures.training_jobs("3.3", "small") if find_entry(layer, j) is None]
    assert not missing
    study = {j.key for j in bs.budget_jobs("small")}
    for fid in figures.ids():
        assert not study & {j.key for j in figures.jobs(fid, "small")}, fid


def test_the_order_runs_the_pareto_panels_tasks_first_and_every_job_once():
    out = bs.ordered("small", RATES)
    assert len(out) == len({p.job.key for p in out}) == len(bs.budget_jobs("small"))
    train = [p.job for p in out if p.job.kind == "train"]
    tasks = list(dict.fromkeys(j.config["env"] for j in train))
    assert tasks == ["Walker2d", "HalfCheetah", "Hopper"]
    assert [j.config["env"] for j in train] == sorted((j.config["env"] for j in train), key=tasks.index)
    # each run's evaluations right after it
    for i, p in enumerate(out):
        if p.job.kind == "evaluate":
            before = next(q.job for q in reversed(out[:i]) if q.job.kind == "train")
            assert Job("train", p.job.config["train"]).key == before.key


def test_within_a_task_items_go_by_claims_settled_per_core_hour():
    """Fig 3.3's item reads every run of a task: ranked first it pays for all, cheapest first (SAC last); a claim
    of Table 3.6 alone worth more per core-hour puts the PPO family's runs first, Table 3.4's SAC still last."""
    fig_first = [Claim("3.3-a", ("3.3",), 4), Claim("3.3-b", ("3.3",), 4), Claim("3.6-a", ("table-3.6",), 32)]
    walker = [p.job for p in bs.ordered("small", RATES, fig_first, ("train",)) if p.job.config["env"] == "Walker2d"]
    assert [j.config["algorithm"] for j in walker[-4:]] == ["sac"] * 4
    assert [j.config["seed"] for j in walker[:2]] == [0, 0]
    t36 = [Claim("3.6-a", ("table-3.6",), 3), Claim("3.3-a", ("3.3",), 12)]
    walker = [p.job for p in bs.ordered("small", RATES, t36, ("train",)) if p.job.config["env"] == "Walker2d"]
    ppo_family = bs.item_learners("table-3.6", "small")
    assert {j.config["algorithm"] for j in walker[: 4 * len(ppo_family)]} == ppo_family
    assert [j.config["algorithm"] for j in walker[-4:]] == ["sac"] * 4


def test_bad_names_are_one_line_errors(capsys):
    assert main(["reference-runs", "--study", "thesis-budgets"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "valid budget studies are: 'thesis-budget'" in err
    assert main(["plan", "thesis-budgets"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "unknown figure 'thesis-budgets'" in err and "'thesis-budget'" in err
    assert main(["verify", "--study", "budget"]) == 2
    assert "valid budget studies are" in capsys.readouterr().err
    assert main(["reference-runs", "--study", "thesis-budget", "--seeds", "0"]) == 2
    assert "drop --seeds" in capsys.readouterr().err
    with pytest.raises(ValueError, match="snapshot_at must hold increasing env steps"):
        train_config("ppo", "Hopper", 0, 1000, snapshot_at=[500, 100])
    with pytest.raises(ValueError, match="not both"):
        train_config("ppo", "Hopper", 0, 1000, snapshot_at=[500], snapshot_every=100)


def test_algos_splits_the_study_into_learner_queues_in_the_study_order(capsys):
    """``--algos sac`` keeps SAC's runs and their evaluations, in the study's order; with the other learners it
    partitions the queue, so two commands (SAC on one core, the rest on the other) make the study between them."""
    from thesis_repro.cli.commands import _of_learners

    queue = bs.ordered("small", RATES, (), ("train", "evaluate"))
    sac = _of_learners(queue, ["sac"])
    rest = _of_learners(queue, [a for a in VARIANTS if a != "sac"])
    assert _of_learners(queue, None) == queue and len(sac) + len(rest) == len(queue)
    assert [q for q in queue if q in sac] == sac and [q for q in queue if q in rest] == rest
    trained = [q.job for q in sac if q.job.kind == "train"]
    assert len(trained) == 12 and {j.config["algorithm"] for j in trained} == {"sac"}
    assert {q.job.config["train"]["algorithm"] for q in sac if q.job.kind == "evaluate"} == {"sac"}
    assert sac[1].job.kind == "evaluate" and Job("train", sac[1].job.config["train"]).key == sac[0].job.key
    assert main(["reference-runs", "--study", "thesis-budget", "--scale", "smoke", "--algos", "td3"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "valid thesis-budget learners are: 'ppo', 'sac'" in err


def test_the_study_refuses_to_start_before_the_design_it_is_judged_under_is_frozen(capsys, monkeypatch):
    monkeypatch.setattr("thesis_repro.core.provenance.claims_design", lambda: {"version": "v2", "hash": "x"})
    assert main(["reference-runs", "--study", "thesis-budget"]) == 2
    assert "freeze v3 first" in capsys.readouterr().err


def test_the_generator_makes_the_smoke_study_resumably_and_plan_missing_reads_0(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("THESIS_REPRO_DATA", str(tmp_path / "runs"))
    monkeypatch.setenv("THESIS_REPRO_REFERENCE", str(tmp_path / "ref"))
    assert main(["plan", "thesis-budget", "--scale", "smoke", "--missing"]) == 0
    out = capsys.readouterr().out
    assert "6 jobs left of 6 (2 training runs, 4 evaluations)" in out
    assert "ppo__Hopper__s0" in out and "sac__Hopper__s0" in out  # the order lists the runs left
    assert main(["reference-runs", "--study", "thesis-budget", "--scale", "smoke"]) == 0
    out = capsys.readouterr().out
    assert out.count("[follows] evaluate") == 4 and "step128" in out and "step150" in out
    assert not plan.to_compute(bs.budget_jobs("smoke"))
    assert main(["plan", "thesis-budget", "--scale", "smoke", "--missing"]) == 0
    out = capsys.readouterr().out
    assert "0 jobs left of 6" in out and "no training runs left" in out and "sac__Hopper__s0" not in out
    assert main(["reference-runs", "--study", "thesis-budget", "--scale", "smoke"]) == 0
    assert "2 already shipped, 0 to produce" in capsys.readouterr().out


@pytest.mark.parametrize("algo", ["sac", "ddpg"])
def test_a_budget_free_learners_snapshot_at_the_shorter_budget_is_the_shorter_run_bit_for_bit(algo, tmp_path):
    """The integrity check on a short run: a 600-step run with a snapshot after 300 steps against the 300-step
    run of the same seed (weights, observation filter, every training episode), as the study's 4M SAC and DDPG
    runs against the shipped 1M ones."""
    cfg = train_config(algo, "Hopper", 0, 600, learning_starts=64, max_episode_steps=40, snapshot_at=[300])
    assert snapshot_at_steps(cfg) == [300] and bs.budget_schedule(cfg) is None
    cache = RunCache(tmp_path / "runs", reference=False)
    job = Job("train", cfg)
    cache.run(job)
    cache.run(Job("train", bs.small_twin(cfg, 300)))
    check = bs.prefix_check(job, cache, 300)
    assert check.status == "identical", check.detail
    ppo = Job("train", train_config("ppo", "Hopper", 0, 600, snapshot_at=[300]))
    assert bs.prefix_check(ppo, cache, 300).status == "budget-dependent"


@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_an_interrupted_study_run_resumes_to_the_same_snapshots(algo, tmp_path):
    """Interrupted after one snapshot and before the next, the rerun ends with the snapshots of an uninterrupted run
    at the predicted steps, bit for bit (a snapshot the lost session wrote past its checkpoint is redone)."""
    over = {"n_steps": 64, "n_envs": 2} if algo == "ppo" else {"learning_starts": 40, "train_freq": 16}
    cfg = train_config(algo, "Hopper", 1, 640, max_episode_steps=60, checkpoint_every=1, snapshot_at=[200, 400], **over)
    steps = snapshot_at_steps(cfg)
    straight = train_job(cfg, tmp_path / "straight")
    with pytest.raises(KeyboardInterrupt):
        train_job(cfg, tmp_path / "resumed", callback=Interrupt(at=steps[0] + 30))
    resumed = train_job(cfg, tmp_path / "resumed")
    assert 0 < resumed["resumed_from"] and straight["snapshots"] == resumed["snapshots"] == steps
    for s in steps:
        a, b = (
            read_state_dict(tmp_path / r / "out" / "snapshots" / f"step_{s:09d}" / "policy.pth")
            for r in ("straight", "resumed")
        )
        assert a.keys() == b.keys() and all(th.equal(a[k], b[k]) for k in a)


def test_a_page_that_reads_the_study_runs_is_executed_again_when_one_lands(tmp_path, monkeypatch):
    """Fig 3.3 reads the study's runs as they land, not through its own job grid: a study run made since the page
    was executed changes its execution key, so the book runs it again; a page that does not read them keeps its key."""
    from thesis_repro.book import notebooks

    monkeypatch.setenv("THESIS_REPRO_DATA", str(tmp_path / "runs"))
    before = {n: notebooks.execution_key(n, "smoke", modules=[]) for n in ("3.3", "4.4")}
    assert notebooks.landed_runs("3.3", "smoke") == []
    job = bs.train_jobs("smoke")[0]
    RunCache().run(job)
    assert notebooks.landed_runs("3.3", "smoke") == [job.key]
    assert notebooks.landed_runs("4.4", "smoke") == []
    assert notebooks.execution_key("3.3", "smoke", modules=[]) != before["3.3"]
    assert notebooks.execution_key("4.4", "smoke", modules=[]) == before["4.4"]
