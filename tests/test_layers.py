"""Imports run one way (issue 21): figures compute numbers, the claims layer judges them.

An AST scan of the sources (every import, also those inside functions): no figure module imports the claims
layer or defines a verdict function; the claims layer never imports the figure layer; ``runs.py`` needs only
the figure registry (job lists), never a chapter module or the claims layer.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import thesis_repro

ROOT = Path(thesis_repro.__file__).parent
FIGURES = sorted((ROOT / "figures").glob("*.py"))
CLAIMS = sorted((ROOT / "claims").glob("*.py"))
#: What builds a verdict (thesis_repro.report); a figure module may still use its status labels (NOT_RUN).
JUDGING = {"Verdict", "status", "decide"}


def imported(path: Path) -> set[str]:
    """Every module ``path`` imports, as dotted names (``from a import b`` gives ``a`` and ``a.b``)."""
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module:
            out |= {node.module, *(f"{node.module}.{a.name}" for a in node.names)}
    return out


def reaches(path: Path, package: str) -> list[str]:
    return sorted(m for m in imported(path) if m == package or m.startswith(package + "."))


def test_the_scan_sees_the_imports_it_checks():
    assert FIGURES and CLAIMS
    assert "thesis_repro.figures" in imported(ROOT / "runs.py")
    assert "thesis_repro.claims.ledger" in imported(ROOT / "claims" / "__init__.py")


@pytest.mark.parametrize("path", FIGURES, ids=lambda p: p.name)
def test_figure_modules_neither_import_the_claims_layer_nor_judge(path):
    assert not reaches(path, "thesis_repro.claims"), f"{path.name} imports the claims layer"
    tree = ast.parse(path.read_text())
    verdicts = [
        n.name
        for n in ast.walk(tree)
        if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef)
        and (n.name.endswith(("_verdict", "_verdicts")) or n.name.startswith("verdict") or n.name == "judge")
    ]
    assert not verdicts, f"{path.name} defines verdict functions {verdicts}: judging belongs in thesis_repro.claims"
    judging = [
        n.attr
        for n in ast.walk(tree)
        if isinstance(n, ast.Attribute) and isinstance(n.value, ast.Name) and n.value.id == "report"
        if n.attr in JUDGING
    ]
    judging += [m for m in imported(path) if m in {f"thesis_repro.report.{j}" for j in JUDGING}]
    assert not judging, f"{path.name} builds verdicts ({sorted(set(judging))}): judging belongs in thesis_repro.claims"


@pytest.mark.parametrize("path", CLAIMS, ids=lambda p: p.name)
def test_the_claims_layer_never_imports_the_figure_layer(path):
    assert not reaches(path, "thesis_repro.figures"), f"claims/{path.name} imports the figure layer"


def test_runs_needs_only_the_figure_registry():
    mods = imported(ROOT / "runs.py")
    assert not reaches(ROOT / "runs.py", "thesis_repro.claims")
    chapters = {f"thesis_repro.figures.{p.stem}" for p in FIGURES if p.stem != "__init__"}
    assert not mods & chapters, sorted(mods & chapters)
