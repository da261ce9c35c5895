"""Field presets, validation messages, geometry and derived crossings."""

import math

import numpy as np
import pytest
import yaml

from stages.common.errors import FieldSpecError
from stages.common.field import MAPS_DIR, field_from_spec, load_field, preset_names

# Hand count from the rulebook drawings.
# MSL: 4 field corners (L); per half: goal area 2 L + 2 T, penalty area 2 L + 2 T; halfway line
# meets the touch lines (2 T) and the centre circle (2 X); the 4 corner arcs end on a touch line
# and a goal line (8 T). L = 4 + 2 * 4 = 12, T = 2 * 4 + 2 + 8 = 18, X = 2.
# SPL / Humanoid: the same without corner arcs: L 12, T 10, X 2.
EXPECTED = {
    "msl-2015": {"L": 12, "T": 18, "X": 2},
    "msl": {"L": 12, "T": 18, "X": 2},
    "spl": {"L": 12, "T": 10, "X": 2},
    "kidsize": {"L": 12, "T": 10, "X": 2},
    "adultsize": {"L": 12, "T": 10, "X": 2},
}


def test_every_preset_loads_with_expected_crossings():
    assert set(EXPECTED) <= set(preset_names())
    for name, counts in EXPECTED.items():
        fm = load_field(name)
        assert fm.summary()["crossings"] == counts, name
        assert fm.source


def test_msl2015_letters():
    """The rulebook's letters are measured from the lines' outer side: the centre lines are
    one line width (K = 0.125 m) less, as the teams' own files have them (CAMBADA 17875 mm)."""
    fm = load_field("msl-2015")
    assert (fm.length, fm.width, fm.line_width) == (17.875, 11.875, 0.125)
    # penalty mark I - K = 2.875 m from the goal line's centre, centre circle H - K diameter
    assert np.allclose(sorted(fm.penalty_marks[:, 0]), [-(8.9375 - 2.875), 0.0, 8.9375 - 2.875])
    assert fm.arcs[0][2] == (4.0 - 0.125) / 2
    # the penalty area front line at x = (A - K) / 2 - (E - K), spanning C - K
    seg = [s for s in fm.segments if np.allclose(s[:, 0], 8.9375 - 2.125)]
    assert len(seg) == 1 and np.isclose(abs(seg[0][0, 1] - seg[0][1, 1]), 6.375)
    assert fm.spec["border"] == 1.0 + 0.125 / 2  # L from the lines' outer side


def test_letters_need_the_line_width(tmp_path):
    spec = dict(load_field("msl-2015").spec)
    for key in ("length", "width", "line_width", "penalty_area", "goal_area",
                "centre_circle_diameter", "corner_arc_radius", "penalty_mark", "border"):
        spec.pop(key, None)
    spec["letters"] = {k: v for k, v in spec["letters"].items() if k != "K"}
    with pytest.raises(FieldSpecError, match="needs K"):
        field_from_spec(spec)


def test_crossing_positions_and_orientation():
    fm = load_field("kidsize")
    i = np.nonzero(np.all(np.isclose(fm.crossings, [4.5, 3.0]), axis=1))[0][0]
    assert fm.crossing_types[i] == "L"
    # the corner at (+4.5, +3): its arms point to -x and -y, the bisector to -135 deg
    assert math.isclose(fm.crossing_orientation[i], math.radians(-135), abs_tol=1e-9)
    # the circle meets the halfway line at (0, +-0.75) as X
    xs = fm.crossings[fm.crossing_types == "X"]
    assert np.allclose(sorted(xs[:, 1]), [-0.75, 0.75]) and np.allclose(xs[:, 0], 0)
    # T where the halfway line meets the touch line: stem along -y from (0, 3)
    j = np.nonzero(np.all(np.isclose(fm.crossings, [0.0, 3.0]), axis=1))[0][0]
    assert fm.crossing_types[j] == "T"
    assert math.isclose(fm.crossing_orientation[j], -math.pi / 2, abs_tol=1e-9)


def test_distance_to_lines_by_hand():
    fm = load_field("msl-2015")
    pts = np.array([[0.0, 0.0], [1.0, 0.0], [0.5, 1.0], [-9.5, 0.0], [8.7, -5.7]])
    d = fm.distance_to_lines(pts)
    # centre lines: goal lines at x = +-8.9375, touch lines at y = +-5.9375, centre circle of
    # radius 1.9375, corner arcs of radius 0.625 about the corners
    # on the halfway line; 1 m from it but 0.9375 from the circle; 0.5 m; 0.5625 m behind the
    # goal line; near the corner (8.9375, -5.9375): 0.2375 from both lines, farther from the arc
    arc = abs(math.hypot(0.2375, 0.2375) - 0.625)
    assert arc > 0.2375
    assert np.allclose(d, [0.0, 0.9375, 0.5, 0.5625, 0.2375])


def test_mirror_pose():
    fm = load_field("spl")
    assert np.allclose(fm.mirror_pose((1.0, 2.0, 0.5)), [-1.0, -2.0, 0.5 - math.pi])


def test_touchline_pose_faces_into_the_field():
    fm = load_field("kidsize")
    hy = fm.width / 2
    left, right = fm.touchline_pose(-2.0, 1.0), fm.touchline_pose(-1.0, -1.0, inset=0.3)
    assert np.allclose(left, [-2.0, hy, -math.pi / 2]) and np.allclose(right, [-1.0, -hy + 0.3,
                                                                               math.pi / 2])
    for pose in (left, right):  # a step forward leads onto the field
        ahead = pose[:2] + 0.5 * np.array([math.cos(pose[2]), math.sin(pose[2])])
        assert abs(ahead[1]) < abs(pose[1])
    many = fm.touchline_pose(np.array([-3.0, -1.0]), np.array([1.0, -1.0]),
                             inset=np.array([0.1, -0.2]))
    assert many.shape == (2, 3) and np.allclose(many[:, 1], [hy - 0.1, -hy - 0.2])


def _spec():
    return yaml.safe_load((MAPS_DIR / "kidsize.yaml").read_text())


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda s: s.pop("width"), "missing key 'width'"),
        (lambda s: s.update(length=-9.0), "key 'length' must be >= 0"),
        (lambda s: s.update(colour="green"), "unknown key 'colour'"),
        (lambda s: s.update(width="six"), "key 'width' must be a number"),
        (lambda s: s["penalty_area"].update(width=7.0), "'penalty_area.width' (7.0 m) is not"),
        (lambda s: s["penalty_area"].update(length=5.0), "reaches past the halfway"),
        (lambda s: s["goal"].pop("depth"), "missing key 'goal.depth'"),
        (lambda s: s["goal_area"].update(width=5.5), "'goal_area' must lie inside"),
        (lambda s: s.update(letters={"Z": 1.0}), "unknown key 'letters.Z'"),
    ],
)
def test_invalid_field_messages(tmp_path, change, message):
    spec = _spec()
    change(spec)
    path = tmp_path / "venue.yaml"
    path.write_text(yaml.safe_dump(spec))
    with pytest.raises(FieldSpecError) as e:
        load_field(path)
    assert message in str(e.value)
    assert str(path) in str(e.value)


def test_unknown_preset_and_bad_yaml(tmp_path):
    with pytest.raises(FieldSpecError, match="unknown field preset 'nope'"):
        load_field("nope")
    bad = tmp_path / "bad.yaml"
    bad.write_text("length: [1,\n")
    with pytest.raises(FieldSpecError, match="not valid YAML"):
        load_field(bad)


def test_letters_equal_named_keys():
    a = load_field("msl-2015")
    spec = dict(a.spec)
    spec.pop("letters")
    b = field_from_spec(spec)
    assert np.allclose(a.segments, b.segments) and np.allclose(a.arcs, b.arcs)


def test_a_field_built_again_gets_its_own_crossings():
    """derive_crossings works a geometry out once per process: a second model of the same
    field has equal crossings, in arrays of its own (changing one leaves the other)."""
    a, b = load_field("msl-2015"), load_field("msl-2015")
    assert np.array_equal(a.crossings, b.crossings)  # exact same-run: one field loaded twice
    assert list(a.crossing_types) == list(b.crossing_types)
    # exact same-run: one field loaded twice
    assert np.array_equal(a.crossing_arms, b.crossing_arms, equal_nan=True)
    a.crossings[0, 0] += 1.0
    assert not np.array_equal(a.crossings, b.crossings)  # exact same-run: a copy changed by 1 m
    # exact same-run: one field loaded twice
    assert np.array_equal(b.crossings, load_field("msl-2015").crossings)


def test_file_hash_follows_the_file(tmp_path):
    """file_hash is memoised in the process, by inode, size and mtime: a file rewritten with
    other bytes (even of the same size) gets its new hash."""
    import os

    from stages.common.artifacts import file_hash

    p = tmp_path / "f.bin"
    p.write_bytes(b"a" * 64)
    first = file_hash(p)
    assert file_hash(p) == first
    st = os.stat(p)
    p.write_bytes(b"b" * 64)
    os.utime(p, ns=(st.st_atime_ns, st.st_mtime_ns + 1000))
    assert file_hash(p) != first
