"""The Ray backend (:mod:`thesis_repro.core.backends`): backend choice, packed entries, the task body without Ray,
and, when ``ray`` is importable, a loopback Ray cluster (head + one worker node, started and stopped here)
that runs the fig-3.3 smoke grid with the local pool's numbers and survives a worker killed mid-training."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from thesis_repro import figures
from thesis_repro.core import backends, job_kinds
from thesis_repro.core.backends import run_jobs
from thesis_repro.core.cache import Job, RunCache, read_entry
from thesis_repro.learners import train_config

#: one `make test` process runs this module (its module-scoped fixture is set up once)
pytestmark = pytest.mark.xdist_group("ray")

NO_RAY = "ray is not installed: `pip install -e '.[ray]'` (make test installs it) to run the Ray backend tests"


def _smoke_train(seed: int = 0, **kw) -> dict:
    return train_config("ppo", "InvertedPendulum", seed, 256, n_envs=2, n_steps=64, **kw)


def _fail(config: dict, workdir: Path) -> dict:
    raise ValueError(f"deterministic failure for x={config['x']}")


job_kinds.register("test-fail", "tests.test_ray:_fail")  # also on Ray workers, which import this module to run it


# ---------------------------------------------------------------- without Ray
def test_backend_choice(monkeypatch):
    monkeypatch.delenv(backends.ENV_VAR, raising=False)
    assert backends.backend() == "local"
    monkeypatch.setenv(backends.ENV_VAR, " Ray ")
    assert backends.backend() == "ray"
    monkeypatch.setenv(backends.ENV_VAR, "dask")
    with pytest.raises(
        ValueError, match="THESIS_REPRO_BACKEND: unknown backend 'dask'; valid backends are: 'local', 'ray'"
    ):
        run_jobs([Job("square", {"x": 2})], progress=False)  # validated before anything runs


def test_resources_are_declared_per_kind():
    assert backends.resources("train")["num_cpus"] == 1
    assert backends.resources("train")["memory"] > backends.resources("evaluate")["memory"]
    assert backends.resources("no-such-kind") == backends.DEFAULT_RESOURCES


def test_pack_unpack_roundtrip_and_corruption(tmp_path):
    cache = RunCache(tmp_path / "a", reference=False)
    res = cache.run(Job("square", {"x": 7}))
    packed = backends.pack(res.path)
    assert packed["kind"] == "square" and "manifest.json" in packed["files"]
    path = backends.unpack(tmp_path / "b", packed)
    assert path.name == res.path.name and read_entry(path)[0] == {"y": 49}
    assert backends.unpack(tmp_path / "b", packed) == path  # already there: kept
    bad = {**packed, "files": {**packed["files"], "result.json": b'{"y": 50}'}}
    with pytest.raises(ValueError, match="manifest"):
        backends.unpack(tmp_path / "c", bad)
    assert not any((tmp_path / "c" / "square").iterdir())  # nothing half-written left behind


def test_compute_materialises_the_training_run_of_an_evaluation(tmp_path):
    """A worker that cannot see the driver's cache gets the training entry from the driver (object ref) and
    evaluates it without retraining; the packed result commits on the driver like a local run."""
    train = Job("train", _smoke_train())
    test = {"perturbation": "obs", "sigmas": [0.0, 0.5], "n_rollouts": 2, "max_episode_steps": 50}
    ev = Job("evaluate", {"train": train.config, "test": test})
    assert [d.key for d in backends.job_dependencies(ev)] == [train.key]
    driver = RunCache(tmp_path / "driver", reference=False)
    trained = driver.run(train)
    worker = tmp_path / "worker"
    env = {"THESIS_REPRO_DATA": str(worker), "THESIS_REPRO_RETRAIN": "1"}
    packed = backends.compute(ev, str(worker), False, env, 1, ["driver", "cmd"], backends.pack(trained.path))
    copied = RunCache(worker, reference=False).load(train)
    assert copied is not None and copied.path.name == trained.path.name
    assert json.loads((copied.path / "provenance.json").read_text()) == json.loads(
        (trained.path / "provenance.json").read_text()
    )  # the driver's entry, not a retrained one
    result = backends.commit(driver, ev, packed)
    assert result.source == "computed" and driver.load(ev).source == "cached"
    assert json.loads((result.path / "provenance.json").read_text())["command"] == "driver cmd"
    local = RunCache(tmp_path / "local", reference=False).run(ev)
    np.testing.assert_array_equal(result["returns"], local["returns"])  # same numbers as the local path
    assert not RunCache(worker, reference=False).workdir(ev).exists()  # workdir removed once packed


def test_jobs_failed_names_config_and_error():
    job = Job("square", {"x": 3})
    err = backends.JobsFailed([(job, ValueError("boom"))], Path("/runs"))
    text = str(err)
    assert isinstance(err, RuntimeError) and "1 job(s) failed" in text and "/runs" in text
    assert f"square x3 (key {job.key})" in text and '{"x": 3}' in text and "ValueError: boom" in text


# ---------------------------------------------------------------- with a loopback Ray cluster
def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _session_pids(tag: str) -> list[int]:
    """Processes whose command line names ``tag`` (the cluster's own temp dir): everything it started."""
    out = []
    for proc in Path("/proc").iterdir():
        try:
            if proc.name.isdigit() and tag.encode() in (proc / "cmdline").read_bytes():
                out.append(int(proc.name))
        except OSError:
            continue
    return out


@pytest.fixture(scope="module")
def ray_cluster():
    """A head and one worker node on 127.0.0.1, one CPU each (``ray start --block``), stopped after the module.

    Token authentication is off (a loopback test cluster); the nodes use their own temp dir, by which every
    process they started is found and stopped (by pid) at the end.
    """
    ray = pytest.importorskip("ray", reason=NO_RAY)
    mp = pytest.MonkeyPatch()
    mp.setenv("RAY_AUTH_MODE", "disabled")
    exe = str(Path(sys.executable).with_name("ray"))
    tmp = tempfile.mkdtemp(prefix="rt", dir="/tmp")  # short: Ray's socket paths live under it
    addr = f"127.0.0.1:{_free_port()}"
    common = ["--node-ip-address=127.0.0.1", "--num-cpus=1", "--block", "--disable-usage-stats"]
    head_args = ["--head", f"--port={addr.split(':')[1]}", f"--temp-dir={tmp}", "--include-dashboard=false"]
    nodes = [subprocess.Popen([exe, "start", *head_args, *common], stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT)]
    try:
        deadline = time.time() + 120
        while True:
            try:
                ray.init(address=addr, log_to_driver=False, _node_ip_address="127.0.0.1")
                break
            except ConnectionError as err:
                if time.time() > deadline or nodes[0].poll() is not None:
                    # the machine cannot host a Ray head (sandbox, ports, shared memory): say so, do not fail
                    # every other test of the run with it; the backend's logic is tested without Ray above
                    pytest.skip(f"cannot start a loopback Ray cluster here: {err}")
                time.sleep(1)
        cmd = [exe, "start", f"--address={addr}", *common]
        nodes.append(subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT))
        while sum(n["Alive"] for n in ray.nodes()) < 2:
            assert time.time() < deadline and nodes[1].poll() is None, "the worker node did not join"
            time.sleep(0.5)
        yield addr
    finally:
        ray.shutdown()
        for node in reversed(nodes):
            node.terminate()
        for node in reversed(nodes):
            try:
                node.wait(timeout=20)
            except subprocess.TimeoutExpired:
                node.kill()
        for pid in _session_pids(tmp):
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGKILL)
        shutil.rmtree(tmp, ignore_errors=True)
        mp.undo()


@pytest.fixture
def on_ray(ray_cluster, monkeypatch):
    monkeypatch.setenv(backends.ENV_VAR, "ray")
    return ray_cluster


def test_ray_runs_the_fig33_smoke_grid_with_the_local_pools_numbers(on_ray, tmp_path, monkeypatch):
    from thesis_repro.figures import ch3

    settings = figures.settings("3.3", "smoke")
    bench = ch3.pareto_benchmark(settings)
    on_ray_res = bench.run(progress=False)
    n_jobs = len(figures.jobs("3.3", "smoke"))
    cache = RunCache()
    assert all(cache.state(j) == "cached" for j in figures.jobs("3.3", "smoke"))  # committed by the driver
    assert sum(1 for _ in cache.root.glob("*/*__*")) == n_jobs
    monkeypatch.setenv(backends.ENV_VAR, "local")
    monkeypatch.setenv("THESIS_REPRO_DATA", str(tmp_path / "local"))
    local = bench.run(n_jobs=settings["n_jobs"], progress=False)  # as the notebook runs it
    np.testing.assert_array_equal(on_ray_res.train_return, local.train_return)
    for test in settings["tests"]:
        np.testing.assert_array_equal(on_ray_res.returns[test], local.returns[test])
        np.testing.assert_array_equal(on_ray_res.auc[test], local.auc[test])


def test_killed_worker_is_retried_and_resumes_from_its_checkpoint(on_ray):
    slow = Job("train", train_config("ppo", "InvertedPendulum", 0, 12_288, n_envs=2, n_steps=64, checkpoint_every=1024))
    quick = [Job("train", _smoke_train(seed)) for seed in (1, 2)]
    cache = RunCache()
    workdir = cache.workdir(slow)
    killed: dict[str, int] = {}

    def killer() -> None:  # kill the slow job's worker process once it has written a checkpoint
        deadline = time.time() + 240
        while time.time() < deadline and not killed:
            if (workdir / backends.WORKER_FILE).exists() and any(workdir.glob("ckpt-*")):
                pid = json.loads((workdir / backends.WORKER_FILE).read_text())["pid"]
                os.kill(pid, signal.SIGKILL)
                killed["pid"] = pid
            time.sleep(0.02)

    thread = threading.Thread(target=killer, daemon=True)
    thread.start()
    first = run_jobs([*quick, slow], progress=False)
    thread.join(timeout=5)
    assert killed, "the slow job finished before it could be killed"
    assert [r.source for r in first] == ["computed"] * 3
    assert first[2]["timesteps_done"] >= 12_288 and first[2].measured("resumed_from") > 0  # resumed, not restarted
    provenance = [json.loads((r.path / "provenance.json").read_text()) for r in first]
    again = run_jobs([*quick, slow], progress=False)
    assert [r.source for r in again] == ["cached"] * 3  # finished runs are never recomputed
    assert [json.loads((r.path / "provenance.json").read_text()) for r in again] == provenance


def test_a_failing_job_fails_the_call_after_committing_the_others(on_ray):
    jobs = [Job("square", {"x": 4}), Job("test-fail", {"x": 1}), Job("square", {"x": 5})]
    with pytest.raises(backends.JobsFailed, match=r"(?s)test-fail.*\{\"x\": 1\}.*deterministic failure for x=1"):
        run_jobs(jobs, progress=False)
    cache = RunCache()
    assert [cache.state(j) for j in jobs] == ["cached", "partial", "cached"]  # its workdir is kept, as locally


def test_evaluation_and_its_training_run_in_one_call(on_ray):
    """The evaluation's task gets its training run as the training task's object ref (Ray orders them)."""
    train = Job("train", _smoke_train(seed=3))
    test = {"perturbation": "act", "sigmas": [0.0, 0.5], "n_rollouts": 2, "max_episode_steps": 50}
    ev = Job("evaluate", {"train": train.config, "test": test})
    ev_res, train_res = run_jobs([ev, train], progress=False)  # the dependent first: still ordered by Ray
    assert (ev_res.source, train_res.source) == ("computed", "computed")
    assert ev_res["train_return"] == pytest.approx(float(np.mean(train_res["train_return"])))
    assert ev_res["returns"].shape == (2, 2)


def test_the_generator_keeps_its_queue_on_ray_with_the_local_pools_numbers(on_ray, tmp_path, monkeypatch):
    """`make thesis-budget BACKEND=ray JOBS=n`: the generator hands Ray its queue n tasks at a time and ships each
    run as it lands, bit for bit the run its local pool ships."""
    from thesis_repro.runs import generator

    def no_local_pool(*args, **kwargs):
        raise AssertionError("THESIS_REPRO_BACKEND=ray: the generator started a local pool")

    queue = [generator.Queued(Job("train", _smoke_train(seed))) for seed in (4, 5)]
    lines: list[str] = []
    with monkeypatch.context() as m:
        m.setattr(backends, "LocalPool", no_local_pool)
        ray_runs = generator.generate(
            "smoke", kinds=["train"], n_jobs=2, layer_root=tmp_path / "ray", jobs=queue, log=lines.append
        )
    assert any("running 2 jobs, 2 at a time" in line for line in lines)
    assert all(RunCache().state(q.job) == "cached" for q in queue)  # committed by the driver as they landed
    monkeypatch.setenv(backends.ENV_VAR, "local")
    monkeypatch.setenv("THESIS_REPRO_DATA", str(tmp_path / "local"))
    local = generator.generate(
        "smoke", kinds=["train"], n_jobs=2, layer_root=tmp_path / "local-layer", jobs=queue, log=str
    )
    assert sorted(e.path.name for e in ray_runs) == sorted(e.path.name for e in local)
    for a, b in zip(sorted(ray_runs, key=lambda e: e.path.name), sorted(local, key=lambda e: e.path.name), strict=True):
        ours, theirs = read_entry(a.path)[0], read_entry(b.path)[0]
        assert ours.keys() == theirs.keys()
        for key in ours:
            np.testing.assert_array_equal(np.asarray(ours[key]), np.asarray(theirs[key]))
