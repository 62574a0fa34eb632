"""The cost plan (`python -m thesis_repro plan`): arithmetic, job counting, throughput file, command line.

No Ray needed: the plan only counts jobs and prices them."""

from __future__ import annotations

import json

import pytest

from thesis_repro import figures
from thesis_repro.cli.commands import main
from thesis_repro.core.cache import Job
from thesis_repro.learners import train_config
from thesis_repro.runs import costs as plan
from thesis_repro.runs import throughput

RATES = throughput.Rates({"ppo": 128.0, "evaluate": 100.0}, {"ppo": "test", "evaluate": "test"})


def test_core_hours_and_makespan():
    assert plan.core_hours(7_200_000, 1_000.0) == pytest.approx(2.0)
    assert plan.core_hours(10, 0.0) == float("inf")  # unknown rate is never silently zero cost
    assert plan.makespan([3.0, 3.0, 2.0, 2.0, 2.0], 2) == 7.0  # LPT: {3,2,2} and {3,2}
    assert plan.makespan([1.0] * 12, 4) == 3.0
    assert plan.makespan([1.0] * 12, 1) == 12.0  # one core: the sum
    assert plan.makespan([9.0, 1.0], 64) == 9.0  # never below the longest job
    assert plan.makespan([], 3) == 0.0
    durations = [5.0, 4.0, 3.0, 3.0, 2.0, 2.0, 1.0]
    for cores in (1, 2, 3, 5):  # within [max(sum/cores, longest), 4/3 of that]
        lower = max(sum(durations) / cores, max(durations))
        assert lower <= plan.makespan(durations, cores) <= 4 / 3 * lower + 1e-9
    with pytest.raises(ValueError, match="cores"):
        plan.makespan([1.0], 0)


def test_family_and_work_of_jobs():
    cfg = train_config("sac", "Hopper", 0, 4_000_000)
    assert throughput.family(Job("train", cfg)) == "sac" and throughput.work(Job("train", cfg)) == 4_000_000
    assert throughput.family(Job("train", train_config("ppo-epopt", "Hopper", 0, 1000))) == "multidomain"
    assert throughput.family(Job("train", train_config("ppo-scn-16", "Hopper", 0, 1000))) == "ppo"
    assert throughput.family(Job("train", train_config("trpo", "Hopper", 0, 1000))) == "trpo"
    test = {"perturbation": "obs", "sigmas": [0.0, 0.1, 0.2], "n_rollouts": 20, "max_episode_steps": 1000}
    ev = Job("evaluate", {"train": cfg, "test": test})
    assert throughput.family(ev) == "evaluate" and throughput.work(ev) == 3 * 20 * 1000
    arm = Job("arm-solve", {"generations": 10, "popsize": None, "family": "bic"})
    assert throughput.family(arm) == "arm" and throughput.work(arm) == 10 * throughput.ARM_DEFAULT_POPSIZE


def test_smoke_plan_matches_the_counted_jobs():
    jobs = figures.jobs("3.3", "smoke")
    train = [j for j in jobs if j.kind == "train"]
    p = plan.plan_figure("3.3", "smoke", cores=2, rates=RATES)
    assert p.n_train == len(train) == 6 and p.n_other == len(jobs) - len(train) == 24
    assert p.env_steps == sum(j.config["timesteps"] for j in train) == 6 * 256
    assert [(ln.kind, ln.family, ln.jobs) for ln in p.lines] == [("train", "ppo", 6), ("evaluate", "evaluate", 24)]
    evals = sum(throughput.work(j) for j in jobs if j.kind == "evaluate")
    assert p.core_hours == pytest.approx((6 * 256 / 128 + evals / 100) / 3600)
    train_h, eval_h = p.wall_hours()
    assert train_h == pytest.approx(3 * 256 / 128 / 3600)  # 6 equal runs on 2 cores: 3 rounds
    assert eval_h == pytest.approx(
        plan.makespan([throughput.work(j) / 100 / 3600 for j in jobs if j.kind == "evaluate"], 2)
    )
    assert "fig-3.3 (smoke): 6 training jobs (1,536 env steps), 24 evaluation and other jobs" in plan.plan_summary(p)


def test_book_plan_counts_shared_runs_once():
    per, book = plan.plan_book("smoke", cores=4, rates=RATES)
    keys = {j.key for fid in figures.ids() for j in figures.jobs(fid, "smoke")}
    assert len(per) == len(figures.ids())
    assert book.n_train + book.n_other == len(keys) <= sum(p.n_train + p.n_other for p in per)
    assert book.env_steps <= sum(p.env_steps for p in per)


def test_throughput_file_roundtrip(tmp_path):
    bench = {
        "training": {"ppo kit steps/s": 1500.0, "sac kit steps/s": 200.0, "ppo ratio": 4.0},
        "multidomain": {"joint steps/s": 1200.0, "kl-avg steps/s": 900.0},
        "evaluation": {"batched_steps_per_s": 20000.0},
        "arm": None,
    }
    assert throughput.throughput_from_bench(bench) == {
        "ppo": 1500.0,
        "sac": 200.0,
        "joint": 1200.0,
        "kl-avg": 900.0,
        "multidomain": 900.0,  # the slowest measured multi-domain learner
        "evaluate": 20000.0,
    }
    path = throughput.write_throughput(bench, tmp_path / "throughput.json")
    assert throughput.write_throughput({"arm": None}, tmp_path / "other.json") is None  # nothing measured: no file
    doc = json.loads(path.read_text())
    assert doc["rates"]["ppo"]["per_cpu_second"] == 1500.0 and doc["rates"]["ppo"]["unit"] == "env steps"
    throughput.write_throughput({"arm": {"vectorised_rollouts_per_s": 5000.0}}, path)  # merged, not replaced
    rates = throughput.load_rates(path)
    assert rates.rate("ppo") == 1500.0 and rates.rate("arm") == 5000.0
    assert rates.source("ppo").startswith("measured 20") and rates.source("ddpg") == "default"
    assert rates.rate("trpo") == 1500.0 and "PPO" in rates.source("trpo")  # not benchmarked: PPO's rate
    assert rates.rate("ddpg") == throughput.DEFAULT_RATES["ddpg"] > 0


def test_plan_command(capsys):
    assert main(["plan", "3.3", "--scale", "smoke", "--cores", "2"]) == 0
    out = capsys.readouterr().out
    assert "rates: " in out and "fig-3.3 (smoke): 6 training jobs" in out and "wall time on 2 cores" in out
    assert main(["plan", "3.3", "--scale", "huge"]) == 2
    assert "valid scales are" in capsys.readouterr().err
    assert main(["plan", "3.3", "--scale", "smoke", "--cores", "0"]) == 2
    assert main(["plan", "9.9", "--scale", "smoke"]) == 2
    assert "valid figures are" in capsys.readouterr().err


def test_plan_of_a_subset_counts_only_its_runs(capsys):
    whole = plan.plan_figure("3.3", "smoke", cores=1)
    part = plan.plan_figure("3.3", "smoke", cores=1, algos=["ppo"], envs=["Hopper"])
    assert whole.n_train == len(figures.training_jobs("3.3", "smoke")) and part.n_train == 1
    assert part.env_steps < whole.env_steps
    assert main(["plan", "3.3", "--scale", "smoke", "--algos", "ppo", "--envs", "Hopper"]) == 0
    assert "fig-3.3 (smoke): 1 training jobs" in capsys.readouterr().out
    assert main(["plan", "3.3", "--scale", "smoke", "--algos", "ppo2"]) == 2
    assert "unknown algorithm 'ppo2'; valid algorithms are: 'ppo'" in capsys.readouterr().err
    assert main(["plan", "all", "--scale", "smoke", "--algos", "ppo"]) == 2


def test_plan_of_what_is_missing_leaves_out_finished_runs():
    from thesis_repro.core.cache import RunCache

    jobs = figures.jobs("3.3", "smoke", algos=["ppo"], envs=["InvertedPendulum"])
    assert plan.plan_figure("3.3", "smoke", 1, None, True, algos=["ppo"], envs=["InvertedPendulum"]).n_train == 1
    RunCache().run(next(j for j in jobs if j.kind == "train"))  # this test's own (empty) cache
    left = plan.plan_figure("3.3", "smoke", 1, None, True, algos=["ppo"], envs=["InvertedPendulum"])
    assert left.n_train == 0 and left.n_other == len(jobs) - 1
    per, book = plan.plan_book("smoke", 1, None, missing=True)  # plan all --missing: the same rule
    every = plan.plan_book("smoke", 1, None)[1]
    assert book.n_train == every.n_train - 1 and book.n_other == every.n_other


def test_plan_reports_cost_per_training_seed():
    """The seed regeneration: `plan` reports per seed. Every job counts for its policy's training seed, and the per-seed
    totals add up to the plan's."""
    jobs = figures.jobs("3.3", "smoke", train_seeds=2)
    p = plan.plan_jobs("fig-3.3", jobs, "smoke", cores=2, rates=RATES)
    assert set(p.seeds) == {0, 1}
    assert sum(n for n, _ in p.seeds.values()) == len({j.key for j in jobs})
    assert sum(h for _, h in p.seeds.values()) == pytest.approx(p.core_hours)
    assert p.seeds[0] == pytest.approx(p.seeds[1])  # the two seeds run the same grid
    text = plan.cost_report(p, RATES)
    assert "per training seed: s0: " in text and "; s1: " in text
    assert plan.cost_per_seed(plan.plan_jobs("x", [], "smoke", 1, RATES)) == ""


def _ship(
    root, name: str, cfg: dict, pace: float | None, machine: dict | None = None, cpu_pace: float | None = None
) -> None:
    entry = root / "train" / name
    entry.mkdir(parents=True)
    (entry / "config.json").write_text(json.dumps({"config": cfg, "kind": "train"}))
    measured = {} if pace is None else {"measured": {"steps_per_s": pace}}
    if cpu_pace is not None:
        measured["measured"]["steps_per_cpu_s"] = cpu_pace
    (entry / "provenance.json").write_text(json.dumps({**measured, "platform": machine}))


def test_shipped_rates_prefer_the_runs_made_on_this_cpu(tmp_path):
    """Chapter 4's Walker2d runs kept half the pace on an AMD EPYC that they kept on an Intel Xeon: a deadline on
    the AMD machine must price them at its own pace once it made enough of them."""
    intel, amd = {"cpu": "Intel Xeon", "isa": ["avx2"]}, {"cpu": "AMD EPYC", "isa": ["avx2"]}
    ppo = train_config("ppo", "Hopper", 0, 1000)
    for i, pace in enumerate([2000.0, 2100.0, 2200.0, 1900.0]):
        _ship(tmp_path, f"intel{i}", ppo, pace, intel)
    _ship(tmp_path, "amd0", ppo, 1000.0, amd)
    base = throughput.load_rates()
    one = throughput.shipped_rates(tmp_path, base, by_env=True, machine=amd)
    assert one.rate("ppo") == 2000.0 and one.source("ppo") == "shipped pace, median of 5"  # 1 AMD run: too few
    _ship(tmp_path, "amd1", ppo, 1100.0, amd)
    two = throughput.shipped_rates(tmp_path, base, by_env=True, machine=amd)
    assert two.rate("ppo") == two.rate("ppo:Hopper") == 1050.0
    assert two.source("ppo") == f"shipped pace on this CPU, median of {throughput.MIN_LOCAL_RUNS}"
    assert "this CPU's runs alone" in throughput.rates_note(two)
    assert throughput.shipped_rates(tmp_path, base, machine=intel).rate("ppo") == 2050.0  # the Xeon: its 4 runs
    assert throughput.shipped_rates(tmp_path, base).rate("ppo") == 1950.0  # no machine: every run's median
    assert "this CPU" not in throughput.rates_note(throughput.shipped_rates(tmp_path, base))


def test_a_run_that_shared_its_core_is_priced_at_its_cpu_pace(tmp_path):
    """A run that shared its core with CI kept 1,000 steps per wall second but 4,000 per CPU-second: the plan
    prices it at 4,000, and once enough runs recorded CPU time their median alone prices the family, so a deadline
    and the core-hours read what a run costs on a core of its own."""
    ppo = train_config("ppo", "Hopper", 0, 1000)
    _ship(tmp_path, "old", ppo, 3000.0)  # made before CPU time was recorded: its wall pace
    _ship(tmp_path, "beside-ci", ppo, 1000.0, cpu_pace=4000.0)
    one = throughput.shipped_rates(tmp_path, throughput.load_rates())
    assert one.rate("ppo") == 3500.0 and one.source("ppo") == "shipped pace, median of 2"  # one CPU-timed run: too few
    _ship(tmp_path, "alone", ppo, 4100.0, cpu_pace=4200.0)
    _ship(tmp_path, "old2", ppo, 900.0)
    two = throughput.shipped_rates(tmp_path, throughput.load_rates())
    assert two.rate("ppo") == 4100.0 and two.source("ppo") == "shipped pace, CPU-timed, median of 2"  # they alone
    assert "per CPU-second" in throughput.rates_note(two)


def test_a_task_with_only_wall_paced_runs_takes_its_cpu_timed_familys_rate(tmp_path):
    """SAC's HalfCheetah runs predate CPU timing and kept 160 steps per wall second on a shared machine, while its
    CPU-timed Walker2d runs kept 470 per CPU-second: a deadline must not price HalfCheetah at a third of its pace."""
    for i, pace in enumerate([150.0, 160.0, 170.0]):
        _ship(tmp_path, f"hc{i}", train_config("sac", "HalfCheetah", i, 1000), pace)
    walker = train_config("sac", "Walker2d", 0, 1000)
    _ship(tmp_path, "w0", walker, 300.0, cpu_pace=460.0)
    one = throughput.shipped_rates(tmp_path, throughput.load_rates(), by_env=True)
    assert one.rate("sac:HalfCheetah") == 160.0  # one CPU-timed run: the family is not CPU-timed yet
    _ship(tmp_path, "w1", walker, 470.0, cpu_pace=480.0)
    two = throughput.shipped_rates(tmp_path, throughput.load_rates(), by_env=True)
    assert "CPU-timed" in two.source("sac") and two.rate("sac") == 470.0
    assert "sac:HalfCheetah" not in two.rates and two.rate("sac:Walker2d") == 470.0
    hc = Job("train", train_config("sac", "HalfCheetah", 5, 1000))
    assert throughput.job_rate(hc, two) == 470.0


def test_shipped_rates_are_the_median_pace_of_the_shipped_runs_per_family(tmp_path, capsys, monkeypatch):
    sac = train_config("sac", "Hopper", 0, 1000)
    for i, pace in enumerate([200.0, 300.0, 1000.0]):
        _ship(tmp_path, f"sac{i}", sac, pace)
    for i, pace in enumerate([3000.0, 4000.0]):
        _ship(tmp_path, f"ppo{i}", train_config("ppo", "Hopper", i, 1000), pace)
    _ship(tmp_path, "old", train_config("ddpg", "Hopper", 0, 1000), None)  # made before paces were recorded
    base = throughput.load_rates()
    r = throughput.shipped_rates(tmp_path, base)
    assert r.rate("sac") == 300.0 and r.source("sac") == "shipped pace, median of 3"
    assert r.rate("ppo") == 3500.0 and r.source("ppo") == "shipped pace, median of 2"
    assert r.rate("ddpg") == base.rate("ddpg") and r.source("ddpg") == base.source("ddpg")  # no pace: unchanged
    assert "an ETA, not a benchmark" in throughput.rates_note(r)
    # by_env: one rate per learner and task beside the family's, which prices the tasks without shipped runs
    _ship(tmp_path, "sac-idp", train_config("sac", "InvertedDoublePendulum", 0, 1000), 2000.0)
    r = throughput.shipped_rates(tmp_path, base, by_env=True)
    assert r.rate("sac:Hopper") == 300.0 and r.rate("sac:InvertedDoublePendulum") == 2000.0
    assert r.rate("sac") == 650.0  # the family's median over all four
    walker = plan.plan_jobs("x", [Job("train", train_config("sac", "Walker2d", 0, 1300))], "small", 1, r)
    hopper = plan.plan_jobs("x", [Job("train", train_config("sac", "Hopper", 0, 1200))], "small", 1, r)
    assert walker.lines[0].rate == pytest.approx(650.0) and hopper.lines[0].rate == pytest.approx(300.0)
    assert "per learner and task" in throughput.rates_note(r)
    # the CLI: --rates shipped reads the shipped layer; a bad choice is rejected with the valid ones
    monkeypatch.setenv("THESIS_REPRO_REFERENCE", str(tmp_path))
    assert main(["plan", "table-3.3", "--scale", "small", "--rates", "shipped"]) == 0
    assert "shipped pace" in capsys.readouterr().out
    assert main(["plan", "3.3", "--rates", "fast"]) == 2
    err = capsys.readouterr().err
    assert "invalid choice: 'fast' (choose from 'bench', 'shipped')" in err and err.count("\n") == 1


def test_a_cpu_pace_elsewhere_beats_this_cpus_wall_pace(tmp_path):
    """This machine's SAC runs all predate CPU timing and read a third of the pace in wall seconds; CPU-timed runs
    made on another CPU price the family (a wall pace reads the share of a core the run got, not the code)."""
    intel, amd = {"cpu": "Intel Xeon", "isa": ["avx2"]}, {"cpu": "AMD EPYC", "isa": ["avx2"]}
    sac = train_config("sac", "Hopper", 0, 1000)
    for i, pace in enumerate([150.0, 160.0, 200.0]):
        _ship(tmp_path, f"intel{i}", sac, pace, intel)
    _ship(tmp_path, "amd0", sac, 430.0, amd, cpu_pace=440.0)
    one = throughput.shipped_rates(tmp_path, throughput.load_rates(), machine=intel)
    assert one.rate("sac") == 160.0 and one.source("sac") == "shipped pace on this CPU, median of 3"
    _ship(tmp_path, "amd1", sac, 450.0, amd, cpu_pace=460.0)
    two = throughput.shipped_rates(tmp_path, throughput.load_rates(), machine=intel)
    assert two.rate("sac") == 450.0 and two.source("sac") == "shipped pace, CPU-timed, median of 2"
    _ship(tmp_path, "intel-timed0", sac, 300.0, intel, cpu_pace=380.0)
    _ship(tmp_path, "intel-timed1", sac, 310.0, intel, cpu_pace=400.0)
    three = throughput.shipped_rates(tmp_path, throughput.load_rates(), machine=intel)
    assert three.rate("sac") == 390.0 and three.source("sac") == "shipped pace on this CPU, CPU-timed, median of 2"


def test_a_resumed_run_is_priced_at_the_work_past_its_checkpoint(tmp_path):
    from thesis_repro.core.cache import RunCache

    job = Job("train", train_config("ppo", "Hopper", 0, 1_000_000))
    cache = RunCache(tmp_path / "runs", reference=False)
    assert throughput.work_left(job, cache) == 1_000_000  # never started: all of it
    (cache.workdir(job) / "ckpt-000000600000").mkdir(parents=True)  # interrupted at 600k steps
    assert throughput.work_left(job, cache) == 400_000
    fresh = plan.plan_jobs("x", [job], "small", 1, RATES)
    resumed = plan.plan_jobs("x", [job], "small", 1, RATES, missing_in=cache)
    assert fresh.env_steps == 1_000_000 and resumed.env_steps == 400_000
    assert resumed.core_hours == pytest.approx(0.4 * fresh.core_hours)
    evaluate = Job("evaluate", {"train": {}, "test": {"sigmas": [0.0], "n_rollouts": 2, "max_episode_steps": 50}})
    assert throughput.work_left(evaluate, cache) == throughput.work(evaluate)  # only training runs resume
