"""The rule that no test compares floating-point results bit for bit, as code: a static scan of
the tests' sources (used by tests/test_comparisons_are_tolerant.py) and a runtime guard of
numpy's exact comparisons (installed for every test by tests/conftest.py).

Why: the bits of a floating-point result depend on the CPU, the BLAS kernel and the library
versions (a dot product fused or not, a summation blocked one way or another). A test that
compares them exactly checks which machine ran it, not what the code must do. Continuous
results are compared with a stated tolerance (np.testing.assert_allclose with rtol/atol,
assert_array_max_ulp for float32).

What the scan flags, in every tests/**/*.py:

- ``.tobytes()`` inside a comparison or a hash;
- a hash (hashlib.*, ``hash()``) of anything;
- an exact array comparison (np.array_equal, np.array_equiv, np.testing.assert_array_equal,
  np.testing.assert_equal, also when imported under another name) whose arguments are not
  all provably integer or boolean: literals of ints and bools, comparisons, ``np.isnan`` and
  the like, ``.astype`` to an integer or bool type, ``len``, index functions (argsort,
  flatnonzero, ...).

An exact comparison is allowed when the call (any of its lines, or a comment line directly
above its statement) carries a marker comment ``# exact <kind>: <why>`` with one of the kinds
below and a reason a reviewer can check:

- ``integers``: the values are integers (counts, pixel coordinates, indices, uint8 images),
  whatever their dtype;
- ``decisions``: booleans or labels (a class, a mask, a kept line);
- ``bytes``: bytes that are no computed float result: a user's input file checked unchanged,
  an encoded image, a file the product copies;
- ``same-run``: both sides are computed in this test run by the same code on the same
  machine (a seed's reproducibility, a resumed run, a cache or a file read back): equality is
  then the property itself and no CPU's rounding enters it.

The runtime guard checks what it can of this at every call from a test module: an exact
comparison in which an argument holds floating-point values that are not all integers (NaN
and infinities aside) fails unless its marker is ``same-run``; a marker ``integers`` or
``decisions`` on non-integer floats fails too (the marker is wrong).
"""

from __future__ import annotations

import ast
import functools
import io
import re
import sys
import tokenize
from dataclasses import dataclass
from pathlib import Path

import numpy as np

TESTS = Path(__file__).resolve().parent
KINDS = ("integers", "decisions", "bytes", "same-run")
MARKER = re.compile(r"#\s*exact\s+(?P<kind>[\w-]+)\s*:\s*(?P<why>.*)$")
# exact comparisons by their qualified name
EXACT = {"numpy.array_equal", "numpy.array_equiv", "numpy.testing.assert_array_equal",
         "numpy.testing.assert_equal"}
# calls whose result is integer or boolean whatever their arguments
INTEGRAL_CALLS = {"isnan", "isfinite", "isinf", "isclose", "logical_and", "logical_or",
                  "logical_not", "logical_xor", "len", "argsort", "argmax", "argmin",
                  "flatnonzero", "nonzero", "searchsorted", "bincount", "count_nonzero", "any",
                  "all", "signbit", "int", "bool"}
INTEGRAL_TYPES = re.compile(r"^(u?int\d*|bool_?|intp|uintp|long|short|byte|ubyte)$")


class BitForBitComparison(AssertionError):
    """A test compared floating-point results exactly without a reason that allows it."""


@dataclass(frozen=True)
class Finding:
    path: str
    line: int
    what: str

    def __str__(self) -> str:
        return f"{self.path}:{self.line}: {self.what}"


def markers(source: str) -> dict[int, tuple[str, str]]:
    """Marker comments (comments, not text in strings) by line number: (kind, why)."""
    out = {}
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.COMMENT:
            m = MARKER.search(tok.string)
            if m:
                out[tok.start[0]] = (m["kind"], m["why"].strip())
    return out


def _aliases(tree: ast.AST) -> dict[str, str]:
    """Local names of numpy modules and functions: name -> qualified name."""
    names = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.name.split(".")[0] in ("numpy", "hashlib"):
                    names[a.asname or a.name.split(".")[0]] = (a.name if a.asname
                                                               else a.name.split(".")[0])
        elif isinstance(node, ast.ImportFrom) and node.module and (
                node.module.split(".")[0] in ("numpy", "hashlib")):
            for a in node.names:
                names[a.asname or a.name] = f"{node.module}.{a.name}"
    return names


def _qualified(func: ast.expr, names: dict[str, str]) -> str | None:
    """The qualified name of a called function (numpy.testing.assert_equal), if known."""
    parts = []
    while isinstance(func, ast.Attribute):
        parts.append(func.attr)
        func = func.value
    if not isinstance(func, ast.Name):
        return None
    head = names.get(func.id, func.id)
    name = ".".join([head, *reversed(parts)])
    return name.replace("numpy.testing._private.utils.", "numpy.testing.")


def _integral(node: ast.expr) -> bool:
    """Whether an expression provably holds integers or booleans."""
    if isinstance(node, ast.Constant):
        return isinstance(node.value, (bool, int))
    if isinstance(node, (ast.List, ast.Tuple, ast.Set)):
        return all(_integral(e) for e in node.elts)
    if isinstance(node, ast.UnaryOp):
        return isinstance(node.op, ast.Not) or _integral(node.operand)
    if isinstance(node, ast.BoolOp):
        return all(_integral(v) for v in node.values)
    if isinstance(node, ast.Compare):
        return True
    if isinstance(node, ast.BinOp) and isinstance(node.op, (ast.BitAnd, ast.BitOr, ast.BitXor)):
        return True  # masks
    if isinstance(node, ast.Call):
        f = node.func
        name = f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", "")
        if name == "astype" and node.args:
            t = node.args[0]
            t = t.attr if isinstance(t, ast.Attribute) else getattr(t, "id", getattr(
                t, "value", ""))
            return bool(INTEGRAL_TYPES.match(str(t)))
        return name in INTEGRAL_CALLS
    return False


def _parents(tree: ast.AST) -> dict[ast.AST, list[ast.AST]]:
    """Each node's chain of enclosing nodes, outermost first."""
    parents: dict[ast.AST, list[ast.AST]] = {}
    stack = [(tree, [])]
    while stack:
        node, chain = stack.pop()
        parents[node] = chain
        for child in ast.iter_child_nodes(node):
            stack.append((child, chain + [node]))
    return parents


def marker_lines(call: ast.Call, chain: list[ast.AST], lines: list[str]) -> list[int]:
    """The lines whose marker applies to ``call``: its own, and a comment line directly
    above the statement that holds it."""
    own = list(range(call.lineno, (call.end_lineno or call.lineno) + 1))
    stmt = next((p for p in reversed(chain) if isinstance(p, ast.stmt)), None)
    if stmt is not None and stmt.lineno >= 2 and lines[stmt.lineno - 2].lstrip().startswith("#"):
        own.append(stmt.lineno - 1)
    return own


def _is_hash(name: str | None) -> bool:
    return bool(name) and (name == "hash" or name.startswith("hashlib."))


def scan(source: str, path: str = "<source>") -> list[Finding]:
    """The bit-for-bit comparisons of ``source`` that carry no valid marker, and markers that
    are malformed or mark no exact comparison."""
    tree = ast.parse(source, path)
    source_lines = source.splitlines()
    names = _aliases(tree)
    marks = markers(source)
    used = set()
    findings = []

    def marked(node) -> bool:
        hit = [i for i in marker_lines(node, parents[node], source_lines) if i in marks]
        used.update(hit)
        return any(marks[i][0] in KINDS and marks[i][1] for i in hit)

    def inside(node, kinds) -> bool:
        return any(isinstance(p, kinds) or (isinstance(p, ast.Call)
                                            and _is_hash(_qualified(p.func, names)))
                   for p in parents.get(node, ()))

    parents = _parents(tree)
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        name = _qualified(node.func, names)
        what = None
        if isinstance(node.func, ast.Attribute) and node.func.attr == "tobytes":
            if inside(node, (ast.Compare,)):
                what = ".tobytes() compared or hashed"
        elif _is_hash(name):
            what = f"hash {name}()"
        elif name in EXACT:
            args = list(node.args) + [k.value for k in node.keywords
                                      if k.arg not in ("err_msg", "equal_nan", "verbose",
                                                       "strict")]
            if not args or not all(_integral(a) for a in args[:2]):
                what = f"{name.split('.')[-1]}() on values not provably integer"
        if what and not marked(node):
            findings.append(Finding(path, node.lineno, what))
    for line, (kind, why) in sorted(marks.items()):
        if kind not in KINDS or not why:
            findings.append(Finding(path, line, f"marker '# exact {kind}: {why}' needs a kind "
                                                f"of {KINDS} and a reason"))
        elif line not in used:
            findings.append(Finding(path, line, "marker on no exact comparison"))
    return sorted(set(findings), key=lambda f: (f.line, f.what))


def scan_tests(root: Path = TESTS) -> list[Finding]:
    """``scan`` over every tests/**/*.py."""
    out = []
    for p in sorted(root.rglob("*.py")):
        out += scan(p.read_text(), str(p.relative_to(root.parent)))
    return out


# ---------------------------------------------------------------------------- runtime guard
@functools.cache
def _call_markers(path: str) -> tuple[tuple[int, int, str], ...]:
    """(first line, last line, kind) of each call in a source file that carries a marker."""
    try:
        source = Path(path).read_text()
        tree = ast.parse(source)
    except (OSError, SyntaxError, ValueError):
        return ()
    marks = markers(source)
    parents = _parents(tree)
    lines = source.splitlines()
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call):
            for i in marker_lines(node, parents[node], lines):
                if i in marks:
                    out.append((node.lineno, node.end_lineno or node.lineno, marks[i][0]))
    return tuple(out)


def marker_at(path: str, line: int) -> str | None:
    """The marker kind of the innermost marked call spanning ``line`` of ``path``."""
    spans = [(last - first, kind) for first, last, kind in _call_markers(path)
             if first <= line <= last]
    return min(spans)[1] if spans else None


def _float_arrays(value, depth: int = 0):
    """The floating-point arrays within a compared value (arrays, scalars, lists, dicts)."""
    if depth > 4:
        return
    if isinstance(value, dict):
        for v in value.values():
            yield from _float_arrays(v, depth + 1)
        return
    if isinstance(value, (str, bytes)) or value is None:
        return
    try:
        a = np.asarray(value)
    except Exception:  # ragged or foreign: look inside
        a = None
    if a is None or a.dtype == object:
        if isinstance(value, (list, tuple)):
            for v in value:
                yield from _float_arrays(v, depth + 1)
        return
    if a.dtype.kind in "fc":
        yield a


def non_integer_floats(*values) -> bool:
    """Whether any value holds a finite floating-point number that is not an integer."""
    for a in (a for v in values for a in _float_arrays(v)):
        parts = [a.real, a.imag] if a.dtype.kind == "c" else [a]
        for p in parts:
            finite = p[np.isfinite(p)]
            if finite.size and not np.all(finite == np.round(finite)):
                return True
    return False


@functools.cache
def _in_tests(path: str) -> bool:
    return Path(path).resolve().is_relative_to(TESTS)


def guarded(fn, name: str):
    """``fn`` (an exact comparison) checked when a test module calls it."""

    @functools.wraps(fn)
    def check(*args, **kwargs):
        frame = sys._getframe(1)
        path = frame.f_code.co_filename
        if _in_tests(path):
            compared = args[:2] if len(args) >= 2 else list(args) + [
                kwargs.get(k) for k in ("a2", "desired", "y", "a1", "actual", "x") if k in kwargs]
            if non_integer_floats(*compared):
                kind = marker_at(path, frame.f_lineno)
                if kind != "same-run":
                    raise BitForBitComparison(
                        f"{Path(path).name}:{frame.f_lineno}: {name} compares floating-point "
                        f"values that are not integers bit for bit"
                        + (f" (marked '{kind}')" if kind else "")
                        + "; compare with a stated tolerance (assert_allclose), or mark the "
                          "call '# exact same-run: ...' if both sides are this run's")
        return fn(*args, **kwargs)

    check.__wrapped_exact__ = fn
    return check


GUARDED = (("numpy", "array_equal"), ("numpy", "array_equiv"),
           ("numpy.testing", "assert_array_equal"), ("numpy.testing", "assert_equal"))
