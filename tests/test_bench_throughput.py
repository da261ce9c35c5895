"""The "images to poses, per core" bench rows (stages.pipelines.bench.throughput) built on tiny
rendered sets: every figure a row reports is finite and positive, and the rows the issue sets
a goal for say it and judge it."""

import math

import pytest

from stages.pipelines.bench import inputs
from stages.pipelines.bench import throughput as bt


@pytest.fixture(scope="module")
def tiny_rows():
    """The rows of one bench run on 1- to 5-frame sets (fit and mcl pipelines, start-up,
    frames, area on msl-2015 and kidsize; fit rather than lut, whose lookup takes seconds to
    build), with the bench's shared inputs set aside."""
    saved = dict(inputs.INPUTS)
    inputs.INPUTS.clear()
    try:
        pipelines = [(k, m, f, g or 1.0) for k, m, f, g in bt.PIPELINES if m in ("fit", "mcl")]
        rows = {"throughput": bt.throughput_rows(1, frames=5, pipelines=pipelines),
                "startup": [bt.startup_row(1, method="fit")],
                "frames": [bt.frames_row(1, sizes=(1, 5), method="fit")],
                "area": bt.area_rows(1, fields=("msl-2015", "kidsize"), frames=5,
                                     method="fit")}
        yield rows
    finally:
        if "tmp" in inputs.INPUTS:
            inputs.INPUTS["tmp"].cleanup()
        inputs.INPUTS.clear()
        inputs.INPUTS.update(saved)


def _positive(*values):
    return all(math.isfinite(v) and v > 0 for v in values)


def test_throughput_rows_report_frames_per_second(tiny_rows):
    rows = tiny_rows["throughput"]
    assert [r.extra["frames"] for r in rows] == [5, 5]
    for r in rows:
        assert _positive(r.median_ms, r.cpu_ms, r.extra["frames_per_cpu_s"], r.baseline_ms)
        # the pipeline reads and decodes the images, and then does more
        assert r.ratio == pytest.approx(r.cpu_ms / r.baseline_ms) and r.ratio > 1
        # frames per second of CPU is the frames over the CPU the run spent
        assert r.extra["frames_per_cpu_s"] == pytest.approx(1e3 / r.cpu_ms, rel=1e-9)
        assert r.goal.startswith(">=") and "frames/s per core" in r.goal
        assert isinstance(r.meets_goal, bool)
        assert r.name.startswith("images to poses, per core")


def test_startup_row_against_an_empty_interpreter(tiny_rows):
    (r,) = tiny_rows["startup"]
    assert _positive(r.median_ms, r.cpu_ms, r.peak_mb, r.baseline_ms, r.ratio)
    assert r.baseline == "python -c pass"
    # a localize process imports numpy, numba, OpenCV and h5py: it cannot start as fast
    assert r.ratio > 1


def test_frames_and_area_rows(tiny_rows):
    (f,) = tiny_rows["frames"]
    assert _positive(f.median_ms, f.cpu_ms, f.baseline_ms, f.ratio)
    assert f.goal and isinstance(f.meets_goal, bool)
    first, other = tiny_rows["area"]
    for r in (first, other):
        assert _positive(r.median_ms, r.cpu_ms, r.peak_mb, r.extra["cells"])
    assert first.meets_goal is None and not first.goal
    assert _positive(other.ratio) and other.goal and isinstance(other.meets_goal, bool)
    # the table cells follow the fields' areas: msl-2015 (18 x 12 m) and kidsize (9 x 6 m)
    assert other.extra["cells"] / first.extra["cells"] == pytest.approx(0.3, abs=0.08)


def test_double_msl_field_has_twice_the_area(tmp_path, monkeypatch):
    from stages.common.field import load_field

    monkeypatch.setattr(inputs, "INPUTS", {"dir": tmp_path})
    monkeypatch.setattr(bt, "INPUTS", inputs.INPUTS)
    big, msl = load_field(bt.double_msl_field()), load_field("msl")
    (x0, x1, y0, y1), (a0, a1, b0, b1) = big.world_bounds(0.0), msl.world_bounds(0.0)
    assert (x1 - x0) * (y1 - y0) == pytest.approx(2 * (a1 - a0) * (b1 - b0), rel=0.02)
