"""Execute the figure notebooks (jupytext percent ``.py`` files) with papermill, quietly.

Notebook ids: ``"3.3"`` for ``notebooks/fig-3.3.py``, ``"table-3.4"`` for ``notebooks/table-3.4.py`` and
``"analysis-4-kl"`` for ``notebooks/analysis-4-kl.py`` (an analysis page of chapter 4). The page id is the
file stem (``fig-3.3``); it names the executed notebook, its figure files and its verdicts.

A run's terminal output is the notebook's progress bars (its stderr, written as they come), one line per
verdict, and a final line naming the executed notebook and the figure files written. The kernel talks
over IPC sockets in the temp folder (removed at shutdown) instead of unencrypted TCP.

Every executed notebook is stamped with an *execution key* (:func:`execution_key`): the notebook source,
the scale, the parameters, ``THESIS_REPRO_RETRAIN``, the kit modules its kernel imported (listed by a
cell appended at execution and removed afterwards) and the configuration and ``data/thesis/`` files.
:func:`is_current` tells the book builder that an executed notebook can be reused. The run cache is not
part of the key (runs are content-addressed by their configs, which those files determine): after
changing runs by hand, rebuild with ``--force``.

>>> page_id("3.3"), page_id("table-3.4"), page_id("analysis-4-kl")
('fig-3.3', 'table-3.4', 'analysis-4-kl')
>>> chapter("table-3.4"), chapter("analysis-4-kl")
('3', '4')
>>> sorted(["analysis-4-kl", "table-4.1", "4.10", "4.2"], key=sort_key)
['4.2', '4.10', 'table-4.1', 'analysis-4-kl']
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from jupyter_client import AsyncKernelManager

from thesis_repro import paths
from thesis_repro.scales import check_scale
from thesis_repro.validation import check_choice

#: Page kinds in the order they appear in a chapter: figures, then tables, then analysis pages.
KINDS: tuple[str, ...] = ("fig", "table", "analysis")


def _kind(stem: str) -> str | None:
    return next((k for k in KINDS if stem.startswith(f"{k}-")), None)


def notebook_ids() -> list[str]:
    """Ids of every notebook, in book order (chapter; figures, tables, analysis pages; number)."""
    ids = []
    for p in paths.NOTEBOOKS.glob("*.py"):
        kind = _kind(p.stem)
        if kind == "fig":
            ids.append(p.stem[4:])
        elif kind is not None:
            ids.append(p.stem)
    return sorted(ids, key=sort_key)


def page_id(nid: str) -> str:
    """File stem of a notebook id: ``"fig-3.3"``, ``"table-3.4"``, ``"analysis-4-kl"``."""
    return nid if _kind(nid) else f"fig-{nid}"


def chapter(nid: str) -> str:
    """Chapter number (as a string) of a notebook id."""
    stem = page_id(nid)
    rest = stem.split("-", 1)[1]
    return rest.split("-")[0].split(".")[0]


def sort_key(nid: str) -> tuple:
    """Book order: chapter, then figures before tables before analysis pages, then the number."""
    stem = page_id(nid)
    kind = _kind(stem)
    rest = stem.split("-", 1)[1]
    parts = rest.replace("-", ".").split(".")
    nums = tuple(int(p) if p.isdigit() else 0 for p in parts)
    return (nums[0], KINDS.index(kind), *nums[1:], stem)


def check_notebook(nid: str) -> str:
    """Normalise ``"fig-3.3"``/``"3.3"`` to ``"3.3"`` and check that the notebook exists.

    >>> check_notebook("fig-3.3")
    '3.3'
    >>> check_notebook("9.99")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    ValueError: unknown figure '9.99'; valid figures are: '3.2', ...
    """
    if not isinstance(nid, str):
        raise ValueError(f"figure id must be a string such as '3.3', got {nid!r}")
    nid = nid[4:] if nid.startswith("fig-") else nid
    return check_choice(nid, notebook_ids(), "figure")


def executed_path(nid: str, scale: str) -> Path:
    """``build/<scale>/notebooks/<page id>.ipynb``."""
    return paths.executed(scale) / f"{page_id(nid)}.ipynb"


#: Files every notebook depends on besides the modules it imports: configuration and thesis data.
_DATA_SUFFIXES = {".yaml", ".yml", ".csv", ".json", ".xml"}
#: Tag of the cell appended to the staged notebook to list the kit modules the kernel imported.
DEPS_TAG = "thesis-repro-deps"
_DEPS_CODE = (
    "import json as _json, sys as _sys\n"
    "print(_json.dumps(sorted({{_m.__file__ for _m in list(_sys.modules.values())\n"
    "    if (getattr(_m, '__file__', None) or '').startswith({root!r})}})))"
)


def _data_files() -> list[Path]:
    """Configuration, model and thesis-data files (every notebook depends on all of them)."""
    found = [p for root in (paths.PACKAGE, paths.THESIS_DATA) for p in root.rglob("*") if p.suffix in _DATA_SUFFIXES]
    return sorted(p for p in found if p.is_file())


def _all_modules() -> list[Path]:
    """Every module of the kit (the dependency list when a notebook's own is unknown)."""
    return sorted(paths.PACKAGE.rglob("*.py"))


def _files_hash(files: list[Path]) -> str:
    h = hashlib.sha256()
    for p in sorted(set(files)):
        h.update(str(p.relative_to(paths.ROOT) if p.is_relative_to(paths.ROOT) else p).encode())
        h.update(p.read_bytes() if p.exists() else b"<missing>")
    return h.hexdigest()


def execution_key(
    nid: str, scale: str, parameters: dict[str, Any] | None = None, modules: list[str] | None = None
) -> str:
    """Key of one execution: notebook source + scale + parameters + RETRAIN + the kit files it depends on.

    ``modules`` are the kit modules the notebook's kernel imported (recorded at execution, paths relative
    to the repository); ``None`` means every module of the kit. Configuration and ``data/thesis`` files
    always count.
    """
    nid = check_notebook(nid)
    mods = _all_modules() if modules is None else [paths.ROOT / m for m in modules]  # relative to the repo
    payload = {
        "notebook": hashlib.sha256(paths.notebook(page_id(nid)).read_bytes()).hexdigest(),
        "scale": scale,
        "parameters": parameters or {},
        "retrain": os.environ.get("THESIS_REPRO_RETRAIN", ""),
        "files": _files_hash([*mods, *_data_files()]),
    }
    return hashlib.sha256(json.dumps(payload, sort_keys=True, default=str).encode()).hexdigest()


def is_current(nid: str, scale: str, parameters: dict[str, Any] | None = None) -> bool:
    """True if ``nid`` was executed at ``scale`` and nothing it depends on changed (same :func:`execution_key`)."""
    out = executed_path(nid, scale)
    if not out.exists():
        return False
    try:
        meta = json.loads(out.read_text())["metadata"].get("thesis_repro", {})
    except (OSError, ValueError, KeyError):
        return False
    key = meta.get("execution_key")
    return key is not None and key == execution_key(nid, scale, parameters, meta.get("modules"))


class QuietKernelManager(AsyncKernelManager):
    """Kernel manager whose kernel talks over IPC sockets in the temp folder (no unencrypted-TCP warning).

    The socket files (``<tmp>/thesis-repro-kernel-<pid>-<n>-<port>``) are removed when the kernel shuts down.
    Shutdown skips jupyter_client's preliminary SIGINT (papermill shuts down an idle kernel), which made
    the kernel log "KeyboardInterrupt caught in kernel" now and then.
    """

    _count = 0

    def __init__(self, **kwargs: Any):
        super().__init__(**kwargs)
        QuietKernelManager._count += 1
        self.transport = "ipc"
        self.ip = str(Path(tempfile.gettempdir()) / f"thesis-repro-kernel-{os.getpid()}-{self._count}")
        self._closing = False

    async def _async_interrupt_kernel(self) -> None:
        if not self._closing:
            await super()._async_interrupt_kernel()

    async def shutdown_kernel(self, now: bool = False, restart: bool = False) -> None:  # type: ignore[override]
        self._closing = True
        try:
            await super()._async_shutdown_kernel(now=now, restart=restart)
        finally:
            self._closing = False


def _stamp(out: Path, nid: str, scale: str, parameters: dict[str, Any] | None, seconds: float) -> None:
    """Remove the dependency cell from the executed notebook and stamp its execution key and modules."""
    nb = json.loads(out.read_text())
    modules = None
    cells = nb["cells"]
    if cells and DEPS_TAG in cells[-1].get("metadata", {}).get("tags", []):
        text = "".join("".join(o.get("text", "")) for o in cells[-1].get("outputs", []) if o.get("name") == "stdout")
        try:
            modules = [str(Path(m).relative_to(paths.ROOT)) for m in json.loads(text)]
        except ValueError:
            modules = None
        nb["cells"] = cells[:-1]
    key = execution_key(nid, scale, parameters, modules)
    nb["metadata"]["thesis_repro"] = {"execution_key": key, "modules": modules, "seconds": round(seconds, 1)}
    tmp = out.with_suffix(".tmp")
    tmp.write_text(json.dumps(nb, indent=1, ensure_ascii=False))
    tmp.replace(out)


def outputs_of(nid: str, scale: str, since: float = 0.0) -> list[Path]:
    """Figure files of ``nid`` in ``build/<scale>/figures`` (``<page id>*``), written at or after ``since``."""
    stem = page_id(nid)
    found = []
    for p in sorted(paths.figures(scale).glob(f"{stem}*")):
        tail = p.name[len(stem) :]
        if tail[:1].isdigit() or p.suffix in {".json", ".tmp"} or not p.is_file():
            continue  # fig-3.3 must not claim fig-3.30's files; verdicts/run lists are not figures
        if p.stat().st_mtime >= since:
            found.append(p)
    return found


def execute(nid: str, scale: str, parameters: dict[str, Any] | None = None, log: bool = True) -> Path:
    """Execute notebook ``nid`` at ``scale`` and return the path of the executed ``.ipynb``.

    With ``log`` the notebook's stderr (progress bars) goes to this process's stderr as it comes, then
    one line per verdict and a final line with the executed notebook and figure files are printed.
    """
    import jupytext
    import nbformat
    import papermill as pm

    from thesis_repro import report

    nid = check_notebook(nid)
    check_scale(scale)
    src = paths.notebook(page_id(nid))
    out = executed_path(nid, scale)
    out.parent.mkdir(parents=True, exist_ok=True)
    paths.figures(scale).mkdir(parents=True, exist_ok=True)
    nb = jupytext.read(src)
    nb.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3", "language": "python"}
    deps = nbformat.v4.new_code_cell(_DEPS_CODE.format(root=str(paths.PACKAGE) + os.sep))
    deps.metadata["tags"] = [DEPS_TAG, "remove-cell"]
    nb.cells.append(deps)
    staged = out.with_suffix(".source.ipynb")
    jupytext.write(nb, staged)
    params = {"SCALE": scale, **(parameters or {})}
    t0 = time.time()
    try:
        pm.execute_notebook(
            str(staged),
            str(out),
            parameters=params,
            cwd=str(paths.ROOT),
            kernel_name="python3",
            progress_bar=False,
            log_output=False,
            stderr_file=sys.stderr if log else None,
            kernel_manager_class=QuietKernelManager,
        )
    finally:
        staged.unlink(missing_ok=True)
    seconds = time.time() - t0
    _stamp(out, nid, scale, parameters, seconds)
    from thesis_repro import runs  # local: the run listing imports the whole figure layer

    runs.record(nid, scale)  # build/<scale>/figures/fig-X.Y.runs.json: where this figure's runs are
    if log:
        verdicts = report.verdicts_path(page_id(nid), scale)
        if verdicts.exists() and verdicts.stat().st_mtime >= t0:
            for v in report.load(page_id(nid), scale):
                print(v)
        figs = ", ".join(str(p) for p in outputs_of(nid, scale, since=t0)) or "none"
        print(f"[thesis_repro] {page_id(nid)} ({scale}, {seconds:.0f} s): notebook {out}; figures: {figs}")
    return out
