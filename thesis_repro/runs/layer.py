"""Where every figure's runs are, and the shipped layer they are copied into.

* :func:`run_rows`: a figure's jobs with their kind, label, key, state (``cached`` in the local cache,
  ``shipped`` in ``data/reference``, ``corrupt`` = either of them failing its manifest, to be recomputed,
  ``partial`` = interrupted and resumable, ``missing``) and path — ``python -m thesis_repro runs 3.3 --scale
  small`` prints them (:func:`thesis_repro.runs.costs.text_table`); :func:`write_run_rows` writes the same rows
  to ``build/<scale>/figures/fig-3.3.runs.json`` after a notebook ran; :func:`summary` is the one line a
  notebook prints.
* :func:`export`: compact copy of a finished training entry into the shipped layer (policy weights,
  obs filter, curves, snapshots, config, provenance; never optimiser state, full SB3 models or replay
  buffers) with a fresh manifest; :func:`entries` lists a layer's entries, :func:`wall_seconds` reads what one
  took to make.

The rest of the shipped layer's code has a module of its own: :mod:`thesis_repro.runs.shipped_checks` (stale and corrupt
entries), :mod:`thesis_repro.runs.retrain_check` (a retrain against the shipped run) and
:mod:`thesis_repro.runs.generator`
(``make reference-runs``, which fills the layer).

>>> from thesis_repro.core.cache import Job
>>> summary([Job("square", {"x": 1}), Job("square", {"x": 2})], RunCache(reference=False))
'2 runs: 0 shipped, 0 cached, 2 to compute'
"""

from __future__ import annotations

import fnmatch
import json
import os
import shutil
import subprocess
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from thesis_repro import figures
from thesis_repro.core import paths
from thesis_repro.core.cache import (
    UNSHIPPED,
    Job,
    Result,
    RunCache,
    entry_identity,
    read_entry,
    sweep_tmp,
    write_manifest,
)
from thesis_repro.core.compact import is_compact, read_arrays, same_arrays, write_compact
from thesis_repro.core.paths import shown

#: States of a job in :func:`run_rows`.
STATES: tuple[str, ...] = ("cached", "shipped", "corrupt", "partial", "missing")
#: Artefacts never shipped (glob patterns on file or folder names): full SB3 models and VecNormalize
#: pickles (optimiser state, env references), replay buffers, resumable checkpoints, optimiser dumps.
#: (The cache's list: these files are not part of an entry's identity either.)
EXCLUDE: tuple[str, ...] = UNSHIPPED
#: Files a shipped entry of a kind must hold to be usable: a training run's policy (``load_policy(result)``),
#: an evaluation's values (rollout returns and lengths live in ``arrays.npz``).
REQUIRED: dict[str, tuple[str, ...]] = {
    "train": ("out/policy.pth", "out/learner.json"),
    "evaluate": ("result.json", "arrays.npz"),
}
#: Size a shipped run should stay under (snapshots included); larger ones are reported.
TARGET_BYTES = 1_000_000


# ---------------------------------------------------------------- findable runs
def corrupt(path: Path) -> str | None:
    """Why entry ``path`` fails its manifest (or cannot be read), ``None`` if it verifies."""
    try:
        read_entry(path)
    except Exception as err:  # noqa: BLE001 - any failure to read means the entry is unusable
        return str(err) or type(err).__name__
    return None


def job_state(job: Job, cache: RunCache, verify: bool = True) -> tuple[str, Path]:
    """State (one of :data:`STATES`) and folder of one job, without computing anything.

    With ``verify`` the entry the cache would read (local, else shipped) is checked against its manifest
    (every file hashed) and is ``corrupt`` if it fails: the cache will not use it but recompute the job.
    """
    state = cache.state(job, verify=verify)
    if state == "cached":
        path = cache.entry(job)
    elif state == "shipped":
        path = cache.shipped(job)
    elif state == "corrupt":
        path = cache.entry(job) if cache.entry(job).is_dir() else cache.shipped(job)
    elif state == "partial":
        path = cache.workdir(job)
    else:
        path = cache.entry(job)
    return state, Path(path)


def job_row(job: Job, cache: RunCache, verify: bool = True) -> dict[str, str]:
    """``kind``, ``label``, ``key``, ``state`` and ``path`` of one job (see :func:`job_state`; no computing). The
    key is the one in the entry's folder name: the job's with its dependencies pinned to the runs it loads (an
    evaluation's key names the training run it evaluates)."""
    state, path = job_state(job, cache, verify)
    bound = cache.bind(job)
    key = (bound if bound is not None else job).key
    return {"kind": job.kind, "label": job.label, "key": key, "state": state, "path": shown(path)}


def rows_summary(rows: Sequence[Mapping[str, str]], listed: int = 5) -> str:
    """How many of ``rows`` (:func:`job_row`) are in each state, one line per job kind, and the labels of the
    first ``listed`` runs still to compute (what ``python -m thesis_repro runs`` prints without ``--verbose``).

    >>> print(rows_summary([{"kind": "train", "label": "a", "state": "shipped"},
    ...                     {"kind": "evaluate", "label": "b", "state": "missing"}]))
    kind      shipped  cached  to compute
    train           1       0           0
    evaluate        0       0           1
    to compute: b
    """
    kinds = list(dict.fromkeys(r["kind"] for r in rows))
    w = max([8, *map(len, kinds)])
    lines = [f"{'kind':<{w}}  {'shipped':>7}  {'cached':>6}  {'to compute':>10}"]
    for kind in kinds:
        states = [r["state"] for r in rows if r["kind"] == kind]
        todo = sum(s not in ("shipped", "cached") for s in states)
        lines.append(f"{kind:<{w}}  {states.count('shipped'):>7,}  {states.count('cached'):>6,}  {todo:>10,}")
    missing = [r["label"] for r in rows if r["state"] not in ("shipped", "cached")]
    if missing:
        more = f" and {len(missing) - listed:,} more" if len(missing) > listed else ""
        lines.append(f"to compute: {', '.join(missing[:listed])}{more}")
    return "\n".join(lines)


def run_rows(figure_id: str, scale: str, cache: RunCache | None = None, verify: bool = True) -> list[dict[str, str]]:
    """One row per job figure ``figure_id`` runs at ``scale`` (training jobs first); ``verify``: see
    :func:`job_state`."""
    cache = cache or RunCache()
    return [job_row(job, cache, verify) for job in figures.jobs(figure_id, scale)]


def summary(jobs: Iterable[Job], cache: RunCache | None = None, verify: bool = False) -> str:
    """One line: how many of ``jobs`` are shipped, cached locally or still to compute.

    ``"35 training runs: 35 shipped, 0 cached, 0 to compute"`` (``runs`` when not all are training jobs;
    interrupted runs that will resume, and with ``verify`` corrupt entries, count as to compute and are named).
    """
    cache = cache or RunCache()
    jobs = list({j.key: j for j in jobs}.values())
    states = [job_state(j, cache, verify)[0] for j in jobs]
    noun = "training runs" if jobs and all(j.kind in figures.TRAINING_KINDS for j in jobs) else "runs"
    n = {s: states.count(s) for s in STATES}
    todo = n["partial"] + n["missing"] + n["corrupt"]
    noun = noun[:-1] if len(jobs) == 1 else noun
    text = f"{len(jobs)} {noun}: {n['shipped']} shipped, {n['cached']} cached, {todo} to compute"
    notes = [f"{n['partial']} interrupted, will resume"] if n["partial"] else []
    notes += [f"{n['corrupt']} corrupt, will be recomputed"] if n["corrupt"] else []
    return text + (f" ({'; '.join(notes)})" if notes else "")


def runs_json(figure_id: str, scale: str) -> Path:
    """``build/<scale>/figures/fig-X.Y.runs.json``."""
    return paths.figures_dir(scale) / f"{figures.get(figure_id).notebook_id}.runs.json"


def write_run_rows(figure_id: str, scale: str, cache: RunCache | None = None) -> Path | None:
    """Write the run rows of ``figure_id`` at ``scale`` to :func:`runs_json`; ``None`` if it is not a registered
    figure (nothing to record)."""
    try:
        figures.get(figure_id)
    except ValueError:
        return None
    cache = cache or RunCache()
    jobs = figures.jobs(figure_id, scale)
    training = [j for j in jobs if j.kind in figures.TRAINING_KINDS]
    doc = {
        "figure": figures.get(figure_id).notebook_id,
        "scale": scale,
        "summary": summary(training, cache) if training else summary(jobs, cache),
        "runs": [job_row(j, cache, verify=False) for j in jobs],  # the notebook has just read (verified) them
    }
    out = runs_json(figure_id, scale)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(f".tmp{os.getpid()}")
    tmp.write_text(json.dumps(doc, indent=1))
    os.replace(tmp, out)
    return out


# ---------------------------------------------------------------- the shipped layer
@dataclass(frozen=True)
class Exported:
    """A run copied into the shipped layer: its folder, size in bytes and the files left out."""

    path: Path
    bytes: int
    dropped: tuple[str, ...] = ()

    @property
    def megabytes(self) -> float:
        return self.bytes / 1e6


def _excluded(name: str) -> bool:
    return any(fnmatch.fnmatch(name, pat) for pat in EXCLUDE)


def _size(folder: Path) -> int:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())


#: Kinds whose shipped ``arrays.npz`` :func:`export` writes compact (:mod:`thesis_repro.core.compact`; ``runs
#: --compact``
#: does the same to runs shipped before).
COMPACT_KINDS = ("train",)


def export(result: Result, layer_root: str | Path | None = None) -> Exported:
    """Compact copy of the finished entry ``result`` into the shipped layer (``paths.reference()`` by default).

    Keeps ``config.json``, ``provenance.json``, ``result.json``, ``arrays.npz`` (in the compact lossless layout for
    :data:`COMPACT_KINDS`) and ``out/`` minus :data:`EXCLUDE`; writes a fresh manifest that keeps the entry's
    :func:`~thesis_repro.core.cache.entry_identity` (the evaluations pinned to it get the same key from either copy);
    replaces an older copy atomically. A training entry without the files evaluation needs (:data:`REQUIRED`) is a
    ``ValueError``.
    """
    layer = Path(layer_root) if layer_root is not None else paths.reference()
    src = Path(result.path)
    kind = json.loads((src / "config.json").read_text())["kind"]
    missing = [f for f in REQUIRED.get(kind, ()) if not (src / f).exists()]
    if missing:
        raise ValueError(f"cannot ship {src}: it lacks {', '.join(missing)} (what a figure loads from it)")
    dest = layer / kind / src.name
    if dest.resolve() == src.resolve():
        return Exported(dest, _size(dest))
    dropped: list[str] = []

    def ignore(folder: str, names: list[str]) -> list[str]:
        out = [n for n in names if _excluded(n)]
        dropped.extend(shown(Path(folder) / n).split(f"{src.name}/", 1)[-1] for n in out)
        return out

    sweep_tmp(dest.parent)  # temporary copies of dead exports
    tmp = dest.parent / f".tmp-export-{src.name}-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    for name in ("config.json", "provenance.json", "result.json"):
        if (src / name).exists():
            shutil.copy2(src / name, tmp / name)
    identity = json.loads((src / "manifest.json").read_text()).get("identity")
    if (src / "arrays.npz").exists():
        if kind in COMPACT_KINDS and not is_compact(src / "arrays.npz"):  # the same arrays, bit for bit, fewer bytes
            write_compact(tmp / "arrays.npz", read_arrays(src / "arrays.npz"))
            identity = entry_identity(src)  # other bytes, the same computation: the local entry's identity
        else:
            shutil.copy2(src / "arrays.npz", tmp / "arrays.npz")
    if (src / "out").is_dir():
        shutil.copytree(src / "out", tmp / "out", ignore=ignore)
    write_manifest(tmp, identity)
    read_entry(tmp)  # the copy verifies before it replaces anything
    if dest.exists():
        shutil.rmtree(dest)
    os.replace(tmp, dest)
    return Exported(dest, _size(dest), tuple(sorted(dropped)))


def compact_entry(entry: str | Path) -> tuple[int, int] | None:
    """Rewrite the ``arrays.npz`` of committed entry ``entry`` in the compact layout (:mod:`thesis_repro.core.compact`:
    the same arrays, bit for bit) and its manifest, keeping the entry's :func:`entry_identity` (the evaluations
    pinned to it keep their keys). Works on a copy that must verify before it replaces the entry. Returns the
    file's bytes ``(before, after)``; ``None`` if there is nothing to do (no arrays, or compact already).
    """
    entry = Path(entry)
    arrays_file = entry / "arrays.npz"
    if not arrays_file.exists() or is_compact(arrays_file):
        return None
    values, _ = read_entry(entry)  # verified against the manifest before anything is rewritten
    arrays = read_arrays(arrays_file)
    identity = entry_identity(entry)
    sweep_tmp(entry.parent)
    tmp = entry.parent / f".tmp-compact-{entry.name}-{os.getpid()}"
    old = entry.parent / f".tmp-old-{entry.name}-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    shutil.copytree(entry, tmp)
    write_compact(tmp / "arrays.npz", arrays)
    write_manifest(tmp, identity)
    back, _ = read_entry(tmp)
    if set(back) != set(values) or not same_arrays(read_arrays(tmp / "arrays.npz"), arrays):
        shutil.rmtree(tmp, ignore_errors=True)
        raise ValueError(f"{entry}: the compact copy does not read back the same arrays")  # pragma: no cover
    before, after = arrays_file.stat().st_size, (tmp / "arrays.npz").stat().st_size
    os.replace(entry, old)
    os.replace(tmp, entry)
    shutil.rmtree(old, ignore_errors=True)
    return before, after


def compact_shipped(layer_root: str | Path | None = None, kind: str = "train") -> dict[Path, tuple[int, int]]:
    """:func:`compact_entry` on every shipped entry of ``kind`` not compact yet (``runs --compact``: runs shipped
    before :func:`export` wrote :data:`COMPACT_KINDS` compact). Returns ``{entry: (bytes before, bytes after)}``
    of the entries rewritten."""
    layer = Path(layer_root) if layer_root is not None else paths.reference()
    done = {}
    for entry in entries(layer):
        if entry.parent.name == kind:
            sizes = compact_entry(entry)
            if sizes is not None:
                done[entry] = sizes
    return done


def entries(root: str | Path) -> list[Path]:
    """Every committed entry folder (``<kind>/<label>__<key>``) under ``root`` (no workdirs, temporary folders
    or locks)."""
    root = Path(root)
    if not root.is_dir():
        return []
    return sorted(
        p
        for p in root.glob("*/*__*")
        if p.is_dir()
        and not p.name.startswith(".")
        and not p.parent.name.startswith(".")
        and not p.name.endswith(".partial")
    )


def shipped_entries(layer_root: str | Path | None = None) -> list[Path]:
    """Every entry folder (``<kind>/<label>__<key>``) of the shipped layer."""
    return entries(layer_root if layer_root is not None else paths.reference())


def local_entries(root: str | Path | None = None) -> list[Path]:
    """Every committed entry folder of the local run cache (``paths.runs_dir()`` unless ``root``)."""
    return entries(root if root is not None else paths.runs_dir())


def wall_seconds(result: Result) -> float:
    """Measured wall time of a finished run, NaN if unknown: a training run's own ``wall_time`` (summed over
    the sessions of a resumed run; :meth:`~thesis_repro.core.cache.Result.measured`), else the ``provenance.json`` of
    the
    process that committed it."""
    try:
        wall = result.measured("wall_time")
        if wall is not None:
            return float(wall)
        return float(result.provenance["wall_seconds"])
    except (OSError, KeyError, ValueError, TypeError, AttributeError):
        return float("nan")


def git_commit(path: Path, message: str, attempts: int = 20) -> str:
    """``git add <path> && git commit -m <message> -- <path>`` in the repository; returns the new commit.

    Retries while another process holds the index lock (several people/agents commit in one tree).
    """
    rel = shown(path)
    for attempt in range(attempts):
        add = subprocess.run(["git", "-C", str(paths.ROOT), "add", "--", rel], capture_output=True, text=True)
        com = None
        if add.returncode == 0:
            com = subprocess.run(
                ["git", "-C", str(paths.ROOT), "commit", "-q", "-m", message, "--", rel], capture_output=True, text=True
            )
            if com.returncode == 0:
                head = subprocess.run(
                    ["git", "-C", str(paths.ROOT), "rev-parse", "--short", "HEAD"], capture_output=True
                )
                return head.stdout.decode().strip()
        err = (com or add).stderr
        if "index.lock" not in err or attempt == attempts - 1:
            raise RuntimeError(f"git commit of {rel} failed: {err.strip()}")
        time.sleep(1 + attempt)
    raise AssertionError("unreachable")  # pragma: no cover
