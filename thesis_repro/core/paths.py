"""Every location the kit reads or writes, in one place.

Override the run cache with ``THESIS_REPRO_DATA`` (tests point it at a temporary folder), the shipped
reference runs with ``THESIS_REPRO_REFERENCE`` and the build folder with ``THESIS_REPRO_BUILD``;
``THESIS_REPRO_RETRAIN=1`` (``make ... RETRAIN=1``) ignores the shipped runs.

Run from its clone (:func:`in_clone`), the kit keeps everything in the clone (``data/runs``, ``build``). Installed
without it (``pip install``: the code alone, no ``data/`` or ``notebooks/``), new runs and builds go to
``~/.cache/thesis_repro`` (``XDG_CACHE_HOME``) and :func:`reference_note` says where the shipped runs are expected.

>>> from thesis_repro.core import paths
>>> paths.notebook("3.3").name
'fig-3.3.py'
"""

from __future__ import annotations

import hashlib
import os
import sys
from pathlib import Path

ROOT: Path = Path(__file__).resolve().parent.parent.parent
PACKAGE: Path = ROOT / "thesis_repro"
CONFIG: Path = PACKAGE / "config"
NOTEBOOKS: Path = ROOT / "notebooks"
THESIS_DATA: Path = ROOT / "data" / "thesis"
#: Other projects' published numbers (CleanRL, the SB3 zoo), neither the thesis's nor ours.
PUBLIC_DATA: Path = ROOT / "data" / "public"
BOOK: Path = ROOT / "book"


def shown(path: str | Path) -> str:
    """``path`` as shown to a user: relative to the repository if inside it, else whole.

    >>> shown(ROOT / "data" / "reference")
    'data/reference'
    """
    try:
        return str(Path(path).resolve().relative_to(ROOT))
    except ValueError:
        return str(path)


def in_clone() -> bool:
    """Whether the kit runs from its clone (``pyproject.toml`` beside the package), not from an installed wheel."""
    return (ROOT / "pyproject.toml").is_file() and (ROOT / "data").is_dir()


def _user_cache() -> Path:
    """``~/.cache/thesis_repro`` (``XDG_CACHE_HOME``): an installed kit's runs and builds, never site-packages."""
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "thesis_repro"


def runs_dir() -> Path:
    """Root of the content-addressed run cache: ``THESIS_REPRO_DATA``, else ``data/runs`` in the clone, else
    ``~/.cache/thesis_repro/runs``."""
    default = ROOT / "data" / "runs" if in_clone() else _user_cache() / "runs"
    return Path(os.environ.get("THESIS_REPRO_DATA", default))


REFERENCE_ENV = "THESIS_REPRO_REFERENCE"


def reference() -> Path:
    """Shipped read-only layer of finished ``small`` runs: training runs and chapter 5's results
    (``data/reference`` unless ``THESIS_REPRO_REFERENCE`` is set); consulted after the local run cache."""
    return Path(os.environ.get(REFERENCE_ENV, ROOT / "data" / "reference"))


def reference_note() -> str | None:
    """One line saying where the shipped runs are expected and how to point at them, when that folder is missing
    (an installed kit carries no ``data/``); ``None`` when it is there.

    >>> import os; saved = os.environ.get(REFERENCE_ENV); os.environ[REFERENCE_ENV] = "/nowhere"
    >>> print(reference_note())
    no shipped runs at /nowhere (THESIS_REPRO_REFERENCE): point it at <clone>/data/reference of a clone of the kit
    >>> _ = os.environ.pop(REFERENCE_ENV); os.environ.update({REFERENCE_ENV: saved} if saved else {})
    """
    ref = reference()
    if ref.is_dir():
        return None
    if REFERENCE_ENV in os.environ:
        return f"no shipped runs at {ref} ({REFERENCE_ENV}): point it at <clone>/data/reference of a clone of the kit"
    return (
        f"no shipped runs in this install (pip installs the code alone): clone the kit and set "
        f"{REFERENCE_ENV}=<clone>/data/reference"
    )


#: Values of ``THESIS_REPRO_RETRAIN`` (``make ... RETRAIN=...``): yes, then no.
RETRAIN_VALUES: tuple[tuple[str, ...], tuple[str, ...]] = (("1", "true", "yes", "on"), ("", "0", "false", "no", "off"))


def retrain() -> bool:
    """Whether ``THESIS_REPRO_RETRAIN`` asks to ignore the shipped runs and recompute them; any other value
    than those of :data:`RETRAIN_VALUES` is a ``ValueError`` (a typo must not silently use shipped runs).

    >>> import os; os.environ["THESIS_REPRO_RETRAIN"] = "1"; retrain()
    True
    >>> os.environ["THESIS_REPRO_RETRAIN"] = "2"; retrain()
    Traceback (most recent call last):
    ...
    ValueError: RETRAIN / THESIS_REPRO_RETRAIN: unknown value '2'; valid values are: 1, true, yes, on, 0, false, no, off
    >>> del os.environ["THESIS_REPRO_RETRAIN"]; retrain()
    False
    """
    value = os.environ.get("THESIS_REPRO_RETRAIN", "").strip().lower()
    yes, no = RETRAIN_VALUES
    if value not in yes + no:
        valid = ", ".join(v for v in yes + no if v)
        raise ValueError(f"RETRAIN / THESIS_REPRO_RETRAIN: unknown value {value!r}; valid values are: {valid}")
    return value in yes


def build_dir(scale: str) -> Path:
    """Root of generated artefacts for one scale (executed notebooks, figures): ``THESIS_REPRO_BUILD``, else
    ``build`` in the clone, else ``~/.cache/thesis_repro/build``."""
    default = ROOT / "build" if in_clone() else _user_cache() / "build"
    return Path(os.environ.get("THESIS_REPRO_BUILD", default)) / scale


PUBLISHED_ENV = "THESIS_REPRO_PUBLISHED_BUILD"


def published_figures(scale: str) -> Path:
    """Figure folder of finished pages. Inside a notebook's kernel, :func:`build_dir` is the notebook's staging folder
    and ``THESIS_REPRO_PUBLISHED_BUILD`` names the build folder it will move to, so a page can read what other
    pages saved (a claim judged on Table 3.4 and repeated on Fig 3.7); elsewhere the same as :func:`figures_dir`."""
    root = os.environ.get(PUBLISHED_ENV)
    return Path(root) / scale / "figures" if root else figures_dir(scale)


def page_output(scale: str, name: str) -> Path:
    """``figures(scale) / name`` if this run wrote it, else the finished pages' copy (:func:`published_figures`).

    >>> page_output("smoke", "no-such-page.data.json") == published_figures("smoke") / "no-such-page.data.json"
    True
    """
    own = figures_dir(scale) / name
    return own if own.exists() else published_figures(scale) / name


def executed(scale: str) -> Path:
    """Folder of notebooks executed at ``scale``."""
    return build_dir(scale) / "notebooks"


def figures_dir(scale: str) -> Path:
    """Folder where notebooks save their figure files at ``scale``."""
    return build_dir(scale) / "figures"


def notebook(figure: str) -> Path:
    """Source (jupytext percent ``.py``) of a notebook id: ``"3.3"``, ``"table-3.4"``, ``"analysis-4-kl"``."""
    name = figure if figure.startswith(("fig-", "table-", "analysis-")) else f"fig-{figure}"
    return NOTEBOOKS / f"{name}.py"


def thesis_table_path(name: str) -> Path:
    """A transcribed reference table of the thesis, e.g. ``thesis_table("fig3_3c")``."""
    return THESIS_DATA / f"{name}.csv"


#: Suffixes of the configuration, model and thesis-data files every page depends on besides its code.
DATA_SUFFIXES = frozenset({".yaml", ".yml", ".csv", ".json", ".xml"})


def data_files() -> list[Path]:
    """Configuration, model and thesis-data files (``thesis_repro/``, ``data/thesis/``): every page depends on all."""
    found = [p for root in (PACKAGE, THESIS_DATA) for p in root.rglob("*") if p.suffix in DATA_SUFFIXES]
    return sorted(p for p in found if p.is_file())


def all_modules() -> list[Path]:
    """Every module of the kit (the dependencies of numbers whose own are unknown)."""
    return sorted(p for p in PACKAGE.rglob("*.py") if "__pycache__" not in p.parts)


def imported_modules() -> list[str]:
    """The kit modules this process has imported, as sorted paths relative to the repository.

    >>> "thesis_repro/core/paths.py" in imported_modules()
    True
    """
    root = str(PACKAGE) + os.sep
    files = {getattr(m, "__file__", None) or "" for m in list(sys.modules.values())}
    return sorted(Path(f).relative_to(ROOT).as_posix() for f in files if f.startswith(root))


def files_hash(files: list[Path]) -> str:
    """SHA-256 over each file's repository-relative path and bytes (``<missing>`` for a missing file)."""
    h = hashlib.sha256()
    for p in sorted(set(files)):
        h.update(str(p.relative_to(ROOT) if p.is_relative_to(ROOT) else p).encode())
        h.update(p.read_bytes() if p.exists() else b"<missing>")
    return h.hexdigest()
