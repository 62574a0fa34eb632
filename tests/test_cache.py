"""The run cache: content addressing, atomic commit, corruption recovery, resume, errors."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest

from thesis_repro.cache import CorruptEntryWarning, Job, RunCache, run_jobs


def _counting(config: dict, workdir: Path) -> dict:
    """Job that records how often it ran (in a file named by the config) and returns arrays."""
    counter = Path(config["counter"])
    counter.write_text(str(int(counter.read_text() or 0) + 1) if counter.exists() else "1")
    (workdir / "out" / "artefact.txt").write_text("model")
    return {"mean": 1.5, "arr": np.arange(config["n"], dtype=float)}


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


def test_key_depends_on_full_config_only():
    a = Job("tests.test_cache:_counting", {"n": 3, "b": {"x": 1.0, "y": [1, 2]}})
    b = Job("tests.test_cache:_counting", {"b": {"y": [1, 2], "x": 1.0}, "n": 3})
    c = Job("tests.test_cache:_counting", {"n": 3, "b": {"x": 1.0, "y": [1, 3]}})
    assert a.key == b.key != c.key


def test_run_then_reuse(tmp_path):
    cache = RunCache(tmp_path / "runs")
    job = Job("tests.test_cache:_counting", {"n": 4, "counter": str(tmp_path / "count")})
    first = cache.run(job)
    again = cache.run(job)
    assert not first.from_cache and again.from_cache
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
    jobs = [Job("thesis_repro.cache:_square", {"x": x}) for x in [3, 1, 2, 3]]
    out = run_jobs(jobs, n_jobs=2, cache=cache, progress=False)
    assert [r["y"] for r in out] == [9, 1, 4, 9]
    assert all(r.from_cache for r in run_jobs(jobs, n_jobs=2, cache=cache, progress=False))


@pytest.mark.parametrize(
    "fn, config, err",
    [
        ("no_colon", {}, ValueError),
        ("m:f", {"x": object()}, TypeError),
        ("m:f", {"x": float("nan")}, TypeError),
        ("m:f", {1: 2}, TypeError),
        ("m:f", [1, 2], TypeError),
    ],
)
def test_malformed_jobs_are_clear_errors(fn, config, err):
    with pytest.raises(err):
        Job(fn, config)
