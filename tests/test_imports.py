"""No import circles inside ``thesis_repro``: an AST walk over every module's imports (nested ones too,
as :func:`tests.test_layers.imported` reads them) finds every set of modules that import each other in a circle.

A submodule's import of its own package (``figures/ch3.py``: ``from thesis_repro.figures import register``) is not
an edge: Python initialises the package before any of its submodules, so the package is always first.
"""

from __future__ import annotations

from tests.test_layers import imported, sources


def graph(imports: dict[str, set[str]]) -> dict[str, set[str]]:
    """Module -> the package modules it imports, without its own packages and itself."""
    return {m: {t for t in ts if t in imports and t != m and not m.startswith(t + ".")} for m, ts in imports.items()}


def circles(edges: dict[str, set[str]]) -> set[frozenset[str]]:
    """The strongly connected components of more than one module (Tarjan's algorithm, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: set[frozenset[str]] = set()
    for root in sorted(edges):
        if root in index:
            continue
        work = [(root, iter(sorted(edges[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(edges[child]))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = set()
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.add(member)
                    if member == node:
                        break
                if len(component) > 1:
                    found.add(frozenset(component))
    return found


def package_circles() -> set[frozenset[str]]:
    return circles(graph({name: imported(path) for name, path in sources().items()}))


def test_no_import_circles_inside_the_package():
    new = package_circles()
    assert not new, "import circles: " + "; ".join(" <-> ".join(sorted(c)) for c in sorted(new, key=sorted))


def test_the_walk_finds_circles_of_any_length_and_nothing_else():
    edges = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}, "e": {"e"}, "p": set(), "p.q": {"p"}}
    assert circles(graph({k: set(v) for k, v in edges.items()})) == {frozenset("abc")}
    nested = imported(
        sources()["thesis_repro.envs"], text="def f():\n    from thesis_repro.runs import layer as runs\n"
    )
    assert "thesis_repro.runs.layer" in nested  # an import inside a function is an edge too


def missing_names(text: str) -> list[str]:
    """``module.name`` of every ``from thesis_repro... import name`` in ``text`` (nested imports too) whose module
    has no such attribute or submodule: a name a split moved away fails only when its code path runs."""
    import ast
    import importlib

    missing = []
    for node in ast.walk(ast.parse(text)):
        if not (
            isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").startswith("thesis_repro")
        ):
            continue
        module = importlib.import_module(node.module)
        for alias in node.names:
            if alias.name == "*" or hasattr(module, alias.name):
                continue
            try:
                importlib.import_module(f"{node.module}.{alias.name}")
            except ModuleNotFoundError:
                missing.append(f"{node.module}.{alias.name}")
    return missing


def test_every_package_import_names_something_that_exists():
    """``study.produce`` imported ``runs._die_with_parent`` and ``runs.git_commit`` after they had moved; nothing
    noticed, as the import sits in a function no test ran."""
    found = {name: missing_names(path.read_text()) for name, path in sources().items()}
    assert not {k: v for k, v in found.items() if v}
    assert missing_names("def f():\n    from thesis_repro.runs.layer import nothing_here\n") == [
        "thesis_repro.runs.layer.nothing_here"
    ]
