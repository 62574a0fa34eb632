"""Execute the figure notebooks (jupytext percent ``.py`` files) with papermill.

>>> sorted(n for n in notebook_ids() if n.startswith("3."))[:1]  # doctest: +SKIP
['3.2']
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

from thesis_repro import paths
from thesis_repro.scales import check_scale
from thesis_repro.validation import check_choice


def notebook_ids() -> list[str]:
    """Ids of every notebook: ``"3.3"`` for ``notebooks/fig-3.3.py``, ``"table-3.4"`` for tables."""
    ids = []
    for p in sorted(paths.NOTEBOOKS.glob("*.py")):
        stem = p.stem
        if stem.startswith("fig-"):
            ids.append(stem[4:])
        elif stem.startswith("table-"):
            ids.append(stem)
    return sorted(ids, key=_sort_key)


def _sort_key(nid: str) -> tuple:
    parts = nid.replace("table-", "").split(".")
    return (nid.startswith("table-"), *[int(p) if p.isdigit() else 0 for p in parts], nid)


def check_notebook(nid: str) -> str:
    """Normalise ``"fig-3.3"``/``"3.3"`` to ``"3.3"`` and check that the notebook exists."""
    nid = nid[4:] if nid.startswith("fig-") else nid
    return check_choice(nid, notebook_ids(), "figure")


def executed_path(nid: str, scale: str) -> Path:
    name = nid if nid.startswith("table-") else f"fig-{nid}"
    return paths.executed(scale) / f"{name}.ipynb"


def execute(nid: str, scale: str, parameters: dict[str, Any] | None = None, log: bool = True) -> Path:
    """Execute notebook ``nid`` at ``scale`` and return the path of the executed ``.ipynb``."""
    import jupytext
    import papermill as pm

    nid = check_notebook(nid)
    check_scale(scale)
    src = paths.notebook(nid)
    out = executed_path(nid, scale)
    out.parent.mkdir(parents=True, exist_ok=True)
    paths.figures(scale).mkdir(parents=True, exist_ok=True)
    nb = jupytext.read(src)
    nb.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3", "language": "python"}
    staged = out.with_suffix(".source.ipynb")
    jupytext.write(nb, staged)
    params = {"SCALE": scale, **(parameters or {})}
    os.environ.setdefault("MUJOCO_GL", "egl")
    t0 = time.time()
    try:
        pm.execute_notebook(
            str(staged),
            str(out),
            parameters=params,
            cwd=str(paths.ROOT),
            kernel_name="python3",
            progress_bar=False,
            log_output=log,
        )
    finally:
        staged.unlink(missing_ok=True)
    if log:
        print(f"[thesis_repro] executed {src.name} at scale={scale} in {time.time() - t0:.1f}s -> {out}")
    return out
