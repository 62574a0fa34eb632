"""The storage layer: the cache stores, the backends run, job kinds register themselves; evaluations
pin their policy's identity; identical computations give identical result files; no temporary leftovers."""

from __future__ import annotations

import ast
import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from thesis_repro.core import backends, job_kinds
from thesis_repro.core.cache import (
    VOLATILE,
    Job,
    Result,
    RunCache,
    entry_identity,
    sweep_tmp,
    verify_entry,
)
from thesis_repro.runs import layer as runs

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "thesis_repro"


# ---------------------------------------------------------------- fake kinds (importable by path)
def _policy(config: dict, workdir: Path) -> dict:
    """A 'training' job: writes weights (plus a local-only model file); ``salt`` files make a recomputation
    give other weights, as a retrained policy would."""
    salt = Path(config["salt"]).read_text() if Path(config["salt"]).exists() else "0"
    (workdir / "out" / "weights.txt").write_text(f"w{config['n']}-{salt}")
    (workdir / "out" / "model.zip").write_text(f"optimiser state {time.time()}")  # never shipped
    return {"train_return": float(config["n"]), "wall_time": time.time(), "curve": np.arange(3.0)}


def _evaluation(config: dict, workdir: Path) -> dict:
    """An 'evaluation': loads its policy from the cache that runs it, counts its own runs."""
    policy = RunCache.current().run(Job("test-policy", config["train"]))
    if config.get("policy") != policy.identity:
        raise AssertionError("evaluated another policy than the one its key pins")
    counter = Path(config["counter"])
    counter.write_text(str(int(counter.read_text()) + 1) if counter.exists() else "1")
    return {"score": (policy.out / "weights.txt").read_text()}


def _eval_deps(config: dict) -> dict:
    return {"policy": Job("test-policy", config["train"])}


def _timed(config: dict, workdir: Path) -> dict:
    """Deterministic results plus measurements that differ on every run."""
    t0 = time.time()
    arr = np.linspace(0.0, 1.0, config["n"])
    return {
        "y": float(arr.sum()),
        "arr": arr,
        "ints": np.arange(config["n"]),
        "wall_time": time.time() - t0 + np.random.default_rng().random(),
        "steps_per_s": float(np.random.default_rng().random()),
        "provenance": {"peak_rss": int(np.random.default_rng().integers(1 << 30))},
    }


job_kinds.register("test-policy", "tests.test_storage:_policy")
job_kinds.register("test-eval", "tests.test_storage:_evaluation", deps="tests.test_storage:_eval_deps", pin=True)
job_kinds.register("test-timed", "tests.test_storage:_timed")


# ---------------------------------------------------------------- item 7: no import cycle
#: Modules of the storage layer and every module that defines a job kind or a kind's hook.
def _job_modules() -> set[str]:
    paths = [*job_kinds.KINDS.values(), *job_kinds.DEPENDENCIES.values()]
    return {p.split(":")[0] for p in paths if p.startswith("thesis_repro")}


def _module_file(name: str) -> Path | None:
    rel = Path(*name.split("."))
    for cand in (ROOT / rel.with_suffix(".py"), ROOT / rel / "__init__.py"):
        if cand.exists():
            return cand
    return None


def _imports(name: str) -> set[str]:
    """Kit modules ``name`` imports anywhere in its source (top level or inside functions)."""
    path = _module_file(name)
    tree = ast.parse(path.read_text())
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*parts, base] if base else parts)
            out.add(base)
            out.update(f"{base}.{a.name}" for a in node.names if _module_file(f"{base}.{a.name}"))
    return {m for m in out if m.startswith("thesis_repro") and _module_file(m)}


def test_cache_imports_neither_backends_nor_any_job_module():
    own = _imports("thesis_repro.core.cache")
    allowed = {"thesis_repro", "thesis_repro.core", "thesis_repro.core.job_kinds", "thesis_repro.core.paths"}
    allowed |= {"thesis_repro.core.provenance"}  # the core folder's face imports nothing
    assert own <= allowed | {"thesis_repro.core.compact"}, own  # compact: the arrays codec, numpy and stdlib only
    assert _imports("thesis_repro.core.compact") <= {"thesis_repro", "thesis_repro.core"}
    assert _imports("thesis_repro.core.job_kinds") <= {"thesis_repro.core", "thesis_repro.core.validation"}
    jobs_modules = _job_modules() - {"thesis_repro.core.cache"}
    assert not _imports("thesis_repro.core.backends") & jobs_modules
    assert not _imports("thesis_repro.core.backends") & {
        m for m in _imports("thesis_repro.core.backends") if ".arm" in m
    }


def test_no_import_cycle_through_the_storage_layer():
    graph: dict[str, set[str]] = {}
    todo = ["thesis_repro.core.cache", "thesis_repro.core.backends", "thesis_repro.core.job_kinds", *_job_modules()]
    while todo:
        name = todo.pop()
        if name not in graph:
            graph[name] = _imports(name)
            todo.extend(graph[name])

    def reaches(start: str, goal: str) -> bool:
        seen, stack = set(), list(graph[start])
        while stack:
            m = stack.pop()
            if m == goal:
                return True
            if m not in seen:
                seen.add(m)
                stack.extend(graph.get(m, ()))
        return False

    for mod in ("thesis_repro.core.cache", "thesis_repro.core.backends", "thesis_repro.core.job_kinds"):
        assert not reaches(mod, mod), f"{mod} imports itself back"


def test_each_module_imports_alone_in_a_fresh_process():
    light = ["thesis_repro.core.cache", "thesis_repro.core.job_kinds", "thesis_repro.core.backends"]
    mods = [*light, *sorted(_job_modules() - set(light))]
    code = (
        "import importlib, json, sys; importlib.import_module(sys.argv[1]); "
        "print(json.dumps(sorted(m for m in sys.modules if m.startswith('thesis_repro'))))"
    )
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    loaded: dict[str, set[str]] = {}
    for i in range(0, len(mods), 2):  # two at a time: the machine's cores are shared
        procs = {
            m: subprocess.Popen([sys.executable, "-c", code, m], cwd=ROOT, env=env, stdout=subprocess.PIPE, text=True)
            for m in mods[i : i + 2]
        }
        for m, proc in procs.items():
            out, _ = proc.communicate(timeout=120)
            assert proc.returncode == 0, f"`import {m}` fails on its own"
            loaded[m] = set(json.loads(out))
    assert loaded["thesis_repro.core.cache"] <= {
        "thesis_repro",
        "thesis_repro.core",
        "thesis_repro.core.cache",
        "thesis_repro.core.compact",
        "thesis_repro.core.job_kinds",
        "thesis_repro.core.paths",
        "thesis_repro.core.provenance",
        "thesis_repro.core.validation",
    }
    assert not loaded["thesis_repro.core.backends"] & (_job_modules() - {"thesis_repro.core.cache"})


def _code_strings(path: Path) -> set[str]:
    """String constants of a module's code (docstrings left out)."""
    tree = ast.parse(path.read_text())
    docs = {
        id(n.body[0].value)
        for n in ast.walk(tree)
        if isinstance(n, ast.Module | ast.FunctionDef | ast.ClassDef)
        and n.body
        and isinstance(n.body[0], ast.Expr)
        and isinstance(n.body[0].value, ast.Constant)
    }
    return {n.value for n in ast.walk(tree) if isinstance(n, ast.Constant) and isinstance(n.value, str)} - {
        n.value for n in ast.walk(tree) if id(n) in docs
    }


def test_neither_cache_nor_backends_names_a_kind():
    kinds = set(job_kinds.KINDS)
    for mod in ("cache.py", "backends.py"):
        assert not _code_strings(PKG / "core" / mod) & kinds, mod
        assert "COMPETITORS" not in (PKG / "core" / mod).read_text()


def test_kinds_declare_their_dependencies_and_resources():
    src = {"family": "reach", "seed": 0}
    tensor, fcnn = (
        Job("arm-target", {"source": src, "strategy": "tensor"}),
        Job("arm-target", {"source": src, "strategy": "fcnn"}),
    )
    assert [d.kind for d in backends.job_dependencies(tensor)] == ["arm-source"]
    assert [(d.kind, d.config["policy"]) for d in backends.job_dependencies(fcnn)] == [
        ("arm-competitor-source", "fcnn")
    ]
    assert backends.job_dependencies(Job("square", {"x": 1})) == []
    assert backends.resources("train")["memory"] > backends.resources("arm-target")["memory"]
    assert (
        job_kinds.pins_dependencies("evaluate")
        and not job_kinds.pins_dependencies("arm-target")
        and not job_kinds.pins_dependencies("train")
    )
    cache = RunCache(reference=False)
    assert cache.bind(tensor) is tensor  # an unpinned kind is keyed by its config alone, as before


def test_pin_needs_a_dependency_hook():
    with pytest.raises(ValueError, match="dependency hook"):
        job_kinds.register("test-nohook", "tests.test_storage:_nowhere", pin=True)


# ---------------------------------------------------------------- item 4c: evaluations pin their policy
def _eval_job(tmp_path: Path, n: int = 1) -> tuple[Job, Job]:
    train = {"n": n, "salt": str(tmp_path / "salt")}
    return Job("test-policy", train), Job("test-eval", {"train": train, "counter": str(tmp_path / "evals")})


def test_an_evaluation_is_recomputed_after_its_policy_is_and_reused_otherwise(tmp_path):
    cache = RunCache(tmp_path / "runs", reference=False)
    train, ev = _eval_job(tmp_path)
    assert cache.bind(ev) is None and cache.state(ev) == "missing"  # not keyed before its policy exists
    first = cache.run(ev)
    trained = cache.load(train)
    assert first.source == "computed" and first.config["config"]["policy"] == entry_identity(trained.path)
    assert first.key != ev.key and cache.bind(ev).key == first.key  # the key includes the identity
    assert cache.run(ev).source == "cached" and cache.state(ev) == "cached"
    assert (tmp_path / "evals").read_text() == "1"

    # recompute the policy with the same bytes (a deterministic retrain): same identity, evaluation reused
    shutil.rmtree(trained.path)
    assert cache.run(ev).source == "cached" and (tmp_path / "evals").read_text() == "1"

    # new weights under the same training config: a new evaluation, never the old one
    shutil.rmtree(cache.load(train).path)
    (tmp_path / "salt").write_text("retrained")
    again = cache.run(ev)
    assert again.source == "computed" and again.key != first.key and again["score"] == "w1-retrained"
    assert (tmp_path / "evals").read_text() == "2"
    assert first.path.exists()  # the old evaluation is kept under its own key (it is still valid for the old weights)


def test_a_tampered_policy_entry_gives_a_new_evaluation(tmp_path):
    cache = RunCache(tmp_path / "runs", reference=False)
    train, ev = _eval_job(tmp_path)
    first = cache.run(ev)
    policy = cache.load(train).path
    (tmp_path / "salt").write_text("other")  # the recomputation after the corruption gives other weights
    (policy / "out" / "weights.txt").write_text("tampered")
    assert cache.state(train, verify=True) == "corrupt" and cache.state(train) == "cached"
    with pytest.warns(UserWarning, match="corrupt cache entry"):
        again = cache.run(ev)
    assert again.source == "computed" and again.key != first.key and again["score"] == "w1-other"


def test_a_fresh_clone_keys_evaluations_as_the_machine_that_shipped_the_policy(tmp_path):
    maker = RunCache(tmp_path / "maker", reference=False)
    train, ev = _eval_job(tmp_path)
    made = maker.run(ev)
    layer = tmp_path / "reference"
    exported = runs.export(maker.load(train), layer)
    assert "out/model.zip" in exported.dropped  # local-only files differ, and are not part of the identity
    clone = RunCache(tmp_path / "clone", reference=layer)
    assert clone.state(train) == "shipped" and clone.bind(ev).key == made.key
    assert entry_identity(exported.path) == entry_identity(maker.load(train).path)
    shutil.copytree(made.path, tmp_path / "clone" / ev.kind / made.path.name)  # e.g. a shipped evaluation
    assert clone.run(ev).source == "cached" and (tmp_path / "evals").read_text() == "1"


def test_run_jobs_binds_evaluations_after_running_their_policies(tmp_path):
    cache = RunCache(tmp_path / "runs", reference=False)
    jobs = [_eval_job(tmp_path, n)[1] for n in (1, 2, 1)]
    out = backends.run_jobs(jobs, n_jobs=1, cache=cache, progress=False)
    assert [r["score"] for r in out] == ["w1-0", "w2-0", "w1-0"] and out[0].path == out[2].path
    assert (tmp_path / "evals").read_text() == "2"
    assert all(r.source == "cached" for r in backends.run_jobs(jobs, n_jobs=1, cache=cache, progress=False))


def test_the_evaluate_kind_pins_its_training_run():
    train = {"algorithm": "ppo", "env": "Hopper", "seed": 0}
    ev = Job("evaluate", {"train": train, "test": {"perturbation": "obs", "sigmas": [0.0]}})
    assert {k: d.key for k, d in job_kinds.dependencies("evaluate", ev.config).items()} == {
        "policy": Job("train", train).key
    }


# ---------------------------------------------------------------- item 5c: byte-identical result files
def test_identical_computations_give_byte_identical_result_files(tmp_path, monkeypatch):
    job = Job("test-timed", {"n": 1000})
    a = RunCache(tmp_path / "a", reference=False).run(job)
    real = time.localtime
    monkeypatch.setattr(time, "localtime", lambda *args: real(0))  # a zip member stamped at another time
    b = RunCache(tmp_path / "b", reference=False).run(job)
    for name in ("result.json", "arrays.npz"):
        assert (a.path / name).read_bytes() == (b.path / name).read_bytes(), name
    assert a.identity == b.identity
    assert set(VOLATILE).isdisjoint(json.loads((a.path / "result.json").read_text()))
    measured = a.provenance["measured"]
    assert set(measured) == {"wall_time", "steps_per_s", "peak_rss"}
    assert a.measured("wall_time") == measured["wall_time"] and "wall_time" not in a
    assert np.array_equal(a["arr"], np.linspace(0.0, 1.0, 1000)) and a["ints"].dtype == np.arange(1).dtype
    assert runs.wall_seconds(a) == pytest.approx(measured["wall_time"])


def test_measurements_of_entries_shipped_before_provenance_held_them(tmp_path):
    (tmp_path / "provenance.json").write_text(json.dumps({"wall_seconds": 25.0}))
    legacy = Result(tmp_path, {"wall_time": 830.0, "steps_per_s": 2.0}, {})
    assert legacy.measured("wall_time") == 830.0 and legacy.measured("steps_per_s") == 2.0
    assert runs.wall_seconds(legacy) == 830.0
    assert Result(tmp_path / "gone", {}, {}).measured("wall_time", -1) == -1


# ---------------------------------------------------------------- item 5a: no leftovers
def _dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def test_temporary_folders_of_dead_processes_are_removed_and_live_ones_kept(tmp_path):
    cache = RunCache(tmp_path / "runs", reference=False)
    job = Job("square", {"x": 4})
    kind_dir = tmp_path / "runs" / "square"
    other = tmp_path / "runs" / "test-timed"
    live = subprocess.Popen(["sleep", "60"])
    try:
        dead = kind_dir / f".tmp-{job.key}-{_dead_pid()}"
        kept = kind_dir / f".tmp-{job.key}-{live.pid}"
        unpacked = other / f".tmp-0123abcd-{_dead_pid()}-unpack"
        odd = kind_dir / ".tmp-not-a-pid"
        for p in (dead, kept, unpacked, odd):
            (p / "out").mkdir(parents=True)
        assert cache.run(job)["y"] == 16  # the commit sweeps its kind's folder
        assert not dead.exists() and kept.exists() and odd.exists() and unpacked.exists()
        backends.run_jobs([Job("square", {"x": 5})], n_jobs=1, cache=cache, progress=False)  # sweeps every kind
        assert not unpacked.exists() and kept.exists()
    finally:
        live.kill()
        live.wait()
    assert sweep_tmp(kind_dir) == [kept]  # its process is gone now


def test_no_tmp_left_after_a_commit_killed_midway(tmp_path):
    root = tmp_path / "runs"
    script = textwrap.dedent(
        f"""
        import time
        import thesis_repro.core.cache as c
        def stuck(folder):  # the process dies while its temporary folder is half written
            time.sleep(600)
        c.write_manifest = stuck
        c.RunCache({str(root)!r}, reference=False).run(c.Job("square", {{"x": 6}}))
        """
    )
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, "-c", script], cwd=ROOT, env=env)
    try:
        deadline = time.time() + 60
        while not list((root / "square").glob(".tmp-*")) and time.time() < deadline:
            time.sleep(0.05)
        assert list((root / "square").glob(".tmp-*")), "the child never reached its commit"
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    assert [p.name for p in (root / "square").glob(".tmp-*")] == [f".tmp-{Job('square', {'x': 6}).key}-{proc.pid}"]
    res = RunCache(root, reference=False).run(Job("square", {"x": 6}))
    assert res["y"] == 36 and res.source == "computed"
    assert not list(root.rglob(".tmp-*"))


def test_export_sweeps_dead_exports_in_the_shipped_layer(tmp_path):
    res = RunCache(tmp_path / "runs", reference=False).run(Job("square", {"x": 2}))
    layer = tmp_path / "reference"
    stale = layer / "square" / f".tmp-export-{res.path.name}-{_dead_pid()}"
    stale.mkdir(parents=True)
    runs.export(res, layer)
    assert not stale.exists() and verify_entry(layer / "square" / res.path.name)


# ---------------------------------------------------------------- state(verify=True)
def test_state_reports_corrupt_entries_when_asked_to_verify(tmp_path):
    maker = RunCache(tmp_path / "maker", reference=False)
    job = Job("test-timed", {"n": 3})
    made = maker.run(job)
    layer = tmp_path / "reference"
    shipped = layer / job.kind / made.path.name
    shutil.copytree(made.path, shipped)
    cache = RunCache(tmp_path / "runs", reference=layer)
    assert cache.state(job, verify=True) == "shipped"
    (shipped / "result.json").write_text('{"y": 0}')
    assert cache.state(job) == "shipped" and cache.state(job, verify=True) == "corrupt"
    assert not verify_entry(shipped) and verify_entry(made.path)
    (made.path / "arrays.npz").write_bytes(b"truncated")
    assert maker.state(job) == "cached" and maker.state(job, verify=True) == "corrupt"
    assert not verify_entry(tmp_path / "nowhere")
