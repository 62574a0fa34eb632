"""The shipped claims snapshot: the numbers each ledger page saved at a scale, so ``claims`` answers in a
fresh clone before its book.

The ledger judges the per-seed numbers a page saves when its notebook runs (``build/<scale>/figures/``:
``<page>.data.json``, and ``<page>.rule.json`` for a page-verdict claim). A fresh clone has none until
``make book`` ran (about ten minutes at ``small``), so :func:`ship` (``make ship-claims SCALE=small``, after
the book) copies the files the ledger reads into ``data/reference/claims/<scale>/`` (under
:func:`~thesis_repro.core.paths.reference`):

* ``<file>.gz``: the saved file without its code stamp, gzip-compressed deterministically, so a refresh
  whose numbers did not change rewrites no data file;
* ``index.json``: per file its SHA-256 (a corrupt file is detected and never judged), its code stamp
  (``kit``, ``kit_modules``: numbers shipped by other kit code are reported stale, as the book's are) and,
  once, the :func:`~thesis_repro.core.cache.provenance` of the shipping (command, git commit, host, platform).

The ledger reads a page's own build file first and falls back to the snapshot when the build has none or only
a stale one (:func:`thesis_repro.claims.store.saved_blob`); ``THESIS_REPRO_RETRAIN=1`` ignores the snapshot,
as it ignores the shipped runs. Nothing here is typed in: every shipped number was saved by a page.

>>> "fig-3.3.data.json" in files() and "analysis-4-kl.rule.json" in files()
True
"""

from __future__ import annotations

import gzip
import hashlib
import json
import time
from pathlib import Path
from typing import Any

from thesis_repro.claims import registry, report
from thesis_repro.core import paths, stamps

#: The code-stamp keys of a saved file, kept in the index (not in the data file) so that a refresh after a code
#: change whose numbers did not change leaves the data file byte-identical.
STAMP_KEYS = ("kit", "kit_modules")
INDEX = "index.json"


class CorruptSnapshot(ValueError):
    """A shipped file does not match the SHA-256 its index records (or cannot be read)."""


def folder(scale: str) -> Path:
    """``data/reference/claims/<scale>`` (under :func:`~thesis_repro.core.paths.reference`)."""
    return paths.reference() / "claims" / scale


def page_of(name: str) -> str:
    """The page of a saved file's name: ``fig-4.1.data.json`` -> ``fig-4.1``.

    >>> page_of("fig-4.1.data.json"), page_of("analysis-4-kl.rule.json")
    ('fig-4.1', 'analysis-4-kl')
    """
    return name.rsplit(".", 2)[0]


def files() -> list[str]:
    """The saved files the ledger reads (sorted): ``<page>.data.json`` of every claim's data pages and
    ``<page>.rule.json`` of every page-verdict claim's page."""
    out: set[str] = set()
    for s in registry.specs():
        if "page_verdict" in s.rule:
            out.add(report.rule_path(s.page, "x").name)
        elif not s.rule.get("derived") and not s.rule.get("visual"):
            out.update(registry.data_name(p) for p in s.data_pages)
    return sorted(out)


def _digest(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def index(scale: str) -> dict[str, Any]:
    """The snapshot's index at ``scale`` (``{}`` when none is shipped or it cannot be read)."""
    p = folder(scale) / INDEX
    try:
        return json.loads(p.read_text())
    except (OSError, ValueError):
        return {}


def read(name: str, scale: str) -> dict[str, Any] | None:
    """The shipped copy of saved file ``name`` at ``scale`` as the page wrote it (stamp included), or None when
    none is shipped (or ``THESIS_REPRO_RETRAIN=1``); :class:`CorruptSnapshot` when its bytes do not match the
    index."""
    if paths.retrain():
        return None
    entry = index(scale).get("files", {}).get(name)
    if entry is None:
        return None
    p = folder(scale) / f"{name}.gz"
    try:
        data = p.read_bytes()
    except OSError as e:
        raise CorruptSnapshot(f"shipped {name} at {scale} is unreadable ({e.__class__.__name__})") from e
    if _digest(data) != entry["sha256"]:
        raise CorruptSnapshot(f"shipped {name} at {scale} does not match its SHA-256 (corrupt)")
    blob = json.loads(gzip.decompress(data))
    return {**blob, **{k: entry[k] for k in STAMP_KEYS if k in entry}, "version": f"shipped:{entry['sha256'][:16]}"}


def snapshot_source(scale: str) -> str:
    """One phrase naming where the snapshot comes from: folder, git commit and date ('' when none is shipped).

    >>> snapshot_source("no-such-scale")
    ''
    """
    prov = index(scale).get("provenance")
    if not prov:
        return ""
    commit = (prov.get("git_commit") or "unknown commit")[:10] + (" + changes" if prov.get("git_dirty") else "")
    return f"{_where(scale)}, shipped at {commit} on {str(prov.get('end', ''))[:10]}"


def _where(scale: str) -> Path:
    """:func:`folder` relative to the repository when it is inside it."""
    f = folder(scale)
    return f.relative_to(paths.ROOT) if f.is_relative_to(paths.ROOT) else f


def ship(scale: str) -> list[str]:
    """Copy the build's saved files the ledger reads (:func:`files`) into :func:`folder` atomically, each
    checked fresh (saved by the current kit code); returns the data files rewritten. A page whose file is
    missing or stale is a ``ValueError`` naming the pages and the command that refreshes them."""
    start = time.time()
    src = {n: paths.figures_dir(scale) / n for n in files()}
    missing = sorted(page_of(n) for n, p in src.items() if not p.exists())
    blobs = {n: json.loads(p.read_text()) for n, p in src.items() if p.exists()}
    stale = sorted(page_of(n) for n, b in blobs.items() if stamps.is_stale(page_of(n), b))
    if missing or stale:
        what = "; ".join(f"{label}: {', '.join(ps)}" for label, ps in (("not run", missing), ("stale", stale)) if ps)
        raise ValueError(f"cannot ship the claims snapshot at {scale} ({what}); run `make book SCALE={scale}` first")
    out = folder(scale)
    out.mkdir(parents=True, exist_ok=True)
    entries, changed = {}, []
    for name, blob in blobs.items():
        data = gzip.compress(json.dumps({k: v for k, v in blob.items() if k not in STAMP_KEYS}).encode(), mtime=0)
        target = out / f"{name}.gz"
        if not target.exists() or target.read_bytes() != data:
            _write(target, data)
            changed.append(name)
        entries[name] = {"sha256": _digest(data), **{k: blob[k] for k in STAMP_KEYS if k in blob}}
    for old in out.glob("*.gz"):
        if old.name.removesuffix(".gz") not in entries:
            old.unlink()
    from thesis_repro.core.cache import provenance as run_provenance

    idx = {"scale": scale, "files": entries, "provenance": run_provenance(start, time.time())}
    _write(out / INDEX, (json.dumps(idx, indent=1, sort_keys=True) + "\n").encode())
    return changed


def _numbers(blob: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in blob.items() if k not in (*STAMP_KEYS, "version")}


def check(scale: str) -> dict[str, str]:
    """Per saved file the ledger reads: ``identical`` when this build's copy holds exactly the shipped numbers,
    else ``differs (...)``, ``not shipped``, ``not run here`` or ``stale here`` (run ``make book`` first); a
    reader's check that the snapshot is what the shipped runs give on their machine."""
    out = {}
    for name in files():
        p = paths.figures_dir(scale) / name
        if not p.exists():
            out[name] = "not run here"
            continue
        built = json.loads(p.read_text())
        if stamps.is_stale(page_of(name), built):
            out[name] = "stale here"
            continue
        try:
            shipped = read(name, scale)
        except CorruptSnapshot as err:
            out[name] = str(err)
            continue
        if shipped is None:
            out[name] = "not shipped"
            continue
        a, b = _numbers(built), _numbers(shipped)
        diff = sorted(k for k in a.get("frames", {}) if a["frames"][k] != b.get("frames", {}).get(k))
        if a == b:
            out[name] = "identical"
        else:
            out[name] = f"differs ({'frames ' + ', '.join(diff) if diff else 'meta or verdicts'})"
    return out


def refresh_hint(scale: str) -> str:
    """One line after a book at ``scale`` when the shipped snapshot is out of date ('' when it is current or none
    is shipped): files whose numbers differ from this build's (or are missing or corrupt) and files shipped by
    other kit code (a fresh clone would call them stale)."""
    idx = index(scale)
    if not idx:
        return ""
    differ = [n for n, v in check(scale).items() if v not in ("identical", "not run here", "stale here")]
    stale = [n for n, e in idx.get("files", {}).items() if stamps.is_stale(page_of(n), e)]
    if not differ and not stale:
        return ""
    parts = [f"{len(differ)} differ from this build's numbers"] if differ else []
    parts += [f"{len(stale)} were shipped by other kit code"] if stale else []
    return (
        f"claims snapshot ({_where(scale)}) out of date: of its {len(idx.get('files', {}))} files, "
        f"{' and '.join(parts)}; `make ship-claims SCALE={scale}` refreshes it from this build"
    )


def _write(path: Path, data: bytes) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_bytes(data)
    tmp.replace(path)
