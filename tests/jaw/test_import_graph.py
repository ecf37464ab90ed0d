"""The lower layers' import graph (issue 13): every ``import`` of facesim/ read with ``ast``, lazy
imports inside functions included. No cycle runs through the jaw rigs, the bone kinematics, the
SE(3) module or the file helpers; the jaw package does not import kinematics (kinematics imports
jaw); ``facesim.se3`` and ``facesim._files`` sit at the bottom."""

import ast
from pathlib import Path

import facesim

PACKAGE = Path(facesim.__file__).resolve().parent
LOWER = ("facesim.jaw", "facesim.kinematics", "facesim.se3", "facesim._files")


def _modules() -> dict[str, Path]:
    mods = {}
    for f in PACKAGE.rglob("*.py"):
        parts = list(f.relative_to(PACKAGE.parent).with_suffix("").parts)
        mods[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = f
    return mods


def import_graph() -> tuple[dict[str, set[str]], dict[str, set[str]]]:
    """(facesim module -> the facesim modules it imports, module -> the outside top-level names it imports)."""
    mods = _modules()

    def known(name):
        while name and name not in mods:
            name = name.rpartition(".")[0]
        return name

    inner, outer = {m: set() for m in mods}, {m: set() for m in mods}
    for m, f in mods.items():
        package = m.split(".") if f.name == "__init__.py" else m.split(".")[:-1]
        for node in ast.walk(ast.parse(f.read_text(), str(f))):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    base = ".".join(package[:len(package) - node.level + 1] + ([base] if base else []))
                names = [f"{base}.{a.name}" if f"{base}.{a.name}" in mods else base for a in node.names]
            else:
                continue
            for name in names:
                if name.split(".")[0] == "facesim":
                    if known(name) != m:
                        inner[m].add(known(name))
                else:
                    outer[m].add(name.split(".")[0])
    return inner, outer


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
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

    for v in graph:
        if v not in index:
            visit(v)
    return found


def _in(module: str, parts) -> bool:
    return any(module == p or module.startswith(p + ".") for p in parts)


def test_no_import_cycle_through_the_lower_layers():
    inner, _ = import_graph()
    assert inner["facesim.jaw.nlpca"] and inner["facesim.kinematics.rig_jaw"]      # the graph is not empty
    assert [c for c in cycles(inner) if any(_in(m, LOWER) for m in c)] == []


def test_jaw_does_not_import_kinematics_and_se3_files_are_the_bottom():
    inner, outer = import_graph()
    jaw = {t for m, ts in inner.items() if _in(m, ("facesim.jaw",)) for t in ts}
    assert "facesim.jaw.frame" in jaw and not any(_in(t, ("facesim.kinematics",)) for t in jaw)
    assert inner["facesim.se3"] == {"facesim.errors"} and outer["facesim.se3"] <= {"__future__", "numpy", "scipy"}
    assert inner["facesim._files"] == {"facesim.errors"}
