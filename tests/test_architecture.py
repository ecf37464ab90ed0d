"""The import graph of facesim/ (issue 13): every ``import`` and ``from ... import`` of the package
read with ``ast`` -- lazy imports inside functions included, ``if TYPE_CHECKING:`` blocks left out
(they never run) -- has no cycle among modules and none among the top-level packages
(``facesim.fem``, ``facesim.inverse``, ...; a top-level module such as ``facesim.simulate`` or
``facesim.cli`` is a node of its own, as is the ``facesim`` package itself). The layers at the
bottom stay there: the jaw rigs do not import the bone kinematics (kinematics imports jaw), and
``facesim.se3`` and ``facesim._files`` import nothing of facesim but its errors."""

import ast
from pathlib import Path

import facesim

PACKAGE = Path(facesim.__file__).resolve().parent


def _modules() -> dict[str, Path]:
    mods = {}
    for f in PACKAGE.rglob("*.py"):
        parts = list(f.relative_to(PACKAGE.parent).with_suffix("").parts)
        mods[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = f
    return mods


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or \
        (isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _imports(tree: ast.AST):
    """Every Import / ImportFrom node of ``tree``, at any depth, outside ``if TYPE_CHECKING:`` bodies
    (their ``else:`` branches run and are kept)."""
    stack = [tree]
    while stack:
        node = stack.pop()
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            yield node
        if isinstance(node, ast.If) and _is_type_checking(node.test):
            stack.extend(node.orelse)
            continue
        stack.extend(ast.iter_child_nodes(node))


def import_graph() -> tuple[dict[str, set[str]], dict[str, set[str]]]:
    """(facesim module -> the facesim modules it imports, module -> the outside top-level names it imports).

    ``from facesim.a import b`` is an edge to ``facesim.a.b`` when that is a module, else to
    ``facesim.a``; relative imports are resolved against the importing module's package."""
    mods = _modules()

    def known(name):
        while name and name not in mods:
            name = name.rpartition(".")[0]
        return name

    inner, outer = {m: set() for m in mods}, {m: set() for m in mods}
    for m, f in mods.items():
        package = m.split(".") if f.name == "__init__.py" else m.split(".")[:-1]
        for node in _imports(ast.parse(f.read_text(encoding="utf-8"), str(f))):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            else:
                base = node.module or ""
                if node.level:
                    base = ".".join(package[:len(package) - node.level + 1] + ([base] if base else []))
                names = [f"{base}.{a.name}" if f"{base}.{a.name}" in mods else base for a in node.names]
            for name in names:
                if name.split(".")[0] == "facesim":
                    if known(name) != m:
                        inner[m].add(known(name))
                else:
                    outer[m].add(name.split(".")[0])
    return inner, outer


def top_level(module: str) -> str:
    """The node of ``module`` in the package graph: ``facesim.inverse.tracking`` -> ``facesim.inverse``,
    ``facesim.simulate`` -> itself, ``facesim`` -> itself."""
    return ".".join(module.split(".")[:2])


def package_graph(inner: dict[str, set[str]]) -> dict[str, set[str]]:
    graph: dict[str, set[str]] = {}
    for m, targets in inner.items():
        graph.setdefault(top_level(m), set())
        for t in targets:
            if top_level(t) != top_level(m):
                graph[top_level(m)].add(top_level(t))
                graph.setdefault(top_level(t), set())
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one node (Tarjan)."""
    index, low, stack, on, found = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while not component or component[-1] != v:
                component.append(stack.pop())
                on.discard(component[-1])
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def _in(module: str, parts) -> bool:
    return any(module == p or module.startswith(p + ".") for p in parts)


def test_the_graph_is_read():
    inner, outer = import_graph()
    # plain, from-, relative-free and lazy (inside a function) imports all count
    assert "facesim.inverse.gauss_newton" in inner["facesim.inverse.tracking"]
    assert "facesim.session" in inner["facesim.simulate"]          # lazy, inside simulate()
    assert "facesim.session" in inner["facesim"]                    # lazy, inside __getattr__
    assert inner["facesim.jaw.nlpca"] and inner["facesim.kinematics.rig_jaw"]
    assert "numpy" in outer["facesim.model"]
    packages = package_graph(inner)
    assert {"facesim.fem", "facesim.inverse", "facesim.mocap", "facesim.viz", "facesim.cli"} <= set(packages)
    assert "facesim.fem" in packages["facesim.inverse"]


def test_type_checking_imports_are_left_out():
    tree = ast.parse("from typing import TYPE_CHECKING\nimport typing\n"
                     "if TYPE_CHECKING:\n    import facesim.a\nelse:\n    import facesim.b\n"
                     "if typing.TYPE_CHECKING:\n    import facesim.c\n"
                     "def f():\n    import facesim.d\n")
    names = [a.name for node in _imports(tree) for a in node.names]
    assert sorted(names) == ["TYPE_CHECKING", "facesim.b", "facesim.d", "typing"]


def test_cycles_are_found():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_no_cycle_among_modules():
    assert cycles(import_graph()[0]) == []


def test_no_cycle_among_top_level_packages():
    assert cycles(package_graph(import_graph()[0])) == []


def test_jaw_does_not_import_kinematics_and_se3_files_are_the_bottom():
    inner, outer = import_graph()
    jaw = {t for m, ts in inner.items() if _in(m, ("facesim.jaw",)) for t in ts}
    assert "facesim.jaw.frame" in jaw and not any(_in(t, ("facesim.kinematics",)) for t in jaw)
    assert inner["facesim.se3"] == {"facesim.errors"} and outer["facesim.se3"] <= {"__future__", "numpy", "scipy"}
    assert inner["facesim._files"] == {"facesim.errors"}
