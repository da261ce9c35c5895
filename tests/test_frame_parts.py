"""extract's resume parts (stages.common.features_file.FrameParts): what a chunk commits is
what it gives back, and what the features file then holds."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from stages.common.artifacts import root_attrs
from stages.common.features_file import SCHEMA, VERSION, FeaturesFile, FrameParts, write_features

ATTRS = {**root_attrs(SCHEMA, VERSION), "camera_kind": "perspective", "calib_hash": "c"}
# perspective datasets: (trailing shape); lines, crossings and posts are required per frame
DATASETS = {"lines": (4,), "crossings": (5,), "posts": (3,), "boundary": (2,)}


@st.composite
def frames(draw):
    out = []
    for i in range(draw(st.integers(1, 6))):
        arrays = {}
        for key, trailing in DATASETS.items():
            if key == "boundary" and draw(st.booleans()):
                continue  # an optional dataset absent from some frames
            n = draw(st.integers(0, 5))
            values = draw(st.lists(st.floats(-1e3, 1e3, width=32), min_size=n * trailing[0],
                                   max_size=n * trailing[0]))
            arrays[key] = np.array(values, np.float64).reshape(n, *trailing)
        out.append((f"{i:03d}", float(i) / 10, arrays))
    return out


@settings(max_examples=25, deadline=None)
@given(frames())
def test_a_chunk_gives_back_its_frames_and_the_file_holds_them(tmp_path_factory, fs):
    """Each frame's arrays, in the schema's dtype (float32) and their shapes (empty ones
    too), and its stamp; a dataset a frame lacks stays absent."""
    out = tmp_path_factory.mktemp("parts") / "f.h5"
    parts = FrameParts(out, ATTRS)
    parts.open()
    for name, stamp, arrays in fs:
        parts.add_frame(name, stamp, arrays)
    parts.flush()
    for name, stamp, arrays in fs:
        got_stamp, got = parts.frame(name)
        assert got_stamp == stamp and sorted(got) == sorted(arrays)
        for key, value in arrays.items():
            assert got[key].dtype == np.float32 and got[key].shape == value.shape
            # exact same-run: float32 draws written and read back, no arithmetic
            assert np.array_equal(got[key], value.astype(np.float32))
    with write_features(out, ATTRS) as w:
        parts.merge_into(w)
    parts.remove()
    with FeaturesFile(out) as ff:
        assert ff.names == [name for name, _s, _a in fs]
        for name, stamp, arrays in fs:
            got = ff.frame(name)
            assert got["stamp"] == stamp
            assert sorted(k for k in got if k != "stamp") == sorted(arrays)
            for key, value in arrays.items():
                assert got[key].dtype == np.float32 and got[key].shape == value.shape
                # exact same-run: float32 draws written and read back, no arithmetic
                assert np.array_equal(got[key], value.astype(np.float32))
