"""Imports run one way (issue 21): figures compute numbers, the claims layer judges them.

An AST scan of the sources (every import, also those inside functions): no figure module imports the claims
layer or defines a verdict function; the claims layer never imports the figure layer; ``runs.py`` and its siblings
(``shipped_checks``, ``retrain_check``, ``generator``) need only the figure registry (job lists), never a chapter
module or the claims layer.

The direction is ``runs -> figures``, ``budgets -> figures, runs`` and ``pages -> figures, runs, budgets``: no
figure module imports ``runs``, ``budgets`` or the claims layer, directly or through any other module of the
package (what a page prints about its runs lives in :mod:`thesis_repro.pages`).

The whole package follows the package map of ``thesis_repro/__init__.py``: each layer (core; store and backends;
envs; learners, mdl, arm; evaluation; figures; runs; claims; book and CLI) imports only itself and the layers below.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import thesis_repro

ROOT = Path(thesis_repro.__file__).parent
FIGURES = sorted((ROOT / "figures").glob("*.py"))
CLAIMS = sorted((ROOT / "claims").rglob("*.py"))
#: What imports the figure registry, so the figure layer must not import it (issue 21: imports run one way).
ABOVE_FIGURES = (
    "thesis_repro.runs",
    "thesis_repro.shipped_checks",
    "thesis_repro.retrain_check",
    "thesis_repro.generator",
    "thesis_repro.budgets",
    "thesis_repro.claims",
    "thesis_repro.pages",
)
#: What builds a verdict (thesis_repro.claims.report); a figure module imports none of it (NOT_RUN is scales').
JUDGING = {"Verdict", "status", "decide"}


def module_name(path: Path) -> str:
    """``thesis_repro/figures/ch3.py`` -> ``thesis_repro.figures.ch3`` (a package's ``__init__`` is the package)."""
    parts = path.relative_to(ROOT.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imported(path: Path, text: str | None = None) -> set[str]:
    """Every module ``path`` imports, as dotted names (``from a import b`` gives ``a`` and ``a.b``).

    Relative imports are resolved against ``path``'s package; ``importlib.import_module("x")`` and
    ``__import__("x")`` with a literal name count as imports of ``x``. ``text`` replaces the file's source.
    """
    package = module_name(path).split(".")
    if path.name != "__init__.py":
        package = package[:-1]
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text() if text is None else text, str(path))):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join([*package[: len(package) - node.level + 1], *([base] if base else [])])
            out |= {base, *(f"{base}.{a.name}" for a in node.names)}
        elif isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant):
            func = node.func
            name = func.attr if isinstance(func, ast.Attribute) else func.id if isinstance(func, ast.Name) else ""
            if name in {"import_module", "__import__"} and isinstance(node.args[0].value, str):
                out.add(node.args[0].value)
    return out


def reaches(path: Path, package: str) -> list[str]:
    return sorted(m for m in imported(path) if m == package or m.startswith(package + "."))


def test_the_scan_sees_the_imports_it_checks():
    assert FIGURES and CLAIMS
    assert "thesis_repro.figures" in imported(ROOT / "runs.py")
    assert "thesis_repro.claims.page_verdicts" in imported(ROOT / "claims" / "__init__.py")
    # the forms a back-import could take in a figure module: nested, aliased, relative, dynamic
    probe = (
        "def f():\n"
        "    from thesis_repro import runs\n"
        "    import thesis_repro.budgets as b\n"
        "    from .. import claims\n"
        "    importlib.import_module('thesis_repro.pages')\n"
    )
    found = imported(ROOT / "figures" / "probe.py", text=probe)
    assert {"thesis_repro.runs", "thesis_repro.budgets", "thesis_repro.claims", "thesis_repro.pages"} <= found, found


def sources() -> dict[str, Path]:
    """Every module of the package by dotted name."""
    return {module_name(p): p for p in sorted(ROOT.rglob("*.py"))}


def closure(start: str, modules: dict[str, Path]) -> set[str]:
    """Every package module ``start`` reaches through imports (nested ones too; ``a.b.c`` also imports ``a.b``)."""
    seen: set[str] = set()
    todo = [start]
    while todo:
        for name in imported(modules[todo.pop()]):
            parts = name.split(".")
            for i in range(1, len(parts) + 1):
                mod = ".".join(parts[:i])
                if mod in modules and mod not in seen:
                    seen.add(mod)
                    todo.append(mod)
    return seen


@pytest.mark.parametrize("path", FIGURES, ids=lambda p: p.name)
def test_figure_modules_import_neither_runs_budgets_nor_claims(path):
    back = sorted(m for m in imported(path) for up in ABOVE_FIGURES if m == up or m.startswith(up + "."))
    assert not back, (
        f"figures/{path.name} imports {back}: runs, budgets and the claims layer import the figure layer, "
        "so imports run one way (a page's runs summary and claim meta live in thesis_repro.pages)"
    )


def test_the_figure_layer_reaches_nothing_that_imports_it():
    """No detour either: no module the figure layer imports (transitively, also at call time) imports
    ``runs``/``budgets``/the claims layer, so ``runs -> figures`` is the only edge between them."""
    modules = sources()
    for path in FIGURES:
        reached = closure(module_name(path), modules)
        back = sorted(m for m in reached for up in ABOVE_FIGURES if m == up or m.startswith(up + "."))
        assert not back, f"figures/{path.name} reaches {back}"
        assert not {"thesis_repro.study", "thesis_repro.verify"} & reached, f"figures/{path.name} reaches {reached}"


def test_pages_sits_above_figures_runs_and_budgets():
    mods = imported(ROOT / "pages.py")
    assert {"thesis_repro.figures", "thesis_repro.runs", "thesis_repro.budgets"} <= mods
    assert "thesis_repro.figures" in imported(ROOT / "budgets.py")
    from thesis_repro import figures, pages

    for name in ("runs_summary", "claim_meta"):
        assert callable(getattr(pages, name)) and not hasattr(figures, name)
        assert name not in figures.__all__
    assert set(figures.__all__) <= set(dir(figures))


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
    judging += [m for m in imported(path) if m in {f"thesis_repro.claims.report.{j}" for j in JUDGING}]
    assert not judging, f"{path.name} builds verdicts ({sorted(set(judging))}): judging belongs in thesis_repro.claims"


@pytest.mark.parametrize("path", CLAIMS, ids=lambda p: p.relative_to(ROOT / "claims").as_posix())
def test_the_claims_layer_never_imports_the_figure_layer(path):
    where = path.relative_to(ROOT).as_posix()
    assert not reaches(path, "thesis_repro.figures"), f"{where} imports the figure layer"


@pytest.mark.parametrize("name", ["runs.py", "shipped_checks.py", "retrain_check.py", "generator.py"])
def test_the_run_modules_need_only_the_figure_registry(name):
    mods = imported(ROOT / name)
    assert not reaches(ROOT / name, "thesis_repro.claims")
    chapters = {f"thesis_repro.figures.{p.stem}" for p in FIGURES if p.stem != "__init__"}
    assert not mods & chapters, sorted(mods & chapters)


# ------------------------------------------------------------------ the package map: each layer imports downward
def package_map() -> list[tuple[str, list[str]]]:
    """The layers of the package docstring (``thesis_repro/__init__.py``), bottom up: (name, module prefixes)."""
    import re

    layers = []
    for m in re.finditer(r"^\d+\. \*\*(.+?)\*\*: (.+?) --", thesis_repro.__doc__ or "", re.M | re.S):
        names = re.findall(r"``([\w.]+)``", m.group(2))
        layers.append((m.group(1), [n if n == "thesis_repro" else f"thesis_repro.{n}" for n in names]))
    return layers


def layer_of(module: str, layers: list[tuple[str, list[str]]]) -> int | None:
    """The index of ``module``'s layer: the one naming its longest prefix (``claims.cli`` before ``claims``)."""
    best: tuple[int, int] | None = None
    for i, (_, prefixes) in enumerate(layers):
        for p in prefixes:
            if (module == p or module.startswith(p + ".")) and (best is None or len(p) > best[1]):
                best = (i, len(p))
    return None if best is None else best[0]


def upward_imports(imports: dict[str, set[str]], layers: list[tuple[str, list[str]]]) -> list[str]:
    """Every import (module -> what it imports, nested ones too) of a module from a higher layer, as
    ``"a (layer) -> b (layer)"``."""
    out = []
    for name, names in imports.items():
        mine = layer_of(name, layers)
        for target in sorted(names & set(imports)):
            theirs = layer_of(target, layers)
            if name.startswith(target + ".") or mine is None or theirs is None:
                continue  # a submodule's own package, or a module the map misses (its own test fails)
            if theirs > mine:
                out.append(f"{name} ({layers[mine][0]}) -> {target} ({layers[theirs][0]})")
    return out


def test_the_package_map_lists_the_layers_of_the_issue_and_every_module():
    layers = package_map()
    assert [name for name, _ in layers] == [
        "core", "store and backends", "envs", "learners, mdl, arm", "evaluation", "figures", "runs", "claims",
        "book and CLI",
    ]  # fmt: skip
    unmapped = sorted(m for m in sources() if layer_of(m, layers) is None)
    assert not unmapped, f"modules the package map (thesis_repro/__init__.py) does not place: {unmapped}"


def test_each_layer_imports_only_downward():
    up = upward_imports({name: imported(path) for name, path in sources().items()}, package_map())
    assert not up, "imports against the package map (thesis_repro/__init__.py):\n" + "\n".join(up)


def test_the_layer_check_catches_an_upward_import():
    probe = imported(ROOT / "envs" / "probe.py", text="def f():\n    from thesis_repro import runs\n")
    imports = {"thesis_repro.envs.probe": probe, "thesis_repro.runs": set()}
    assert upward_imports(imports, package_map()) == ["thesis_repro.envs.probe (envs) -> thesis_repro.runs (runs)"]
