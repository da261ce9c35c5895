"""The Carpe Noctem route of docs/manual.md (``--from-cnc``) as written: a calibration
picture smaller than the camera's frames, ``--centre`` / ``--image-size`` placing the written
calibration in those frames while the rings are measured about the picture's own centre; then
the team's frames through extract and localize on their lab field. The real-data tests skip
when ../shared/realdata is absent."""


from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner
from conftest import REALDATA
from test_calibrate_cnc import CENTRE, DIST, _conf_file, _mirror_radius, _ring_picture

from fieldloc_cli.main import cli
from stages.calibrate import cnc, report
from stages.common.camera import load_calib

CNC_CONF = REALDATA / "cnc-calibration" / cnc.CONF_NAME
FRAMES = REALDATA / "cnc-omni-testimages"
FIELD_CONF = REALDATA / "field-dimensions" / "cnc_msl" / "FootballField.conf"
FRAME_CENTRE = (322.0, 235.0)  # their Vision.conf's CameraMY, CameraMX (docs/manual.md)
FRAME_SIZE = (640, 480)


def _picture_conf(tmp_path):
    cv2.imwrite(str(tmp_path / cnc.IMAGE_NAME), _ring_picture())
    return _conf_file(tmp_path, [0, *(DIST * 1000).astype(int)])


def _calibrate(conf, out, *extra):
    return CliRunner().invoke(cli, ["calibrate", "omni", "--from-cnc", str(conf), "--rings",
                                    "detected", "-o", str(out), *extra])


def test_frames_centre_places_the_calibration_not_the_ring_search(tmp_path):
    conf = _picture_conf(tmp_path)  # a 300 x 300 picture, the mirror at CENTRE
    res = _calibrate(conf, tmp_path / "frames.yaml", "--centre", "402.5", "251",
                     "--image-size", "800", "500")
    assert res.exit_code == 0, res.output
    cam = load_calib(tmp_path / "frames.yaml")
    assert cam.image_size == (800, 500) and tuple(cam.centre) == (402.5, 251.0)
    # the rings were measured in the picture about its own centre: each ring's radius maps to
    # its distance, as without --centre
    np.testing.assert_allclose(cam.distance_of_radius(_mirror_radius(DIST)), DIST, atol=0.01)
    assert cam.image_size != (300, 300)


def test_a_centre_given_for_a_full_frame_picture_is_where_rings_are_measured(tmp_path):
    conf = _picture_conf(tmp_path)
    # no --image-size (or the picture's own): the picture is the frame, its centre is given
    for extra in ([], ["--image-size", "300", "300"]):
        out = tmp_path / f"c{len(extra)}.yaml"
        res = _calibrate(conf, out, "--centre", f"{CENTRE[0]:g}", f"{CENTRE[1]:g}", *extra)
        assert res.exit_code == 0, res.output
        rec = load_calib(out)
        assert tuple(rec.centre) == CENTRE and rec.image_size == (300, 300)
        assert report(out)["detected_rings"]["centre"] == list(CENTRE)
    # a centre in the picture's corner holds no ring: said as 'none', not an empty list
    res = _calibrate(conf, tmp_path / "x.yaml", "--centre", "45", "45")
    assert res.exit_code == 1
    assert "0 rings in the picture" in res.output and "Rings found: none" in res.output
    assert not (tmp_path / "x.yaml").exists()
    res = CliRunner().invoke(cli, ["calibrate", "omni", "--from-cnc", str(conf), "--centre",
                                   "45", "45", "-o", str(tmp_path / "x.yaml")])
    assert res.exit_code == 1 and "shows 0 rings." in res.output


@pytest.mark.realdata
def test_manual_cnc_route_on_the_team_files(tmp_path):
    """docs/manual.md's commands, pasted: the calibration of the team's frames has the
    picture's ring radii and the frames' centre; the frames' poses explain their line points
    well beyond the null baseline (random bearings)."""
    for p in (CNC_CONF, FRAMES):
        if not p.exists():
            pytest.skip(f"{p} absent")
    from stages.common.features_file import FeaturesFile
    from stages.common.field import load_field
    from stages.common.poses_file import read_poses
    from stages.evaluate.line_share import LineRaster

    runner = CliRunner()

    def run(*args):
        res = runner.invoke(cli, [str(a) for a in args])
        assert res.exit_code == 0, (args, res.output)
        return res.output

    ds = tmp_path / "ds"
    (ds / "images").mkdir(parents=True)
    for p in sorted(FRAMES.glob("*.png")):
        (ds / "images" / p.name).write_bytes(p.read_bytes())
    run("calibrate", "omni", "--from-cnc", CNC_CONF, "--rings", "detected", "-o",
        tmp_path / "picture.yaml")
    run("calibrate", "omni", "--from-cnc", CNC_CONF, "--rings", "detected", "--centre",
        *FRAME_CENTRE, "--image-size", *FRAME_SIZE, "-o", ds / "calib.yaml")
    picture, frames = load_calib(tmp_path / "picture.yaml"), load_calib(ds / "calib.yaml")
    assert frames.image_size == FRAME_SIZE and tuple(frames.centre) == FRAME_CENTRE
    np.testing.assert_allclose(frames.radial_table[:, 0], picture.radial_table[:, 0], atol=0.5)
    np.testing.assert_allclose(frames.radial_table[:, 1], picture.radial_table[:, 1])

    run("field", "import", FRAMES / "Globals.conf", "--base", "msl-2015", "-o",
        tmp_path / "lab.yaml")
    run("build-map", tmp_path / "lab.yaml", "-o", tmp_path / "lab.map.h5")
    run("extract", ds, "-o", tmp_path / "features.h5", "--preset", "real")
    run("localize", ds, "--map", tmp_path / "lab.map.h5", "--features",
        tmp_path / "features.h5", "--method", "lut", "--heading", "histogram", "--independent",
        "-o", tmp_path / "lut.poses.h5")
    cols = read_poses(tmp_path / "lut.poses.h5")[0]
    assert len(cols["name"]) == 4 and not np.any(cols["failed"])
    raster = LineRaster(load_field(tmp_path / "lab.yaml"))
    near = 0.15
    with FeaturesFile(tmp_path / "features.h5") as ff:
        for i, name in enumerate(cols["name"]):
            p = np.asarray(ff.frame(str(name))["points"], float)
            share = float(raster.share_near(p, cols["hypotheses"][i][0, :3], near)[0])
            # measured: 0.92-0.95 against a null of 0.37-0.41, 126-205 points a frame
            assert len(p) >= 100 and share >= raster.null_share(p, 3, near, seed=i) + 0.3, (
                name, len(p), share)



GLOBALS = """[Globals]
\tOwnTeamColour = magenta
\t[FootballField]
\t\tGoalInnerAreaExists = true
\t\tFieldWidth = 5580.0
\t\tFieldLength = 8900.0
\t\tMiddleCircleRadius = 1000.0
\t\tGoalAreaXSize = 400.0
\t\tGoalAreaYSize = 2800.0
\t\tPenaltySpot = 2000.0
\t\tPenaltyAreaYSize = 3600.0
\t\tPenaltyAreaXSize = 1290.0
\t\tCornerCircleRadius = 350.0
\t\tSurrounding = 1000.0
\t\tGoalWidth = 2000.0
\t\tGoalDepth = 580.0
\t\tGoalPostWidth = 125.0
\t\tLineWidth = 122.3
\t[!FootballField]
\t[Team]
\t\t[nase]
\t\t\tID = 9
\t\t[!nase]
\t[!Team]
[!Globals]
"""


def _geometry(path):
    """A field YAML's geometry: all but its name, source and import record."""
    import yaml

    doc = yaml.safe_load(Path(path).read_text())
    return {k: v for k, v in doc.items() if k not in ("name", "source", "imported")}


def test_globals_conf_field_block_imported(tmp_path):
    """The team's Globals.conf holds one field's keys directly in [FootballField], inside
    [Globals] beside their team settings: that block is the field; the rest is recorded as
    not the field, and --section (which names a field among several) is refused."""
    src = tmp_path / "Globals.conf"
    src.write_text(GLOBALS)
    runner = CliRunner()
    res = runner.invoke(cli, ["field", "import", str(src), "-o", str(tmp_path / "g.yaml"),
                              "--base", "msl-2015"])
    assert res.exit_code == 0, res.output
    g = _geometry(tmp_path / "g.yaml")
    assert (g["length"], g["width"], g["line_width"], g["goal"]["width"]) == (
        8.9, 5.58, 0.1223, 2.125)
    res = runner.invoke(cli, ["field", "import", str(src), "-o", str(tmp_path / "h.yaml"),
                              "--section", "Lab"])
    assert res.exit_code == 1 and "without --section" in res.output
    assert len(res.output.strip().splitlines()) == 1 and not (tmp_path / "h.yaml").exists()


@pytest.mark.realdata
def test_team_globals_conf_is_their_lab_field(tmp_path):
    src = FRAMES / "Globals.conf"
    for p in (src, FIELD_CONF):
        if not p.exists():
            pytest.skip(f"{p} absent")
    runner = CliRunner()
    for args, out in (([src], "g.yaml"), ([FIELD_CONF, "--section", "Lab"], "lab.yaml")):
        res = runner.invoke(cli, ["field", "import", *map(str, args), "--base", "msl-2015",
                                  "-o", str(tmp_path / out)])
        assert res.exit_code == 0, res.output
    assert _geometry(tmp_path / "g.yaml") == _geometry(tmp_path / "lab.yaml")
