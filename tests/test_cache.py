"""The run cache: stable keys, readable folders, atomic commit, corruption recovery, resume, the shipped
layer, errors."""

from __future__ import annotations

import json
import pickle
import shutil
import warnings
import zipfile
from pathlib import Path

import numpy as np
import pytest

from thesis_repro.core import job_kinds
from thesis_repro.core.backends import run_jobs
from thesis_repro.core.cache import CACHE_VERSION, CorruptEntryWarning, Job, RunCache, canonical_json


def _counting(config: dict, workdir: Path) -> dict:
    """Job that records how often it ran (in a file named by the config) and returns arrays."""
    counter = Path(config["counter"])
    counter.write_text(str(int(counter.read_text() or 0) + 1) if counter.exists() else "1")
    (workdir / "out" / "artefact.txt").write_text("model")
    return {"mean": 1.5, "arr": np.arange(config["n"], dtype=float)}


def _user_job(config: dict, workdir: Path) -> dict:
    return {"n": config["n"]}


def _resumable(config: dict, workdir: Path) -> dict:
    """Job that crashes once after writing a checkpoint, then resumes from it."""
    ckpt = workdir / "ckpt.json"
    step = json.loads(ckpt.read_text())["step"] if ckpt.exists() else 0
    while step < 10:
        step += 1
        ckpt.write_text(json.dumps({"step": step}))
        if step == 5 and config["crash"] and not (workdir / "crashed").exists():
            (workdir / "crashed").write_text("")
            raise KeyboardInterrupt("simulated interruption")
    return {"resumed_from_checkpoint": (workdir / "crashed").exists(), "step": step}


job_kinds.register("test-counting", "tests.test_cache:_counting", label=lambda c: f"n{c['n']}")
job_kinds.register("test-resumable", "tests.test_cache:_resumable")


@pytest.fixture
def scratch_registry(monkeypatch):
    """Registry changes made by a test are undone after it."""
    for name in ("KINDS", "LABELS", "PATHS", "DEPENDENCIES", "RESOURCES", "PINNED"):
        monkeypatch.setattr(job_kinds, name, type(getattr(job_kinds, name))(getattr(job_kinds, name)))


def test_key_depends_on_full_config_only():
    a = Job("tests.test_cache:_counting", {"n": 3, "b": {"x": 1.0, "y": [1, 2]}})
    b = Job("tests.test_cache:_counting", {"b": {"y": [1, 2], "x": 1.0}, "n": 3})
    c = Job("tests.test_cache:_counting", {"n": 3, "b": {"x": 1.0, "y": [1, 3]}})
    assert a.key == b.key != c.key


def test_key_is_hash_of_version_kind_and_config():
    import hashlib

    job = Job("square", {"x": 2})
    text = f"v{CACHE_VERSION}|square|{canonical_json({'x': 2})}"
    assert job.key == hashlib.sha256(text.encode()).hexdigest()[:20]
    assert Job("test-counting", {"x": 2}).key != job.key  # the kind is part of the key


def test_moving_the_function_keeps_the_key(scratch_registry):
    before = Job("test-counting", {"n": 1})
    job_kinds.register("test-counting", "tests.test_cache:_counting_moved")  # the function moved
    after = Job("test-counting", {"n": 1})
    assert after.key == before.key and after.fn == "tests.test_cache:_counting_moved"
    assert Job("tests.test_cache:_counting", {"n": 1}).kind == "test-counting"  # old spelling still maps


def test_path_and_kind_forms_are_one_entry(tmp_path):
    cache = RunCache(tmp_path / "runs", reference=False)
    cfg = {"n": 2, "counter": str(tmp_path / "count")}
    via_path, via_kind = Job("tests.test_cache:_counting", cfg), Job("test-counting", cfg)
    assert via_path == via_kind and via_path.key == via_kind.key
    assert run_jobs([via_path, via_kind], n_jobs=1, cache=cache, progress=False)[1]["mean"] == 1.5
    assert cache.run(via_kind).source == "cached"
    assert (tmp_path / "count").read_text() == "1"  # computed once


def test_unknown_kind_is_one_line_error_listing_kinds():
    for name in ("trian", "thesis_repro.nowhere:job"):
        with pytest.raises(ValueError, match=r"valid job kinds are: .*'arm-source'.*'train'") as err:
            Job(name, {})
        assert "\n" not in str(err.value)
    with pytest.raises(ValueError, match="short lowercase name"):
        job_kinds.register("Bad Kind", "m:f")


def test_a_path_cannot_name_two_kinds(scratch_registry):
    with pytest.raises(ValueError, match="already registered as job kind 'train'"):
        job_kinds.register("other", "thesis_repro.learners:train_job")


def test_jobs_are_plain_picklable_data(scratch_registry):
    job_kinds.register("test-user", "tests.test_cache:_user_job")
    job = Job("test-user", {"n": 1})
    back = pickle.loads(pickle.dumps(job))
    assert back == job and back.key == job.key
    # a worker process that never registered the kind still finds the function via the recorded target
    del job_kinds.KINDS["test-user"]
    assert back.resolve() is _user_job


def test_labels_of_the_kit_kinds():
    train = {"algorithm": "ppo-scn-16", "env": "Hopper", "seed": 0, "timesteps": 10}
    assert Job("train", train).label == "ppo-scn-16__Hopper__s0"
    ev = {"train": train, "test": {"perturbation": "obs", "sigmas": [0.0], "snapshot": 2048}}
    assert Job("evaluate", ev).label == "ppo-scn-16__Hopper__s0__obs__step2048"
    tgt = {"source": {"family": "reach"}, "target": "bic", "strategy": "tensor", "seed": 1}
    assert Job("arm-target", tgt).label == "tensor__reach-to-bic__s1"
    assert Job("arm-source", {"family": "throw", "seed": 3, "k": [1]}).label == "throw__s3"
    assert job_kinds.label("train", {"algorithm": "a/b c", "env": "E", "seed": 0}) == "a-b-c__E__s0"


def test_readable_self_describing_entry(tmp_path):
    cache = RunCache(tmp_path / "runs", reference=False)
    job = Job("test-counting", {"n": 3, "counter": str(tmp_path / "count")})
    res = cache.run(job)
    assert res.path == tmp_path / "runs" / "test-counting" / f"n3__{job.key}"
    assert (res.kind, res.key, res.source) == ("test-counting", job.key, "computed")
    meta = json.loads((res.path / "config.json").read_text())
    assert (meta["kind"], meta["key"], meta["config"]) == ("test-counting", job.key, job.config)
    prov = json.loads((res.path / "provenance.json").read_text())
    assert prov["cache_version"] == CACHE_VERSION and prov["wall_seconds"] >= 0
    assert {"command", "git_commit", "git_dirty", "hostname", "start", "end"} <= set(prov)
    assert {"torch", "stable-baselines3", "gymnasium", "mujoco", "numpy"} <= set(prov["packages"])
    manifest = json.loads((res.path / "manifest.json").read_text())["sha256"]
    on_disk = {str(p.relative_to(res.path)) for p in res.path.rglob("*") if p.is_file()} - {"manifest.json"}
    assert set(manifest) == on_disk >= {"config.json", "provenance.json", "result.json", "arrays.npz"}


def test_arrays_are_stored_deflated_and_read_back_exactly(tmp_path):
    cache = RunCache(tmp_path / "runs", reference=False)
    res = cache.run(Job("test-counting", {"n": 5000, "counter": str(tmp_path / "count")}))
    assert np.array_equal(res["arr"], np.arange(5000, dtype=float))
    with zipfile.ZipFile(res.path / "arrays.npz") as zf:
        assert {i.compress_type for i in zf.infolist()} == {zipfile.ZIP_DEFLATED}
    steps = np.arange(0, 130_000 * 15, 15, dtype=np.int64)  # a long per-episode log compresses well
    np.savez_compressed(tmp_path / "a.npz", t=steps)
    np.savez(tmp_path / "b.npz", t=steps)
    assert (tmp_path / "a.npz").stat().st_size < (tmp_path / "b.npz").stat().st_size / 3
    assert np.array_equal(np.load(tmp_path / "a.npz")["t"], steps)


def test_lookup_goes_by_key_not_label(tmp_path):
    cache = RunCache(tmp_path / "runs", reference=False)
    job = Job("test-counting", {"n": 1, "counter": str(tmp_path / "count")})
    path = cache.run(job).path
    path.rename(path.parent / f"renamed-label__{job.key}")  # e.g. the label function changed
    res = cache.run(job)
    assert res.source == "cached" and res.path.name == f"renamed-label__{job.key}"
    assert (tmp_path / "count").read_text() == "1"


def test_run_then_reuse(tmp_path):
    cache = RunCache(tmp_path / "runs")
    job = Job("tests.test_cache:_counting", {"n": 4, "counter": str(tmp_path / "count")})
    first = cache.run(job)
    again = cache.run(job)
    assert not first.from_cache and again.from_cache
    assert (first.source, again.source) == ("computed", "cached")
    np.testing.assert_array_equal(again["arr"], np.arange(4.0))
    assert again["mean"] == 1.5
    assert (again.out / "artefact.txt").read_text() == "model"
    assert json.loads((again.path / "config.json").read_text())["config"]["n"] == 4
    assert (tmp_path / "count").read_text() == "1"
    assert not cache.workdir(job).exists()


def test_corrupt_entry_is_detected_and_recomputed(tmp_path):
    cache = RunCache(tmp_path / "runs")
    job = Job("tests.test_cache:_counting", {"n": 2, "counter": str(tmp_path / "count")})
    entry = cache.run(job).path
    (entry / "result.json").write_text('{"mean": 999}')  # tampered / half-written
    with pytest.warns(CorruptEntryWarning, match="corrupt cache entry"):
        res = cache.run(job)
    assert res["mean"] == 1.5 and not res.from_cache
    assert (tmp_path / "count").read_text() == "2"


def test_truncated_manifest_is_corrupt(tmp_path):
    cache = RunCache(tmp_path / "runs")
    job = Job("tests.test_cache:_counting", {"n": 2, "counter": str(tmp_path / "count")})
    entry = cache.run(job).path
    (entry / "manifest.json").write_text("{")
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        assert cache.load(job) is None
    assert any(issubclass(w.category, CorruptEntryWarning) for w in rec)


def test_interrupted_job_resumes_from_workdir(tmp_path):
    cache = RunCache(tmp_path / "runs")
    job = Job("tests.test_cache:_resumable", {"crash": True})
    with pytest.raises(KeyboardInterrupt):
        cache.run(job)
    assert cache.load(job) is None  # nothing half-committed
    res = cache.run(job)
    assert res["resumed_from_checkpoint"] is True and res["step"] == 10


def test_run_jobs_parallel_keeps_order_and_dedupes(tmp_path):
    cache = RunCache(tmp_path / "runs")
    jobs = [Job("square", {"x": x}) for x in [3, 1, 2, 3]]
    out = run_jobs(jobs, n_jobs=2, cache=cache, progress=False)
    assert [r["y"] for r in out] == [9, 1, 4, 9]
    assert all(r.from_cache for r in run_jobs(jobs, n_jobs=2, cache=cache, progress=False))


@pytest.mark.parametrize(
    "fn, config, err",
    [
        ("no_colon", {}, ValueError),
        ("m:f", {}, ValueError),
        ("square", {"x": object()}, TypeError),
        ("square", {"x": float("nan")}, TypeError),
        ("square", {1: 2}, TypeError),
        ("square", [1, 2], TypeError),
    ],
)
def test_malformed_jobs_are_clear_errors(fn, config, err):
    with pytest.raises(err):
        Job(fn, config)


# ---------------------------------------------------------------- the shipped read-only layer
def _ship(tmp_path: Path, job: Job) -> tuple[Path, Path]:
    """Compute ``job`` in a scratch cache and copy its entry into a layer; returns (layer, shipped entry)."""
    made = RunCache(tmp_path / "maker", reference=False).run(job)
    layer = tmp_path / "reference"
    dest = layer / job.kind / made.path.name
    shutil.copytree(made.path, dest)
    return layer, dest


def test_shipped_entry_is_used_after_the_local_cache(tmp_path):
    job = Job("test-counting", {"n": 2, "counter": str(tmp_path / "count")})
    layer, dest = _ship(tmp_path, job)
    cache = RunCache(tmp_path / "runs", reference=layer)
    assert cache.state(job) == "shipped"
    res = cache.run(job)
    assert res.source == "shipped" and res.from_cache and res.path == dest
    assert (res.out / "artefact.txt").read_text() == "model" and res["mean"] == 1.5
    assert (tmp_path / "count").read_text() == "1"  # not recomputed
    assert not (tmp_path / "runs" / job.kind / job.folder).exists()  # nothing copied locally


def test_retrain_ignores_the_shipped_layer(tmp_path, monkeypatch):
    job = Job("test-counting", {"n": 2, "counter": str(tmp_path / "count")})
    layer, _ = _ship(tmp_path, job)
    monkeypatch.setenv("THESIS_REPRO_REFERENCE", str(layer))
    assert RunCache(tmp_path / "runs").state(job) == "shipped"
    monkeypatch.setenv("THESIS_REPRO_RETRAIN", "1")
    res = RunCache(tmp_path / "runs").run(job)
    assert res.source == "computed" and (tmp_path / "count").read_text() == "2"


def test_corrupt_shipped_entry_is_recomputed_locally_and_left_in_place(tmp_path):
    job = Job("test-counting", {"n": 2, "counter": str(tmp_path / "count")})
    layer, dest = _ship(tmp_path, job)
    (dest / "out" / "artefact.txt").write_text("tampered")
    cache = RunCache(tmp_path / "runs", reference=layer)
    with pytest.warns(CorruptEntryWarning, match="corrupt shipped run .*artefact.txt"):
        res = cache.run(job)
    assert res.source == "computed" and res.path.is_relative_to(tmp_path / "runs")
    assert (res.out / "artefact.txt").read_text() == "model"
    assert (dest / "out" / "artefact.txt").read_text() == "tampered"  # repo folder untouched
    assert cache.run(job).source == "cached"  # the local copy now wins


def _threads(config: dict, workdir: Path) -> dict:
    import torch

    return {"threads": torch.get_num_threads(), "dot": float(torch.ones(config["n"]) @ torch.ones(config["n"]))}


job_kinds.register("test-threads", "tests.test_cache:_threads")


def test_a_job_computes_single_threaded_wherever_it_runs(tmp_path):
    """Every kit job runs with torch on one thread, also in the calling process (`reference-runs --jobs 1`,
    smoke notebooks): a shipped evaluation made in a 2-thread process was not bit-identical to its recomputation
    in `make verify`'s worker. The caller's thread count is restored."""
    import torch

    saved = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        result = RunCache(tmp_path, reference=False).run(Job("test-threads", {"n": 4}))
        assert (result.values["threads"], result.values["dot"]) == (1, 4.0)
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(saved)
