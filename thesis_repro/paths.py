"""Every location the kit reads or writes, in one place.

Override the run cache with ``THESIS_REPRO_DATA`` (tests point it at a temporary folder), the shipped
reference runs with ``THESIS_REPRO_REFERENCE`` and the build folder with ``THESIS_REPRO_BUILD``;
``THESIS_REPRO_RETRAIN=1`` (``make ... RETRAIN=1``) ignores the shipped runs.

>>> from thesis_repro import paths
>>> paths.notebook("3.3").name
'fig-3.3.py'
"""

from __future__ import annotations

import hashlib
import os
from functools import cache
from pathlib import Path

ROOT: Path = Path(__file__).resolve().parent.parent
PACKAGE: Path = ROOT / "thesis_repro"
CONFIG: Path = PACKAGE / "config"
NOTEBOOKS: Path = ROOT / "notebooks"
THESIS_DATA: Path = ROOT / "data" / "thesis"
#: Other projects' published numbers (CleanRL, the SB3 zoo), neither the thesis's nor ours.
PUBLIC_DATA: Path = ROOT / "data" / "public"
BOOK: Path = ROOT / "book"


def runs() -> Path:
    """Root of the content-addressed run cache (``data/runs`` unless ``THESIS_REPRO_DATA`` is set)."""
    return Path(os.environ.get("THESIS_REPRO_DATA", ROOT / "data" / "runs"))


def reference() -> Path:
    """Shipped read-only layer of finished ``small`` runs: training runs and chapter 5's results
    (``data/reference`` unless ``THESIS_REPRO_REFERENCE`` is set); consulted after the local run cache."""
    return Path(os.environ.get("THESIS_REPRO_REFERENCE", ROOT / "data" / "reference"))


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


def build(scale: str) -> Path:
    """Root of generated artefacts for one scale: executed notebooks and figures."""
    return Path(os.environ.get("THESIS_REPRO_BUILD", ROOT / "build")) / scale


PUBLISHED_ENV = "THESIS_REPRO_PUBLISHED_BUILD"


def published_figures(scale: str) -> Path:
    """Figure folder of finished pages. Inside a notebook's kernel, :func:`build` is the notebook's staging folder
    and ``THESIS_REPRO_PUBLISHED_BUILD`` names the build folder it will move to, so a page can read what other
    pages saved (a claim judged on Table 3.4 and repeated on Fig 3.7); elsewhere the same as :func:`figures`."""
    root = os.environ.get(PUBLISHED_ENV)
    return Path(root) / scale / "figures" if root else figures(scale)


def page_output(scale: str, name: str) -> Path:
    """``figures(scale) / name`` if this run wrote it, else the finished pages' copy (:func:`published_figures`).

    >>> page_output("smoke", "no-such-page.data.json") == published_figures("smoke") / "no-such-page.data.json"
    True
    """
    own = figures(scale) / name
    return own if own.exists() else published_figures(scale) / name


def executed(scale: str) -> Path:
    """Folder of notebooks executed at ``scale``."""
    return build(scale) / "notebooks"


def figures(scale: str) -> Path:
    """Folder where notebooks save their figure files at ``scale``."""
    return build(scale) / "figures"


def notebook(figure: str) -> Path:
    """Source (jupytext percent ``.py``) of a notebook id: ``"3.3"``, ``"table-3.4"``, ``"analysis-4-kl"``."""
    name = figure if figure.startswith(("fig-", "table-", "analysis-")) else f"fig-{figure}"
    return NOTEBOOKS / f"{name}.py"


def thesis_table(name: str) -> Path:
    """A transcribed reference table of the thesis, e.g. ``thesis_table("fig3_3c")``."""
    return THESIS_DATA / f"{name}.csv"


@cache
def kit_stamp() -> str:
    """Short hash of what a page's saved numbers depend on besides its runs: the kit's code and configuration
    (``thesis_repro/**/*.py``, ``*.yaml``), the notebooks (``notebooks/*.py``) and the thesis's numbers and
    claims (``data/thesis/``). Saved with the numbers, so numbers written by other kit code are reported as stale
    instead of judged silently.

    >>> len(kit_stamp()) == 12 and kit_stamp() == kit_stamp()
    True
    """
    code = sorted(f for f in [*PACKAGE.rglob("*.py"), *PACKAGE.rglob("*.yaml")] if "__pycache__" not in f.parts)
    thesis = sorted(f for f in THESIS_DATA.rglob("*") if f.is_file())
    h = hashlib.sha256()
    for base, files in ((PACKAGE, code), (NOTEBOOKS, sorted(NOTEBOOKS.glob("*.py"))), (THESIS_DATA, thesis)):
        for f in files:
            h.update(f.relative_to(base).as_posix().encode() + b"\0" + f.read_bytes())
    return h.hexdigest()[:12]
