"""Running jobs: :func:`run_jobs` loads what the run cache has and computes the rest in a local process pool or
on Ray. The run cache (:mod:`thesis_repro.core.cache`) only stores; the job kinds (:mod:`thesis_repro.core.job_kinds`)
say what
a kind needs (dependencies, resources); this module knows no kind.

The backend is chosen by ``THESIS_REPRO_BACKEND`` (``make figure-3.3 BACKEND=ray`` sets it), so the figure
code, which calls ``run_jobs``, does not change:

* ``local`` (default): a process pool of ``THESIS_REPRO_JOBS`` workers (:func:`default_jobs`), each job run by
  :func:`execute`.
* ``ray``: one Ray task per job (:func:`run_ray`), on the cluster at ``RAY_ADDRESS`` (``ray://host:10001``,
  ``host:6379`` or ``auto``) or, without it, on a new local Ray instance on this machine
  (``THESIS_REPRO_JOBS`` CPUs if set). Ray is the optional extra ``pip install -e '.[ray]'``.

Pinned dependencies. A job whose key pins its dependencies' entries (an evaluation pins its training run:
:meth:`~thesis_repro.core.cache.RunCache.bind`) can be keyed only once they are committed: :func:`run_jobs` first
runs the missing ones (the usual figure calls ``run_jobs`` for training first anyway), then binds.

Ray tasks. Each task asks for the resources of its job kind (:data:`RESOURCES`, registered with the kind: CPUs
and memory; a kind without gets :data:`DEFAULT_RESOURCES`). The task (:func:`compute`) runs the job function in
the job's usual workdir ``<THESIS_REPRO_DATA>/<kind>/<label>__<key>.partial`` (training checkpoints there),
commits the finished entry into a scratch folder and returns it as bytes (:func:`pack`); the *driver*
verifies it against its manifest and commits it to its run cache (:func:`commit`) as soon as it lands, with
the same progress bar as the local pool. Provenance (host, times) is the worker's.

Dependencies. A job's dependencies are what its kind's hook declares (:func:`job_dependencies`: an evaluation's
training job, a transfer job's source job). When the dependency is in the same ``run_jobs`` call, its task's
object ref is passed to the dependent task (Ray runs it after); when it is already in the driver's cache,
the driver ``ray.put``\\ s its packed entry once. Either way the worker materialises the entry into its own run
cache before running the job, so an evaluation never retrains on a node that cannot see the driver's disk.

Fault tolerance. Tasks run with ``max_retries`` (:data:`MAX_RETRIES`, ``THESIS_REPRO_RAY_RETRIES``): a
worker process or node that dies is retried by Ray, and a training job resumes from its newest
checkpoint when ``THESIS_REPRO_DATA`` is the same path on shared storage on every node (otherwise it
restarts from zero on another node). An exception in a job is deterministic and not retried: the
remaining jobs still finish and are committed, then :class:`JobsFailed` is raised with each failed
job's kind, label, key, config and remote traceback.

>>> backend({"THESIS_REPRO_BACKEND": "ray"})
'ray'
>>> backend({"THESIS_REPRO_BACKEND": "slurm"})  # doctest: +ELLIPSIS
Traceback (most recent call last):
...
ValueError: THESIS_REPRO_BACKEND: unknown backend 'slurm'; valid backends are: 'local', 'ray'
"""

from __future__ import annotations

import json
import logging
import multiprocessing as mp
import os
import shutil
import socket
import sys
import tempfile
import time
from collections.abc import Iterable, Iterator, Mapping
from concurrent.futures import Future, ProcessPoolExecutor, as_completed
from contextlib import contextmanager
from pathlib import Path
from types import SimpleNamespace
from typing import Any

from thesis_repro.core import job_kinds
from thesis_repro.core.cache import Job, Result, RunCache, read_entry
from thesis_repro.core.validation import check_choice

#: Valid values of ``THESIS_REPRO_BACKEND``.
BACKENDS: tuple[str, ...] = ("local", "ray")
ENV_VAR = "THESIS_REPRO_BACKEND"
_GIB = 1024**3
#: Ray resources of one task per job kind (``num_cpus``, ``memory`` in bytes), as each kind registered them
#: (:func:`thesis_repro.core.job_kinds.register`; the registry's own dict).
RESOURCES: dict[str, dict[str, float]] = job_kinds.RESOURCES
#: Resources of a kind not in :data:`RESOURCES`.
DEFAULT_RESOURCES: dict[str, float] = {"num_cpus": 1, "memory": 1 * _GIB}
#: Retries of a task whose worker died (Ray's ``max_retries``); ``THESIS_REPRO_RAY_RETRIES`` overrides.
MAX_RETRIES = 3
#: Environment variables the driver hands to every task (paths of the run cache and the shipped layer, ...).
FORWARDED = ("THESIS_REPRO_DATA", "THESIS_REPRO_REFERENCE", "THESIS_REPRO_RETRAIN", "MUJOCO_GL")
#: File a task writes into its job's workdir while it runs: ``{"pid", "host", "start"}`` (who is computing it).
WORKER_FILE = "worker.json"


def backend(environ: Mapping[str, str] | None = None) -> str:
    """The backend named by ``THESIS_REPRO_BACKEND`` (default ``local``); ``ValueError`` naming the choices."""
    env = os.environ if environ is None else environ
    name = (env.get(ENV_VAR) or "local").strip().lower() or "local"
    try:
        return check_choice(name, BACKENDS, "backend")
    except ValueError as err:
        raise ValueError(f"{ENV_VAR}: {err}") from None


def resources(kind: str) -> dict[str, float]:
    """Ray resources of one ``kind`` task (:data:`RESOURCES`).

    >>> resources("train")["num_cpus"]
    1
    """
    return dict(job_kinds.RESOURCES.get(kind, DEFAULT_RESOURCES))


def job_dependencies(job: Job) -> list[Job]:
    """Jobs whose results ``job`` loads through the run cache (its kind's hook,
    :func:`thesis_repro.core.job_kinds.dependencies`).

    >>> [d.kind for d in job_dependencies(Job("evaluate", {"train": {"algorithm": "ppo"}, "test": {}}))]
    ['train']
    """
    return list(job_kinds.dependencies(job.kind, job.config).values())


# ---------------------------------------------------------------- running jobs
def default_jobs() -> int:
    """Worker processes for :func:`run_jobs`: ``THESIS_REPRO_JOBS`` or the number of cores."""
    return int(os.environ.get("THESIS_REPRO_JOBS", os.cpu_count() or 1))


def execute(job: Job, root: str | None = None, reference: str | bool = True) -> Result:
    """Run one job through the cache, single-threaded (what a pool worker calls).

    ``reference`` is the shipped layer to consult (see :class:`~thesis_repro.core.cache.RunCache`).
    """
    import torch  # local: keep the module importable without torch

    torch.set_num_threads(1)
    return RunCache(root, reference=reference).run(job)


def _bind_all(
    jobs: list[Job], cache: RunCache, n_jobs: int | None, progress: bool, desc: str
) -> tuple[list[Job], dict[str, Result]]:
    """``jobs`` bound (:meth:`RunCache.bind`), and the results of their pinned dependencies, which are run first
    (loaded and verified, or computed)."""
    deps = {d.key: d for job in jobs if job_kinds.pins_dependencies(job.kind) for d in job_dependencies(job)}
    done: dict[str, Result] = {}
    if deps:
        ran = run_jobs(list(deps.values()), n_jobs, cache, progress, f"{desc}: dependencies")
        done = dict(zip(deps, ran, strict=True))
    bound = []
    for job in jobs:
        b = cache.bind(job) or cache.bind(job, compute=True)  # compute: only if a dependency vanished meanwhile
        assert b is not None
        bound.append(b)
    return bound, done


def run_jobs(
    jobs: Iterable[Job],
    n_jobs: int | None = None,
    cache: RunCache | None = None,
    progress: bool = True,
    desc: str = "jobs",
) -> list[Result]:
    """Run ``jobs`` (cached ones are loaded, the rest computed in parallel); results in input order.

    The rest run in ``n_jobs`` local worker processes, or as Ray tasks when ``THESIS_REPRO_BACKEND=ray``
    (``n_jobs`` is then Ray's business). Temporary folders of dead processes' commits are removed first.
    """
    cache = cache or RunCache()
    n_jobs = default_jobs() if n_jobs is None else n_jobs
    where = backend()  # THESIS_REPRO_BACKEND: local | ray
    cache.sweep()
    jobs, deps = _bind_all(list(jobs), cache, n_jobs, progress, desc)
    results: dict[str, Result] = {}
    todo: dict[str, Job] = {}
    for job in jobs:
        if job.key in results or job.key in todo:
            continue
        hit = deps.get(job.key) or cache.load(job)
        if hit is not None:
            results[job.key] = hit
        else:
            todo[job.key] = job
    bar = None
    if progress and todo:
        from tqdm import tqdm  # local: only a progress bar needs it (the cache stays light to import)

        shipped = sum(r.source == "shipped" for r in results.values())
        bar = tqdm(total=len(todo), desc=f"{desc} ({len(results) - shipped} cached, {shipped} shipped)")
    t0 = time.time()
    if where == "ray" and todo:
        results.update(run_ray(todo, cache, bar))
    elif n_jobs <= 1 or len(todo) <= 1:
        for key, job in todo.items():
            results[key] = cache.run(job)
            if bar:
                bar.update()
    else:
        with LocalPool(min(n_jobs, len(todo)), cache) as pool:
            try:  # Ctrl-C or SIGTERM: end the workers now (their runs resume from their checkpoints), one line
                futures = {pool.submit(job): key for key, job in todo.items()}
                for fut in as_completed(futures):
                    results[futures[fut]] = fut.result()
                    if bar:
                        bar.update()
            except BaseException:
                pool.stop()
                raise
    if bar:
        bar.set_postfix_str(f"{time.time() - t0:.0f}s")
        bar.close()
    return [results[job.key] for job in jobs]


# ---------------------------------------------------------------- worker processes
def die_with_parent() -> None:  # pragma: no cover - runs in the pool's worker processes
    """Worker initializer of every process pool of the kit: on Linux, end this worker when the process that
    spawned it dies (a killed figure or generator must not leave orphan workers training on, holding their job
    locks); ignore Ctrl-C, which the parent handles by ending its workers (:func:`stop_pool`) instead of each
    printing a traceback."""
    import ctypes
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})  # blocked by the spawning parent (interrupts_held)
    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass
    import multiprocessing as mp

    parent = mp.parent_process()
    if parent is not None and os.getppid() != parent.pid:  # the parent died before prctl took effect
        os._exit(143)


@contextmanager
def interrupts_held() -> Iterator[None]:
    """Hold the interrupts for the block, so that a worker is never cut between being started and being handed its
    job (it would print a traceback, "EOFError: Ran out of input"); one that arrives meanwhile is held, not lost: it
    is raised when the block ends.

    SIGINT is blocked in this thread: processes spawned in it start with it blocked (their
    :func:`die_with_parent` ignores and then unblocks it, dropping a pending one). Another thread (a process pool's
    manager thread) may take a signal instead, so in the main thread the block also swaps the Python handlers of
    SIGINT and of SIGTERM / SIGHUP (where the command line raises on them) for one that notes the signal."""
    import signal
    import threading

    noted: list[int] = []
    handlers: dict[int, Any] = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
            if callable(signal.getsignal(sig)):  # a Python handler (SIG_DFL / SIG_IGN act in C, at once)
                handlers[sig] = signal.signal(sig, lambda signum, _frame: noted.append(signum))
    old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        for sig, handler in handlers.items():
            signal.signal(sig, handler)
        signal.pthread_sigmask(signal.SIG_SETMASK, old)  # a Ctrl-C held pending above lands now (unless blocked before)
        if noted:
            signal.raise_signal(noted[0])  # the one another thread took meanwhile, to its own handler now


def stop_pool(ex: ProcessPoolExecutor) -> None:
    """End a process pool's workers now and drop its queued jobs (leaving the ``with`` block would otherwise
    wait for every running and queued job to finish)."""
    workers = list((getattr(ex, "_processes", None) or {}).values())  # shutdown() forgets them
    ex.shutdown(wait=False, cancel_futures=True)
    for proc in workers:
        proc.terminate()


# ---------------------------------------------------------------- packed entries
def pack(folder: Path) -> dict[str, Any]:
    """A committed entry ``<root>/<kind>/<label>__<key>`` as plain data.

    Returns ``{"kind", "folder", "files": {relative path: bytes}}`` (manifest included), for :func:`unpack`.
    """
    folder = Path(folder)
    files = {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}
    return {"kind": folder.parent.name, "folder": folder.name, "files": files}


def _has(root: Path, packed: Mapping[str, Any]) -> Path | None:
    key = packed["folder"].rsplit("__", 1)[-1]
    kind_dir = Path(root) / packed["kind"]
    return next((p for p in sorted(kind_dir.glob(f"*__{key}")) if p.is_dir()), None) if kind_dir.is_dir() else None


def unpack(root: str | Path, packed: Mapping[str, Any]) -> Path:
    """Commit a :func:`pack`\\ ed entry under ``root`` atomically (verified against its manifest first); returns
    its folder. An entry already there (same key) is kept as is."""
    found = _has(Path(root), packed)
    if found is not None:
        return found
    kind_dir = Path(root) / packed["kind"]
    key = packed["folder"].rsplit("__", 1)[-1]
    tmp = kind_dir / f".tmp-{key}-{os.getpid()}-unpack"
    shutil.rmtree(tmp, ignore_errors=True)
    for rel, data in packed["files"].items():
        path = tmp / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data)
    try:
        read_entry(tmp)  # raises if the bytes do not match the manifest
    except Exception:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    final = kind_dir / packed["folder"]
    if final.exists():
        shutil.rmtree(final)
    os.replace(tmp, final)
    return final


def commit(cache: RunCache, job: Job, packed: Mapping[str, Any]) -> Result:
    """Driver side: commit the packed result of ``job`` to ``cache`` (under its lock) and return it as computed."""
    with cache._lock(job):
        path = _has(cache.root, packed) or unpack(cache.root, packed)
    shutil.rmtree(cache.workdir(job), ignore_errors=True)
    values, config = read_entry(path)
    return Result(path, values, config, source="computed")


# ---------------------------------------------------------------- the task
@contextmanager
def _environ(env: Mapping[str, str | None]) -> Iterator[None]:
    old = {k: os.environ.get(k) for k in env}
    try:
        for k, v in env.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
        yield
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def compute(
    job: Job,
    root: str,
    reference: str | bool,
    env: Mapping[str, str | None],
    threads: int,
    command: list[str],
    *deps: Mapping[str, Any],
) -> dict[str, Any]:
    """Body of one Ray task (plain Python, also callable without Ray): compute ``job`` and return it packed.

    ``deps`` are packed entries of the jobs it loads through the cache; each is committed into the worker's
    run cache ``root`` unless already there. The job runs in its usual workdir under ``root`` (resuming from
    a checkpoint left by an earlier, killed attempt), is committed into a scratch folder and packed; the
    workdir is removed once packed. The entry's provenance names the driver's ``command`` and this worker's host.
    """
    import torch  # local: keep the module importable without torch

    torch.set_num_threads(max(1, int(threads)))
    fn = job.resolve()  # imports the job's module first: it may register a user-defined kind (and its label)
    if job.kind not in job_kinds.KINDS:
        job_kinds.register(job.kind, job.target)
    with _environ(env):
        cache = RunCache(root, reference=reference)
        for dep in deps:  # shipped or already local (shared storage): nothing to do
            if _has(cache.root, dep) is None and (cache.reference is None or _has(cache.reference, dep) is None):
                with cache._lock(SimpleNamespace(kind=dep["kind"], key=dep["folder"].rsplit("__", 1)[-1])):
                    unpack(cache.root, dep)
        bound = cache.bind(job, compute=True)  # the driver binds already; a direct call may not have
        assert bound is not None
        job = bound
        with cache._lock(job):  # as RunCache.run: a second computation of the same job waits, then reuses
            hit = cache.load(job)
            if hit is not None and hit.source == "cached":  # committed meanwhile (shared storage)
                return pack(hit.path)
            start = time.time()
            workdir = cache.workdir(job)
            (workdir / "out").mkdir(parents=True, exist_ok=True)
            note = {"pid": os.getpid(), "host": socket.gethostname(), "start": start}
            (workdir / WORKER_FILE).write_text(json.dumps(note))
            with cache.computing():
                values = fn(dict(job.config), workdir)
            scratch = Path(tempfile.mkdtemp(prefix="thesis-repro-ray-"))
            argv, sys.argv = sys.argv, list(command)  # provenance records the command that asked for the job
            try:
                packed = pack(RunCache(scratch, reference=False)._commit(job, values, workdir, start))
            finally:
                sys.argv = argv
                shutil.rmtree(scratch, ignore_errors=True)
            shutil.rmtree(workdir, ignore_errors=True)
        return packed


# ---------------------------------------------------------------- the driver
class JobsFailed(RuntimeError):
    """Jobs that raised on Ray (deterministic failures); the other jobs of the call were committed."""

    def __init__(self, failures: list[tuple[Job, BaseException]], root: Path):
        self.failures = failures
        parts = [f"{len(failures)} job(s) failed on Ray; every finished run was committed to {root}"]
        for job, err in failures:
            parts.append(
                f"--- {job.kind} {job.label} (key {job.key})\nconfig: {json.dumps(job.config, sort_keys=True)}\n"
                f"{type(err).__name__}: {err}"
            )
        super().__init__("\n".join(parts))


def retries() -> int:
    """Ray ``max_retries`` of every task: ``THESIS_REPRO_RAY_RETRIES`` or :data:`MAX_RETRIES`."""
    return int(os.environ.get("THESIS_REPRO_RAY_RETRIES", MAX_RETRIES))


def init_ray() -> Any:
    """Import and connect Ray once: ``RAY_ADDRESS`` if set, else a new local instance (``THESIS_REPRO_JOBS`` CPUs)."""
    try:
        import ray  # local: Ray is an optional extra (`pip install -e .[ray]`)
    except ImportError as err:
        raise RuntimeError(
            f"{ENV_VAR}=ray needs Ray: `pip install -e '.[ray]'` (`make figure-X.Y BACKEND=ray` installs it)"
        ) from err
    if not ray.is_initialized():
        address = os.environ.get("RAY_ADDRESS") or None
        kw: dict[str, Any] = {"log_to_driver": False, "logging_level": logging.WARNING}
        if address is None:
            jobs = os.environ.get("THESIS_REPRO_JOBS")
            kw.update(address="local", include_dashboard=False, num_cpus=int(jobs) if jobs else None)
        else:
            kw["address"] = address
        ray.init(**kw)
    return ray


def _env(cache: RunCache) -> dict[str, str | None]:
    env: dict[str, str | None] = {k: os.environ.get(k) for k in FORWARDED}
    env["THESIS_REPRO_DATA"] = str(cache.root.resolve())
    if cache.reference is None:
        env["THESIS_REPRO_RETRAIN"] = "1"
    else:
        env["THESIS_REPRO_REFERENCE"] = str(Path(cache.reference).resolve())
        env["THESIS_REPRO_RETRAIN"] = None
    return env


def _task_options(job: Job) -> tuple[dict[str, Any], int]:
    """Ray options of ``job``'s task (its kind's resources, retries, a name) and the torch threads it runs with."""
    res = resources(job.kind)
    opts = {**res, "max_retries": retries(), "retry_exceptions": False, "name": f"{job.kind}:{job.label}"}
    return opts, int(res.get("num_cpus", 1))


def _reference(cache: RunCache) -> str | bool:
    return str(Path(cache.reference).resolve()) if cache.reference is not None else False


def run_ray(todo: Mapping[str, Job], cache: RunCache, bar: Any = None) -> dict[str, Result]:
    """Compute ``todo`` (key -> job, none of them cached) as Ray tasks; commit each result as it lands.

    Returns key -> :class:`Result` (``source="computed"``); raises :class:`JobsFailed` after every other job
    finished if any job raised.
    """
    ray = init_ray()
    remote = ray.remote(compute)
    root, reference, env = str(cache.root.resolve()), _reference(cache), _env(cache)
    refs: dict[str, Any] = {}
    put: dict[str, Any] = {}  # dependency key -> ref of its packed committed entry

    def dep_ref(dep: Job) -> Any:
        if dep.key in refs:
            return refs[dep.key]
        if dep.key not in put:
            hit = cache.load(dep)
            put[dep.key] = None if hit is None else ray.put(pack(hit.path))
        return put[dep.key]

    # jobs another job of this call depends on go first, so their refs exist when the dependents are submitted
    needed = {d.key for job in todo.values() for d in job_dependencies(job)}
    for key, job in sorted(todo.items(), key=lambda kv: kv[0] not in needed):
        deps = [r for r in (dep_ref(d) for d in job_dependencies(job)) if r is not None]
        opts, threads = _task_options(job)
        refs[key] = remote.options(**opts).remote(job, root, reference, env, threads, list(sys.argv), *deps)
    pending = {ref: key for key, ref in refs.items()}
    results: dict[str, Result] = {}
    failures: list[tuple[Job, BaseException]] = []
    while pending:
        done, _ = ray.wait(list(pending), num_returns=1)
        for ref in done:
            key = pending.pop(ref)
            try:
                packed = ray.get(ref)
            except Exception as err:  # noqa: BLE001 - reported with the job's config once the rest finished
                failures.append((todo[key], err))
                continue
            results[key] = commit(cache, todo[key], packed)
            if bar is not None:
                bar.update()
    if failures:
        raise JobsFailed(failures, cache.root)
    return results


# ---------------------------------------------------------------- pools for a caller's own queue
class LocalPool:
    """``n_jobs`` local worker processes (:func:`execute`) for a caller that keeps its own queue and hands them one
    job at a time (the reference-run generator): :meth:`submit` returns a future of the job's :class:`Result`,
    :meth:`stop` ends the workers now (their runs resume from their checkpoints)."""

    def __init__(self, n_jobs: int, cache: RunCache):
        ctx = mp.get_context("spawn")
        self.ex = ProcessPoolExecutor(max_workers=n_jobs, mp_context=ctx, initializer=die_with_parent)
        self.root, self.reference = str(cache.root), str(cache.reference) if cache.reference is not None else False

    def submit(self, job: Job) -> Future:
        with interrupts_held():  # the workers start (and stay) deaf to Ctrl-C: the caller ends them
            return self.ex.submit(execute, job, self.root, self.reference)

    def stop(self) -> None:
        stop_pool(self.ex)

    def __enter__(self) -> LocalPool:
        return self

    def __exit__(self, *exc: object) -> None:
        self.ex.shutdown(wait=True)


class RayPool:
    """:class:`LocalPool`'s interface on Ray (``THESIS_REPRO_BACKEND=ray``): each job one task (:func:`compute`,
    resuming from its workdir's checkpoint on shared storage), its packed entry committed to ``cache`` by this
    process as it lands (:func:`commit`); the jobs it loads are sent from ``cache``, packed. The future says
    ``running()`` from the start: Ray, not this process, queues a task until a node has its resources."""

    def __init__(self, cache: RunCache):
        self.ray = init_ray()
        self.remote = self.ray.remote(compute)
        self.cache = cache
        self.args = (str(cache.root.resolve()), _reference(cache), _env(cache))
        self.refs: list[Any] = []

    def submit(self, job: Job) -> Future:
        deps = [self.ray.put(pack(hit.path)) for d in job_dependencies(job) if (hit := self.cache.load(d)) is not None]
        opts, threads = _task_options(job)
        ref = self.remote.options(**opts).remote(job, *self.args, threads, list(sys.argv), *deps)
        self.refs.append(ref)
        out: Future = Future()
        out.set_running_or_notify_cancel()

        def landed(task: Future) -> None:  # in Ray's thread: commit here, then hand the caller its Result
            try:
                out.set_result(commit(self.cache, job, task.result()))
            except BaseException as err:  # noqa: BLE001 - the caller's result() raises it
                out.set_exception(err)

        ref.future().add_done_callback(landed)
        return out

    def stop(self) -> None:
        for ref in self.refs:
            self.ray.cancel(ref, force=True)

    def __enter__(self) -> RayPool:
        return self

    def __exit__(self, *exc: object) -> None:
        pass


def job_pool(n_jobs: int, cache: RunCache) -> LocalPool | RayPool:
    """The pool of the backend ``THESIS_REPRO_BACKEND`` names (:func:`backend`): :class:`RayPool` or
    :class:`LocalPool` of ``n_jobs`` workers."""
    return RayPool(cache) if backend() == "ray" else LocalPool(n_jobs, cache)
