"""``make verify SCALE=small [N=20] [SEED=...] [TRAIN=1]``: are the shipped numbers real on this machine? One file
on purpose (over 800 lines): it is one command, and each of its parts (which entries, recomputing them in a worker,
comparing the values, the report) serves only that command.

Picks a seeded random sample (seed printed, so a run can be repeated) of ``N`` shipped evaluation entries of a
scale (``data/reference/evaluate/``, keys made by that scale's figures; ``--kind`` picks other shipped kinds of
:data:`VERIFIABLE`, such as chapter 5's ``arm-target``), recomputes each into a temporary run
cache (never ``data/runs``) from the shipped policy it pins, in a worker process with the float numerics the
entry records (:func:`numerics_env`), and compares the values with the shipped ones. It trusts nothing it
checks: a manifest only says the files are the ones it lists, so every value is recomputed.

* **numerics pinned** (:func:`pinned`: the entry's provenance records ``MKL_CBWR``, the default since
  :data:`thesis_repro.PORTABLE_NUMERICS`), or made on this very platform: every value must be bit-identical;
  any difference is a mismatch, reported with its size;
* **native numerics** (``THESIS_REPRO_NUMERICS=native``) **on another CPU, or one not recorded**: individual
  rollouts may differ (see :data:`VERIFY_RTOL`), the averages over the rollouts must agree within
  :data:`VERIFY_RTOL` (for chapter 5's arm kinds, the entry's scalar summaries: see :func:`compare_values`); the
  verdict says so.

Targets instead of a sample: ``--entry KEY`` (one shipped entry, any kind; a training run is retrained),
``--figure 3.3`` (every shipped evaluation behind a figure), ``--claim ID`` (every one behind the claim's pages,
then the pages' saved numbers recomputed from them and compared with the shipped claims snapshot) and ``--all``
(``make verify-all``: every shipped evaluation of the scale, its cost printed first).

It prints a table (entry, shipped value, recomputed value, largest |diff| of any value, verdict; over
:data:`LISTED` entries, only those not bit-identical, with the count of the others, and in a terminal a progress
bar instead of a line per entry) and exits 1 on a mismatch. With ``--train`` it also retrains the cheapest shipped
training run of the scale from scratch (into the temporary cache) and checks it with
:func:`thesis_repro.runs.retrain_check.compare_retrain`, saying whether the shipped run was resumed after an
interruption
and whether that resume was exact.


>>> compare_values({"r": np.array([[1.0, 2.0]])}, {"r": np.array([[1.0, 2.0]])}, same=True).verdict
'identical'
>>> compare_values({"r": np.array([[100.0, 200.0]])}, {"r": np.array([[120.0, 182.0]])}, same=False).verdict
'within 5% (native numerics on another CPU: rollout means differ by 0.7%)'
>>> compare_values({"r": np.array([[100.0, 200.0]])}, {"r": np.array([[100.0, 200.1]])}, same=True).ok
False
"""

from __future__ import annotations

import argparse
import json
import os
import random
import secrets
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np

import thesis_repro
from thesis_repro.core import job_kinds, paths, scales
from thesis_repro.core.cache import Result, RunCache, find_entry, read_entry
from thesis_repro.core.provenance import numerics_env, same_making
from thesis_repro.core.validation import check_choice, one_line
from thesis_repro.runs import costs as plan
from thesis_repro.runs import layer as runs
from thesis_repro.runs import retrain_check, shipped_checks, studies, throughput

#: Shipped kinds whose entries ``verify`` recomputes by default (evaluations: seconds to minutes each, from a
#: shipped policy).
KINDS: tuple[str, ...] = ("evaluate",)
#: Chapter 5's shipped kinds ``verify --kind`` can recompute too: CMA-ES policy searches and their transfers, 3 s to
#: 2.5 min each as their provenance records. Across platforms only their summaries are compared (see
#: :func:`compare_values`).
ARM_KINDS: tuple[str, ...] = ("arm-solve", "arm-source", "arm-competitor-source", "arm-curriculum", "arm-target")
#: Every kind ``verify --kind`` accepts. Training runs are checked by ``--train`` instead (one run, minutes to hours).
VERIFIABLE: tuple[str, ...] = KINDS + ARM_KINDS
#: Tolerance across platforms: |shipped - recomputed| <= VERIFY_RTOL * max(|shipped|, |recomputed|, 1) for every
#: value averaged over the rollouts (each test point's mean return and length, AUC, scalars). MuJoCo and the
#: policy's torch forward pass round differently on another CPU (other MKL/oneDNN/ATen SIMD kernels, other float
#: reduction orders), and a 1,000-step locomotion rollout amplifies those last bits until single rollouts are other
#: samples (a fall or not); means over the rollouts move far less. 5 % is the kit's cross-platform rule for a
#: retrained run's returns too (:data:`thesis_repro.runs.retrain_check.OUTCOME_RTOL`). On the platform that made the
#: entry
#: the rule is bit-identity: the kit claims evaluation is deterministic there.
VERIFY_RTOL = retrain_check.OUTCOME_RTOL
#: Default sample size (``make verify N=...``).
DEFAULT_N = 20
#: Commit and time at which exact resume landed (58d06f8): a training run resumed in a session that started
#: earlier is not bit-identical to an uninterrupted one; one resumed later is.
EXACT_RESUME_COMMIT = "58d06f86adddc45e7c97db6eb2b2491a31e0b4cf"
EXACT_RESUME_TIME = "2026-11-25T08:51:58+00:00"


# ---------------------------------------------------------------- comparing values
@dataclass(frozen=True)
class Check:
    """One compared entry: its name, headline values (shipped, recomputed), largest |diff| and verdict."""

    entry: str
    shipped: float | None
    recomputed: float | None
    diff: float | None
    verdict: str
    ok: bool

    def row(self) -> dict[str, str]:
        def num(v: float | None, fmt: str = ".2f") -> str:
            return "-" if v is None else format(v, fmt)

        return {
            "entry": self.entry,
            "shipped": num(self.shipped),
            "recomputed": num(self.recomputed),
            "|diff|": num(self.diff, ".3g"),
            "verdict": self.verdict,
        }


def _numeric(values: Mapping[str, Any]) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """``values`` split into float arrays (numbers, numeric arrays and lists) and everything else (other arrays,
    such as the phase names of a curriculum, as lists, so that ``==`` compares them).

    >>> _numeric({"cost": 1, "phases": np.array(["reach", "bic"]), "name": "x"})
    ({'cost': array(1.)}, {'phases': ['reach', 'bic'], 'name': 'x'})
    """
    nums, other = {}, {}
    for k, v in values.items():
        arr = np.asarray(v) if not isinstance(v, Mapping | str) and v is not None else None
        if arr is not None and arr.dtype.kind in "biuf":
            nums[k] = arr.astype(np.float64)
        else:
            other[k] = arr.tolist() if isinstance(v, np.ndarray) else v
    return nums, other


def headline_value(values: Mapping[str, Any]) -> float | None:
    """The number a row shows: the mean test return (over every point and rollout) of an evaluation, else the
    first numeric scalar (by name), else ``None``."""
    for name in ("returns", "expected_return"):
        if name in values:
            return float(np.mean(np.asarray(values[name], dtype=np.float64)))
    nums, _ = _numeric(values)
    return next((float(a) for k, a in sorted(nums.items()) if a.ndim == 0), None)


def _relative(x: np.ndarray, y: np.ndarray) -> float:
    """Largest ``|x - y| / max(|x|, |y|, 1)`` (NaN pairs ignored; 0.0 for empty arrays)."""
    r = np.abs(x - y) / np.maximum(np.maximum(np.abs(x), np.abs(y)), 1.0)
    return float(np.nanmax(r)) if r.size and not np.all(np.isnan(r)) else 0.0


def _averaged(arr: np.ndarray) -> np.ndarray:
    """What must agree across platforms: the mean over the last axis (rollouts) of a 2-D or deeper array."""
    return arr.mean(axis=-1) if arr.ndim >= 2 else arr


def compare_values(
    shipped: Mapping[str, Any],
    fresh: Mapping[str, Any],
    same: bool | None,
    rtol: float = VERIFY_RTOL,
    entry: str = "",
    summaries_only: bool = False,
) -> Check:
    """Compare a shipped entry's values with their recomputation (see the module docstring for the rule):
    ``same`` True requires bit-identity (numerics pinned, or the same platform); False / None (native numerics on
    another CPU / on one not recorded) allows ``rtol`` on the rollout means.

    ``summaries_only`` (chapter 5's arm kinds): across platforms judge only the entry's scalars (its mean total
    cost, success rate, ...). A CMA-ES search made on another CPU takes another path once a float rounds
    differently, so its weights and per-generation curves are other samples; its outcome must still agree.

    >>> a = {"cost": 2224.81, "curve": np.array([[11.3, 1.6]])}
    >>> compare_values(a, {"cost": 2223.84, "curve": np.array([[11.3, 1.5]])}, same=False, summaries_only=True).verdict
    'within 5% (native numerics on another CPU: summaries differ by 0.0%)'
    """
    a_num, a_other = _numeric(shipped)
    b_num, b_other = _numeric(fresh)
    a_h, b_h = headline_value(shipped), headline_value(fresh)

    def check(diff: float | None, verdict: str, ok: bool) -> Check:
        return Check(entry, a_h, b_h, diff, verdict, ok)

    if a_num.keys() != b_num.keys() or any(a_num[k].shape != b_num[k].shape for k in a_num):
        diff = sorted(a_num.keys() ^ b_num.keys()) or [k for k in a_num if a_num[k].shape != b_num[k].shape]
        return check(None, f"MISMATCH: different values ({', '.join(diff[:3])})", False)
    if a_other != b_other:
        names = sorted(k for k in a_other.keys() | b_other.keys() if a_other.get(k) != b_other.get(k))
        return check(None, f"MISMATCH: {', '.join(names[:3])} differ", False)
    diffs = [np.abs(a_num[k] - b_num[k]) for k in a_num if a_num[k].size]
    nan_same = all(np.array_equal(np.isnan(a_num[k]), np.isnan(b_num[k])) for k in a_num)
    diff = max((float(np.nanmax(d)) if not np.all(np.isnan(d)) else 0.0 for d in diffs), default=0.0)
    if nan_same and diff == 0.0:
        return check(0.0, "identical", True)
    if same:
        rel = max((_relative(a_num[k], b_num[k]) for k in a_num), default=0.0)
        return check(diff, f"MISMATCH: not bit-identical (max |diff| {diff:.3g}, {rel:.3g} relative)", False)
    where = "native numerics on another CPU" if same is False else "native numerics, platform not recorded"
    rel = 0.0
    for k in a_num:
        if summaries_only and a_num[k].ndim:
            continue
        x, y = (a_num[k], b_num[k]) if summaries_only else (_averaged(a_num[k]), _averaged(b_num[k]))
        if not np.array_equal(np.isnan(x), np.isnan(y)):
            return check(diff, f"MISMATCH: {k} is NaN in one of them ({where})", False)
        scale = np.maximum(np.maximum(np.abs(x), np.abs(y)), 1.0)
        r = np.abs(x - y) / scale
        if r.size and not np.all(np.isnan(r)):
            rel = max(rel, float(np.nanmax(r)))
    what = "summaries" if summaries_only else "rollout means"
    if rel <= rtol:
        return check(diff, f"within {rtol:.0%} ({where}: {what} differ by {rel:.1%})", True)
    return check(diff, f"MISMATCH: {what} differ by {rel:.1%} > {rtol:.0%} ({where})", False)


# ---------------------------------------------------------------- which entries
def shipped_of_scale(scale: str, layer: Path, kinds: Iterable[str] = KINDS) -> tuple[list[Path], list[Path]]:
    """Shipped entries of ``kinds`` in ``layer`` that ``scale``'s figures make (keys bound to the shipped
    policies; the fresh seeds' too, up to :func:`~thesis_repro.runs.needs.target_seeds`) or its studies
    (:mod:`thesis_repro.runs.studies`), and the other shipped entries of those kinds (stale, or of another
    scale)."""
    kinds = tuple(kinds)
    entries = [p for p in runs.shipped_entries(layer) if p.parent.name in kinds]
    if not entries:
        return [], []
    keys = shipped_checks.target_keys(scale, kinds, layer_root=layer) | studies.keys(scale, layer)
    ours = [p for p in entries if p.name.rsplit("__", 1)[1] in keys]
    return ours, [p for p in entries if p not in ours]


def shipped_of_figures(
    scale: str, layer: Path, figure_ids: Iterable[str], kinds: Iterable[str] | None = None
) -> list[Path]:
    """Every shipped entry of ``kinds`` (default :data:`VERIFIABLE`) that the figures ``figure_ids`` make at
    ``scale`` (keys bound to the shipped policies; the fresh seeds' too), in listing order."""
    kinds, figure_ids = tuple(VERIFIABLE if kinds is None else kinds), list(figure_ids)
    if not figure_ids:
        return []
    keys = shipped_checks.target_keys(scale, kinds, figure_ids=figure_ids, layer_root=layer)
    return [p for p in runs.shipped_entries(layer) if p.parent.name in kinds and p.name.rsplit("__", 1)[1] in keys]


def find_shipped(key: str, layer: Path) -> Path:
    """The shipped entry labelled ``key`` (``ppo__Hopper__s0__obs``, its folder name without the key), or whose key
    (or folder name) is ``key`` or starts with it (at least 6 characters); a ``ValueError`` naming what to pass
    when there is none or several."""
    key = str(key).strip().rstrip("/").rsplit("/", 1)[-1]
    entries = runs.shipped_entries(layer)
    named = [p for p in entries if p.name.rsplit("__", 1)[0] == key]
    if len(named) > 1:
        keys = ", ".join(p.name.rsplit("__", 1)[1][:10] for p in named)
        raise ValueError(f"--entry: {key!r} names {len(named)} shipped entries (keys {keys}); pass one key")
    if named:
        return named[0]
    bare = key.rsplit("__", 1)[-1]
    if len(bare) < 6:
        raise ValueError(
            f"--entry: {key!r} is too short; pass an entry's label (ppo__Hopper__s0__obs) or its key (20 hex digits,"
            " or its first 6+)"
        )
    found = [p for p in entries if p.name == key or p.name.rsplit("__", 1)[1].startswith(bare)]
    if not found:
        raise ValueError(
            f"--entry: no shipped entry named {key!r} or with key {bare!r} in {layer}"
            " (`python -m thesis_repro runs` lists them)"
        )
    if len(found) > 1:
        raise ValueError(f"--entry: {bare!r} matches {len(found)} shipped entries; pass more of the key")
    return found[0]


def claim_pages(claim_id: str) -> list[str]:
    """The pages whose saved numbers claim ``claim_id`` reads (``ValueError`` for an unknown claim)."""
    from thesis_repro.claims import registry  # local: the claims package loads scipy; only --claim needs it

    return registry.spec(claim_id).data_pages


def recorded_seconds(paths_: Iterable[Path]) -> float:
    """Wall time the entries took when they were made, as their provenance records it (0 where it does not)."""
    return sum(float(_provenance(p).get("wall_seconds") or 0.0) for p in paths_)


def _duration(seconds: float) -> str:
    """``42 s``, ``17 min``, ``3.2 h``.

    >>> _duration(10.8), _duration(1020), _duration(11520)
    ('11 s', '17 min', '3.2 h')
    """
    if seconds < 120:
        return f"{seconds:.0f} s"
    return f"{seconds / 60:.0f} min" if seconds < 7200 else f"{seconds / 3600:.1f} h"


def recompute_pages(
    pages: Sequence[str], scale: str, layer: Path, root: Path, log: Callable[[str], None], rtol: float = 0.0
) -> dict[str, str]:
    """Execute the notebooks of ``pages`` at ``scale`` into a temporary build (``root/build``), reading the
    recomputed entries of ``root/runs`` first (then the shipped layer), and compare each file they save for the
    ledger with the shipped claims snapshot (:func:`compare_saved`, with ``rtol``): ``{file: "identical" |
    "within ..." | "MISMATCH: ..."}``."""
    from thesis_repro.book import notebooks
    from thesis_repro.claims import snapshot

    env = {**os.environ, "THESIS_REPRO_BUILD": str(root / "build"), "THESIS_REPRO_DATA": str(root / "runs")}
    env["THESIS_REPRO_REFERENCE"] = str(layer)
    out: dict[str, str] = {}
    for page in pages:
        nid = notebooks.check_notebook(page)
        if not [n for n in snapshot.files() if snapshot.page_of(n) == page]:
            log(f"  the page {page} saves no numbers for the ledger: nothing to compare with the snapshot")
            continue
        log(f"  recomputing the page {page} from the recomputed entries (its notebook at {scale}) ...")
        cmd = [sys.executable, "-m", "thesis_repro", "figure", nid, "--scale", scale]
        done = subprocess.run(cmd, env=env, cwd=paths.ROOT, capture_output=True, text=True, check=False)
        names = [n for n in snapshot.files() if snapshot.page_of(n) == page]
        for name in names:
            if done.returncode != 0:
                tail = (done.stderr.strip().splitlines() or ["no output"])[-1]
                out[name] = f"MISMATCH: the page failed to recompute ({tail})"
                continue
            built = json.loads((root / "build" / scale / "figures" / name).read_text())
            try:
                shipped = snapshot.read(name, scale)
            except snapshot.CorruptSnapshot as err:
                out[name] = f"MISMATCH: {one_line(err, 160)}"
                continue
            out[name] = compare_saved(built, shipped, rtol)
    return out


def compare_saved(built: Mapping[str, Any], shipped: Mapping[str, Any] | None, rtol: float = 0.0) -> str:
    """``identical`` when a page's recomputed saved file holds exactly the shipped snapshot's numbers, else a
    ``MISMATCH`` naming the frames (or meta) that differ. ``rtol`` > 0 (a page built on entries made under native
    numerics on another CPU, which match only within :data:`VERIFY_RTOL`): each frame's numbers may differ by
    ``rtol`` of that frame's largest magnitude, with the same layout and the same non-numbers.

    >>> compare_saved({"frames": {"auc": [1.0]}, "kit": "a"}, {"frames": {"auc": [1.0]}, "kit": "b"})
    'identical'
    >>> compare_saved({"frames": {"auc": [1.0]}}, {"frames": {"auc": [1.045]}})
    'MISMATCH: the snapshot differs from the recomputed page in frames auc'
    >>> compare_saved({"frames": {"auc": [1.0, 2.0]}}, {"frames": {"auc": [1.045, 2.0]}}, rtol=0.05)
    'within 5% (its entries were made under native numerics on another CPU: frames differ by up to 2.2% of their scale)'
    >>> compare_saved({"frames": {"auc": [1.0]}}, {"frames": {"auc": [1.2]}}, rtol=0.05)
    'MISMATCH: the snapshot differs from the recomputed page in frames auc (by 16.7% of its scale, over 5%)'
    """
    if shipped is None:
        return "MISMATCH: not in the shipped snapshot"
    from thesis_repro.claims.snapshot import STAMP_KEYS

    a, b = ({k: v for k, v in x.items() if k not in (*STAMP_KEYS, "version")} for x in (built, shipped))
    if a == b:
        return "identical"
    fa, fb = a.get("frames", {}), b.get("frames", {})
    frames = sorted(k for k in fa if fa[k] != fb.get(k))
    where = f"frames {', '.join(frames)}" if frames else "meta or verdicts"
    if (
        rtol <= 0
        or not frames
        or {k: v for k, v in a.items() if k != "frames"} != {k: v for k, v in b.items() if k != "frames"}
    ):
        return f"MISMATCH: the snapshot differs from the recomputed page in {where}"
    worst = {k: _relative_gap(fa[k], fb.get(k)) for k in frames}
    over = {k: g for k, g in worst.items() if g is None or g > rtol}
    if over:
        gaps = ", ".join(
            f"{k}" + ("" if g is None else f" (by {g:.1%} of its scale, over {rtol:.0%})") for k, g in over.items()
        )
        return f"MISMATCH: the snapshot differs from the recomputed page in frames {gaps}"
    return (
        f"within {rtol:.0%} (its entries were made under native numerics on another CPU: frames differ by up to "
        f"{max(worst.values()):.1%} of their scale)"
    )


def _leaves(x: Any) -> tuple[list[float], list[Any]]:
    """A saved frame's numbers and its other leaves (strings, keys, layout), in a fixed order."""
    if isinstance(x, bool) or x is None or isinstance(x, str):
        return [], [x]
    if isinstance(x, (int, float)):
        return [float(x)], [type(x).__name__]
    if isinstance(x, Mapping):
        nums, other = [], [sorted(x)]
        for k in sorted(x):
            n, o = _leaves(x[k])
            nums += n
            other += o
        return nums, other
    if isinstance(x, (list, tuple)):
        nums, other = [], [len(x)]
        for v in x:
            n, o = _leaves(v)
            nums += n
            other += o
        return nums, other
    return [], [repr(x)]


def _relative_gap(a: Any, b: Any) -> float | None:
    """The largest |difference| between two saved frames' numbers over the frame's largest magnitude; ``None``
    when they differ in anything but numbers (layout, labels, NaN places)."""
    (na, oa), (nb, ob) = _leaves(a), _leaves(b)
    if oa != ob or len(na) != len(nb):
        return None
    x, y = np.asarray(na, float), np.asarray(nb, float)
    if not np.array_equal(np.isnan(x), np.isnan(y)):
        return None
    ok = ~np.isnan(x)
    scale = float(np.max(np.abs(np.concatenate([x[ok], y[ok]])), initial=0.0))
    gap = float(np.max(np.abs(x[ok] - y[ok]), initial=0.0))
    return 0.0 if gap == 0 else (gap / scale if scale else None)


def sample(entries: Sequence[Path], n: int, seed: int) -> list[Path]:
    """``n`` of ``entries`` (all if fewer) drawn with ``random.Random(seed)``, in listing order."""
    chosen = random.Random(seed).sample(list(entries), min(n, len(entries)))
    return sorted(chosen)


def _name(path: Path) -> str:
    label, key = path.name.rsplit("__", 1)
    return f"{label}__{key[:8]}"


# ---------------------------------------------------------------- recomputing
#: The worker process of :func:`recompute_all` (run with ``python -c``; ``sys.argv[1]`` is its spec file).
_WORKER = "import sys; from thesis_repro.cli.verify import _worker; _worker(sys.argv[1])"


def _worker(spec_file: str) -> None:
    """Recompute the entries a spec names (``entries``: ``[index, path]``) into ``root``, their dependencies read
    from ``layer``; write ``{path: fresh entry path or "error: ..."}`` to ``out``."""
    import importlib

    import torch

    torch.set_num_threads(1)  # as the pool workers that compute a figure's entries
    spec = json.loads(Path(spec_file).read_text())
    for module in spec["modules"]:  # modules registering the kinds (a test's own kinds)
        importlib.import_module(module)
    cache = RunCache(spec["root"], reference=Path(spec["layer"]))
    out: dict[str, str] = {}
    bar = None
    if sys.stdout.isatty() and spec["total"] > LISTED:  # a long run in a terminal: a bar, not a line per entry
        from tqdm import tqdm

        bar = tqdm(total=len(spec["entries"]), desc="recomputing", unit="entry", file=sys.stdout, leave=False)
    for i, path in spec["entries"]:
        t0 = time.time()
        try:
            # compute, never load: the shipped entry is in the layer
            fresh = cache.compute(shipped_checks.shipped_job(path))
            out[path] = str(fresh)
            said = "recomputed"
        except Exception as err:  # noqa: BLE001 - a recomputation that fails is a failed check, shown in the table
            out[path] = f"error: {one_line(err, 160)}"
            said = out[path]
        line = f"  [{i}/{spec['total']}] {_name(Path(path))}: {said} ({time.time() - t0:.0f} s)"
        if bar is None:
            print(line, flush=True)
        else:
            if said != "recomputed":
                bar.write(line)
            bar.update()
    if bar is not None:
        bar.close()
    Path(spec["out"]).write_text(json.dumps(out))


def _modules(kinds: Iterable[str]) -> list[str]:
    hooks = [job_kinds.KINDS.get(k, "") for k in kinds] + [job_kinds.DEPENDENCIES.get(k, "") for k in kinds]
    return sorted({h.split(":")[0] for h in hooks if h})


def recompute_all(entries: Sequence[Path], layer: Path, root: Path) -> dict[Path, Path | str]:
    """Recompute each shipped entry into a cache at ``root`` (dependencies read from ``layer``; nothing written
    anywhere else), in one worker process per set of numerics (:func:`numerics_env`), entries that share them
    together. Returns ``{entry: fresh entry folder, or "error: ..."}``."""
    root.mkdir(parents=True, exist_ok=True)
    groups: dict[tuple[tuple[str, str], ...], list[tuple[int, Path]]] = {}
    for i, path in enumerate(entries, 1):
        groups.setdefault(tuple(sorted(numerics_env(path).items())), []).append((i, path))
    pinned = set(getattr(thesis_repro, "PORTABLE_NUMERICS", {}))
    out: dict[Path, Path | str] = {}
    for g, (env_items, members) in enumerate(groups.items()):
        spec_file, out_file = root / f".verify-spec-{g}.json", root / f".verify-out-{g}.json"
        spec = {
            "entries": [[i, str(p)] for i, p in members],
            "total": len(entries),
            "root": str(root),
            "layer": str(layer),
            "out": str(out_file),
            "modules": _modules({p.parent.name for _, p in members}),
        }
        spec_file.write_text(json.dumps(spec))
        env = {k: v for k, v in os.environ.items() if not (env_items and k in pinned)}
        env.update(dict(env_items))
        proc = subprocess.run([sys.executable, "-c", _WORKER, str(spec_file)], env=env, cwd=paths.ROOT, check=False)
        done = json.loads(out_file.read_text()) if out_file.exists() else {}
        for _, p in members:
            got = done.get(str(p), f"error: the worker process ended with code {proc.returncode}")
            out[p] = got if got.startswith("error: ") else Path(got)
    return out


def _provenance(path: Path) -> dict[str, Any]:
    try:
        return json.loads((path / "provenance.json").read_text())
    except (OSError, ValueError):
        return {}


def pinned(path: Path) -> bool:
    """Was entry ``path`` made with pinned numerics (:data:`thesis_repro.PORTABLE_NUMERICS`, its provenance's
    ``numerics`` records ``MKL_CBWR``)? Then its recomputation must be bit-identical on any x86-64 CPU."""
    return bool((_provenance(path).get("numerics") or {}).get("MKL_CBWR"))


def check_entry(path: Path, fresh: Path | str) -> Check:
    """Compare shipped entry ``path`` with its recomputation ``fresh`` (or the error that stopped it)."""
    name = _name(path)
    try:
        shipped_values, _ = read_entry(path)
    except Exception as err:  # noqa: BLE001 - any failure to read means the entry is unusable
        return Check(name, None, None, None, f"MISMATCH: shipped entry is corrupt ({one_line(err, 160)})", False)
    if isinstance(fresh, str):
        return Check(
            name, headline_value(shipped_values), None, None, f"MISMATCH: {fresh.removeprefix('error: ')}", False
        )
    fresh_values, _ = read_entry(fresh)
    summaries = path.parent.name in ARM_KINDS
    same = same_making(path, fresh)
    return compare_values(shipped_values, fresh_values, same, entry=name, summaries_only=summaries)


def missing_dependencies(path: Path, layer: Path) -> list[str]:
    """Names of the dependencies (``policy``) of shipped entry ``path`` that ``layer`` does not hold."""
    job = shipped_checks.shipped_job(path)
    return [n for n, dep in job_kinds.dependencies(job.kind, job.config).items() if find_entry(layer, dep) is None]


def resume_note(result: Result) -> str:
    """Whether the shipped training run ``result`` was resumed, and whether that resume was exact."""
    step = int(result.get("resumed_from") or 0)
    if step <= 0:
        return "the shipped run trained without interruption (resumed_from 0)"
    try:
        start = datetime.fromisoformat(result.provenance["start"])
    except (OSError, KeyError, ValueError):
        start = None
    if start is not None and start >= datetime.fromisoformat(EXACT_RESUME_TIME):
        return (
            f"the shipped run was resumed from step {step:,} after exact resume landed ({EXACT_RESUME_COMMIT[:7]}): "
            "it equals an uninterrupted run, so a retrain on the same platform must be bit-identical"
        )
    return (
        f"the shipped run was resumed from step {step:,} before exact resume landed ({EXACT_RESUME_COMMIT[:7]}, "
        f"{EXACT_RESUME_TIME[:10]}): it is NOT the uninterrupted run, so a retrain differs even on the same "
        "platform (regenerate it)"
    )


def retrain_check(scale: str, layer: Path, root: Path, log: Callable[[str], None] = print) -> bool:
    """Retrain the cheapest shipped training run of ``scale`` into a cache at ``root`` and compare it with the
    shipped one (:func:`thesis_repro.runs.retrain_check.compare_retrain`); ``True`` if it passes (or there is none)."""
    from thesis_repro import figures

    keys = shipped_checks.current_keys(scale, figures.TRAINING_KINDS, layer_root=layer)
    job = shipped_checks.cheapest_shipped("train", layer, keys=keys)
    if job is None:
        log(f"--train: no shipped training run at scale {scale}; nothing to retrain")
        return True
    where = find_entry(layer, job)
    values, config = read_entry(where)
    shipped = Result(where, values, config, source="shipped")
    log(f"--train: retraining the cheapest shipped training run, {job.label} ({throughput.cost(job):,.0f} steps) ...")
    t0 = time.time()
    recompute = getattr(runs, "recompute", None)  # in the numerics the shipped run was made in, where recorded
    fresh = recompute(job, root, shipped) if recompute is not None else RunCache(root, reference=False).run(job)
    check = retrain_check.compare_retrain(shipped, fresh)
    log(f"--train: {check.message} ({time.time() - t0:.0f} s)")
    log(f"--train: {resume_note(shipped)}")
    log(f"--train: {'ok' if check.ok else 'MISMATCH'}")
    return check.ok


# ---------------------------------------------------------------- the command
def check_n(n: int) -> int:
    """``-n``: an integer >= 1, else a ``ValueError``."""
    if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 1:
        raise ValueError(f"-n: invalid value {n!r}; valid values are integers >= 1")
    return int(n)


def check_kinds(kinds: Iterable[str]) -> tuple[str, ...]:
    """``--kind``: a non-empty selection of :data:`VERIFIABLE`, else a ``ValueError`` naming the valid kinds.

    >>> check_kinds(["arm-target", "evaluate"])
    ('arm-target', 'evaluate')
    """
    kinds = tuple(kinds)
    bad = [k for k in kinds if k not in VERIFIABLE] or ([] if kinds else [""])
    if bad:
        valid = ", ".join(repr(k) for k in VERIFIABLE)
        raise ValueError(f"--kind: invalid value {bad[0]!r}; valid kinds are: {valid}")
    return kinds


def _check_all(chosen: Sequence[Path], layer: Path, root: Path) -> dict[Path, Check]:
    """Recompute each of ``chosen`` into the cache at ``root`` and compare it with the shipped one."""
    checks: dict[Path, Check] = {}
    for path in chosen:
        try:
            missing = missing_dependencies(path, layer)
        except Exception as err:  # noqa: BLE001 - e.g. a config that no longer hashes to its key
            checks[path] = check_entry(path, f"error: {one_line(err, 160)}")
            continue
        if missing:
            checks[path] = check_entry(path, f"error: its {', '.join(missing)} is not shipped")
    todo = [p for p in chosen if p not in checks]
    for path, fresh in recompute_all(todo, layer, root).items():
        checks[path] = check_entry(path, fresh)
    return {p: checks[p] for p in chosen}


#: Above this many entries (``--figure``, ``--claim``, ``--all``) the table lists only those not bit-identical.
LISTED = 40


def _report(checks: Mapping[Path, Check], log: Callable[[str], None], listed: int = LISTED) -> bool:
    """The table of ``checks`` (only the entries that are not identical when there are more than ``listed``),
    then the count that match; True if all do."""
    rows = list(checks.values())
    shown = rows if len(rows) <= listed else [c for c in rows if c.verdict != "identical"]
    log("")
    if shown:
        log(plan.text_table([c.row() for c in shown], ("entry", "shipped", "recomputed", "|diff|", "verdict")))
    if len(shown) < len(rows):
        if shown:
            log("")
        log(f"{len(rows) - len(shown)} entries bit-identical (not listed)")
    bad = sum(not c.ok for c in rows)
    log(f"\n{len(rows) - bad}/{len(rows)} match" + (f"; {bad} MISMATCH" if bad else ""))
    return not bad


#: The rule, as every run states it.
RULE = (
    "bit-identical wherever the numerics are pinned (the default) or on the platform that made the entry; "
    f"rollout means within {VERIFY_RTOL:.0%} only for entries made under THESIS_REPRO_NUMERICS=native on another CPU"
)


def _retrain_entry(path: Path, root: Path, log: Callable[[str], None]) -> bool:
    """``--entry`` of a training run: retrain it and require the same weights bit for bit (numerics pinned),
    else :func:`thesis_repro.runs.retrain_check.compare_retrain`'s rule."""
    values, config = read_entry(path)
    shipped = Result(path, values, config, source="shipped")
    job = shipped_checks.shipped_job(path)
    cost = shipped_checks.shipped_seconds(path)
    log(
        f"verify --entry: retraining {job.label} ({throughput.cost(job):,.0f} steps"
        + (f", {cost / 60:.0f} min when made)" if cost == cost else ")")
    )
    fresh = retrain_check.recompute(job, root, shipped)
    if pinned(path):
        diff = retrain_check.max_abs_diff(shipped, fresh)
        check = compare_values(values, read_entry(fresh.path)[0], True, entry=_name(path))
        ok = diff == 0.0 and check.ok
        log(f"weights: max |diff| {diff:.3g}; values: {check.verdict}")
    else:
        retrain = retrain_check.compare_retrain(shipped, fresh)
        ok = retrain.ok
        log(retrain.message)
    log("ok" if ok else "MISMATCH")
    return ok


def run_checks(
    scale: str,
    n: int = DEFAULT_N,
    seed: int | None = None,
    train: bool = False,
    layer_root: str | Path | None = None,
    kinds: Iterable[str] | None = None,
    log: Callable[[str], None] = print,
    figure: str | None = None,
    entry: str | None = None,
    claim: str | None = None,
    everything: bool = False,
) -> int:
    """``python -m thesis_repro verify``: the exit code (0 all checks pass, 1 a mismatch). ``figure``, ``entry``,
    ``claim`` and ``everything`` (at most one) recompute every entry behind them instead of a sample."""
    scales.check_scale(scale)
    n = check_n(n)
    targets = [f"--{k}" for k, v in (("figure", figure), ("entry", entry), ("claim", claim), ("all", everything)) if v]
    if len(targets) > 1:
        raise ValueError(
            f"verify: {' and '.join(targets)} exclude each other; pass one of --figure, --entry, --claim, --all"
        )
    layer = Path(layer_root) if layer_root is not None else paths.reference()
    kinds = KINDS if kinds is None else check_kinds(kinds)
    pages: list[str] = []
    chosen: list[Path] | None = None
    if entry:
        chosen = [find_shipped(entry, layer)]
        what = f"entry {_name(chosen[0])}"
    elif figure:
        from thesis_repro import figures

        fid = check_choice(str(figure).removeprefix("fig-"), figures.ids(), "--figure figure")
        chosen, what = shipped_of_figures(scale, layer, [fid]), f"figure {fid}"
    elif claim:
        from thesis_repro import figures

        pages = claim_pages(claim)
        fids = [f for f in (pg.removeprefix("fig-") for pg in pages) if f in figures.ids()]
        chosen, what = shipped_of_figures(scale, layer, fids), f"claim {claim} (pages {', '.join(pages)})"
    elif everything:
        chosen, what = shipped_of_scale(scale, layer, VERIFIABLE)[0], f"every shipped entry at {scale}"
    if chosen is not None and not chosen and not pages:
        raise ValueError(f"verify: nothing shipped behind {what} at scale {scale} in {layer}; nothing to recompute")
    tmp = Path(tempfile.mkdtemp(prefix="thesis-repro-verify-"))
    ok = True
    try:
        if chosen is not None and chosen and chosen[0].parent.name == "train":
            ok = _retrain_entry(chosen[0], tmp / "runs", log)
        elif chosen is not None:
            cost, noun = recorded_seconds(chosen), "entry" if len(chosen) == 1 else "entries"
            log(
                f"verify ({scale}) {what}: {len(chosen)} shipped {noun} to recompute, {_duration(cost)} of compute "
                f"when they were made; recomputed in {tmp}; {RULE}"
            )
            checks = _check_all(chosen, layer, tmp / "runs") if chosen else {}
            if chosen:
                ok = _report(checks, log)
            if pages:
                # a page built on entries that match only within the tolerance can match only within it too
                native = any(c.ok and c.verdict.startswith("within") for c in checks.values())
                saved = recompute_pages(pages, scale, layer, tmp, log, VERIFY_RTOL if native else 0.0)
                for name, verdict in saved.items():
                    log(f"{name}: {verdict}")
                ok = ok and all(not v.startswith("MISMATCH") for v in saved.values())
        else:
            seed = secrets.randbelow(2**31) if seed is None else int(seed)
            ok = _sample_run(scale, n, seed, layer, kinds, tmp, train, log)
        if train:
            ok = retrain_check(scale, layer, tmp / "train", log) and ok
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return 0 if ok else 1


def _sample_run(
    scale: str,
    n: int,
    seed: int,
    layer: Path,
    kinds: tuple[str, ...],
    tmp: Path,
    train: bool,
    log: Callable[[str], None],
) -> bool:
    ours, others = shipped_of_scale(scale, layer, kinds)
    what = "/".join(kinds)
    if not ours:
        log(
            f"no shipped {'evaluations' if kinds == KINDS else what + ' entries'} yet at scale {scale} ({what} "
            f"entries in {layer}: {len(others)} of other scales or stale); nothing to re-evaluate"
        )
        if not train:
            log(f"nothing verified; `make verify SCALE={scale} TRAIN=1` retrains the cheapest shipped training run")
        return True
    chosen = sample(ours, n, seed)
    log(
        f"verify ({scale}): {len(chosen)} of {len(ours)} shipped {what} entries, seed {seed} "
        f"(repeat with --seed {seed}); recomputed in {tmp}; {RULE}"
    )
    if others:
        log(
            f"({len(others)} other shipped {what} entries are not made by the {scale} figures from the shipped "
            "policies: of another scale, or stale (`runs --check`); skipped)"
        )
    return _report(_check_all(chosen, layer, tmp / "runs"), log)


def main(args: argparse.Namespace) -> int:
    """The ``verify`` subcommand (``args``: ``scale``, ``n``, ``seed``, ``train``, ``kind``, ``figure``, ``entry``,
    ``claim``, ``all``)."""
    return run_checks(
        args.scale,
        args.n,
        args.seed,
        args.train,
        kinds=getattr(args, "kind", None),
        figure=getattr(args, "figure", None),
        entry=getattr(args, "entry", None),
        claim=getattr(args, "claim", None),
        everything=bool(getattr(args, "all", False)),
    )
