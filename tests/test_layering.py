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
    """The arrows issue 10 found ran through imports inside functions: they are read, and
    relative ones resolved (`from .. import extract` inside show.points.write_picture)."""
    src = (ROOT / "stages" / "show" / "points.py").read_text()
    line = next(i for i, t in enumerate(src.splitlines(), 1) if t == "    from .. import extract")
    assert ("stages.extract", line) in imports_of(ROOT / "stages" / "show" / "points.py")
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
