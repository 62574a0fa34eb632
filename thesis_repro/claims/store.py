"""Page storage: the per-seed numbers each page saves for its claims, read back from the build or the snapshot.

A notebook's :func:`save_page` writes ``build/<scale>/figures/<page>.data.json``; :func:`saved_blob` reads the
build's copy, or the shipped claims snapshot's (:mod:`thesis_repro.claims.snapshot`) when the build has none or
only a stale one; :func:`page_data` gathers the frames one claim's measure reads. Inside :func:`one_pass` each page
is read once (:func:`in_pass`).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Hashable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import pandas as pd

from thesis_repro.claims import snapshot
from thesis_repro.claims.confirmatory import fresh_frames
from thesis_repro.claims.registry import Spec, data_name
from thesis_repro.core import paths, stamps


def data_path(page: str, scale: str) -> Path:
    """``build/<scale>/figures/<page>.data.json``: the per-seed numbers a notebook saved for its claims."""
    return paths.figures_dir(scale) / data_name(page)


def save_page(page: str, scale: str, frames: Mapping[str, pd.DataFrame], meta: Mapping[str, Any]) -> Path:
    """Write a page's per-seed frames (records) and meta (scale, seeds, budget note) atomically, stamped
    with :func:`~thesis_repro.core.stamps.code_stamp` over the kit modules this process imported."""
    out = data_path(page, scale)
    out.parent.mkdir(parents=True, exist_ok=True)
    blob = {
        "page": page,
        "scale": scale,
        **stamps.page_stamp(page),
        "meta": dict(meta),
        "frames": {k: json.loads(v.to_json(orient="records")) for k, v in frames.items()},
    }
    tmp = out.with_suffix(".tmp")
    tmp.write_text(json.dumps(blob, default=_jsonable))
    tmp.replace(out)
    return out


def _jsonable(x: Any) -> Any:
    if isinstance(x, (np.integer, np.floating)):
        return x.item()
    if isinstance(x, (set, tuple)):
        return list(x)
    return str(x)


def saved_blob(page: str, name: str, scale: str) -> dict[str, Any] | None:
    """The file ``name`` (``<page>.data.json`` or ``<page>.verdicts.json``) as ``page`` saved it at ``scale``, or
    None: the build's copy (inside a notebook, also a finished page's: :func:`~thesis_repro.core.paths.page_output`)
    unless it is missing or stale and the shipped snapshot (:mod:`~thesis_repro.claims.snapshot`) has one that is
    not. ``blob["stale"]``: written by other kit code (:func:`~thesis_repro.core.stamps.code_stamp`);
    ``blob["shipped"]``: read from the snapshot; ``blob["version"]``: changes whenever the numbers may have.
    A corrupt shipped file with no build copy raises :class:`~thesis_repro.claims.snapshot.CorruptSnapshot`."""
    p = paths.page_output(scale, name)
    built = json.loads(p.read_text()) if p.exists() else None
    if built is not None:
        built["version"] = f"{p}@{p.stat().st_mtime_ns}"
    if built is not None and not stamps.is_stale(page, built):
        return {**built, "stale": False, "shipped": False}
    try:
        shipped = snapshot.read(name, scale)
    except snapshot.CorruptSnapshot:
        if built is None:
            raise
        shipped = None
    if shipped is not None and (built is None or not stamps.is_stale(page, shipped)):
        return {**shipped, "stale": stamps.is_stale(page, shipped), "shipped": True}
    return None if built is None else {**built, "stale": True, "shipped": False}


def load_page(page: str, scale: str) -> dict[str, Any] | None:
    """The saved blob of ``page`` (:func:`saved_blob`, frames as DataFrames) or None; read once per
    :func:`~thesis_repro.claims.ledger.ledger` pass (:func:`one_pass`)."""

    def read() -> dict[str, Any] | None:
        blob = saved_blob(page, data_path(page, scale).name, scale)
        if blob is not None:
            blob["frames"] = {k: pd.DataFrame(v) for k, v in blob["frames"].items()}
        return blob

    return in_pass((page, scale), read)


def page_data(
    s: Spec, scale: str, seeds: Sequence[int] | None = None
) -> tuple[dict[str, pd.DataFrame], dict[str, Any]] | None:
    """The frames a claim's measure reads (``name`` for its own page, ``name@page`` for others) and meta
    (``meta["stale_pages"]``: those of its pages written by other kit code); with ``seeds``, only those training
    seeds' rows (None when the pages do not hold them all: :func:`~thesis_repro.claims.confirmatory.fresh_frames`)."""
    frames: dict[str, pd.DataFrame] = {}
    meta: dict[str, Any] = {}
    found, stale, shipped, versions, local = False, [], [], [], {}
    for p in s.data_pages:
        blob = load_page(p, scale)
        if blob is None:
            continue
        found = True
        versions.append(blob["version"])
        meta = meta or blob["meta"]
        stale += [p] if blob["stale"] else []
        shipped += [p] if blob["shipped"] else []
        if blob["meta"].get("local_runs"):
            local[p] = blob["meta"]["local_runs"]
        for k, v in blob["frames"].items():
            frames[f"{k}@{p}"] = v
            if p == s.page or len(s.data_pages) == 1:
                frames[k] = v
    extra = {"stale_pages": stale, "shipped_pages": shipped, "versions": versions, "local_runs": local}
    if found and seeds is not None:
        picked = fresh_frames(frames, seeds)
        if picked is None:
            return None
        frames = picked
    return (frames, {**meta, **extra}) if found else None


#: Within one :func:`~thesis_repro.claims.ledger.ledger` pass: the pages read and the measures run so far (pages do
#: not change inside a pass).
_PASS: dict[Any, Any] | None = None


@contextmanager
def one_pass() -> Iterator[None]:
    """Read each page and run each claim's measure once while judging every claim (Holm's families re-read the
    same pages); outside a pass every call reads afresh, as a notebook that just saved its numbers needs."""
    global _PASS
    outer, _PASS = _PASS, _PASS if _PASS is not None else {}
    try:
        yield
    finally:
        _PASS = outer


T = TypeVar("T")


def in_pass(key: Hashable, compute: Callable[[], T]) -> T:
    """``compute()``, memoised under ``key`` while a :func:`one_pass` is open (computed afresh outside one).

    >>> calls = []
    >>> with one_pass():
    ...     [in_pass("k", lambda: calls.append(1) or len(calls)) for _ in range(2)]
    [1, 1]
    >>> in_pass("k", lambda: calls.append(1) or len(calls))
    2
    """
    if _PASS is not None and key in _PASS:
        return _PASS[key]
    got = compute()
    if _PASS is not None:
        _PASS[key] = got
    return got


def read_json(p: Path) -> dict[str, Any]:
    """The JSON object in ``p``; ``{}`` when it is missing or unreadable (a cache starts empty)."""
    try:
        return json.loads(p.read_text())
    except (OSError, ValueError):
        return {}


def make_target(page: str) -> str:
    """The Makefile target of a page: ``table-3.4`` -> ``table-3.4``, ``fig-3.3`` -> ``figure-3.3``."""
    return page if page.startswith("table-") else f"figure-{page.removeprefix('fig-')}"
