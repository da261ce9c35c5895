"""No test compares floating-point results bit for bit: the tests' sources are
scanned (tests/exact_comparisons.py states the rule, its markers and why), and numpy's exact
comparisons are guarded at run time (tests/conftest.py). The scan and the guard are tested on
small synthetic sources and values here."""

from __future__ import annotations

import textwrap

import numpy as np
import pytest
from exact_comparisons import TESTS, BitForBitComparison, scan, scan_tests


def test_no_test_compares_floats_bit_for_bit():
    """Every exact comparison in tests/**/*.py is of integers or decisions, or carries a
    marker a reviewer can check; every marker is well formed and marks one."""
    findings = scan_tests()
    assert not findings, "\n".join(map(str, findings))


def _scan(src: str) -> list[str]:
    return [f.what for f in scan(textwrap.dedent(src))]


@pytest.mark.parametrize("src", [
    "assert a.tobytes() == b.tobytes()\n",
    "import hashlib\nh = hashlib.sha256(np.ascontiguousarray(a)).hexdigest()\n",
    "from hashlib import md5\nh = md5(a.tobytes())\n",
    "import numpy as np\nassert np.array_equal(fast, slow)\n",
    "import numpy as np\nnp.testing.assert_array_equal(x, [0.5, 1.0])\n",
    "import numpy.testing as npt\nnpt.assert_equal(x, y)\n",
    "from numpy.testing import assert_array_equal as same\nsame(x, y)\n",
    "from numpy import array_equal\nassert array_equal(x, y.astype(np.float32))\n",
    "import numpy as np\nassert not np.array_equal(a, b)\n",
    # a marker without a reason, or of an unknown kind, allows nothing
    "import numpy as np\nassert np.array_equal(a, b)  # exact same-run:\n",
    "import numpy as np\nassert np.array_equal(a, b)  # exact close: they are\n",
])
def test_the_scan_flags_bit_for_bit_comparisons(src):
    assert _scan(src)


@pytest.mark.parametrize("src", [
    "import numpy as np\nnp.testing.assert_allclose(a, b, rtol=1e-7)\n",
    "import numpy as np\nassert np.array_equal(np.isnan(a), np.isnan(b))\n",
    "import numpy as np\nassert np.array_equal(a > 0, [True, False])\n",
    "import numpy as np\nnp.testing.assert_array_equal(idx.astype(np.int64), [1, 2, 3])\n",
    "import numpy as np\nassert np.array_equal(np.flatnonzero(m), np.argsort(v))\n",
    "import numpy as np\nassert np.array_equal(labels, ref)  # exact decisions: class labels\n",
    """\
    import numpy as np
    np.testing.assert_array_equal(
        first, second)  # exact same-run: the same seed twice in this process
    """,
    """\
    import hashlib
    # the input file is read, not written
    h = hashlib.sha256(p.read_bytes())  # exact bytes: the user's input file
    """,
    "b = cv2.imencode('.jpg', im)[1].tobytes()\n",  # bytes made, not compared
    "s = '# exact same-run: in a string, not a comment'\n",
])
def test_the_scan_passes_tolerant_or_marked_comparisons(src):
    assert not _scan(src)


def test_a_marker_on_no_exact_comparison_is_flagged():
    assert _scan("x = 1  # exact integers: nothing compared here\n") == [
        "marker on no exact comparison"]


def _called_from(path: str, expr: str, **names):
    """Evaluate ``expr`` as if a line of the file ``path`` called it (the guard looks at the
    calling file and its markers; a file that does not exist has none)."""
    return eval(compile(expr, path, "eval"), {"np": np, **names})


SYNTHETIC_TEST = str(TESTS / "test_synthetic_violation.py")  # not a file: no markers


@pytest.mark.parametrize("expr", [
    "np.testing.assert_array_equal(a, a.copy())",
    "np.array_equal(a, a)",
    "np.array_equiv(a, a)",
    "np.testing.assert_equal({'x': a}, {'x': a})",
    "np.testing.assert_equal(float(a[0]), float(a[0]))",
])
def test_the_guard_fails_exact_comparisons_of_non_integer_floats(expr):
    """Called from a test module, numpy's exact comparisons refuse non-integer floats."""
    with pytest.raises(BitForBitComparison):
        _called_from(SYNTHETIC_TEST, expr, a=np.array([0.1, 0.2]) * 3)


def test_the_guard_checks_the_markers_claim():
    """A call marked ``integers`` that compares non-integer floats fails: the marker is
    wrong."""
    a = np.array([0.1, 0.2]) * 3
    with pytest.raises(BitForBitComparison):
        np.array_equal(a, a)  # exact integers: a wrong claim, which the guard must refuse


def test_the_guard_passes_integers_decisions_and_same_run():
    """Floats holding integers (pixel coordinates stored as float), NaN and infinities,
    integer and boolean arrays pass; so do non-integer floats marked same-run."""
    np.testing.assert_array_equal(np.array([1.0, np.nan, -np.inf, 4e6]),  # exact integers: x
                                  np.array([1.0, np.nan, -np.inf, 4e6]))
    assert _called_from(SYNTHETIC_TEST, "np.array_equal(np.arange(4.0), [0, 1, 2, 3])")
    assert _called_from(SYNTHETIC_TEST, "np.array_equal(np.array([True, False]), [1, 0])")
    a = np.array([0.1, 0.2]) * 3
    assert np.array_equal(a, a.copy())  # exact same-run: a copy of the same array


def test_the_guard_leaves_library_code_alone():
    """Only calls from files under tests/ are checked: a library's exact comparisons of its
    own floats pass through."""
    assert hasattr(np.testing.assert_array_equal, "__wrapped_exact__")
    assert _called_from("/elsewhere/library.py", "np.array_equal(a, a)",
                        a=np.array([0.1, 0.7]))
