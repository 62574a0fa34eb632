"""Content-addressed, atomic, resumable run cache and a parallel job runner.

A :class:`Job` is a pure function named by its dotted path (``"module:function"``) plus a JSON
config. Its cache key is a hash of both, so any change to the resolved config is a new entry.
The function is called as ``fn(config, workdir)`` and returns a dict of JSON values and numpy
arrays; files it writes under ``workdir / "out"`` are kept as artefacts (e.g. a trained model).

``workdir`` survives an interruption (it is only removed once the entry is committed), so long
jobs checkpoint there and resume. Entries are committed atomically (a temporary folder, then
``os.replace``) with a manifest of SHA-256 sums; an entry whose files do not match is reported as
corrupt, removed and recomputed. A per-entry lock makes concurrent processes safe: the second waits
and then reuses the first one's result. Jobs are plain data, so a distributed engine can run the same
jobs by calling :func:`execute` remotely.

>>> import tempfile
>>> cache = RunCache(tempfile.mkdtemp())
>>> job = Job("thesis_repro.cache:_square", {"x": 3})
>>> cache.run(job)["y"]
9
>>> cache.run(job).from_cache
True
"""

from __future__ import annotations

import fcntl
import hashlib
import importlib
import json
import os
import shutil
import time
import warnings
from collections.abc import Callable, Iterable, Iterator, Mapping
from concurrent.futures import ProcessPoolExecutor, as_completed
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from thesis_repro import paths

#: Bump to invalidate every cached entry after a change that alters results but not configs.
CACHE_VERSION = 1


class CorruptEntryWarning(UserWarning):
    """A cache entry failed verification and is being recomputed."""


def _jsonable(obj: Any, where: str = "config") -> Any:
    """Canonical JSON-compatible copy of ``obj``; raises ``TypeError`` naming the offending key."""
    if isinstance(obj, Mapping):
        out = {}
        for k, v in obj.items():
            if not isinstance(k, str):
                raise TypeError(f"{where}: keys must be strings, got {k!r}")
            out[k] = _jsonable(v, f"{where}.{k}")
        return out
    if isinstance(obj, list | tuple):
        return [_jsonable(v, f"{where}[{i}]") for i, v in enumerate(obj)]
    if isinstance(obj, bool | str) or obj is None:
        return obj
    if isinstance(obj, np.integer | int):
        return int(obj)
    if isinstance(obj, np.floating | float):
        f = float(obj)
        if not np.isfinite(f):
            raise TypeError(f"{where}: non-finite number {obj!r} cannot be part of a config")
        return f
    raise TypeError(f"{where}: {type(obj).__name__} is not JSON-serialisable; configs must be plain data")


def canonical_json(config: Mapping[str, Any]) -> str:
    """Deterministic JSON text of a config (sorted keys, no whitespace)."""
    return json.dumps(_jsonable(config), sort_keys=True, separators=(",", ":"))


@dataclass(frozen=True)
class Job:
    """A unit of work: ``fn`` is ``"package.module:function"``, ``config`` its full resolved config."""

    fn: str
    config: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not isinstance(self.config, Mapping):
            raise TypeError(f"Job config must be a mapping, got {type(self.config).__name__}")
        if ":" not in self.fn:
            raise ValueError(f"Job fn must look like 'package.module:function', got {self.fn!r}")
        object.__setattr__(self, "config", _jsonable(self.config))

    @property
    def name(self) -> str:
        return self.fn.rsplit(":", 1)[1]

    @property
    def key(self) -> str:
        text = f"v{CACHE_VERSION}|{self.fn}|{canonical_json(self.config)}"
        return hashlib.sha256(text.encode()).hexdigest()[:20]

    def resolve(self) -> Callable[[dict[str, Any], Path], dict[str, Any]]:
        module, func = self.fn.split(":")
        return getattr(importlib.import_module(module), func)


class Result(Mapping[str, Any]):
    """A committed cache entry: its values (JSON + arrays), config and artefact folder."""

    def __init__(self, path: Path, values: dict[str, Any], config: dict[str, Any], from_cache: bool):
        self.path = path
        self.values = values
        self.config = config
        self.from_cache = from_cache

    @property
    def out(self) -> Path:
        """Folder of artefacts the job wrote (e.g. ``model.zip``)."""
        return self.path / "out"

    def __getitem__(self, key: str) -> Any:
        return self.values[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self.values)

    def __len__(self) -> int:
        return len(self.values)

    def __repr__(self) -> str:
        return f"Result({self.path.name}, keys={sorted(self.values)}, from_cache={self.from_cache})"


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _files(root: Path) -> list[Path]:
    return sorted(p for p in root.rglob("*") if p.is_file() and p.name != "manifest.json")


class RunCache:
    """The on-disk cache (``paths.runs()`` unless ``root`` is given)."""

    def __init__(self, root: str | Path | None = None):
        self.root = Path(root) if root is not None else paths.runs()

    def entry(self, job: Job) -> Path:
        return self.root / job.name / job.key

    def workdir(self, job: Job) -> Path:
        """Scratch folder kept across interruptions (checkpoints live here until commit)."""
        return self.root / job.name / f"{job.key}.partial"

    @contextmanager
    def _lock(self, job: Job) -> Iterator[None]:
        lock = self.root / job.name / f"{job.key}.lock"
        lock.parent.mkdir(parents=True, exist_ok=True)
        with open(lock, "w") as fh:
            fcntl.flock(fh, fcntl.LOCK_EX)
            try:
                yield
            finally:
                fcntl.flock(fh, fcntl.LOCK_UN)

    def load(self, job: Job) -> Result | None:
        """The committed entry for ``job``, or ``None``. A corrupt entry is removed (with a warning)."""
        path = self.entry(job)
        if not path.exists():
            return None
        try:
            manifest = json.loads((path / "manifest.json").read_text())
            files = {str(p.relative_to(path)): _sha256(p) for p in _files(path)}
            if files != manifest["sha256"]:
                raise ValueError("file checksums differ from the manifest")
            config = json.loads((path / "config.json").read_text())
            values: dict[str, Any] = json.loads((path / "result.json").read_text())
            if (path / "arrays.npz").exists():
                with np.load(path / "arrays.npz", allow_pickle=False) as npz:
                    values.update({k: npz[k] for k in npz.files})
        except Exception as err:  # noqa: BLE001 - any failure to read means the entry is unusable
            warnings.warn(f"corrupt cache entry {path} ({err}); recomputing", CorruptEntryWarning, stacklevel=2)
            shutil.rmtree(path, ignore_errors=True)
            return None
        return Result(path, values, config, from_cache=True)

    def _commit(self, job: Job, values: Mapping[str, Any], workdir: Path) -> Path:
        if not isinstance(values, Mapping):
            raise TypeError(f"job {job.fn} must return a dict, got {type(values).__name__}")
        arrays = {k: np.asarray(v) for k, v in values.items() if isinstance(v, np.ndarray)}
        scalars = _jsonable({k: v for k, v in values.items() if k not in arrays}, f"{job.fn} result")
        final = self.entry(job)
        tmp = final.parent / f".tmp-{job.key}-{os.getpid()}"
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir(parents=True)
        if (workdir / "out").exists():
            shutil.copytree(workdir / "out", tmp / "out")
        (tmp / "config.json").write_text(
            json.dumps({"fn": job.fn, "config": job.config, "key": job.key}, indent=1, sort_keys=True)
        )
        (tmp / "result.json").write_text(json.dumps(scalars, indent=1, sort_keys=True))
        if arrays:
            np.savez(tmp / "arrays.npz", **arrays)
        manifest = {"sha256": {str(p.relative_to(tmp)): _sha256(p) for p in _files(tmp)}}
        (tmp / "manifest.json").write_text(json.dumps(manifest, indent=1))
        for p in tmp.rglob("*"):
            if p.is_file():
                with open(p, "rb") as fh:
                    os.fsync(fh.fileno())
        if final.exists():
            shutil.rmtree(final)
        os.replace(tmp, final)
        return final

    def run(self, job: Job) -> Result:
        """Load ``job`` from the cache or compute and commit it."""
        cached = self.load(job)
        if cached is not None:
            return cached
        with self._lock(job):
            cached = self.load(job)  # another process may have finished it while we waited
            if cached is not None:
                return cached
            workdir = self.workdir(job)
            workdir.mkdir(parents=True, exist_ok=True)
            (workdir / "out").mkdir(exist_ok=True)
            values = job.resolve()(dict(job.config), workdir)
            path = self._commit(job, values, workdir)
            shutil.rmtree(workdir, ignore_errors=True)
        result = self.load(job)
        if result is None:  # pragma: no cover - only if the disk lies to us
            raise RuntimeError(f"cache entry {path} vanished right after commit")
        result.from_cache = False
        return result


def execute(job: Job, root: str | None = None) -> Result:
    """Run one job through the cache (the unit a distributed engine would call remotely)."""
    import torch  # local: keep the cache importable without torch

    torch.set_num_threads(1)
    return RunCache(root).run(job)


def default_jobs() -> int:
    """Worker processes for :func:`run_jobs`: ``THESIS_REPRO_JOBS`` or the number of cores."""
    return int(os.environ.get("THESIS_REPRO_JOBS", os.cpu_count() or 1))


def run_jobs(
    jobs: Iterable[Job],
    n_jobs: int | None = None,
    cache: RunCache | None = None,
    progress: bool = True,
    desc: str = "jobs",
) -> list[Result]:
    """Run ``jobs`` (cached ones are loaded, the rest computed in parallel); results in input order."""
    jobs = list(jobs)
    cache = cache or RunCache()
    n_jobs = default_jobs() if n_jobs is None else n_jobs
    results: dict[str, Result] = {}
    todo: dict[str, Job] = {}
    for job in jobs:
        if job.key in results or job.key in todo:
            continue
        hit = cache.load(job)
        if hit is not None:
            results[job.key] = hit
        else:
            todo[job.key] = job
    bar = None
    if progress and todo:
        from tqdm import tqdm

        bar = tqdm(total=len(todo), desc=f"{desc} ({len(jobs) - len(todo)} cached)")
    t0 = time.time()
    if n_jobs <= 1 or len(todo) <= 1:
        for key, job in todo.items():
            results[key] = cache.run(job)
            if bar:
                bar.update()
    else:
        import multiprocessing as mp

        with ProcessPoolExecutor(max_workers=min(n_jobs, len(todo)), mp_context=mp.get_context("spawn")) as ex:
            futures = {ex.submit(execute, job, str(cache.root)): key for key, job in todo.items()}
            for fut in as_completed(futures):
                results[futures[fut]] = fut.result()
                if bar:
                    bar.update()
    if bar:
        bar.set_postfix_str(f"{time.time() - t0:.0f}s")
        bar.close()
    return [results[job.key] for job in jobs]


def _square(config: dict[str, Any], workdir: Path) -> dict[str, Any]:
    """Toy job used by doctests and tests."""
    return {"y": config["x"] ** 2}
