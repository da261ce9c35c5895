"""simulate never writes a calib.yaml its own readers refuse.

`simulate perspective --camera-height 1e-308` was accepted and extract then refused the
calib.yaml it wrote. simulate reads its camera options through the calib.yaml reader's own
checks (the renderers' ``camera_from_conf``: ``from_dict`` with the reader's bounds) and reads
back the calibration it is about to write (``_check_written_calib``), so whatever camera value
it accepts gives a calib.yaml ``load_calib`` (what extract reads) accepts: checked here for any
height, pitch, roll and calibration error (hypothesis), and through the command line for the
values of the finding.
"""

from __future__ import annotations

import copy

import pytest
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fieldloc_cli.main import cli
from stages import simulate
from stages.common.camera import load_calib, save_calib
from stages.common.errors import FieldlocError
from stages.common.perspective_camera import MAX_HEIGHT_M, MIN_HEIGHT_M

NUMBERS = st.one_of(st.floats(allow_nan=False, allow_infinity=False),
                    st.floats(-2 * MAX_HEIGHT_M, 2 * MAX_HEIGHT_M),  # near the bounds
                    st.sampled_from([0.0, 1e-308, -1e-308, MIN_HEIGHT_M, MAX_HEIGHT_M,
                                     MIN_HEIGHT_M * (1 - 1e-9), MAX_HEIGHT_M * (1 + 1e-9)]))


def _written_calib(conf: dict):
    """The camera simulate would write to calib.yaml for ``conf``, or None where simulate
    refuses the conf (FieldlocError) before rendering."""
    try:
        conf = simulate.resolve_simulate_conf(conf)
        simulate.check_conf(conf)
        kind = conf["camera"]
        module = simulate.renderer_class(kind)[0]
        camera = module.camera_from_conf(module._merged(conf[kind]))
        written = simulate.written_camera(module, camera, conf["calib_error"], 0)
        simulate._check_written_calib(written)
    except FieldlocError:
        return None
    return written


@settings(max_examples=150, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(height=NUMBERS, pitch=NUMBERS, roll=NUMBERS, height_offset=NUMBERS)
def test_an_accepted_perspective_camera_writes_a_calib_the_reader_accepts(
        tmp_path, height, pitch, roll, height_offset):
    conf = {"camera": "perspective", "perspective": {"height": height, "pitch": pitch,
                                                     "roll": roll},
            "calib_error": {"height_offset": height_offset}}
    written = _written_calib(conf)
    if written is None:
        return
    save_calib(written, tmp_path / "calib.yaml")
    load_calib(tmp_path / "calib.yaml")  # raises where the reader refuses it


@settings(max_examples=80, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(du=NUMBERS, dv=NUMBERS, scale=NUMBERS)
def test_an_accepted_omni_calibration_error_writes_a_calib_the_reader_accepts(
        tmp_path, du, dv, scale):
    conf = {"camera": "omni", "calib_error": {"centre_shift": [du, dv], "scale": scale}}
    written = _written_calib(copy.deepcopy(conf))
    if written is None:
        return
    save_calib(written, tmp_path / "calib.yaml")
    load_calib(tmp_path / "calib.yaml")


@pytest.mark.parametrize("args,fragment", [
    (["--camera-height", "1e-308"], "'height' must be >= 0.001 and <= 10 m"),
    (["--camera-height", "10", "-c", "calib_error.height_offset=0.2"],
     "calib_error would write a calibration extract refuses"),
    (["--camera-height", "0.001", "-c", "calib_error.height_offset=-0.0005"],
     "calib_error would write a calibration extract refuses"),
])
def test_simulate_refuses_a_camera_its_reader_would_refuse(tmp_path, args, fragment):
    res = CliRunner().invoke(cli, ["simulate", "perspective", "--field", "spl", "--frames", "1",
                                   "-o", str(tmp_path / "d"), *args])
    assert res.exit_code == 1, res.output
    assert fragment in res.stderr and len(res.stderr.splitlines()) == 1, res.stderr
    assert not (tmp_path / "d").exists()


def test_the_height_bounds_are_the_readers():
    """One source of truth: simulate's perspective camera is read by the calib reader's
    from_dict, so its bounds are perspective_camera's constants."""
    conf = {"camera": "perspective", "perspective": {"height": MAX_HEIGHT_M}}
    assert _written_calib(conf) is not None
    conf["perspective"]["height"] = MAX_HEIGHT_M * 1.001
    assert _written_calib(conf) is None
    conf["perspective"]["height"] = MIN_HEIGHT_M * 0.999
    assert _written_calib(conf) is None
