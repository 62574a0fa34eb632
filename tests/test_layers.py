"""Imports run one way: figures compute numbers, the claims layer judges them.

An AST scan of the sources (every import, also those inside functions): no figure module imports the claims
layer or defines a verdict function; the claims layer never imports the figure layer; ``runs.py`` and its siblings
(``shipped_checks``, ``retrain_check``, ``generator``) need only the figure registry (job lists), never a chapter
module or the claims layer.

The direction is ``runs -> figures``, ``budgets -> figures, runs`` and ``pages -> figures, runs, budgets``: no
figure module imports ``runs``, ``budgets`` or the claims layer, directly or through any other module of the
package (what a page prints about its runs lives in :mod:`thesis_repro.book.pages`).

The whole package follows the package map of ``thesis_repro/__init__.py``: each layer, one folder each (core; envs;
learners, mdl, arm; evaluation; figures; runs; claims; book; command line) imports only itself and the layers below.

One name per idea: no two modules define public module-level functions of the same name, unless the name means the
same thing in each (:data:`SAME_NAME_SAME_IDEA`, each entry with its reason).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import thesis_repro

ROOT = Path(thesis_repro.__file__).parent
FIGURES = sorted((ROOT / "figures").glob("*.py"))
CLAIMS = sorted((ROOT / "claims").rglob("*.py"))
#: The layer folders that import the figure registry, so the figure layer imports none of them (imports run one way).
ABOVE_FIGURES = ("thesis_repro.runs", "thesis_repro.claims", "thesis_repro.book", "thesis_repro.cli")
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
    assert "thesis_repro.figures" in imported(ROOT / "runs" / "layer.py")
    assert "thesis_repro.claims.page_verdicts" in imported(ROOT / "claims" / "__init__.py")
    # the forms a back-import could take in a figure module: nested, aliased, relative, dynamic
    probe = (
        "def f():\n"
        "    from thesis_repro.runs import layer\n"
        "    import thesis_repro.runs.budgets as b\n"
        "    from .. import claims\n"
        "    importlib.import_module('thesis_repro.book.pages')\n"
    )
    found = imported(ROOT / "figures" / "probe.py", text=probe)
    assert {
        "thesis_repro.runs.layer",
        "thesis_repro.runs.budgets",
        "thesis_repro.claims",
        "thesis_repro.book.pages",
    } <= found


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
        "so imports run one way (a page's runs summary and claim meta live in thesis_repro.book.pages)"
    )


def test_the_figure_layer_reaches_nothing_that_imports_it():
    """No detour either: no module the figure layer imports (transitively, also at call time) imports
    ``runs``/``budgets``/the claims layer, so ``runs -> figures`` is the only edge between them."""
    modules = sources()
    for path in FIGURES:
        reached = closure(module_name(path), modules)
        back = sorted(m for m in reached for up in ABOVE_FIGURES if m == up or m.startswith(up + "."))
        assert not back, f"figures/{path.name} reaches {back}"
        assert not {"thesis_repro.runs.study", "thesis_repro.cli.verify"} & reached, (
            f"figures/{path.name} reaches {reached}"
        )


def test_pages_sits_above_figures_runs_and_budgets():
    mods = imported(ROOT / "book" / "pages.py")
    assert {"thesis_repro.figures", "thesis_repro.runs.layer", "thesis_repro.runs.budgets"} <= mods
    assert "thesis_repro.figures" in imported(ROOT / "runs" / "budgets.py")
    from thesis_repro import figures
    from thesis_repro.book import pages

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


@pytest.mark.parametrize("name", ["layer.py", "shipped_checks.py", "retrain_check.py", "generator.py", "needs.py"])
def test_the_run_modules_need_only_the_figure_registry(name):
    mods = imported(ROOT / "runs" / name)
    assert not reaches(ROOT / "runs" / name, "thesis_repro.claims")
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


def test_the_package_map_names_one_folder_per_layer_and_places_every_module():
    layers = package_map()
    assert [name for name, _ in layers] == [
        "core", "envs", "learners, mdl, arm", "evaluation", "figures", "runs", "claims", "book", "command line",
    ]  # fmt: skip
    folders = sorted(p.name for p in ROOT.iterdir() if (p / "__init__.py").is_file())
    mapped = {prefix.removeprefix("thesis_repro.") for _, prefixes in layers for prefix in prefixes}
    assert set(folders) <= mapped, f"folders the package map does not name: {sorted(set(folders) - mapped)}"
    top = sorted(p.name for p in ROOT.iterdir() if p.name not in {"__init__.py", "__main__.py", "__pycache__"})
    assert [p for p in top if p.endswith(".py")] == [], f"modules outside the layer folders: {top}"
    assert len(top) <= 12, f"the package map fits one screen: {len(top)} top-level entries {top}"
    for name in top:
        face = ROOT / name / "__init__.py"
        doc = ast.get_docstring(ast.parse(face.read_text())) if face.is_file() else "Data, no module."
        assert doc and doc.splitlines()[0].endswith("."), f"thesis_repro/{name}: a docstring opening with one line"
    unmapped = sorted(m for m in sources() if layer_of(m, layers) is None)
    assert not unmapped, f"modules the package map (thesis_repro/__init__.py) does not place: {unmapped}"


def test_each_layer_imports_only_downward():
    up = upward_imports({name: imported(path) for name, path in sources().items()}, package_map())
    assert not up, "imports against the package map (thesis_repro/__init__.py):\n" + "\n".join(up)


def test_the_layer_check_catches_an_upward_import():
    probe = imported(ROOT / "envs" / "probe.py", text="def f():\n    from thesis_repro.runs import layer as runs\n")
    imports = {"thesis_repro.envs.probe": probe, "thesis_repro.runs.layer": set()}
    assert upward_imports(imports, package_map()) == [
        "thesis_repro.envs.probe (envs) -> thesis_repro.runs.layer (runs)"
    ]


def test_a_page_s_metadata_never_loads_the_generator():
    """What a figure needs is a pure question (:mod:`thesis_repro.runs.needs`): the page module, its claim meta
    and budgets answer it without importing the reference-run generator."""
    import subprocess
    import sys

    code = (
        "import sys\n"
        "from thesis_repro.book import pages\n"
        "from thesis_repro.runs import budgets\n"
        "budgets.ordered_training_jobs('smoke', ['3.3'])\n"
        "print('thesis_repro.runs.generator' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False", out.stderr


#: Public module-level functions that several modules define on purpose, each meaning the same thing in every one
#: of them: name -> the modules allowed to define it (``None``: any module). Anything else is one name per idea.
SAME_NAME_SAME_IDEA: dict[str, set[str] | None] = {
    # ``python -m <module>``'s entry point: every runnable module has its own, and each means just that.
    "main": None,
    # Holm's step-down over a claim's family of pooled tests: each frozen design's judge keeps its own copy (v2's
    # pools Pooled, v3's PooledTest), so that changing one design's statistics cannot move the other's verdicts.
    "holm_outcome": {"thesis_repro.claims.judge", "thesis_repro.claims.judge_v3"},
}


def public_functions(modules: dict[str, Path], texts: dict[str, str] | None = None) -> dict[str, list[str]]:
    """Public (no leading underscore) module-level function name -> the modules that define it (methods, classes
    and imported names do not count). ``texts`` replaces some modules' sources."""
    out: dict[str, list[str]] = {}
    for name, path in modules.items():
        text = (texts or {}).get(name)
        for node in ast.parse(path.read_text() if text is None else text, str(path)).body:
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef) and not node.name.startswith("_"):
                out.setdefault(node.name, []).append(name)
    return out


def shared_names(defined: dict[str, list[str]]) -> list[str]:
    """One line per public function name that more than one module defines, outside :data:`SAME_NAME_SAME_IDEA`."""
    out = []
    for fn, modules in sorted(defined.items()):
        allowed = SAME_NAME_SAME_IDEA.get(fn, set())
        if len(modules) > 1 and not (allowed is None or set(modules) <= allowed):
            out.append(f"{fn}: {', '.join(sorted(modules))}")
    return out


def test_no_two_modules_define_a_public_function_of_the_same_name():
    """One name per idea: two modules never define public functions of the same name, except the deliberate
    same-meaning ones of :data:`SAME_NAME_SAME_IDEA`. Rename the less apt one to say what it returns or does."""
    shared = shared_names(public_functions(sources()))
    assert not shared, "public functions defined in more than one module:\n" + "\n".join(shared)


def test_the_name_check_catches_a_shared_name():
    modules = sources()
    probe = {"thesis_repro.envs.registry": "def build_dir(scale):\n    return scale\n"}
    assert "build_dir: thesis_repro.core.paths, thesis_repro.envs.registry" in shared_names(
        public_functions(modules, probe)
    )
    allowed = {"thesis_repro.envs.registry": "def main():\n    return 0\n"}
    assert not shared_names(public_functions(modules, allowed))
