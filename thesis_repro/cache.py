"""Content-addressed, atomic, resumable run cache with a shipped read-only layer, and a parallel job runner.

A :class:`Job` is a registered *kind* (:mod:`thesis_repro.jobs`: ``"train"``, ``"evaluate"``, ...) plus a
JSON config. Its key is ``sha256(v<CACHE_VERSION>|<kind>|<canonical config>)``: any change to the resolved
config is a new entry, moving the job function is not. The function is called as ``fn(config, workdir)``
and returns a dict of JSON values and numpy arrays; files it writes under ``workdir / "out"`` are kept
as artefacts (e.g. a trained policy).

Entries live in readable folders ``<root>/<kind>/<label>__<key>/`` (``train/ppo__Hopper__s0__<key>``;
lookups go by key) holding ``config.json`` (kind, config, key), ``provenance.json`` (command, git commit,
package versions, host, platform, times), ``result.json``, ``arrays.npz``, ``out/`` and ``manifest.json`` (SHA-256
of every file). ``workdir`` (``<label>__<key>.partial``) survives an interruption, so long jobs checkpoint
there and resume. Entries are committed atomically (a temporary folder, then ``os.replace``); an entry
whose files do not match its manifest is reported as corrupt, removed and recomputed. A per-entry lock
makes concurrent processes safe: the second waits and then reuses the first one's result.

Lookup order: the local cache (``paths.runs()``), then the shipped read-only layer of reference runs
(``paths.reference()``, ignored when ``THESIS_REPRO_RETRAIN=1``). A shipped entry is verified against its
manifest too; a corrupt one is reported and recomputed into the local cache, never used and never deleted.
``Result.source`` says where a result came from: ``"computed"``, ``"cached"`` or ``"shipped"``.

>>> import tempfile
>>> cache = RunCache(tempfile.mkdtemp(), reference=False)
>>> job = Job("square", {"x": 3})
>>> cache.run(job)["y"]
9
>>> cache.run(job).source
'cached'
>>> Job("thesis_repro.cache:_square", {"x": 3}).key == job.key  # the path form maps to the kind
True
"""

from __future__ import annotations

import fcntl
import hashlib
import json
import os
import platform
import shlex
import shutil
import subprocess
import sys
import time
import warnings
from collections.abc import Callable, Iterable, Iterator, Mapping
from concurrent.futures import ProcessPoolExecutor, as_completed
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import UTC, datetime
from functools import cache as _memo
from pathlib import Path
from typing import Any

import numpy as np

from thesis_repro import jobs as registry
from thesis_repro import paths

#: Bump to invalidate every cached entry after a change that alters results but not configs.
#: 2: keys from the job kind instead of the module path; readable ``<kind>/<label>__<key>`` folders.
CACHE_VERSION = 2
#: Where a :class:`Result` came from.
SOURCES: tuple[str, ...] = ("computed", "cached", "shipped")
#: Packages whose versions go into every entry's provenance.
PROVENANCE_PACKAGES: tuple[str, ...] = (
    "torch",
    "stable-baselines3",
    "sb3-contrib",
    "gymnasium",
    "mujoco",
    "numpy",
)


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
    """A unit of work: a registered ``kind`` (or, during the transition, its ``"module:function"`` path)
    and its full resolved ``config``. Plain picklable data; equal jobs have equal keys.

    ``target`` (filled in) records the function path the kind had when the job was made, so a worker
    process that has not registered a user-defined kind can still run it.
    """

    kind: str
    config: Mapping[str, Any] = field(default_factory=dict)
    target: str = field(default="", compare=False, repr=False)

    def __post_init__(self) -> None:
        if not isinstance(self.config, Mapping):
            raise TypeError(f"Job config must be a mapping, got {type(self.config).__name__}")
        kind = registry.kind_of(self.kind)
        object.__setattr__(self, "kind", kind)
        object.__setattr__(self, "target", registry.KINDS[kind])
        object.__setattr__(self, "config", _jsonable(self.config))

    @property
    def fn(self) -> str:
        """The ``"module:function"`` computing this job (from the registry)."""
        return self.target

    @property
    def label(self) -> str:
        """Readable part of the run folder name (``ppo-scn-16__Hopper__s0``)."""
        return registry.label(self.kind, self.config)

    @property
    def key(self) -> str:
        text = f"v{CACHE_VERSION}|{self.kind}|{canonical_json(self.config)}"
        return hashlib.sha256(text.encode()).hexdigest()[:20]

    @property
    def folder(self) -> str:
        """``<label>__<key>``: the entry's folder name under ``<root>/<kind>/``."""
        return f"{self.label}__{self.key}"

    def resolve(self) -> Callable[[dict[str, Any], Path], dict[str, Any]]:
        return registry.resolve(self.kind, self.target)


class Result(Mapping[str, Any]):
    """A committed cache entry: its values (JSON + arrays), config, artefact folder and ``source``."""

    def __init__(self, path: Path, values: dict[str, Any], config: dict[str, Any], source: str = "cached"):
        if source not in SOURCES:
            raise ValueError(f"unknown result source {source!r}; valid sources are: {', '.join(SOURCES)}")
        self.path = path
        self.values = values
        self.config = config
        self.source = source

    @property
    def from_cache(self) -> bool:
        """Loaded rather than computed now (from the local cache or the shipped layer)."""
        return self.source != "computed"

    @property
    def out(self) -> Path:
        """Folder of artefacts the job wrote (e.g. ``policy.pth``)."""
        return self.path / "out"

    @property
    def key(self) -> str:
        return self.path.name.rsplit("__", 1)[-1]

    @property
    def kind(self) -> str:
        return self.path.parent.name

    def __getitem__(self, key: str) -> Any:
        return self.values[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self.values)

    def __len__(self) -> int:
        return len(self.values)

    def __repr__(self) -> str:
        return f"Result({self.path.name}, keys={sorted(self.values)}, source={self.source!r})"


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _files(root: Path) -> list[Path]:
    return sorted(p for p in root.rglob("*") if p.is_file() and p.name != "manifest.json")


def write_manifest(folder: Path) -> dict[str, str]:
    """Write ``folder/manifest.json`` (SHA-256 of every other file) and return the sums."""
    sums = {str(p.relative_to(folder)): _sha256(p) for p in _files(folder)}
    (folder / "manifest.json").write_text(json.dumps({"sha256": sums}, indent=1))
    return sums


def read_entry(path: Path) -> tuple[dict[str, Any], dict[str, Any]]:
    """Verify entry ``path`` against its manifest and return ``(values, config)``; raises if unusable."""
    manifest = json.loads((path / "manifest.json").read_text())
    files = {str(p.relative_to(path)): _sha256(p) for p in _files(path)}
    if files != manifest["sha256"]:
        bad = sorted(set(files) ^ set(manifest["sha256"]) | {f for f in files if manifest["sha256"].get(f) != files[f]})
        raise ValueError(f"files differ from the manifest: {', '.join(bad[:5])}")
    config = json.loads((path / "config.json").read_text())
    values: dict[str, Any] = json.loads((path / "result.json").read_text())
    if (path / "arrays.npz").exists():
        with np.load(path / "arrays.npz", allow_pickle=False) as npz:
            values.update({k: npz[k] for k in npz.files})
    return values, config


def find_entry(root: Path, job: Job) -> Path | None:
    """The committed folder of ``job`` under ``root`` (matched by key, whatever its label), or ``None``."""
    folder = root / job.kind
    direct = folder / job.folder
    if direct.is_dir():
        return direct
    if not folder.is_dir():
        return None
    return next((p for p in sorted(folder.glob(f"*__{job.key}")) if p.is_dir()), None)


@_memo
def _versions() -> dict[str, str | None]:
    from importlib import metadata

    out: dict[str, str | None] = {"python": platform.python_version()}
    for name in PROVENANCE_PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    return out


def _git(*args: str) -> str | None:
    try:
        proc = subprocess.run(
            ["git", "-C", str(paths.ROOT), *args], capture_output=True, text=True, timeout=10, check=True
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return proc.stdout.strip()


#: CPU features that select different float kernels (MKL, ATen, NumPy dispatch); part of :func:`platform_info`.
_ISA_FLAGS = ("sse4_2", "avx", "avx2", "fma", "avx512f", "avx512_vnni", "avx512_bf16", "avx512_fp16", "amx_tile")


def platform_info() -> dict[str, Any]:
    """What decides a run's float rounding besides its config and code: CPU, SIMD kernels, BLAS.

    Training is deterministic on one platform, but MKL, PyTorch (ATen) and NumPy pick different SIMD
    kernels on different CPUs, and RL amplifies the last-bit differences; so a run is bit-reproducible
    only where this dict is equal (:func:`thesis_repro.runs.compare_retrain`).

    >>> sorted(platform_info())
    ['cpu', 'isa', 'machine', 'numpy_simd', 'torch_cpu_capability', 'vendor']
    """
    cpu = vendor = ""
    flags: set[str] = set()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            key, _, value = line.partition(":")
            key = key.strip()
            if key == "model name" and not cpu:
                cpu = value.strip()
            elif key == "vendor_id" and not vendor:
                vendor = value.strip()
            elif key == "flags" and not flags:
                flags = set(value.split())
    except OSError:  # not Linux: the processor string is all we know
        cpu = platform.processor()
    try:
        from numpy._core._multiarray_umath import __cpu_features__ as npf  # type: ignore[attr-defined]

        numpy_simd = sorted(k for k, v in npf.items() if v and k.startswith(("AVX512", "X86_V", "AVX2", "FMA")))
    except ImportError:  # pragma: no cover - other NumPy layouts
        numpy_simd = []
    try:
        import torch

        capability = torch.backends.cpu.get_cpu_capability()
    except ImportError:  # pragma: no cover - torch is a dependency
        capability = None
    return {
        "machine": platform.machine(),
        "vendor": vendor,
        "cpu": cpu,
        "isa": [f for f in _ISA_FLAGS if f in flags],
        "torch_cpu_capability": capability,
        "numpy_simd": numpy_simd,
    }


def provenance(start: float, end: float) -> dict[str, Any]:
    """Who/what/when made an entry: command line, git commit (+ dirty flag), package versions, host, times,
    and the :func:`platform_info` that decides its float rounding."""
    commit = _git("rev-parse", "HEAD")
    status = _git("status", "--porcelain", "--untracked-files=no") if commit else None
    return {
        "command": shlex.join(sys.argv),
        "cwd": os.getcwd(),
        "git_commit": commit,
        "git_dirty": None if status is None else bool(status),
        "packages": _versions(),
        "hostname": platform.node(),
        "platform": platform_info(),
        "start": datetime.fromtimestamp(start, UTC).isoformat(timespec="seconds"),
        "end": datetime.fromtimestamp(end, UTC).isoformat(timespec="seconds"),
        "wall_seconds": round(end - start, 3),
        "cache_version": CACHE_VERSION,
    }


class RunCache:
    """The on-disk cache (``paths.runs()`` unless ``root`` is given) over the shipped read-only layer.

    ``reference=True`` consults ``paths.reference()`` unless ``THESIS_REPRO_RETRAIN=1``; a path consults
    that folder; ``False`` disables the layer.
    """

    def __init__(self, root: str | Path | None = None, reference: str | Path | bool = True):
        self.root = Path(root) if root is not None else paths.runs()
        if reference is True:
            self.reference: Path | None = None if paths.retrain() else paths.reference()
        elif reference is False or reference is None:
            self.reference = None
        else:
            self.reference = Path(reference)
        self._bad_shipped: set[str] = set()

    def entry(self, job: Job) -> Path:
        """Local folder of ``job``: the committed one if any, else where it will be committed."""
        return find_entry(self.root, job) or self.root / job.kind / job.folder

    def shipped(self, job: Job) -> Path | None:
        """Folder of ``job`` in the shipped layer (unverified), or ``None``."""
        return find_entry(self.reference, job) if self.reference is not None else None

    def workdir(self, job: Job) -> Path:
        """Scratch folder kept across interruptions (checkpoints live here until commit)."""
        folder = self.root / job.kind
        if folder.is_dir():
            for p in folder.glob(f"*__{job.key}.partial"):
                return p
        return folder / f"{job.folder}.partial"

    def state(self, job: Job) -> str:
        """``cached`` / ``shipped`` / ``partial`` (interrupted, resumable) / ``missing``, without verifying."""
        if find_entry(self.root, job):
            return "cached"
        if self.shipped(job) is not None:
            return "shipped"
        return "partial" if self.workdir(job).exists() else "missing"

    @contextmanager
    def _lock(self, job: Job) -> Iterator[None]:
        lock = self.root / job.kind / ".locks" / f"{job.key}.lock"
        lock.parent.mkdir(parents=True, exist_ok=True)
        with open(lock, "w") as fh:
            fcntl.flock(fh, fcntl.LOCK_EX)
            try:
                yield
            finally:
                fcntl.flock(fh, fcntl.LOCK_UN)

    def load(self, job: Job) -> Result | None:
        """The committed entry for ``job`` (local cache, then shipped layer), or ``None``.

        A corrupt local entry is removed (with a warning); a corrupt shipped entry is reported and skipped.
        """
        path = find_entry(self.root, job)
        if path is not None:
            try:
                values, config = read_entry(path)
            except Exception as err:  # noqa: BLE001 - any failure to read means the entry is unusable
                warnings.warn(f"corrupt cache entry {path} ({err}); recomputing", CorruptEntryWarning, stacklevel=2)
                shutil.rmtree(path, ignore_errors=True)
            else:
                return Result(path, values, config, source="cached")
        path = self.shipped(job)
        if path is None or job.key in self._bad_shipped:
            return None
        try:
            values, config = read_entry(path)
        except Exception as err:  # noqa: BLE001
            self._bad_shipped.add(job.key)
            warnings.warn(
                f"corrupt shipped run {path} ({err}); not used, recomputing into the local cache {self.root} "
                "(the shipped folder is left as is: regenerate it with `make reference-runs`)",
                CorruptEntryWarning,
                stacklevel=2,
            )
            return None
        return Result(path, values, config, source="shipped")

    def _commit(self, job: Job, values: Mapping[str, Any], workdir: Path, start: float) -> Path:
        if not isinstance(values, Mapping):
            raise TypeError(f"job {job.kind} ({job.fn}) must return a dict, got {type(values).__name__}")
        arrays = {k: np.asarray(v) for k, v in values.items() if isinstance(v, np.ndarray)}
        scalars = _jsonable({k: v for k, v in values.items() if k not in arrays}, f"{job.kind} result")
        final = self.entry(job)
        tmp = final.parent / f".tmp-{job.key}-{os.getpid()}"
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir(parents=True)
        if (workdir / "out").exists():
            shutil.copytree(workdir / "out", tmp / "out")
        meta = {"kind": job.kind, "config": job.config, "key": job.key, "label": job.label, "fn": job.fn}
        (tmp / "config.json").write_text(json.dumps(meta, indent=1, sort_keys=True))
        (tmp / "provenance.json").write_text(json.dumps(provenance(start, time.time()), indent=1))
        (tmp / "result.json").write_text(json.dumps(scalars, indent=1, sort_keys=True))
        if arrays:
            # deflated: a diverging learner's 2M-step run logs ~130k short episodes (3.2 MB raw, 0.8 MB deflated)
            np.savez_compressed(tmp / "arrays.npz", **arrays)
        write_manifest(tmp)
        for p in tmp.rglob("*"):
            if p.is_file():
                with open(p, "rb") as fh:
                    os.fsync(fh.fileno())
        if final.exists():
            shutil.rmtree(final)
        os.replace(tmp, final)
        return final

    def run(self, job: Job) -> Result:
        """Load ``job`` (local cache, then shipped layer) or compute and commit it to the local cache."""
        cached = self.load(job)
        if cached is not None:
            return cached
        with self._lock(job):
            cached = self.load(job)  # another process may have finished it while we waited
            if cached is not None:
                return cached
            start = time.time()
            workdir = self.workdir(job)
            workdir.mkdir(parents=True, exist_ok=True)
            (workdir / "out").mkdir(exist_ok=True)
            values = job.resolve()(dict(job.config), workdir)
            path = self._commit(job, values, workdir, start)
            shutil.rmtree(workdir, ignore_errors=True)
        found = find_entry(self.root, job)
        if found is None:  # pragma: no cover - only if the disk lies to us
            raise RuntimeError(f"cache entry {path} vanished right after commit")
        values, config = read_entry(found)
        return Result(found, values, config, source="computed")


def execute(job: Job, root: str | None = None, reference: str | bool = True) -> Result:
    """Run one job through the cache (the unit a distributed engine would call remotely).

    ``reference`` is the shipped layer to consult (see :class:`RunCache`).
    """
    import torch  # local: keep the cache importable without torch

    torch.set_num_threads(1)
    return RunCache(root, reference=reference).run(job)


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
    """Run ``jobs`` (cached ones are loaded, the rest computed in parallel); results in input order.

    The rest run in ``n_jobs`` local worker processes, or as Ray tasks when ``THESIS_REPRO_BACKEND=ray``
    (:mod:`thesis_repro.backends`; ``n_jobs`` is then Ray's business).
    """
    from thesis_repro import backends  # local: backends imports this module

    jobs = list(jobs)
    cache = cache or RunCache()
    n_jobs = default_jobs() if n_jobs is None else n_jobs
    where = backends.backend()  # THESIS_REPRO_BACKEND: local | ray
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

        shipped = sum(r.source == "shipped" for r in results.values())
        bar = tqdm(total=len(todo), desc=f"{desc} ({len(results) - shipped} cached, {shipped} shipped)")
    t0 = time.time()
    if where == "ray" and todo:
        results.update(backends.run_ray(todo, cache, bar))
    elif n_jobs <= 1 or len(todo) <= 1:
        for key, job in todo.items():
            results[key] = cache.run(job)
            if bar:
                bar.update()
    else:
        import multiprocessing as mp

        with ProcessPoolExecutor(max_workers=min(n_jobs, len(todo)), mp_context=mp.get_context("spawn")) as ex:
            ref = str(cache.reference) if cache.reference is not None else False
            futures = {ex.submit(execute, job, str(cache.root), ref): key for key, job in todo.items()}
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
