"""The package's shape: no import circles between its modules, no imports of other modules' private names.

Every ``import`` and ``from ... import`` of a ``uavsim`` module counts, at the top
of a file or inside a function (an import deferred into a function still ties
the two modules together; deferring it only hides the circle). Imports of the
root package ``uavsim`` itself do not count: it is the lazy facade of the
public API, and importing any ``uavsim.x`` imports it first anyway.
"""

from __future__ import annotations

import ast
from pathlib import Path

import uavsim

ROOT = Path(uavsim.__file__).parent

#: private names imported across modules, each with its way out (none today)
KNOWN_PRIVATE: set[tuple[str, str, str]] = set()


def _modules() -> dict[str, Path]:
    out = {}
    for p in ROOT.rglob("*.py"):
        parts = list(p.relative_to(ROOT.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = p
    return out


def _imports(mods: dict[str, Path]) -> tuple[dict[str, set[str]], set[tuple[str, str, str]]]:
    """Module -> the uavsim modules it imports; and every (importer, module, private name) imported."""
    graph: dict[str, set[str]] = {m: set() for m in mods}
    private = set()
    for m, path in mods.items():
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0 and (
                    node.module == "uavsim" or node.module.startswith("uavsim.")):
                for a in node.names:
                    sub = f"{node.module}.{a.name}"
                    graph[m].add(sub if sub in mods else node.module)
                    if a.name.startswith("_") and not a.name.startswith("__") and node.module != m:
                        private.add((m, node.module, a.name))
            elif isinstance(node, ast.Import):
                graph[m].update(a.name for a in node.names if a.name in mods)
        graph[m].discard("uavsim")
        graph[m].discard(m)
    return graph, private


def _cycles(graph: dict[str, set[str]]) -> list[set[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[set[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = set()
            while True:
                w = stack.pop()
                on.discard(w)
                comp.add(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(comp)

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_the_checks_see_circles_and_private_names(tmp_path):
    # the checks themselves: a made-up circle and a private import are found
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [{"a", "b", "c"}]
    graph, _ = _imports(_modules())
    assert "uavsim.sim.runner" in graph["uavsim.data.episodes"]
    fake = tmp_path / "fake.py"
    fake.write_text("from uavsim.tuning.grid import _hidden, Grid\n")
    _, private = _imports({**_modules(), "uavsim.fake": fake})
    assert ("uavsim.fake", "uavsim.tuning.grid", "_hidden") in private


def test_no_import_circles():
    graph, _ = _imports(_modules())
    cycles = sorted(_cycles(graph), key=sorted)
    assert cycles == [], f"import circles between modules: {[sorted(c) for c in cycles]}"


def test_no_private_names_imported_from_other_modules():
    _, private = _imports(_modules())
    assert private == KNOWN_PRIVATE, f"private names imported: {sorted(private - KNOWN_PRIVATE)}; " \
                                     f"no longer imported (drop from KNOWN_PRIVATE): {sorted(KNOWN_PRIVATE - private)}"


def test_package_docstrings_say_what_the_package_is():
    for init in sorted(ROOT.rglob("__init__.py")):
        doc = ast.get_docstring(ast.parse(init.read_text())) or ""
        assert len(doc.split()) >= 8 and "TODO" not in doc, f"{init}: package docstring {doc!r}"
