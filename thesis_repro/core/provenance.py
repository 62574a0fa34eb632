"""Where an entry was made and in which numerics: the provenance record of every cached entry (:func:`record`), the
platform that decides a run's float rounding (:func:`platform_info`), and whether (:func:`same_platform`) and how
(:func:`numerics_env`) a run can be recomputed bit for bit here. The numerics themselves are pinned at
``import thesis_repro`` (:data:`thesis_repro.PORTABLE_NUMERICS`, before torch loads).

>>> sorted(record(0.0, 1.0))[:3]
['claims_design', 'command', 'cwd']
"""

from __future__ import annotations

import json
import os
import platform
import shlex
import subprocess
import sys
import time
from datetime import UTC, datetime
from functools import cache
from importlib import metadata
from pathlib import Path
from typing import Any, Protocol

from thesis_repro import NUMERICS_ENV, PORTABLE_NUMERICS, numerics
from thesis_repro.core import paths


class HasPath(Protocol):
    """A cached entry (:class:`~thesis_repro.core.cache.Result`): anything with the ``path`` of its folder."""

    path: Path


#: Packages whose versions go into every entry's provenance.
PROVENANCE_PACKAGES: tuple[str, ...] = (
    "torch",
    "stable-baselines3",
    "sb3-contrib",
    "gymnasium",
    "mujoco",
    "numpy",
)


@cache
def _versions() -> dict[str, str | None]:
    """The :data:`PROVENANCE_PACKAGES`' versions (read once per process: the code it runs is what it imported)."""
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


#: Seconds a process reuses its reading of the repository's git state: a figure commits dozens of entries within
#: seconds, and ``git status`` stats every tracked file (a third of a second each on a busy machine).
GIT_STATE_SECONDS = 10.0
_git_read: tuple[float, str | None, bool | None] | None = None


def git_state() -> tuple[str | None, bool | None]:
    """``(HEAD commit, whether tracked files differ from it)``, ``(None, None)`` outside a git checkout; read again
    once :data:`GIT_STATE_SECONDS` have passed since this process last read it."""
    global _git_read
    now = time.monotonic()
    if _git_read is None or now - _git_read[0] > GIT_STATE_SECONDS:
        commit = _git("rev-parse", "HEAD")
        status = _git("status", "--porcelain", "--untracked-files=no") if commit else None
        _git_read = (now, commit, None if status is None else bool(status))
    return _git_read[1], _git_read[2]


#: CPU features that select different float kernels (MKL, ATen, NumPy dispatch); part of :func:`platform_info`.
_ISA_FLAGS = ("sse4_2", "avx", "avx2", "fma", "avx512f", "avx512_vnni", "avx512_bf16", "avx512_fp16", "amx_tile")


def platform_info() -> dict[str, Any]:
    """What decides a run's float rounding besides its config and code: CPU, SIMD kernels, BLAS.

    Training is deterministic on one platform, but MKL, PyTorch (ATen) and NumPy pick different SIMD
    kernels on different CPUs, and RL amplifies the last-bit differences; so a run is bit-reproducible
    only where this dict is equal (:func:`thesis_repro.runs.retrain_check.compare_retrain`).

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
        import torch  # local: the cache and the run listing stay importable (and quick) without torch

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


def record(start: float, end: float) -> dict[str, Any]:
    """Who/what/when made an entry: command line, git commit (+ dirty flag), package versions, host, times,
    and the :func:`platform_info` that decides its float rounding."""
    commit, dirty = git_state()
    return {
        "command": shlex.join(sys.argv),
        "cwd": os.getcwd(),
        "git_commit": commit,
        "git_dirty": dirty,
        "packages": dict(_versions()),
        "hostname": platform.node(),
        "platform": platform_info(),
        "numerics": numerics(),
        "start": datetime.fromtimestamp(start, UTC).isoformat(timespec="seconds"),
        "end": datetime.fromtimestamp(end, UTC).isoformat(timespec="seconds"),
        "wall_seconds": round(end - start, 3),
        "claims_design": claims_design(),
    }


def claims_design() -> dict[str, str]:
    """The frozen claims design in force when an entry was made (``version``, ``hash``), read from
    ``data/thesis/claims-design.json`` (written by :mod:`thesis_repro.claims.design`); ``{}`` when none is."""
    try:
        lock = json.loads((paths.THESIS_DATA / "claims-design.json").read_text())
    except (OSError, ValueError):
        return {}
    return {"version": str(lock.get("version", "")), "hash": str(lock.get("hash", ""))}


def same_platform(result_or_path: HasPath | str | Path) -> bool | None:
    """Was this run made on a platform equal to this one (:func:`platform_info`) and in the
    numerics in effect here (:func:`thesis_repro.numerics`)? ``None`` if its provenance does not record a
    platform (runs made before it was recorded)."""
    path = Path(getattr(result_or_path, "path", result_or_path))
    prov = json.loads((path / "provenance.json").read_text())
    recorded = prov.get("platform")
    if recorded is None:
        return None
    return recorded == json.loads(json.dumps(platform_info())) and numerics_env(path) == numerics_env(None)


def same_making(a: HasPath | str | Path, b: HasPath | str | Path) -> bool | None:
    """Were runs ``a`` and ``b`` made so that the kit claims they agree bit for bit: both in the same pinned
    numerics (on any x86-64 CPU), or both in native numerics on equal platforms? ``None`` if they are native and
    either does not record its platform (or has no readable provenance). Unlike :func:`same_platform`, this
    platform plays no part: it compares two stored runs, recomputing neither."""

    def prov(r: HasPath | str | Path) -> dict[str, Any]:
        try:
            return json.loads((Path(getattr(r, "path", r)) / "provenance.json").read_text())
        except (OSError, ValueError):
            return {}

    (pa, na), (pb, nb) = ((p.get("platform"), _numerics_of(p.get("numerics"))) for p in (prov(a), prov(b)))
    if na != nb:
        return False
    if na[NUMERICS_ENV] == "portable":
        return True
    return None if pa is None or pb is None else pa == pb


def numerics_env(result_or_path: HasPath | str | Path | None) -> dict[str, str]:
    """The numerics variables that recompute an entry as it was made: its provenance's ``numerics`` (entries
    made before they were recorded: native, ``THESIS_REPRO_NUMERICS=native``); ``None``: this process's.

    >>> numerics_env(None)["MKL_CBWR"]
    'COMPATIBLE'
    """
    if result_or_path is None:
        rec: dict[str, Any] | None = numerics()
    else:
        path = Path(getattr(result_or_path, "path", result_or_path))
        rec = json.loads((path / "provenance.json").read_text()).get("numerics")
    return _numerics_of(rec)


def _numerics_of(rec: dict[str, Any] | None) -> dict[str, str]:
    """:func:`numerics_env` of a provenance's ``numerics`` record."""
    if not rec or not rec.get("MKL_CBWR"):
        return {NUMERICS_ENV: "native"}
    return {NUMERICS_ENV: "portable", **{k: str(rec[k]) for k in PORTABLE_NUMERICS}}
