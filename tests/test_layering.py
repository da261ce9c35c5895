"""The house's layers (README "Architecture"): every import of every module of fieldloc_cli/
and stages/ (read with ast, so imports inside functions count) points down the layers
fieldloc_cli -> stages.pipelines -> stages.show -> stages.<stage> -> stages.common; a stage
imports another stage only where the README's list says so; only stages/show/ imports
matplotlib."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LAYERS = {"fieldloc_cli": 4, "pipelines": 3, "show": 2, "common": 0}  # other stages: 1


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _is_module(name: str) -> bool:
    p = ROOT.joinpath(*name.split("."))
    return p.is_dir() or p.with_suffix(".py").is_file()


def imports_of(path: Path) -> list[tuple[str, int]]:
    """(module imported, line) of every import in ``path``, relative ones resolved; ``from
    package import name`` gives package.name when that is a module."""
    name = _module_name(path)
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out += [(a.name, node.lineno) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            for a in node.names:
                full = f"{module}.{a.name}"
                out.append((full if _is_module(full) else module, node.lineno))
    return out


def unit(module: str) -> str | None:
    """The layer unit of a module of ours: fieldloc_cli, pipelines, show, common or a stage's
    name; None for the stages root (its version), other packages."""
    parts = module.split(".")
    if parts[0] == "fieldloc_cli":
        return "fieldloc_cli"
    if parts[0] != "stages" or len(parts) == 1:
        return None
    return parts[1]


def layer(u: str) -> int:
    return LAYERS.get(u, 1)


def allowed_stage_imports() -> set[tuple[str, str]]:
    """The stage-to-stage imports the README's architecture section lists
    (``- stages.a -> stages.b: why``)."""
    text = (ROOT / "docs" / "architecture.md").read_text()
    m = re.search(r"<!-- stage-imports:begin -->\n(.*?)<!-- stage-imports:end -->", text,
                  flags=re.S)
    assert m, "docs/architecture.md lacks the list of stage-to-stage imports"
    pairs = re.findall(r"^- stages\.(\w+) -> stages\.(\w+)", m.group(1), flags=re.M)
    return set(pairs)


MODULES = sorted(p for d in ("stages", "fieldloc_cli") for p in (ROOT / d).rglob("*.py"))


def test_the_layering_test_sees_imports_inside_functions():
    """The layering faults found in review ran through imports inside functions: they are
    read, and relative ones resolved (`from .. import extract` inside a function)."""
    path = ROOT / "stages" / "pipelines" / "frame_points.py"
    line = next(i for i, t in enumerate(path.read_text().splitlines(), 1)
                if t == "    from .. import extract")
    assert ("stages.extract", line) in imports_of(path)
    assert unit("stages.localize.lut") == "localize" and layer("localize") == 1
    assert layer("show") > layer("localize") > layer("common") and unit("stages") is None


@pytest.mark.parametrize("path", MODULES, ids=[str(p.relative_to(ROOT)) for p in MODULES])
def test_imports_point_down_the_layers(path):
    me = unit(_module_name(path))
    allowed = allowed_stage_imports()
    wrong = []
    for module, line in imports_of(path):
        if module.split(".")[0] == "matplotlib" and me != "show":
            wrong.append(f"line {line}: matplotlib outside stages/show/")
        other = unit(module)
        if other is None or other == me:
            continue
        if layer(other) > layer(me):
            wrong.append(f"line {line}: {module} is a layer above {me}")
        elif layer(other) == layer(me) == 1 and (me, other) not in allowed:
            wrong.append(f"line {line}: stage {me} imports stage {other} ({module}), which the"
                         " README's list of stage-to-stage imports does not name")
    assert not wrong, f"{path.relative_to(ROOT)}: " + "; ".join(wrong)


def import_graph() -> dict[str, dict[str, list[int]]]:
    """module -> {module of ours it imports: [lines]} over stages/ and fieldloc_cli/, imports
    at module level and inside functions alike (a circle closed by an import inside a function
    is one at run time all the same)."""
    names = {_module_name(p): p for p in MODULES}
    graph: dict[str, dict[str, list[int]]] = {}
    for name, path in names.items():
        out = graph.setdefault(name, {})
        for module, line in imports_of(path):
            parts = module.split(".")
            target = next((".".join(parts[:k]) for k in range(len(parts), 0, -1)
                           if ".".join(parts[:k]) in names), None)
            if target is not None and target != name:
                out.setdefault(target, []).append(line)
    return graph


def circles(graph: dict[str, dict]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found = []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_the_circle_finder_finds_circles():
    graph = {"a": {"b": [1]}, "b": {"c": [2]}, "c": {"a": [3], "d": [4]}, "d": {}}
    assert circles(graph) == [["a", "b", "c"]]
    assert circles({"a": {"b": [1]}, "b": {}}) == []


def test_no_import_circles():
    """No two modules of stages/ and fieldloc_cli/ import each other, directly or
    through others (imports inside functions included): the bench is a package whose rows
    import its harness and inputs, the map reader computes no tables, a picture runs no stage."""
    graph = import_graph()
    assert "stages.pipelines.bench.harness" in graph["stages.pipelines.bench.omni"]
    found = circles(graph)
    shown = []
    for comp in found:
        arrows = [f"{a} -> {b} (line {', '.join(map(str, graph[a][b]))})"
                  for a in comp for b in sorted(graph[a]) if b in comp]
        shown.append("; ".join(arrows))
    assert not found, "import circles: " + " | ".join(shown)
    # the bench's registry imports its rows by name (importlib), which the graph does not see:
    # no module of the package imports the registry back
    back = [m for m in graph if m.startswith("stages.pipelines.bench.")
            and "stages.pipelines.bench" in graph[m]]
    assert not back, f"modules of the bench import its registry: {back}"
