"""Code stamps: what a page's saved numbers depend on besides its runs, hashed so that only a change that can
move a number makes them stale.

A page's numbers depend on the code its kernel ran, the configuration and thesis data, and its notebook; never
on where a module lives or on its prose. So each part is hashed by what it computes:

* a kit module by its normalised syntax tree (:func:`normalised`): comments and docstrings dropped, each import
  reduced to the names it binds, so a module's path is not part of its identity (a move, or a split package's
  ``from a.b import f`` becoming ``from a.c import f``, keeps every hash);
* a configuration or thesis-data file (:func:`~thesis_repro.core.paths.data_files`) by its parsed content (YAML and
  JSON: comments and layout dropped; other files: bytes), under its repository path;
* the page's notebook (a jupytext percent ``.py``: its markdown cells are comments) by its normalised tree.

Every kit module the page imported counts, whatever its layer: a page's numbers pass through the run cache
(decompression), the budgets (which runs count as trained) and the page metadata, so no layer is known to
compute none. :func:`page_stamp` records each module's hash beside its path; :func:`code_stamp` recomputes the stamp
from those hashes, each looked up among the hashes of the kit's current modules: a module that still exists
somewhere, unchanged, keeps the stamp.

>>> moved = normalised("from d import b as c\\nx = c.f(1)\\n")
>>> normalised("import a.b as c\\n'''doc'''\\nx = c.f(1)  # note\\n") == moved
True
"""

from __future__ import annotations

import ast
import hashlib
import json
import os
import re
import sys
from collections.abc import Callable, Mapping, Sequence
from functools import cache, lru_cache
from pathlib import Path

from thesis_repro.core import paths, yamlfile


def _is_prose(node: ast.stmt) -> bool:
    """A statement that is a bare string: a docstring, or prose that computes nothing."""
    return isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant) and isinstance(node.value.value, str)


def _bound(node: ast.Import | ast.ImportFrom) -> list[str]:
    """The names an import binds (``import a.b`` binds ``a``; ``from x import y as z`` binds ``z``)."""
    if isinstance(node, ast.Import):
        return sorted(a.asname or a.name.split(".")[0] for a in node.names)
    return sorted(a.asname or a.name for a in node.names)


class _Normalise(ast.NodeTransformer):
    def generic_visit(self, node: ast.AST) -> ast.AST:
        super().generic_visit(node)
        for field in ("body", "orelse", "finalbody"):
            body = getattr(node, field, None)
            if isinstance(body, list) and body and all(isinstance(s, ast.stmt) for s in body):
                kept = [s for s in body if not _is_prose(s)]
                setattr(node, field, kept or ([ast.Pass()] if field == "body" else []))
        return node

    def visit_Import(self, node: ast.Import) -> ast.AST:
        return ast.Expr(ast.Tuple([ast.Name(n) for n in _bound(node)]))

    visit_ImportFrom = visit_Import  # type: ignore[assignment]


def normalised(source: str) -> str:
    """The syntax tree of ``source`` as text, without comments, docstrings or other bare strings, each import
    replaced by the names it binds."""
    tree = _Normalise().visit(ast.parse(source))
    return ast.dump(tree, annotate_fields=False, include_attributes=False)


@cache
def _memo_version() -> str:
    """Python's version (its syntax trees differ between versions) and this module's bytes (the normalisation)."""
    return hashlib.sha256(f"{sys.version_info[:2]}".encode() + Path(__file__).read_bytes()).hexdigest()[:12]


#: Environment variable naming a folder for the computed hashes instead of the build folder's ``.stamps``: the
#: entries are content-addressed, so any number of build folders (``make test`` gives each test its own) can
#: share one.
STAMPS_ENV = "THESIS_REPRO_STAMPS"


def _memo_dir() -> Path:
    """Where computed hashes are kept between processes: ``$THESIS_REPRO_STAMPS/<version>``, else the build folder's
    ``.stamps/<version>`` (in a notebook's kernel the finished build's, not its own staging folder's, so that the
    pages of one build share it)."""
    given = os.environ.get(STAMPS_ENV)
    if given:
        return Path(given) / _memo_version()
    published = os.environ.get(paths.PUBLISHED_ENV)
    return (Path(published) / ".stamps" if published else paths.build_dir(".stamps")) / _memo_version()


_MEMO_VALUE = re.compile(r"(bytes:)?[0-9a-f]{16}|[0-9a-f]{64}")


def _memo(kind: str, data: bytes, compute: Callable[[], str]) -> str:
    """``compute()``, kept on disk under the SHA-256 of ``data`` (content-addressed: a file's bytes decide its hash,
    so an entry never goes stale). Every notebook kernel and command hashes the kit's ~120 modules, seconds of
    syntax-tree work each time; this makes it once per content. Written atomically; an unreadable or malformed
    entry is recomputed and rewritten."""
    entry = _memo_dir() / f"{kind}-{hashlib.sha256(data).hexdigest()}"
    try:
        value = entry.read_text()
        if _MEMO_VALUE.fullmatch(value):
            return value
    except OSError:
        pass
    value = compute()
    try:
        entry.parent.mkdir(parents=True, exist_ok=True)
        tmp = entry.with_name(f".{entry.name}.{os.getpid()}.tmp")
        tmp.write_text(value)
        os.replace(tmp, entry)
    except OSError:  # a read-only build folder: the hash is still right, only not kept
        pass
    return value


def _normalised_hash(data: bytes) -> str:
    try:
        return hashlib.sha256(normalised(data.decode()).encode()).hexdigest()[:16]
    except (SyntaxError, UnicodeDecodeError, ValueError):
        return "bytes:" + hashlib.sha256(data).hexdigest()[:16]


@lru_cache(maxsize=4096)
def _source_hash(data: bytes) -> str:
    return _memo("module", data, lambda: _normalised_hash(data))


def module_hash(path: Path) -> str:
    """16 hex digits of ``path``'s normalised syntax tree (:func:`normalised`; ``<missing>`` if absent)."""
    return _source_hash(path.read_bytes()) if path.is_file() else "<missing>"


def _parsed_hash(suffix: str, data: bytes) -> str:
    if suffix in {".yaml", ".yml", ".json"}:
        try:
            if suffix == ".json":
                value = json.loads(data)
            else:
                value = yamlfile.parse(data)
            data = json.dumps(value, sort_keys=True, default=str).encode()
        except ValueError:
            pass
    return hashlib.sha256(data).hexdigest()


@lru_cache(maxsize=1024)
def _data_hash(suffix: str, data: bytes) -> str:
    return _memo(f"data{suffix}", data, lambda: _parsed_hash(suffix, data))


def data_hash(path: Path) -> str:
    """SHA-256 of a configuration or data file's content: YAML and JSON as parsed, other files as bytes."""
    return _data_hash(path.suffix, path.read_bytes()) if path.is_file() else "<missing>"


def current_hashes() -> set[str]:
    """The :func:`module_hash` of every module of the kit as it is now."""
    return {module_hash(p) for p in paths.all_modules()}


def kit_modules(modules: Sequence[str]) -> dict[str, str]:
    """``{repository-relative path: module_hash}`` of ``modules`` (as :func:`~thesis_repro.core.paths.imported_modules`
    lists them)."""
    return {m: module_hash(paths.ROOT / m) for m in modules}


def code_stamp(page: str, modules: Mapping[str, str] | Sequence[str] | None) -> str:
    """12 hex digits over what ``page``'s saved numbers depend on besides its runs: the hashes of the kit
    ``modules`` that wrote them (:func:`kit_modules`: each counts as itself if some current module has it, else as
    gone; a list of paths: their current hashes; ``None``: every current module), the configuration and thesis
    data and the page's notebook.

    >>> mods = kit_modules(paths.imported_modules())
    >>> s = code_stamp("table-3.4", mods)
    >>> len(s) == 12 and s == code_stamp("table-3.4", mods) != code_stamp("table-3.3", mods)
    True
    """
    if modules is None:
        hashes = sorted(current_hashes())
    elif isinstance(modules, Mapping):
        now = current_hashes()
        hashes = sorted(h if h in now else f"gone:{h}" for h in set(modules.values()))
    else:
        hashes = sorted({module_hash(paths.ROOT / m) for m in modules})
    data = [f"{paths.shown(p)}:{data_hash(p)}" for p in paths.data_files()]
    payload = {"modules": hashes, "data": data, "notebook": module_hash(paths.notebook(page))}
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()[:12]


def page_stamp(page: str) -> dict[str, object]:
    """What a page's saved numbers carry to tell which code wrote them: ``kit``, the :func:`code_stamp` over
    ``kit_modules``, the kit modules this process imported with their hashes."""
    modules = kit_modules(paths.imported_modules())
    return {"kit": code_stamp(page, modules), "kit_modules": modules}


def is_stale(page: str, blob: Mapping[str, object]) -> bool:
    """Whether ``blob`` (saved with :func:`page_stamp`) was written by code that computes differently: a module it
    imported is nowhere in the kit any more, unchanged, or the configuration, thesis data or the page's notebook
    changed since (every module counts for a blob saved without its list)."""
    modules = blob.get("kit_modules")
    return blob.get("kit") != code_stamp(page, modules if isinstance(modules, Mapping | list) else None)
