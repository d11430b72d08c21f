"""The package's import graph, read from the sources: no module imports itself through
others (no circle), no two sibling packages import each other, and the IK layers import
downward only (``_model`` <- ``_solvers`` <- ``_driver``).  Function-level imports count."""

from __future__ import annotations

import ast
import pathlib

import jaxsim

ROOT = pathlib.Path(jaxsim.__file__).parent


def _modules() -> dict[str, pathlib.Path]:
    out = {}
    for p in ROOT.rglob("*.py"):
        parts = ("jaxsim",) + p.relative_to(ROOT).with_suffix("").parts
        out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = p
    return out


def _edges(mods) -> dict[str, set[str]]:
    edges = {}
    for m, p in mods.items():
        pkg = m if p.name == "__init__.py" else m.rsplit(".", 1)[0]
        out = set()
        for node in ast.walk(ast.parse(p.read_text())):
            if not isinstance(node, ast.ImportFrom):
                continue
            if node.level:
                base = pkg.split(".")[: len(pkg.split(".")) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            elif node.module and node.module.startswith("jaxsim"):
                target = node.module
            else:
                continue
            for a in node.names:
                out.add(f"{target}.{a.name}" if f"{target}.{a.name}" in mods else target)
        edges[m] = {o for o in out if o in mods and o != m}
    return edges


MODS = _modules()
EDGES = _edges(MODS)
PACKAGES = {m for m, p in MODS.items() if p.name == "__init__.py"}


def _cycles(graph) -> list[list[str]]:
    index, low, stack, on, found, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_no_module_imports_itself_through_others():
    graph = {m: {o for o in e if o not in PACKAGES} for m, e in EDGES.items() if m not in PACKAGES}
    assert _cycles(graph) == []


def test_no_two_sibling_packages_import_each_other():
    def pkg(m):
        return m if m in PACKAGES else m.rsplit(".", 1)[0]

    pairs = set()
    for m, e in EDGES.items():
        for o in e:
            a, b = pkg(m), pkg(o)
            if a != b and not a.startswith(b + ".") and not b.startswith(a + "."):
                pairs.add((a, b))
    assert sorted((a, b) for a, b in pairs if (b, a) in pairs) == []


def test_the_ik_layers_import_downward():
    rank = {"jaxsim.ik._model": 0, "jaxsim.ik._solvers": 1, "jaxsim.ik._driver": 2}

    def layer(m):
        return next((r for p, r in rank.items() if m == p or m.startswith(p + ".")), None)

    up = [(m, o) for m, e in EDGES.items() for o in e
          if layer(m) is not None and layer(o) is not None and layer(o) > layer(m)]
    assert up == []


def test_the_check_sees_a_circle():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
