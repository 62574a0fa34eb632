"""Execute the figure notebooks (jupytext percent ``.py`` files) with papermill, quietly.

Notebook ids: ``"3.3"`` for ``notebooks/fig-3.3.py``, ``"table-3.4"`` for ``notebooks/table-3.4.py`` and
``"analysis-4-kl"`` for ``notebooks/analysis-4-kl.py`` (an analysis page of chapter 4). The page id is the
file stem (``fig-3.3``); it names the executed notebook, its figure files and its verdicts.

A *guide* (``notebooks/guide-<name>.py``, id ``"guide-<name>"``) is a how-to page of the book, not a thesis
item: it has no entry in ``data/thesis/claims.yaml``, writes no verdict, and the claims ledger never reads it.
:func:`notebook_ids` lists the thesis pages; ``notebook_ids(guides=True)`` adds the guides after them (what
the book and ``figure all`` execute).

A run's terminal output is the notebook's progress bars (its stderr, written as they come), one line per
verdict, and a final line naming the executed notebook and the figure files written. The kernel talks
over IPC sockets in the temp folder (removed at shutdown) instead of unencrypted TCP.

Nothing good is overwritten: the kernel sees ``THESIS_REPRO_BUILD`` pointing at a staging folder
(``<build>/.staging-<scale>-<page id>-<pid>``), so the executed notebook, its figures and its verdicts are
written there and moved into ``build/<scale>/`` (``os.replace``, the notebook last) only when the run
succeeds. A failed run raises :class:`NotebookError` (the failing cell's own exception, one line) and keeps
its executed copy as ``<page id>.failed.ipynb`` beside the previous, intact one; an interrupted run kills its
kernel (and the kernel's worker processes) and removes its connection files. Kernel files and staging
folders left by a process that was killed outright are removed by the next :func:`execute_notebook`.

Every executed notebook is stamped with an *execution key* (:func:`execution_key`): the notebook source,
the scale, the parameters, ``THESIS_REPRO_RETRAIN``, the kit modules its kernel imported (listed by a
cell appended at execution and removed afterwards) and the configuration and ``data/thesis/`` files.
:func:`is_current` tells the book builder that an executed notebook can be reused. The run cache is not
part of the key (runs are content-addressed by their configs, which those files determine): after
changing runs by hand, rebuild with ``--force``.

>>> page_id("3.3"), page_id("table-3.4"), page_id("analysis-4-kl")
('fig-3.3', 'table-3.4', 'analysis-4-kl')
>>> page_chapter("table-3.4"), page_chapter("analysis-4-kl")
('3', '4')
>>> sorted(["analysis-4-kl", "table-4.1", "4.10", "4.2"], key=sort_key)
['4.2', '4.10', 'table-4.1', 'analysis-4-kl']
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from thesis_repro.claims import report
from thesis_repro.core import paths
from thesis_repro.core.cache import pid_alive
from thesis_repro.core.scales import check_scale
from thesis_repro.core.validation import check_choice

#: Page kinds in the order they appear in a chapter: figures, then tables, then analysis pages.
KINDS: tuple[str, ...] = ("fig", "table", "analysis")


#: Prefix of a guide's id and file stem (``notebooks/guide-<name>.py``): a how-to page, not a thesis item.
GUIDE = "guide-"


def _kind(stem: str) -> str | None:
    return next((k for k in KINDS if stem.startswith(f"{k}-")), None)


def is_guide(nid: str) -> bool:
    """Whether ``nid`` is a guide page (no thesis claims, no verdict; listed among the book's guides).

    >>> is_guide("guide-score-agent"), is_guide("3.3")
    (True, False)
    """
    return nid.startswith(GUIDE)


def guide_ids() -> list[str]:
    """Ids of the guide pages (``notebooks/guide-*.py``), sorted."""
    return sorted(p.stem for p in paths.NOTEBOOKS.glob(f"{GUIDE}*.py"))


def notebook_ids(guides: bool = False) -> list[str]:
    """Ids of every thesis notebook, in book order (chapter; figures, tables, analysis pages; number); with
    ``guides`` the guide pages follow them."""
    ids = []
    for p in paths.NOTEBOOKS.glob("*.py"):
        kind = _kind(p.stem)
        if kind == "fig":
            ids.append(p.stem[4:])
        elif kind is not None:
            ids.append(p.stem)
    return sorted(ids, key=sort_key) + (guide_ids() if guides else [])


def page_id(nid: str) -> str:
    """File stem of a notebook id: ``"fig-3.3"``, ``"table-3.4"``, ``"analysis-4-kl"``, ``"guide-score-agent"``."""
    return nid if _kind(nid) or is_guide(nid) else f"fig-{nid}"


def source(nid: str) -> Path:
    """The notebook's source file (jupytext percent ``.py``) in ``notebooks/``."""
    page = page_id(nid)
    return paths.NOTEBOOKS / f"{page}.py" if is_guide(page) else paths.notebook(page)


def page_chapter(nid: str) -> str:
    """Chapter number (as a string) of a notebook id; ``"guide"`` for a guide page."""
    if is_guide(nid):
        return "guide"
    stem = page_id(nid)
    rest = stem.split("-", 1)[1]
    return rest.split("-")[0].split(".")[0]


def sort_key(nid: str) -> tuple:
    """Book order: chapter, then figures before tables before analysis pages, then the number; guides last."""
    stem = page_id(nid)
    if is_guide(stem):
        return (sys.maxsize, len(KINDS), stem)
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
    return check_choice(nid, notebook_ids(guides=True), "figure")


def executed_path(nid: str, scale: str) -> Path:
    """``build/<scale>/notebooks/<page id>.ipynb``."""
    return paths.executed(scale) / f"{page_id(nid)}.ipynb"


def failed_path(nid: str, scale: str) -> Path:
    """``build/<scale>/notebooks/<page id>.failed.ipynb``: the last failed execution, with its traceback."""
    return paths.executed(scale) / f"{page_id(nid)}.failed.ipynb"


#: Tag of the cell appended to the staged notebook to list the kit modules the kernel imported.
DEPS_TAG = "thesis-repro-deps"
_DEPS_CODE = (
    "import json as _json\nfrom thesis_repro.core import paths as _paths\nprint(_json.dumps(_paths.imported_modules()))"
)


def landed_runs(nid: str, scale: str) -> list[str]:
    """The keys of the thesis-budget study's training runs made so far (local cache or shipped), for a page that
    reads them as they land rather than through its own job grid (:data:`thesis_repro.claims.thesis_budget.PAGES`:
    Fig 3.3, Tables 3.4 and 3.6); ``[]`` for any other page. Part of :func:`execution_key`, so such a page is
    executed again when a study run lands (its evaluations land with it: the generator makes them next)."""
    from thesis_repro.claims import thesis_budget  # local: the claims' measures load pandas

    if page_id(nid) not in thesis_budget.PAGES:
        return []
    from thesis_repro.runs import studies  # local: the study's job list loads the figures (torch)

    return studies.made_study_runs(scale)


def execution_key(
    nid: str, scale: str, parameters: dict[str, Any] | None = None, modules: list[str] | None = None
) -> str:
    """Key of one execution: notebook source + scale + parameters + RETRAIN + the kit files it depends on.

    ``modules`` are the kit modules the notebook's kernel imported (recorded at execution, paths relative
    to the repository); ``None`` means every module of the kit. Configuration and ``data/thesis`` files
    always count, and so do the study runs the page reads as they land (:func:`landed_runs`).
    """
    nid = check_notebook(nid)
    mods = paths.all_modules() if modules is None else [paths.ROOT / m for m in modules]  # relative to the repo
    payload = {
        "notebook": hashlib.sha256(source(nid).read_bytes()).hexdigest(),
        "scale": scale,
        "parameters": parameters or {},
        "retrain": os.environ.get("THESIS_REPRO_RETRAIN", ""),
        "files": paths.files_hash([*mods, *paths.data_files()]),
    }
    if landed := landed_runs(nid, scale):
        payload["landed"] = landed
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


def clean_stale(build_root: Path | None = None) -> list[Path]:
    """Remove kernel files (temp folder) and staging folders (``build_root``, default the build folder) left
    by processes that are dead (killed before they could clean up); returns what was removed."""
    from thesis_repro.book.notebook_kernel import KERNEL_PREFIX, owner_pid  # local: the [book] extra's jupyter_client

    removed = []
    tmp = Path(tempfile.gettempdir())
    for p in tmp.glob(f"{KERNEL_PREFIX}*"):
        pid = owner_pid(p.name, KERNEL_PREFIX)
        if pid is not None and pid != os.getpid() and not pid_alive(pid):
            with contextlib.suppress(OSError):
                p.unlink()
                removed.append(p)
    root = build_root if build_root is not None else paths.build_dir("x").parent
    if root.is_dir():
        for p in root.glob(".staging-*"):
            pid = owner_pid(p.name, ".staging-", "")
            if pid is not None and pid != os.getpid() and not pid_alive(pid):
                shutil.rmtree(p, ignore_errors=True)
                removed.append(p)
    return removed


class NotebookError(RuntimeError):
    """A notebook's cell raised: ``ename``/``evalue`` are that exception's type and message."""

    def __init__(self, page: str, ename: str, evalue: str, failed: Path | None = None):
        self.page, self.ename, self.evalue, self.failed = page, ename, evalue, failed
        msg = " ".join(str(evalue).split()) or "(no message)"
        where = f" (its traceback: {paths.shown(failed)})" if failed is not None else ""
        super().__init__(f"notebook {page} failed: {ename}: {msg}{where}")


def parameter_names(nid: str) -> list[str]:
    """Names the notebook's ``parameters`` cell assigns (what ``-p NAME VALUE`` may set), in its order.

    >>> parameter_names("3.3")[:2]
    ['SCALE', 'SELECTION']
    """
    import ast

    text = source(check_notebook(nid)).read_text()
    parts = text.split('# %% tags=["parameters"]', 1)
    if len(parts) < 2:
        return []
    names: list[str] = []
    for node in ast.parse(parts[1].split("\n# %%", 1)[0]).body:
        targets = (
            node.targets if isinstance(node, ast.Assign) else [node.target] if isinstance(node, ast.AnnAssign) else []
        )
        names += [t.id for t in targets if isinstance(t, ast.Name) and t.id not in names]
    return names


def check_parameters(parameters: dict[str, Any] | None, scale: str) -> dict[str, Any]:
    """The notebook parameters without ``SCALE``: the scale argument sets it, and a different ``SCALE``
    parameter is a ``ValueError`` (it would run one scale and file the result under another).

    >>> check_parameters({"SCALE": "small", "SEEDS": 2}, "small")
    {'SEEDS': 2}
    >>> check_parameters({"SCALE": "full"}, "small")
    Traceback (most recent call last):
    ...
    ValueError: parameter SCALE='full' differs from the scale 'small'; the scale argument (--scale) sets SCALE
    """
    params = dict(parameters or {})
    if "SCALE" in params:
        if params["SCALE"] != scale:
            raise ValueError(
                f"parameter SCALE={params['SCALE']!r} differs from the scale {scale!r}; "
                "the scale argument (--scale) sets SCALE"
            )
        del params["SCALE"]
    return params


def _stamp(
    out: Path,
    nid: str,
    scale: str,
    parameters: dict[str, Any] | None,
    seconds: float,
    moved: tuple[Path, Path] | None = None,
) -> None:
    """Remove the dependency cell from the executed notebook and stamp its execution key and modules;
    ``moved`` (staging folder, build folder): the printed paths name the build folder, where the files go."""
    text = out.read_text()
    if moved is not None:
        text = text.replace(json.dumps(str(moved[0]))[1:-1], json.dumps(str(moved[1]))[1:-1])
    nb = json.loads(text)
    modules = None
    cells = nb["cells"]
    if cells and DEPS_TAG in cells[-1].get("metadata", {}).get("tags", []):
        text = "".join("".join(o.get("text", "")) for o in cells[-1].get("outputs", []) if o.get("name") == "stdout")
        try:
            modules = [str(m) for m in json.loads(text)]  # repository-relative (paths.imported_modules)
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
    for p in sorted(paths.figures_dir(scale).glob(f"{stem}*")):
        tail = p.name[len(stem) :]
        if tail[:1].isdigit() or p.suffix in {".json", ".tmp"} or not p.is_file():
            continue  # fig-3.3 must not claim fig-3.30's files; verdicts/run lists are not figures
        if p.stat().st_mtime >= since:
            found.append(p)
    return found


#: The [book] extra's packages that executing a notebook needs (import names).
BOOK_PACKAGES: tuple[str, ...] = ("papermill", "jupytext", "nbclient", "ipykernel")


def require_book() -> None:
    """A one-line ``RuntimeError`` naming the install command when the ``[book]`` extra is missing (a lean
    ``pip install thesis_repro`` scores, trains and renders, but executes no notebook)."""
    import importlib.util

    missing = [name for name in BOOK_PACKAGES if importlib.util.find_spec(name) is None]
    if missing:
        raise RuntimeError(
            f"executing notebooks needs the book extra ({', '.join(missing)} missing): "
            "pip install 'thesis_repro[book]' (make venv installs it)"
        )
    if not paths.NOTEBOOKS.is_dir():
        raise RuntimeError(f"no notebooks at {paths.NOTEBOOKS}: they ship with the kit's clone, not with pip install")


def execute_notebook(nid: str, scale: str, parameters: dict[str, Any] | None = None, log: bool = True) -> Path:
    """Execute notebook ``nid`` at ``scale`` and return the path of the executed ``.ipynb``.

    With ``log`` the notebook's stderr (progress bars) goes to this process's stderr as it comes, then
    one line per verdict and a final line with the executed notebook and figure files are printed.
    Outputs are staged and swapped in on success (module docstring); a failing cell raises
    :class:`NotebookError`; a ``SCALE`` parameter other than ``scale`` is a ``ValueError``.
    """
    require_book()
    # local: papermill and jupytext take seconds to import (and come with the [book] extra); only executing a
    # notebook needs them
    import jupytext
    import nbformat
    import papermill as pm
    from jupyter_client.kernelspec import NoSuchKernel
    from papermill.exceptions import PapermillExecutionError

    from thesis_repro.book.notebook_kernel import TRACKED_STDERR, QuietKernelManager, kill_kernels, noting_interrupts

    nid = check_notebook(nid)
    check_scale(scale)
    parameters = check_parameters(parameters, scale)
    page = page_id(nid)
    known = [n for n in parameter_names(nid) if n != "SCALE"]
    unknown = sorted(set(parameters) - set(known))
    if unknown:
        valid = ", ".join(known) or "none (only --scale)"
        raise ValueError(f"unknown parameter {unknown[0]!r} of notebook {page}; valid parameters are: {valid}")
    build_root = paths.build_dir(scale).parent.absolute()  # absolute: the kernel runs in the repository
    clean_stale(build_root)
    src = source(nid)
    out = executed_path(nid, scale)
    failed = failed_path(nid, scale)
    out.parent.mkdir(parents=True, exist_ok=True)
    paths.figures_dir(scale).mkdir(parents=True, exist_ok=True)
    stage = build_root / f".staging-{scale}-{page}-{os.getpid()}"
    shutil.rmtree(stage, ignore_errors=True)
    staged_out = stage / out.absolute().relative_to(build_root)
    staged_out.parent.mkdir(parents=True)
    (stage / paths.figures_dir(scale).absolute().relative_to(build_root)).mkdir(parents=True)
    nb = jupytext.read(src)
    nb.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3", "language": "python"}
    deps = nbformat.v4.new_code_cell(_DEPS_CODE)
    deps.metadata["tags"] = [DEPS_TAG, "remove-cell"]
    nb.cells.append(deps)
    staged = staged_out.with_suffix(".source.ipynb")
    jupytext.write(nb, staged)
    kernel_env = {"THESIS_REPRO_BUILD": str(stage), paths.PUBLISHED_ENV: str(build_root)}  # reads finished pages
    manager = type("StagedKernelManager", (QuietKernelManager,), {"extra_env": kernel_env})
    t0 = time.time()
    try:
        try:
            with noting_interrupts():
                pm.execute_notebook(
                    str(staged),
                    str(staged_out),
                    parameters={"SCALE": scale, **parameters},
                    cwd=str(paths.ROOT),
                    kernel_name="python3",
                    progress_bar=False,
                    log_output=False,
                    stderr_file=TRACKED_STDERR if log else None,
                    kernel_manager_class=manager,
                )
        except PapermillExecutionError as err:
            kept = None
            if staged_out.exists():
                os.replace(staged_out, failed)
                kept = failed
            raise NotebookError(page, err.ename, err.evalue, kept) from None
        except NoSuchKernel as err:
            raise RuntimeError(f"no Jupyter kernel {err}; install it with `make venv`") from None
        except (RuntimeError, TimeoutError) as err:  # the kernel died, a cell timed out, ...
            lines = [ln for ln in str(err).splitlines() if ln.strip()]
            raise NotebookError(page, type(err).__name__, lines[-1] if lines else "") from None
        finally:
            kill_kernels()  # a no-op unless interrupted or failed before papermill shut the kernel down
        staged.unlink(missing_ok=True)
        seconds = time.time() - t0
        _stamp(staged_out, nid, scale, parameters, seconds, moved=(stage, build_root))
        _swap_in(stage, build_root, last=staged_out)
        failed.unlink(missing_ok=True)
    finally:
        shutil.rmtree(stage, ignore_errors=True)
    from thesis_repro.runs import layer as runs  # local: the run listing imports the whole figure layer

    runs.write_run_rows(nid, scale)  # build/<scale>/figures/fig-X.Y.runs.json: where this figure's runs are
    if log:
        verdicts = report.verdicts_path(page, scale)
        if verdicts.exists() and verdicts.stat().st_mtime >= t0:
            for v in report.load_verdicts(page, scale):
                print(v)
        figs = ", ".join(str(p) for p in outputs_of(nid, scale, since=t0)) or "none"
        print(f"[thesis_repro] {page} ({scale}, {seconds:.0f} s): notebook {out}; figures: {figs}")
    return out


def _swap_in(stage: Path, root: Path, last: Path) -> list[Path]:
    """Move every file of ``stage`` to the same place under ``root`` (``os.replace``), ``last`` last (the
    executed notebook: it marks the run as complete); returns the destinations."""
    files = sorted((p for p in stage.rglob("*") if p.is_file() and p.suffix != ".tmp"), key=lambda p: (p == last, p))
    moved = []
    for p in files:
        dest = root / p.relative_to(stage)
        dest.parent.mkdir(parents=True, exist_ok=True)
        os.replace(p, dest)
        moved.append(dest)
    return moved
