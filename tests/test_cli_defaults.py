"""Every command run with its defaults hands its stage the stage's own preset, and the keyword
options it passes are the main's defaults: the CLI's defaults cannot drift from the stages'.

Each case runs the command with only its required arguments, with the stage main it calls
replaced by one that records its arguments (nothing is read or written); the conf recorded,
resolved as the stage resolves it, must equal the preset, and every keyword the command
passes that the main has a default for must equal that default.
"""

from __future__ import annotations

import importlib
import inspect
import math

import pytest
from click.testing import CliRunner

from fieldloc_cli.main import cli
from stages import build_map, build_templates, calibrate, evaluate, extract, localize, simulate
from stages.calibrate import hulks
from stages.common.conf import stage_conf
from stages.evaluate import export
from stages.ingest import rosbag, team_fields
from stages.pipelines import batch, error_surface, frame_belief
from stages.show import html_report, hypotheses
from stages.show import map as show_map


class Called(Exception):
    """Raised by the stand-in of a stage main: what the command passed it."""

    def __init__(self, args, kwargs):
        super().__init__("stage main called")
        self.call_args, self.call_kwargs = args, kwargs


def _points_conf(conf):
    return extract.resolve_extract_conf("omni", conf)


# (id, argv, "module:main", resolve the recorded conf like the stage, the preset it must be,
#  keywords the case sets itself, camera kind of the dataset for extract's presets)
CASES = [
    ("build-map", ["build-map", "msl-2015", "-o", "m.h5"], "stages.build_map:main",
     lambda c: stage_conf(build_map.confs, c), build_map.confs["default"], (), None),
    ("simulate omni", ["simulate", "omni", "--field", "spl", "-o", "d"], "stages.simulate:main",
     simulate.resolve_simulate_conf, simulate.confs["omni-default"], (), None),
    ("simulate perspective", ["simulate", "perspective", "--field", "kidsize", "-o", "d"],
     "stages.simulate:main", simulate.resolve_simulate_conf,
     simulate.confs["perspective-default"], (), None),
    ("extract omni", ["extract", "ds"], "stages.extract:main",
     lambda c: extract.resolve_extract_conf("omni", c), extract.confs["omni-default"], (),
     "omni"),
    ("extract perspective", ["extract", "ds"], "stages.extract:main",
     lambda c: extract.resolve_extract_conf("perspective", c),
     extract.confs["perspective-default"], (), "perspective"),
    ("localize lut", ["localize", "ds", "--map", "m.h5", "--features", "f.h5"],
     "stages.pipelines.images_to_poses:main", localize.resolve_localize_conf,
     localize.confs["default"], ("features",), None),
    ("localize mcl", ["localize", "ds", "--map", "m.h5", "--features", "f.h5", "--method",
                      "mcl"], "stages.pipelines.images_to_poses:main",
     localize.resolve_localize_conf, localize.confs["mcl-default"], ("features",), None),
    ("localize templates", ["localize", "ds", "--method", "templates", "--templates", "t.h5"],
     "stages.localize:main", localize.resolve_localize_conf, localize.confs["templates-default"],
     ("templates",), None),
    ("build-templates", ["build-templates", "ds", "-o", "t.h5"], "stages.build_templates:main",
     build_templates.resolve_build_conf, build_templates.confs["default"], (), None),
    ("localize fit", ["localize", "ds", "--map", "m.h5", "--features", "f.h5", "--method",
                      "fit"], "stages.pipelines.images_to_poses:main",
     localize.resolve_localize_conf, localize.confs["fit-default"], ("features",), None),
    ("localize from images", ["localize", "ds", "--map", "m.h5"],
     "stages.pipelines.images_to_poses:main", localize.resolve_localize_conf,
     localize.confs["default"], (), None),
    ("evaluate", ["evaluate", "p.h5", "--truth", "t.csv"], "stages.pipelines.evaluation:main",
     lambda c: stage_conf(evaluate.confs, c), evaluate.confs["default"], (), None),
    ("report", ["report", "runs", "-o", "r.html"], "stages.show.html_report:main",
     lambda c: stage_conf(html_report.confs, c), html_report.confs["default"], (), None),
    ("show map", ["show", "map", "m.h5", "-o", "x.png"], "stages.show.map:main",
     lambda c: stage_conf(show_map.confs, c), show_map.confs["default"], (), None),
    ("show points", ["show", "points", "ds", "--frame", "0", "-o", "x.png"],
     "stages.pipelines.frame_points:write_picture", _points_conf, extract.confs["omni-default"],
     ("frame",), None),
    ("show belief", ["show", "belief", "ds", "--frame", "0", "--map", "m.h5", "-o", "x.png"],
     "stages.pipelines.frame_belief:write_picture",
     lambda c: stage_conf(frame_belief.confs, c),
     frame_belief.confs["default"], ("frame",), None),
    ("show hypotheses", ["show", "hypotheses", "p.h5", "-o", "x.png"],
     "stages.show.hypotheses:main", lambda c: stage_conf(hypotheses.confs, c),
     hypotheses.confs["default"], (), None),
    ("show error-surface", ["show", "error-surface", "t.h5", "queries", "-o", "x.png"],
     "stages.pipelines.error_surface:write_picture", lambda c: stage_conf(error_surface.confs, c),
     error_surface.confs["default"], (), None),
    ("calibrate omni points", ["calibrate", "omni", "pairs.csv", "-o", "c.yaml", "--centre",
                               "240", "240", "--image-size", "480", "480", "--valid-radius",
                               "40", "220"], "stages.calibrate:main",
     lambda c: stage_conf(calibrate.confs, c), calibrate.confs["default"], ("geometry",),
     None),
    ("calibrate omni minho", ["calibrate", "omni", "--from-minho", "team", "-o", "c.yaml"],
     "stages.calibrate:from_minho", lambda c: stage_conf(calibrate.confs, c, "minho"),
     calibrate.confs["minho"], (), None),
    ("calibrate omni cnc", ["calibrate", "omni", "--from-cnc", "Carpet.conf", "--rings",
                            "detected", "-o", "c.yaml"], "stages.calibrate:from_cnc",
     lambda c: stage_conf(calibrate.confs, c, "cnc"), calibrate.confs["cnc"], ("rings",),
     None),
    ("calibrate perspective", ["calibrate", "perspective", "--from-hulks", "HULKS", "-o",
                               "c.yaml"], "stages.calibrate.hulks:main",
     lambda c: stage_conf(hulks.confs, c), hulks.confs["default"], (), None),
    ("import rosbag", ["import", "rosbag", "run.bag", "-o", "d", "--image-topic", "/img"],
     "stages.ingest.rosbag:main", lambda c: stage_conf(rosbag.confs, c),
     rosbag.confs["default"], ("image_topic",), None),
    ("field import", ["field", "import", "f.cfg", "--format", "bhuman", "-o", "f.yaml"],
     "stages.ingest.team_fields:main", lambda c: stage_conf(team_fields.confs, c),
     team_fields.confs["default"], ("fmt",), None),
    ("export", ["export", "p.h5", "--format", "csv"], "stages.evaluate.export:main",
     lambda c: stage_conf(export.confs, c), export.confs["default"], ("fmt",), None),
    ("batch", ["batch", "spec.yaml", "-o", "results"], "stages.pipelines.batch:main",
     lambda c: stage_conf(batch.confs, c), batch.confs["default"], ("report",), None),
]


def _same(value, default) -> bool:
    if isinstance(default, float) and isinstance(value, float):
        return math.isclose(value, default, rel_tol=0, abs_tol=1e-12)
    if isinstance(default, (int, float)) and isinstance(value, str):  # --frame "0"
        return value == str(default)
    return value == default


@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
def test_cli_defaults_are_the_stage_presets(case, tmp_path, monkeypatch):
    name, argv, target, resolve, preset, set_here, kind = case
    monkeypatch.chdir(tmp_path)
    (tmp_path / "HULKS").write_text("{}")  # --from-hulks must exist
    mod_name, attr = target.split(":")
    module = importlib.import_module(mod_name)
    real = getattr(module, attr)

    def called(*args, **kwargs):
        raise Called(args, kwargs)

    monkeypatch.setattr(module, attr, called)
    if kind is not None:  # extract's presets are the dataset's camera kind's
        monkeypatch.setattr(extract, "camera_kind", lambda _d: kind)
    res = CliRunner().invoke(cli, argv)
    assert isinstance(res.exception, Called), (name, res.output, res.exception)
    args, kwargs = res.exception.call_args, res.exception.call_kwargs
    assert resolve(args[0]) == preset, name
    params = inspect.signature(real).parameters
    for key, value in kwargs.items():
        default = params[key].default
        if key in set_here or default is inspect.Parameter.empty:
            continue
        assert _same(value, default), (name, key, value, default)
