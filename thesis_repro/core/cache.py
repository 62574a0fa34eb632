"""Content-addressed, atomic, resumable run cache with a shipped read-only layer: it stores and verifies entries.

One file on purpose (over 600 lines): an entry's format on disk (folders, temporary names, manifest, identity)
and the :class:`RunCache` that commits, verifies and finds it are one contract, changed together with
:data:`CACHE_VERSION`; the :mod:`thesis_repro.core.provenance` of an entry is already its own module.

A :class:`Job` is a registered *kind* (:mod:`thesis_repro.core.job_kinds`: ``"train"``, ``"evaluate"``, ...) plus a
JSON config. Its key is ``sha256(v<CACHE_VERSION>|<kind>|<canonical config>)``: any change to the resolved
config is a new entry, moving the job function is not. The function is called as ``fn(config, workdir)``
and returns a dict of JSON values and numpy arrays; files it writes under ``workdir / "out"`` are kept
as artefacts (e.g. a trained policy).

Entries live in readable folders ``<root>/<kind>/<label>__<key>/`` (``train/ppo__Hopper__s0__<key>``;
lookups go by key) holding ``config.json`` (kind, config, key), ``provenance.json`` (command, git commit,
package versions, host, platform, times, and what the job measured: wall time, throughput),
``result.json``, ``arrays.npz``, ``out/`` and ``manifest.json`` (SHA-256 of every file). ``result.json`` and
``arrays.npz`` hold only what the job computed (:data:`VOLATILE` values go to the provenance), so identical
computations give byte-identical result files. ``workdir`` (``<label>__<key>.partial``) survives an
interruption, so long jobs checkpoint there and resume. Entries are committed atomically (a temporary
folder ``.tmp-<key>-<pid>``, then ``os.replace``; one left by a dead process is removed on the next run); an
entry whose files do not match its manifest is reported as corrupt, removed and recomputed. A per-entry
lock makes concurrent processes safe: the second waits and then reuses the first one's result.

Lookup order: the local cache (``paths.runs_dir()``), then the shipped read-only layer of reference runs
(``paths.reference()``, ignored when ``THESIS_REPRO_RETRAIN=1``). A shipped entry is verified against its
manifest too; a corrupt one is reported and recomputed into the local cache, never used and never deleted.
``Result.source`` says where a result came from: ``"computed"``, ``"cached"`` or ``"shipped"``.

Pinned dependencies. A kind registered with ``pin=True`` (an evaluation) has the *identity* of each of its
dependencies' entries (:func:`entry_identity`: a hash of what the job computed, the same for a local entry
and its shipped copy) in its config, filled in by :meth:`RunCache.bind`: recomputing a training run gives
new evaluations, never the old weights' ones. The cache knows no kind: the registry's hooks say which.

This module stores; :mod:`thesis_repro.core.backends` runs many jobs (``run_jobs``: a process pool or Ray).

>>> import tempfile
>>> cache = RunCache(tempfile.mkdtemp(), reference=False)
>>> job = Job("square", {"x": 3})
>>> cache.run(job)["y"]
9
>>> cache.run(job).source
'cached'
>>> Job("thesis_repro.core.cache:_square", {"x": 3}).key == job.key  # the path form maps to the kind
True
"""

from __future__ import annotations

import fcntl
import fnmatch
import hashlib
import json
import os
import re
import shutil
import time
import warnings
import zipfile
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass, field
from functools import cache as _memo
from pathlib import Path
from typing import Any

import numpy as np

from thesis_repro.core import job_kinds, paths
from thesis_repro.core.compact import read_arrays, same_arrays
from thesis_repro.core.provenance import record

#: Bump to invalidate every cached entry after a change that alters results but not configs.
#: 2: keys from the job kind instead of the module path; readable ``<kind>/<label>__<key>`` folders.
CACHE_VERSION = 2
#: Where a :class:`Result` came from.
SOURCES: tuple[str, ...] = ("computed", "cached", "shipped")
#: Result values that are measurements of the computation, not its outcome (they differ between identical
#: runs): moved from ``result.json`` to ``provenance.json["measured"]``. A job may also return them (and any
#: other measurement) in a ``"provenance"`` dict. Read them with :meth:`Result.measured`.
VOLATILE: tuple[str, ...] = ("wall_time", "steps_per_s", "resumed_from", "cpu_time", "steps_per_cpu_s")
#: Artefacts that stay in the local cache and are never shipped (glob patterns on any file or folder name
#: under ``out/``): full SB3 models and VecNormalize pickles, replay buffers, resumable checkpoints,
#: optimiser dumps. They are not part of an entry's :func:`entry_identity` either.
UNSHIPPED: tuple[str, ...] = (
    "model.zip",
    "vecnormalize.pkl",
    "*replay_buffer*",
    "ckpt*",
    "checkpoint*",
    "*optimizer*",
    "*optimiser*",
    ".ckpt-tmp",
)
#: Name of the temporary folder of a commit (``.tmp-<key>-<pid>``) and of the other writers' temporary
#: folders (``.tmp-<key>-<pid>-unpack``, ``.tmp-export-<label>__<key>-<pid>``): the pid is the last number.
_TMP_RE = re.compile(r"^\.tmp-.+-(\d+)(?:-unpack)?$")


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
        kind = job_kinds.kind_of(self.kind)
        object.__setattr__(self, "kind", kind)
        object.__setattr__(self, "target", job_kinds.KINDS[kind])
        object.__setattr__(self, "config", _jsonable(self.config))

    @property
    def fn(self) -> str:
        """The ``"module:function"`` computing this job (from the registry)."""
        return self.target

    @property
    def label(self) -> str:
        """Readable part of the run folder name (``ppo-scn-16__Hopper__s0``)."""
        return job_kinds.label(self.kind, self.config)

    @property
    def key(self) -> str:
        try:  # the config is canonical since __post_init__: its JSON text is canonical_json's
            body = json.dumps(self.config, sort_keys=True, separators=(",", ":"), allow_nan=False)
        except (TypeError, ValueError):  # changed in place since: canonical_json converts it, or names what is wrong
            body = canonical_json(self.config)
        text = f"v{CACHE_VERSION}|{self.kind}|{body}"
        return hashlib.sha256(text.encode()).hexdigest()[:20]

    @property
    def folder(self) -> str:
        """``<label>__<key>``: the entry's folder name under ``<root>/<kind>/``."""
        return f"{self.label}__{self.key}"

    def resolve(self) -> Callable[[dict[str, Any], Path], dict[str, Any]]:
        return job_kinds.resolve(self.kind, self.target)


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

    @property
    def provenance(self) -> dict[str, Any]:
        """The entry's ``provenance.json`` (``OSError``/``ValueError`` if unreadable)."""
        return json.loads((self.path / "provenance.json").read_text())

    def measured(self, name: str, default: Any = None) -> Any:
        """A value the job measured (``wall_time``, ``steps_per_s``, ...): from ``provenance.json["measured"]``,
        else from the result itself (entries committed before :data:`VOLATILE` existed), else ``default``."""
        try:
            measured = self.provenance.get("measured") or {}
        except (OSError, ValueError):
            measured = {}
        if name in measured:
            return measured[name]
        return self.values.get(name, default)

    @property
    def identity(self) -> str:
        """:func:`entry_identity` of this entry."""
        return entry_identity(self.path)


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _files(root: Path) -> list[Path]:
    return sorted(p for p in root.rglob("*") if p.is_file() and p.name != "manifest.json")


def write_manifest(folder: Path, identity: str | None = None) -> dict[str, str]:
    """Write ``folder/manifest.json`` (SHA-256 of every other file) and return the sums; ``identity`` keeps the
    :func:`entry_identity` of an entry whose artefacts were rewritten in another format with the same content."""
    sums = {str(p.relative_to(folder)): _sha256(p) for p in _files(folder)}
    manifest: dict[str, Any] = {"sha256": sums} if identity is None else {"sha256": sums, "identity": identity}
    (folder / "manifest.json").write_text(json.dumps(manifest, indent=1))
    return sums


def check_manifest(path: Path) -> None:
    """Raise (``ValueError``, ``OSError``) unless the files of entry ``path`` match its manifest."""
    manifest = json.loads((path / "manifest.json").read_text())
    files = {str(p.relative_to(path)): _sha256(p) for p in _files(path)}
    if files != manifest["sha256"]:
        bad = sorted(set(files) ^ set(manifest["sha256"]) | {f for f in files if manifest["sha256"].get(f) != files[f]})
        raise ValueError(f"files differ from the manifest: {', '.join(bad[:5])}")


def verify_entry(path: str | Path) -> bool:
    """Do the files of entry ``path`` match its manifest (and is it readable)? Never raises."""
    try:
        read_entry(Path(path))
    except Exception:  # noqa: BLE001 - any failure to read means the entry is unusable
        return False
    return True


def _unshipped(rel: str) -> bool:
    return any(fnmatch.fnmatch(part, pat) for part in Path(rel).parts[1:] for pat in UNSHIPPED)


def entry_identity(path: str | Path) -> str:
    """What a committed entry computed, as a hash: its manifest's sums of ``result.json``, ``arrays.npz`` and
    the shipped artefacts under ``out/`` (not ``config.json``, ``provenance.json`` nor :data:`UNSHIPPED` files).

    Equal for a local entry and its shipped copy (``runs.export``), and for two computations that give the same
    bytes; different when a recomputation gives other weights or results. Read from the manifest (an entry is
    verified when it is loaded). A manifest's ``identity`` wins: the shipped training runs whose policies were
    rewritten from pickles to tensors only (the same weights, bit for bit) keep the identity they were first
    committed with, so the evaluations pinned to them keep their keys.
    """
    manifest = json.loads((Path(path) / "manifest.json").read_text())
    if manifest.get("identity"):
        return str(manifest["identity"])
    sums = manifest["sha256"]
    kept = {
        rel: digest
        for rel, digest in sums.items()
        if rel in ("result.json", "arrays.npz") or (rel.startswith("out/") and not _unshipped(rel))
    }
    return hashlib.sha256(canonical_json(kept).encode()).hexdigest()[:20]


def same_computation(a: str | Path, b: str | Path) -> bool:
    """Whether committed entries ``a`` and ``b`` computed the same thing: the same :func:`entry_identity`, or the
    same files but for the layout of ``arrays.npz`` holding the same arrays bit for bit (a local run and the
    compact copy shipped with an identity of its own, as the shipped layer's exports did before they kept it)."""
    a, b = Path(a), Path(b)
    if entry_identity(a) == entry_identity(b):
        return True

    def kept(entry: Path) -> dict[str, str]:
        sums = json.loads((entry / "manifest.json").read_text())["sha256"]
        return {k: v for k, v in sums.items() if k == "result.json" or (k.startswith("out/") and not _unshipped(k))}

    if kept(a) != kept(b) or (a / "arrays.npz").exists() != (b / "arrays.npz").exists():
        return False
    if not (a / "arrays.npz").exists():
        return True
    return same_arrays(read_arrays(a / "arrays.npz"), read_arrays(b / "arrays.npz"))


def adopt_identity(entry: str | Path, identity: str) -> None:
    """Give committed entry ``entry`` the :func:`entry_identity` ``identity`` (a rewritten manifest, atomically;
    its files verified first): for a local run whose shipped copy, the same computation
    (:func:`same_computation`), was committed with an identity of its own, so that the evaluations pinned to the
    shipped copy load the local one too."""
    entry = Path(entry)
    check_manifest(entry)
    sums = json.loads((entry / "manifest.json").read_text())["sha256"]
    tmp = entry.parent / f".tmp-manifest-{entry.name}-{os.getpid()}"  # beside the entry: never one of its files
    tmp.write_text(json.dumps({"sha256": sums, "identity": identity}, indent=1))
    os.replace(tmp, entry / "manifest.json")


@contextmanager
def naming(path: Path) -> Iterator[None]:
    """An ``OSError`` raised in the block without a file name (``ENOSPC`` from a write, an fsync) is re-raised
    naming ``path``, so its one ``error:`` line says where.

    >>> with naming(Path("/x/runs/.tmp-k")):
    ...     raise OSError(28, "No space left on device")
    Traceback (most recent call last):
    ...
    OSError: [Errno 28] No space left on device: '/x/runs/.tmp-k'
    """
    try:
        yield
    except OSError as err:
        if err.filename is None and err.errno is not None:
            raise OSError(err.errno, err.strerror or str(err), str(path)) from err
        raise


def pid_alive(pid: int) -> bool:
    """Is process ``pid`` running on this machine (or not ours to signal)?"""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    return True


def sweep_tmp(folder: str | Path) -> list[Path]:
    """Remove the temporary folders (``.tmp-<key>-<pid>`` and the like) in ``folder`` left by dead processes.

    A folder whose pid is alive (a commit in progress) is left alone. Returns the removed folders.
    """
    folder = Path(folder)
    removed = []
    try:
        candidates = [p for p in folder.iterdir() if p.name.startswith(".tmp-")]
    except OSError:  # no such folder yet
        return []
    for p in candidates:
        m = _TMP_RE.match(p.name)
        if m is None or not p.is_dir() or pid_alive(int(m.group(1))):
            continue
        shutil.rmtree(p, ignore_errors=True)
        if not p.exists():
            removed.append(p)
    return removed


def save_arrays(path: Path, arrays: Mapping[str, np.ndarray]) -> None:
    """Write ``arrays`` as a deflated ``.npz`` whose bytes depend on the arrays only.

    ``np.savez_compressed`` stamps every member with the current time; this writes a fixed timestamp, so
    equal arrays give byte-identical files. ``np.load`` reads it as usual.
    """
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED, allowZip64=True) as zf:
        for name, value in arrays.items():
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            with zf.open(info, "w", force_zip64=True) as fh:
                np.lib.format.write_array(fh, np.asanyarray(value), allow_pickle=False)


def read_entry(path: Path) -> tuple[dict[str, Any], dict[str, Any]]:
    """Verify entry ``path`` against its manifest and return ``(values, config)``; raises if unusable."""
    check_manifest(path)
    config = json.loads((path / "config.json").read_text())
    values: dict[str, Any] = json.loads((path / "result.json").read_text())
    if (path / "arrays.npz").exists():  # plain .npz or the compact layout (thesis_repro.core.compact), checked on read
        values.update(read_arrays(path / "arrays.npz"))
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
def provenance(start: float, end: float) -> dict[str, Any]:
    """Who/what/when made an entry (:func:`thesis_repro.core.provenance.record`: command line, git commit, package
    versions, host, times, the platform and numerics that decide its float rounding) and the cache version."""
    return {**record(start, end), "cache_version": CACHE_VERSION}


#: The cache whose :meth:`RunCache.run` is computing a job in this thread (:meth:`RunCache.current`).
_ACTIVE: ContextVar[RunCache | None] = ContextVar("thesis_repro_active_cache", default=None)


@contextmanager
def single_threaded() -> Iterator[None]:
    """Run the block with torch on one thread, then restore its count: every kit job computes so, in a pool
    worker or in the calling process alike. A torch op's summation order depends on its thread count, so a job
    computed in a 2-thread process (the generator with ``--jobs 1``) is not bit-identical to the same job in
    a worker, and a chaotic task's rollout return moves by hundreds.

    >>> import torch
    >>> torch.set_num_threads(2)
    >>> with single_threaded():
    ...     torch.get_num_threads()
    1
    >>> torch.get_num_threads()
    2
    """
    try:
        import torch  # local: the cache machinery itself needs no torch (and stays quick to import)
    except ImportError:  # pragma: no cover - the kit's jobs need torch; the cache machinery does not
        yield
        return
    saved = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(saved)


class RunCache:
    """The on-disk cache (``paths.runs_dir()`` unless ``root`` is given) over the shipped read-only layer.

    ``reference=True`` consults ``paths.reference()`` unless ``THESIS_REPRO_RETRAIN=1``; a path consults
    that folder; ``False`` disables the layer.

    Every method taking a job first :meth:`bind`\\ s it (a no-op for kinds that pin nothing).
    """

    def __init__(self, root: str | Path | None = None, reference: str | Path | bool = True):
        self.root = Path(root) if root is not None else paths.runs_dir()
        if reference is True:
            self.reference: Path | None = None if paths.retrain() else paths.reference()
        elif reference is False or reference is None:
            self.reference = None
        else:
            self.reference = Path(reference)
        self._bad_shipped: set[str] = set()
        self._ids: dict[Path, tuple[tuple[int, int], str]] = {}

    @staticmethod
    def current() -> RunCache:
        """The cache computing the job that calls this (so a job function loads its dependencies from the
        same cache that binds them), else a default ``RunCache()``."""
        return _ACTIVE.get() or RunCache()

    @contextmanager
    def computing(self) -> Iterator[None]:
        """Make this cache :meth:`current` while a job function runs."""
        token = _ACTIVE.set(self)
        try:
            yield
        finally:
            _ACTIVE.reset(token)

    # ---------------------------------------------------------------- pinned dependencies
    def _identity(self, path: Path) -> str:
        st = (path / "manifest.json").stat()
        stamp = (st.st_mtime_ns, st.st_size)
        hit = self._ids.get(path)
        if hit is None or hit[0] != stamp:
            hit = (stamp, entry_identity(path))
            self._ids[path] = hit
        return hit[1]

    def _located(self, job: Job) -> Path | None:
        """Where :meth:`load` would read ``job`` from (local, then shipped), without verifying."""
        found = find_entry(self.root, job)
        if found is None and job.key not in self._bad_shipped:
            found = self.shipped(job)
        return found

    def bind(self, job: Job, compute: bool = False) -> Job | None:
        """``job`` with the identity of each of its pinned dependencies' entries in its config.

        For kinds registered with ``pin=True`` (:mod:`thesis_repro.core.job_kinds`; an evaluation pins its training run
        as
        ``config["policy"]``); every other job, and a job already bound, is returned as is. The identity is that
        of the entry :meth:`load` gives (local first, then shipped). A dependency not committed yet gives
        ``None``, unless ``compute``: then it is loaded or computed through this cache first.
        """
        if not job_kinds.pins_dependencies(job.kind):
            return job
        deps = job_kinds.dependencies(job.kind, job.config)
        if all(name in job.config for name in deps):
            return job
        pins: dict[str, str] = {}
        for name, dep in deps.items():
            dep = self.bind(dep, compute)
            if dep is None:
                return None
            if compute:
                path = self.run(dep).path
            else:
                path = self._located(dep)
                if path is None:
                    return None
            pins[name] = self._identity(path)
        return Job(job.kind, {**job.config, **pins})

    def _bound(self, job: Job) -> Job:
        """:meth:`bind` ``job``, or ``job`` itself when a dependency is missing (nothing can be stored for it)."""
        return self.bind(job) or job

    # ---------------------------------------------------------------- where entries are
    def entry(self, job: Job) -> Path:
        """Local folder of ``job``: the committed one if any, else where it will be committed."""
        job = self._bound(job)
        return find_entry(self.root, job) or self.root / job.kind / job.folder

    def shipped(self, job: Job) -> Path | None:
        """Folder of ``job`` in the shipped layer (unverified), or ``None``."""
        return find_entry(self.reference, self._bound(job)) if self.reference is not None else None

    def workdir(self, job: Job) -> Path:
        """Scratch folder kept across interruptions (checkpoints live here until commit)."""
        job = self._bound(job)
        folder = self.root / job.kind
        if folder.is_dir():
            for p in folder.glob(f"*__{job.key}.partial"):
                return p
        return folder / f"{job.folder}.partial"

    def state(self, job: Job, verify: bool = False) -> str:
        """``cached`` / ``shipped`` / ``partial`` (interrupted, resumable) / ``missing``; with ``verify``,
        ``corrupt`` for a committed entry that fails its manifest (the one :meth:`load` would read first).

        Without ``verify`` nothing is read but folder names (and, for pinned kinds, their dependencies' manifests).
        """
        bound = self.bind(job)
        if bound is None:  # a pinned dependency is not committed: neither is this job
            return "missing"
        found = find_entry(self.root, bound)
        if found is not None:
            return "corrupt" if verify and not verify_entry(found) else "cached"
        shipped = self.shipped(bound)
        if shipped is not None:
            bad = bound.key in self._bad_shipped or (verify and not verify_entry(shipped))
            return "corrupt" if bad else "shipped"
        return "partial" if self.workdir(bound).exists() else "missing"

    def sweep(self, kind: str | None = None) -> list[Path]:
        """Remove the temporary folders of dead processes' commits (:func:`sweep_tmp`) under ``root`` (one
        ``kind``'s folder, or all). Returns the removed folders."""
        folders = [self.root / kind] if kind else [p for p in self.root.glob("*") if p.is_dir()]
        return [p for folder in folders for p in sweep_tmp(folder)]

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

    # ---------------------------------------------------------------- load, commit, run
    def load(self, job: Job) -> Result | None:
        """The committed entry for ``job`` (local cache, then shipped layer), or ``None``.

        A corrupt local entry is removed (with a warning); a corrupt shipped entry is reported and skipped.
        """
        job = self.bind(job)
        if job is None:
            return None
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
        measured = dict(values.get("provenance") or {})
        measured.update({k: values[k] for k in VOLATILE if k in values})
        values = {k: v for k, v in values.items() if k != "provenance" and k not in VOLATILE}
        arrays = {k: np.asarray(v) for k, v in values.items() if isinstance(v, np.ndarray)}
        scalars = _jsonable({k: v for k, v in values.items() if k not in arrays}, f"{job.kind} result")
        prov = provenance(start, time.time())
        if measured:
            prov["measured"] = _jsonable(measured, f"{job.kind} measurements")
        final = self.entry(job)
        sweep_tmp(final.parent)
        tmp = final.parent / f".tmp-{job.key}-{os.getpid()}"
        shutil.rmtree(tmp, ignore_errors=True)
        with naming(tmp):  # a full disk names the entry being written, not just "[Errno 28]"
            tmp.mkdir(parents=True)
            if (workdir / "out").exists():
                shutil.copytree(workdir / "out", tmp / "out")
            meta = {"kind": job.kind, "config": job.config, "key": job.key, "label": job.label, "fn": job.fn}
            (tmp / "config.json").write_text(json.dumps(meta, indent=1, sort_keys=True))
            (tmp / "provenance.json").write_text(json.dumps(prov, indent=1))
            (tmp / "result.json").write_text(json.dumps(scalars, indent=1, sort_keys=True))
            if arrays:
                # deflated: a diverging learner's 2M-step run logs ~130k short episodes (3.2 MB raw, 0.8 MB deflated)
                save_arrays(tmp / "arrays.npz", arrays)
            write_manifest(tmp)
            for p in tmp.rglob("*"):
                if p.is_file():
                    with open(p, "rb") as fh:
                        os.fsync(fh.fileno())
            if final.exists():
                shutil.rmtree(final)
            os.replace(tmp, final)
        return final

    def compute(self, job: Job) -> Path:
        """Compute the (bound) ``job`` in its workdir and commit it; the caller holds its lock. Returns the entry.

        The job function runs single-threaded (:func:`single_threaded`), wherever it is called from.
        """
        start = time.time()
        workdir = self.workdir(job)
        (workdir / "out").mkdir(parents=True, exist_ok=True)
        with self.computing(), single_threaded():
            values = job.resolve()(dict(job.config), workdir)
        path = self._commit(job, values, workdir, start)
        shutil.rmtree(workdir, ignore_errors=True)
        return path

    def run(self, job: Job) -> Result:
        """Load ``job`` (local cache, then shipped layer) or compute and commit it to the local cache.

        A pinned dependency (:meth:`bind`) is loaded or computed first.
        """
        bound = self.bind(job, compute=True)
        assert bound is not None  # compute=True commits every dependency
        job = bound
        cached = self.load(job)
        if cached is not None:
            return cached
        with self._lock(job):
            cached = self.load(job)  # another process may have finished it while we waited
            if cached is not None:
                return cached
            path = self.compute(job)
        found = find_entry(self.root, job)
        if found is None:  # pragma: no cover - only if the disk lies to us
            raise RuntimeError(f"cache entry {path} vanished right after commit")
        values, config = read_entry(found)
        return Result(found, values, config, source="computed")


def _square(config: dict[str, Any], workdir: Path) -> dict[str, Any]:
    """Toy job used by doctests and tests."""
    return {"y": config["x"] ** 2}
