"""The features file (stages.common.features_file): what a writer adds is what a reader gives
back, across the writer's and reader's blocks, through a resumed write, and from a file of
the schema's version 1 (a group per frame), which a resumed write moves into columns."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stages.common import features_file as F
from stages.common.artifacts import root_attrs
from stages.common.errors import SchemaError

ATTRS = {**root_attrs(F.SCHEMA, F.VERSION), "camera_kind": "perspective", "calib_hash": "c"}
DATASETS = {"lines": (4,), "crossings": (5,), "posts": (3,), "boundary": (2,)}


@st.composite
def frames(draw, most=9):
    """Perspective frames: the required datasets (some empty), ``boundary`` in some; names
    not in stamp order, stamps possibly shared."""
    out = []
    for i in range(draw(st.integers(1, most))):
        arrays = {}
        for key, trailing in DATASETS.items():
            if key == "boundary" and draw(st.booleans()):
                continue
            n = draw(st.integers(0, 4))
            values = draw(st.lists(st.floats(-1e3, 1e3, width=32), min_size=n * trailing[0],
                                   max_size=n * trailing[0]))
            arrays[key] = np.array(values, np.float32).reshape(n, *trailing)
        out.append((f"{(7 * i) % 10}{i:02d}", float(draw(st.integers(0, 4))), arrays))
    return out


def _expected_order(fs):
    return [n for n, _s, _a in sorted(fs, key=lambda f: (f[1], f[0]))]


def _holds(path, fs):
    with F.FeaturesFile(path) as ff:
        assert ff.names == _expected_order(fs)
        for name, stamp, arrays in fs:
            got = ff.frame(name)
            assert got.pop("stamp") == stamp and sorted(got) == sorted(arrays)
            for key, value in arrays.items():
                assert got[key].dtype == np.float32 and got[key].shape == value.shape
                # exact same-run: float32 values written and read back, no arithmetic
                assert np.array_equal(got[key], value)


def _write_v1(path, fs):
    """A features file as version 1 wrote it: a group per frame (the reference layout)."""
    with h5py.File(path, "w") as h5:
        for k, v in {**ATTRS, "schema_version": 1}.items():
            h5.attrs[k] = v
        for name, stamp, arrays in fs:
            g = h5.create_group(f"frames/{name}")
            g.attrs["stamp"] = stamp
            for key, value in arrays.items():
                g.create_dataset(key, data=value).attrs["units"] = F.FRAME_DATASETS[key][0]
        h5.create_dataset("failures", data=np.array([], dtype=h5py.string_dtype()))


@settings(max_examples=30, deadline=None)
@given(frames(), st.integers(1, 4), st.data())
def test_frames_read_back_across_blocks_and_a_resumed_write(tmp_path_factory, fs, block, data):
    """Blocks of ``block`` frames (the writer's flushes and the reader's reads cross them);
    the frames written in two runs, the second resuming the first's file."""
    out = tmp_path_factory.mktemp("f") / "f.h5"
    cut = data.draw(st.integers(0, len(fs)))
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(F, "BLOCK_FRAMES", block)
        with F.write_features(out, ATTRS) as w:
            for name, stamp, arrays in fs[:cut]:
                w.add_frame(name, stamp, arrays)
        with F.write_features(out, ATTRS, resume=True) as w:
            assert all(w.has(n) for n, _s, _a in fs[:cut])
            for name, stamp, arrays in fs[cut:]:
                w.add_frame(name, stamp, arrays)
        _holds(out, fs)


@settings(max_examples=20, deadline=None)
@given(frames(), frames(most=3))
def test_a_version_1_file_is_read_and_a_resume_moves_it_into_columns(tmp_path_factory, fs, more):
    out = tmp_path_factory.mktemp("v1") / "f.h5"
    _write_v1(out, fs)
    _holds(out, fs)
    more = [(f"new{i}", s, a) for i, (_n, s, a) in enumerate(more)]
    with F.write_features(out, ATTRS, resume=True) as w:
        for name, stamp, arrays in more:
            w.add_frame(name, stamp, arrays)
    with h5py.File(out, "r") as h5:
        assert "frames" not in h5 and int(h5.attrs["schema_version"]) == 2
    _holds(out, fs + more)


def test_a_frame_added_again_is_read_with_its_last_rows(tmp_path):
    a = {k: np.ones((1, *t), np.float32) for k, t in DATASETS.items()}
    b = {k: np.full((2, *t), 2, np.float32) for k, t in DATASETS.items() if k != "boundary"}
    with F.write_features(tmp_path / "f.h5", ATTRS) as w:
        w.add_frame("x", 0.0, a)
        w.add_frame("y", 1.0, a)
        w.add_frame("x", 2.0, b)
    _holds(tmp_path / "f.h5", [("y", 1.0, a), ("x", 2.0, b)])


def _damage(path, change):
    with h5py.File(path, "a") as h5:
        change(h5)


@pytest.mark.parametrize("change, says", [
    (lambda h5: h5["rows/lines"].resize((1,)), "rows/lines does not give one row count"),
    (lambda h5: h5["data/posts"].resize((0, 3)), "data/posts holds 0 rows, its frames 2"),
    (lambda h5: h5["index/stamp"].resize((3,)), "2 frame names but 3 stamps"),
    (lambda h5: h5.__delitem__("data/crossings"), "crossings"),
])
def test_damaged_columns_are_refused_in_one_line(tmp_path, change, says):
    a = {k: np.ones((1, *t), np.float32) for k, t in DATASETS.items()}
    with F.write_features(tmp_path / "f.h5", ATTRS) as w:
        w.add_frame("x", 0.0, a)
        w.add_frame("y", 1.0, a)
    _damage(tmp_path / "f.h5", change)
    with pytest.raises(SchemaError, match="damaged features file") as e:
        F.FeaturesFile(tmp_path / "f.h5")
    assert says in str(e.value) and "\n" not in str(e.value)


def test_a_frame_of_another_width_is_refused_by_the_writer(tmp_path):
    a = {k: np.ones((1, *t), np.float32) for k, t in DATASETS.items()}
    with pytest.raises(ValueError, match="rows of shape"):
        with F.write_features(tmp_path / "f.h5", ATTRS) as w:
            w.add_frame("x", 0.0, a)
            w.close()  # the first frames' columns are made
            w.add_frame("y", 1.0, {**a, "lines": np.ones((1, 3), np.float32)})
            w.close()
    assert not (tmp_path / "f.h5").exists()
