"""Findable runs, the shipped layer (export, stale/corrupt checks, policy comparison) and the generator."""

from __future__ import annotations

import json
import subprocess
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np
import pytest

from thesis_repro import figures
from thesis_repro.cli.commands import main
from thesis_repro.core import job_kinds, paths, provenance
from thesis_repro.core.cache import CorruptEntryWarning, Job, RunCache, read_entry
from thesis_repro.runs import costs as plan
from thesis_repro.runs import generator, needs, retrain_check, shipped_checks
from thesis_repro.runs import layer as runs

INTERRUPT_ONCE = "THESIS_REPRO_TEST_INTERRUPT"


def toy_train(config: dict, workdir: Path) -> dict:
    """A 'training' job: checkpoints every step in its workdir, can be interrupted once, writes artefacts
    of every sort (a full model that must not be shipped, a policy, snapshots) and a curve."""
    ckpt = workdir / "ckpt-state.json"
    step = json.loads(ckpt.read_text())["step"] if ckpt.exists() else 0
    resumed = step > 0
    while step < config["timesteps"]:
        step += 1
        ckpt.write_text(json.dumps({"step": step}))
        marker = Path(config.get("interrupt", "/nonexistent"))
        if step == 2 and marker.exists():
            marker.unlink()
            raise KeyboardInterrupt("simulated Ctrl-C")
    out = workdir / "out"
    (out / "model.zip").write_bytes(b"optimizer state" * 100)
    (out / "replay_buffer.pkl").write_bytes(b"buffer")
    (out / "policy.txt").write_text(f"w={config['seed']}")
    (out / "snapshots" / "step_1").mkdir(parents=True, exist_ok=True)
    (out / "snapshots" / "step_1" / "policy.txt").write_text("w=0")
    return {"resumed": resumed, "curve": np.arange(float(step))}


job_kinds.register("toy-train", "tests.test_runs:toy_train")


def _cfg(name: str, timesteps: int, seed: int = 0, **kw) -> dict:
    return {"algorithm": name, "env": "Toy", "seed": seed, "timesteps": timesteps, **kw}


@pytest.fixture
def fake_figures(monkeypatch, tmp_path):
    """Two fake figures sharing one training run, plus an evaluation-like job; a private shipped layer."""
    monkeypatch.setattr(figures, "FIGURES", {})
    monkeypatch.setattr(figures, "TRAINING_KINDS", ("train", "toy-train"))
    shared = Job("toy-train", _cfg("b", 20, interrupt=str(tmp_path / "interrupt")))
    grids = {
        "9.1": lambda s: [Job("toy-train", _cfg("c", 30)), shared, Job("square", {"x": 1})],
        "9.2": lambda s: [shared, Job("toy-train", _cfg("a", 10))],
    }
    for fid, grid in grids.items():
        figures.register_figure(fid, f"toy figure {fid}", kinds=["toy-train", "square"], settings_id="_example")(grid)
    layer = tmp_path / "reference"
    monkeypatch.setenv("THESIS_REPRO_REFERENCE", str(layer))
    return layer


def test_generator_end_to_end(fake_figures, tmp_path):
    layer, lines = fake_figures, []
    (tmp_path / "interrupt").write_text("")  # the shared run (20 steps) will be interrupted once
    with pytest.raises(KeyboardInterrupt):
        generator.generate("smoke", kinds=["toy-train"], layer_root=layer, log=lines.append)
    assert "3 toy-train jobs, 0 already shipped, 3 to produce (60 env steps" in lines[0]
    assert [p.name.split("__")[0] for p in runs.shipped_entries(layer)] == ["a"]  # cheapest first, shipped
    assert RunCache().state(Job("toy-train", _cfg("b", 20, interrupt=str(tmp_path / "interrupt")))) == "partial"

    lines.clear()
    done = generator.generate("smoke", kinds=["toy-train"], layer_root=layer, log=lines.append)
    assert "1 already shipped, 2 to produce" in lines[0]
    assert [e.path.name.split("__")[0] for e in done] == ["b", "c"]
    assert [p.name.split("__")[0] for p in runs.shipped_entries(layer)] == ["a", "b", "c"]
    shipped = RunCache(reference=layer).load(Job("toy-train", _cfg("b", 20, interrupt=str(tmp_path / "interrupt"))))
    assert shipped is not None and shipped["resumed"] is True  # resumed from the workdir checkpoint
    entry = done[0].path
    files = {str(p.relative_to(entry)) for p in entry.rglob("*") if p.is_file()}
    assert {"out/policy.txt", "out/snapshots/step_1/policy.txt", "arrays.npz", "provenance.json"} <= files
    assert not {"out/model.zip", "out/replay_buffer.pkl"} & files
    assert set(done[0].dropped) == {"out/model.zip", "out/replay_buffer.pkl"}
    read_entry(entry)  # fresh manifest verifies
    assert generator.generate("smoke", kinds=["toy-train"], layer_root=layer, log=lines.append) == []


def test_generator_until_starts_only_jobs_that_end_in_time(fake_figures, monkeypatch):
    """`--until`: a job expected to outlast the deadline is not started; a later, shorter one is, and the log says
    what is left for the next run (which then finishes it)."""
    layer, lines = fake_figures, []
    monkeypatch.setenv("THESIS_REPRO_REFERENCE", str(layer))
    need = {"a": 10.0, "b": 500.0, "c": 5.0}  # seconds each job is expected to take: b with the margin does not fit
    assert generator.DEADLINE_MARGIN * 500.0 > 600.0
    eta = lambda job: need[job.config["algorithm"]]  # noqa: E731
    until = datetime.now() + timedelta(seconds=600)
    done = generator.generate("smoke", kinds=["toy-train"], layer_root=layer, log=lines.append, until=until, eta=eta)
    assert [e.path.name.split("__")[0] for e in done] == ["a", "c"]  # cheapest first, b skipped
    assert any("1 longer job(s) wait; starting c__Toy__s0" in line for line in lines)
    assert "1 job(s) left, none expected to end in time" in lines[-1]
    done = generator.generate("smoke", kinds=["toy-train"], layer_root=layer, log=lines.append)  # no deadline: the rest
    assert [e.path.name.split("__")[0] for e in done] == ["b"]


def test_deadline_stretches_the_eta_by_the_core_share_trainings_kept():
    """`--until`: a machine shared with other work (trainings keeping 0.5 of a core) doubles a job's expected wall
    time, so a job that fits on a quiet machine waits; evaluations (no pace measured) leave the share as it is."""

    class Landed:  # what generate() hands _Deadline.observe: a finished run and its measured paces
        def __init__(self, per_wall, per_cpu):
            self.paces = {"steps_per_s": per_wall, "steps_per_cpu_s": per_cpu}

        def measured(self, name, default=None):
            return self.paces.get(name, default)

    assert generator.core_share(Landed(300.0, 400.0)) == pytest.approx(0.75)
    assert generator.core_share(Landed(500.0, 400.0)) == 1.0  # a pace per wall second above the CPU pace: capped
    assert generator.core_share(Landed(None, None)) is None
    job = generator.Queued(Job("train", _cfg("a", 10)), ["9.9"])
    queue = generator._Deadline([job], datetime.now() + timedelta(seconds=600), lambda j: 300.0, lambda line: None)
    assert queue.share == 1.0
    for _ in range(generator.SHARE_WINDOW):
        queue.observe(Landed(200.0, 400.0))
    queue.observe(Landed(None, None))
    assert queue.share == pytest.approx(0.5)
    assert queue.take() is None  # 1.25 x 300 s / 0.5 > 600 s left
    queue.shares = [1.0]
    assert queue.take() is job


def test_eta_counts_the_work_left_past_a_checkpoint(monkeypatch, tmp_path):
    from thesis_repro.learners import train
    from thesis_repro.runs.throughput import Rates

    job = Job("train", {"algorithm": "ppo", "env": "Hopper", "seed": 0, "timesteps": 1_000_000})
    rates = Rates({"ppo": 1000.0}, {})
    cache = RunCache(tmp_path / "runs", reference=False)
    assert generator.eta_seconds(job, cache, rates) == pytest.approx(1000.0)
    monkeypatch.setattr(train, "checkpoint_steps", lambda workdir: 600_000)  # a resumed run: 400k steps left
    assert generator.eta_seconds(job, cache, rates) == pytest.approx(400.0)
    assert generator.eta_seconds(job, cache, Rates({}, {})) == float("inf")  # no rate: never fits a deadline


def test_until_is_a_clock_time():
    assert generator.parse_until("23:59", now=datetime(2026, 1, 1, 23, 0)) == datetime(2026, 1, 1, 23, 59)
    assert generator.parse_until("00:10", now=datetime(2026, 1, 1, 23, 0)) == datetime(2026, 1, 2, 0, 10)
    with pytest.raises(ValueError, match=r"--until takes a clock time HH:MM \(such as 22:40\), got '25:00'"):
        generator.parse_until("25:00")
    assert main(["reference-runs", "--scale", "smoke", "--until", "late", "--figures", "9.9"]) == 2


def test_generator_commits_each_run(fake_figures, tmp_path, monkeypatch):
    repo = tmp_path / "repo"
    repo.mkdir()
    for args in (["init", "-q"], ["config", "user.email", "t@t"], ["config", "user.name", "t"]):
        subprocess.run(["git", "-C", str(repo), *args], check=True)
    monkeypatch.setattr(paths, "ROOT", repo)
    layer = repo / "data" / "reference"
    done = generator.generate("smoke", ["9.2"], ["toy-train"], commit=True, layer_root=layer, log=str)
    log = subprocess.run(["git", "-C", str(repo), "log", "--format=%s"], capture_output=True, text=True).stdout
    subjects = log.splitlines()[::-1]
    assert len(subjects) == 2 and subjects[0].startswith("reference run: a__Toy__s0 (toy-train, key ")
    assert subjects[0].endswith(" s)") and done[0].path.name.split("__")[-1] in subjects[0]
    tracked = subprocess.run(["git", "-C", str(repo), "ls-files"], capture_output=True, text=True).stdout
    assert "data/reference/toy-train/a__Toy__s0__" in tracked and "model.zip" not in tracked


def test_plan_dedupes_and_orders_by_cost(fake_figures):
    plan = generator.job_queue("smoke", kinds=["toy-train"])
    assert [p.job.config["algorithm"] for p in plan] == ["a", "b", "c"]
    assert [p.cost for p in plan] == [10.0, 20.0, 30.0]
    assert plan[1].figures == ["fig-9.1", "fig-9.2"]
    by_figure = generator.job_queue("smoke", ["9.1", "9.2"], kinds=["toy-train"], by_figure=True)
    assert [p.job.config["algorithm"] for p in by_figure] == ["b", "c", "a"]  # 9.1's runs first, then 9.2's
    with pytest.raises(ValueError, match="valid job kinds are"):
        generator.generate("smoke", kinds=["trian"], log=str)


def test_plan_of_several_seeds_completes_seed_0_then_item_by_item(monkeypatch):
    """`reference-runs --seeds 0 1 2`: seed 0 of every figure first (each figure in the order given, cheapest
    first), then seeds 1 and 2 figure by figure; the seeds' order is the caller's."""
    monkeypatch.setattr(figures, "FIGURES", {})
    monkeypatch.setattr(figures, "TRAINING_KINDS", ("toy-train",))
    grids = {
        "9.1": lambda s: [Job("toy-train", _cfg(n, t, seed)) for seed in (0, 1, 2) for n, t in (("c", 30), ("a", 5))],
        "9.2": lambda s: [Job("toy-train", _cfg("b", 10, seed)) for seed in (0, 1, 2)],
    }
    for fid, grid in grids.items():
        figures.register_figure(fid, f"toy figure {fid}", kinds=["toy-train"], settings_id="_example")(grid)
    order = generator.job_queue("smoke", ["9.1", "9.2"], kinds=["toy-train"], by_figure=True, seeds=[0, 1, 2])
    labels = [f"{p.job.config['algorithm']}{p.job.config['seed']}" for p in order]
    assert labels == ["a0", "c0", "b0", "a1", "c1", "a2", "c2", "b1", "b2"]
    order = generator.job_queue("smoke", kinds=["toy-train"], seeds=[2, 0])
    assert [f"{p.job.config['algorithm']}{p.job.config['seed']}" for p in order] == ["a2", "b2", "c2", "a0", "b0", "c0"]


def test_rows_states_summary_and_runs_json(fake_figures, tmp_path):
    layer = fake_figures
    cache = RunCache(reference=layer)
    jobs = figures.jobs("9.1", "smoke")
    assert [j.kind for j in jobs] == ["toy-train", "toy-train", "square"]  # training first
    runs.export(RunCache(tmp_path / "maker", reference=False).run(jobs[0]), layer)  # ship c
    cache.run(jobs[2])  # cache the square job locally
    rows = {r["label"]: r for r in runs.run_rows("9.1", "smoke", cache)}
    assert {k: r["state"] for k, r in rows.items()} == {
        "c__Toy__s0": "shipped",
        "b__Toy__s0": "missing",
        "x1": "cached",
    }
    assert rows["c__Toy__s0"]["path"].endswith(f"toy-train/c__Toy__s0__{jobs[0].key}")
    assert "c__Toy__s0" in plan.text_table(list(rows.values())).splitlines()[1]
    training = [j for j in jobs if j.kind in figures.TRAINING_KINDS]
    assert runs.summary(training, cache) == "2 training runs: 1 shipped, 0 cached, 1 to compute"
    path = runs.write_run_rows("9.1", "smoke", cache)
    assert path == paths.figures_dir("smoke") / "fig-9.1.runs.json"
    doc = json.loads(path.read_text())
    assert doc["summary"].startswith("2 training runs: 1 shipped") and len(doc["runs"]) == 3
    assert runs.write_run_rows("table-9.9", "smoke") is None  # not a registered figure: nothing to record


def test_check_shipped_reports_stale_runs_with_the_fix(fake_figures, tmp_path):
    layer = fake_figures
    maker = RunCache(tmp_path / "maker", reference=False)
    runs.export(maker.run(Job("toy-train", _cfg("a", 10))), layer)
    assert shipped_checks.check_shipped("smoke", layer) == []
    old = runs.export(maker.run(Job("toy-train", _cfg("a", 11))), layer)  # a config no figure makes any more
    stale = shipped_checks.check_shipped("smoke", layer)
    assert [s.path for s in stale] == [old.path]
    assert "make reference-runs SCALE=smoke" in stale[0].message and "git rm -r" in stale[0].message


def test_shipped_job_and_cheapest_shipped(fake_figures, tmp_path, monkeypatch):
    layer = fake_figures
    assert shipped_checks.cheapest_shipped("toy-train", layer) is None
    maker = RunCache(tmp_path / "maker", reference=False)
    for job in (Job("toy-train", _cfg("c", 30)), Job("toy-train", _cfg("a", 10))):
        runs.export(maker.run(job), layer)
    walls = {"a": 5.0, "c": 1.0}  # c has more env steps but took less time (DDPG vs PPO steps): time decides
    for entry in runs.shipped_entries(layer):
        prov_path = entry / "provenance.json"
        prov = json.loads(prov_path.read_text())
        algo = json.loads((entry / "config.json").read_text())["config"]["algorithm"]
        prov.update(platform={"machine": "x86_64"}, measured={"wall_time": walls[algo], "resumed_from": 0})
        prov_path.write_text(json.dumps(prov))
    assert shipped_checks.cheapest_shipped("toy-train", layer) == Job("toy-train", _cfg("c", 30))
    c_entry = next(e for e in runs.shipped_entries(layer) if '"c"' in (e / "config.json").read_text())
    prov = json.loads((c_entry / "provenance.json").read_text())
    prov["measured"]["resumed_from"] = 4096  # an interrupted run is no conclusive retrain target
    (c_entry / "provenance.json").write_text(json.dumps(prov))
    assert shipped_checks.cheapest_shipped("toy-train", layer) == Job("toy-train", _cfg("a", 10))
    for entry in runs.shipped_entries(layer):  # no platform or measured time anywhere: the env steps decide
        (entry / "provenance.json").write_text("{}")
    cheapest = shipped_checks.cheapest_shipped("toy-train", layer)
    assert cheapest == Job("toy-train", _cfg("a", 10))
    fresh = RunCache(tmp_path / "fresh", reference=False).run(cheapest)  # the retrain-and-compare check
    assert fresh.source == "computed" and (fresh.out / "policy.txt").read_text() == "w=0"
    monkeypatch.setattr("thesis_repro.core.cache.CACHE_VERSION", 99)  # keys changed: the shipped run is unusable
    with pytest.raises(ValueError, match="no longer hashes to its key.*make reference-runs"):
        shipped_checks.cheapest_shipped("toy-train", layer)


def test_verify_shipped_and_cache_refuse_a_corrupt_file(fake_figures, tmp_path):
    layer = fake_figures
    job = Job("toy-train", _cfg("a", 10))
    ex = runs.export(RunCache(tmp_path / "maker", reference=False).run(job), layer)
    assert shipped_checks.verify_shipped(layer) == {}
    (ex.path / "out" / "policy.txt").write_text("w=666")
    assert "out/policy.txt" in shipped_checks.verify_shipped(layer)[ex.path]
    with pytest.warns(CorruptEntryWarning, match="corrupt shipped run"):
        res = RunCache(reference=layer).run(job)
    assert res.source == "computed" and (res.out / "policy.txt").read_text() == "w=0"
    assert (ex.path / "out" / "policy.txt").read_text() == "w=666"  # never deleted or repaired silently


def test_export_of_a_real_training_run_keeps_what_evaluation_needs(tmp_path):
    from thesis_repro.learners import load_policy, snapshots, train_config

    tiny = {"n_steps": 64, "n_envs": 2, "batch_size": 32, "n_epochs": 2, "max_episode_steps": 50}
    cfg = train_config("ppo", "InvertedPendulum", 0, 256, snapshot_every=128, **tiny)
    local = RunCache(reference=False).run(Job("train", cfg))
    assert (local.out / "model.zip").exists()
    ex = runs.export(local, tmp_path / "reference")
    assert not (ex.path / "out" / "model.zip").exists() and "out/model.zip" in ex.dropped
    assert ex.bytes < runs.TARGET_BYTES
    shipped = RunCache(tmp_path / "empty", reference=tmp_path / "reference").run(Job("train", cfg))
    assert shipped.source == "shipped" and shipped.path == ex.path
    obs = np.zeros((3, load_policy(local).obs_dim))
    np.testing.assert_array_equal(load_policy(shipped)(obs), load_policy(local)(obs))
    assert snapshots(shipped) == snapshots(local) != []
    assert retrain_check.max_abs_diff(local, shipped) == 0.0
    other = RunCache(reference=False).run(Job("train", {**cfg, "seed": 1}))
    assert retrain_check.max_abs_diff(local, other) > 0.0
    (tmp_path / "bare" / "out").mkdir(parents=True)
    (tmp_path / "bare" / "config.json").write_text(json.dumps({"kind": "train"}))
    with pytest.raises(ValueError, match="lacks out/policy.pth"):
        runs.export(type("R", (), {"path": tmp_path / "bare"})(), tmp_path / "reference")


def test_retrain_comparison_is_bit_exact_on_the_same_platform_else_by_outcome(tmp_path):
    from thesis_repro.core.provenance import platform_info

    entry = tmp_path / "train" / "a__Toy__s0__0123"
    entry.mkdir(parents=True)
    prov = entry / "provenance.json"
    prov.write_text(json.dumps({"wall_seconds": 1.0}))
    assert provenance.same_platform(entry) is None  # runs made before the platform was recorded
    import thesis_repro

    prov.write_text(json.dumps({"platform": platform_info(), "numerics": thesis_repro.numerics()}))
    assert provenance.same_platform(entry) is True
    # same CPU, other numerics: a run made before the numerics were pinned (native MKL dispatch)
    prov.write_text(json.dumps({"platform": platform_info()}))
    assert provenance.same_platform(entry) is False
    prov.write_text(json.dumps({"platform": {**platform_info(), "torch_cpu_capability": "NO AVX"}}))
    assert provenance.same_platform(entry) is False
    # same platform: only weights count; elsewhere both returns within OUTCOME_RTOL of the larger one
    assert retrain_check.retrain_verdict("r", True, 0.0, (1.0, 2.0), None).ok
    assert not retrain_check.retrain_verdict("r", True, 2e-6, (990.0, 990.0), (1000.0, 1000.0)).ok
    edge = 1000.0 * (1 - retrain_check.OUTCOME_RTOL)
    assert retrain_check.retrain_verdict("r", False, 0.4, (1000.0, edge + 1e-6), (1000.0, 1000.0)).ok
    bad = retrain_check.retrain_verdict("r", False, 0.4, (1000.0, 1000.0), (1000.0, edge - 1.0))
    assert not bad.ok and "testing return 1000.00 shipped vs 949.00 retrained: NOT within 5%" in bad.message


def test_wall_seconds_of_a_resumed_run_counts_every_session(tmp_path):
    from thesis_repro.core.cache import Result

    (tmp_path / "provenance.json").write_text(json.dumps({"wall_seconds": 25.0}))  # the last session only
    assert runs.wall_seconds(Result(tmp_path, {"wall_time": 830.0}, {})) == 830.0
    assert runs.wall_seconds(Result(tmp_path, {"y": 1}, {})) == 25.0  # jobs without their own clock
    assert np.isnan(runs.wall_seconds(Result(tmp_path / "gone", {}, {})))


def test_generator_progress_line_reads_the_newest_checkpoint(tmp_path):
    cache = RunCache(tmp_path / "runs", reference=False)
    job, fresh = Job("square", {"x": 1, "timesteps": 300_000}), Job("square", {"x": 2, "timesteps": 10})
    work = cache.workdir(job)
    for steps in (100_000, 200_704):
        (work / f"ckpt-{steps:012d}").mkdir(parents=True)
    line = generator.jobs_progress_line([job, fresh], cache, 125.0)
    assert line.startswith("  ... 2 min: training ")
    assert f"{job.label} 200,704/300,000 steps; {fresh.label} 0/10 steps" in line
    line = generator.jobs_progress_line(
        [job], cache, 125.0, eta=lambda j: 1500.0
    )  # the generator's estimate of the rest
    assert f"{job.label} 200,704/300,000 steps, ~25 min left (newest checkpoints)" in line


def test_runs_command(fake_figures, capsys):
    assert main(["runs", "9.2", "--scale", "smoke"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("fig-9.2 (smoke): 2 training runs: 0 shipped, 0 cached, 2 to compute")
    assert "to compute: b__Toy__s0, a__Toy__s0" in out
    assert main(["runs", "9.2", "--scale", "smoke", "--verbose"]) == 0
    out = capsys.readouterr().out
    assert "a__Toy__s0" in out and "missing" in out
    assert main(["runs", "9.9", "--scale", "smoke"]) == 2
    assert "valid figures are: '9.1', '9.2'" in capsys.readouterr().err
    assert main(["runs", "--check", "--scale", "smoke"]) == 0
    assert main(["reference-runs", "--scale", "smoke", "--figures", "9.2", "--kind", "toy-train"]) == 0
    assert "[2/2] toy-train b__Toy__s0" in capsys.readouterr().out
    assert len(runs.shipped_entries(fake_figures)) == 2
    assert main(["runs", "9.2", "--scale", "smoke", "--json"]) == 0
    assert {r["state"] for r in json.loads(capsys.readouterr().out)["runs"]} == {"cached"}


def test_plan_produces_seeds_past_the_scale_s_own_count():
    """`--seeds 1` plans seed 1 even where the scale shows one seed (seeds land ahead of the scale table)."""
    seed0 = generator.job_queue("smoke", ["3.3"], seeds=[0])
    seed1 = generator.job_queue("smoke", ["3.3"], seeds=[1])
    assert figures.settings("3.3", "smoke")["train_seeds"] == 1
    assert len(seed1) == len(seed0) > 0 and {needs.training_seed(p.job) for p in seed1} == {1}
    assert {p.job.config["env"] for p in seed1} == {p.job.config["env"] for p in seed0}


def test_two_stored_runs_compare_bit_for_bit_in_equal_pinned_numerics_on_any_cpu(tmp_path):
    """``same_making`` compares two runs with each other, not with this machine: pinned numerics on two CPUs agree
    bit for bit; native numerics only on equal platforms; native against pinned never."""
    import thesis_repro
    from thesis_repro.core.provenance import platform_info

    amd = {**platform_info(), "cpu": "AMD EPYC", "vendor": "AuthenticAMD"}
    intel = {**platform_info(), "cpu": "Intel(R) Xeon(R) Processor", "vendor": "GenuineIntel"}

    def run(name: str, **prov: object) -> Path:
        (tmp_path / name).mkdir()
        (tmp_path / name / "provenance.json").write_text(json.dumps(prov))
        return tmp_path / name

    pinned_amd = run("a", platform=amd, numerics=thesis_repro.numerics())
    pinned_intel = run("b", platform=intel, numerics=thesis_repro.numerics())
    native_amd, native_intel = run("c", platform=amd), run("d", platform=intel)
    assert provenance.same_making(pinned_amd, pinned_intel) is True
    assert provenance.same_making(native_amd, run("e", platform=amd)) is True
    assert provenance.same_making(native_amd, native_intel) is False
    assert provenance.same_making(native_intel, pinned_intel) is False
    assert provenance.same_making(native_amd, run("f")) is None
