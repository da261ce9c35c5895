"""The stage contract (README "Architecture"): every stage main takes ``conf`` as a preset name,
None, or a dict of overrides on the default preset (of its kind), rejects unknown presets and
keys with a FieldlocError (never KeyError or TypeError), and ``confs`` lists every preset of
every kind, each of which resolves to itself by name and as a dict."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pytest

from stages import build_map, build_templates, calibrate, evaluate, extract, localize, simulate
from stages.calibrate import hulks
from stages.common.camera import save_calib
from stages.common.conf import stage_conf
from stages.common.errors import FieldlocError
from stages.evaluate import export
from stages.ingest import rosbag, team_fields
from stages.pipelines import (
    batch,
    error_surface,
    evaluation,
    frame_belief,
    frame_points,
    images_to_poses,
)
from stages.show import comparison, html_report, hypotheses, report_plots
from stages.show import map as show_map
from stages.simulate.omni_renderer import OMNI_DEFAULTS, camera_from_conf


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """An omni dataset folder: one black frame and its calib.yaml."""
    import cv2

    d = tmp_path_factory.mktemp("contract") / "ds"
    (d / "images").mkdir(parents=True)
    cv2.imwrite(str(d / "images" / "000000.png"), np.zeros((480, 480, 3), np.uint8))
    save_calib(camera_from_conf(OMNI_DEFAULTS), d / "calib.yaml")
    return d


def _mains(ds, tmp):
    """(name, call with a conf) of every stage main, with inputs its conf is read before."""
    out = tmp / "out"
    return [
        ("build_map", lambda c: build_map.main(c, "kidsize", out)),
        ("build_templates", lambda c: build_templates.main(c, ds, out)),
        ("localize templates", lambda c: localize.main(
            {"method": "templates", **c} if isinstance(c, dict) else c, ds, None, out,
            templates=tmp / "t.h5")),
        ("simulate", lambda c: simulate.main(c, "kidsize", out)),
        ("extract", lambda c: extract.main(c, ds, out)),
        ("localize", lambda c: localize.main(c, ds, tmp / "m.h5", out, features=tmp / "f.h5")),
        ("evaluate", lambda c: evaluate.main(c, tmp / "p.h5", None, out)),
        ("calibrate", lambda c: calibrate.main(c, tmp / "pairs.csv", out,
                                               geometry=calibrate.MirrorGeometry(
                                                   (240, 240), (480, 480), (40, 220)))),
        ("calibrate.from_minho", lambda c: calibrate.from_minho(c, tmp, out)),
        ("calibrate.from_cnc", lambda c: calibrate.from_cnc(c, tmp / "c.conf", out,
                                                            rings="detected")),
        ("hulks", lambda c: hulks.main(c, tmp, out)),
        ("rosbag", lambda c: rosbag.main(c, tmp / "b.bag", out, image_topic="/i")),
        ("team_fields", lambda c: team_fields.main(c, tmp / "f.cfg", out, fmt="bhuman")),
        ("export", lambda c: export.main(c, tmp / "p.h5", out, fmt="csv")),
        ("show.map", lambda c: show_map.main(c, tmp / "m.h5", out)),
        ("pipelines.frame_points", lambda c: frame_points.main(c, ds, out)),
        ("pipelines.frame_belief", lambda c: frame_belief.main(c, ds, tmp / "m.h5", out)),
        ("show.hypotheses", lambda c: hypotheses.main(c, tmp / "p.h5", out)),
        ("show.report_plots", lambda c: report_plots.main(c, tmp)),
        ("show.html_report", lambda c: html_report.main(c, tmp, out)),
        ("show.comparison", lambda c: comparison.main(c, tmp / "results")),
        ("pipelines.error_surface", lambda c: error_surface.main(c, tmp / "t.h5", tmp / "q", out)),
        ("pipelines.evaluation", lambda c: evaluation.main(c, tmp / "p.h5", None, out)),
        ("pipelines.images_to_poses", lambda c: images_to_poses.main(c, ds, tmp / "m.h5", out)),
        ("pipelines.batch", lambda c: batch.main(c, tmp / "spec.yaml", out)),
    ]


NAMES = [name for name, _ in _mains(Path("ds"), Path("tmp"))]
BAD = [("unknown preset", "no-such-preset", "unknown preset"),
       ("unknown key", {"no_such_key": 1}, "unknown conf key"),
       ("neither name nor dict", 3, "preset name or a dict")]


@pytest.mark.parametrize("bad", BAD, ids=[b[0] for b in BAD])
@pytest.mark.parametrize("name", NAMES)
def test_bad_conf_is_a_fieldloc_error(name, bad, dataset, tmp_path):
    call = dict(_mains(dataset, tmp_path))[name]
    _label, conf, message = bad
    with pytest.raises(FieldlocError, match=message):
        call(conf)
    assert not (tmp_path / "out").exists()


def _resolvers():
    """(stage, its confs, resolve a conf as its main does, default of a preset's kind)."""
    def kind_of_extract(name):
        return name.split("-")[0]

    return [
        ("build_map", build_map.confs, lambda c, n: stage_conf(build_map.confs, c)),
        ("build_templates", build_templates.confs,
         lambda c, n: build_templates.resolve_build_conf(c)),
        ("simulate", simulate.confs, lambda c, n: simulate.resolve_simulate_conf(c)),
        ("extract", extract.confs,
         lambda c, n: extract.resolve_extract_conf(kind_of_extract(n), c)),
        ("localize", localize.confs, lambda c, n: localize.resolve_localize_conf(c)),
        ("evaluate", evaluate.confs, lambda c, n: stage_conf(evaluate.confs, c)),
        ("calibrate", calibrate.confs,
         lambda c, n: stage_conf(calibrate.confs, c,
                                 n if n in ("cnc", "nubot") else "default")),
        ("hulks", hulks.confs, lambda c, n: stage_conf(hulks.confs, c)),
        ("rosbag", rosbag.confs, lambda c, n: stage_conf(rosbag.confs, c)),
        ("team_fields", team_fields.confs, lambda c, n: stage_conf(team_fields.confs, c)),
        ("export", export.confs, lambda c, n: stage_conf(export.confs, c)),
        ("show.map", show_map.confs, lambda c, n: stage_conf(show_map.confs, c)),
        ("pipelines.frame_belief", frame_belief.confs,
         lambda c, n: stage_conf(frame_belief.confs, c)),
        ("show.hypotheses", hypotheses.confs, lambda c, n: stage_conf(hypotheses.confs, c)),
        ("show.report_plots", report_plots.confs,
         lambda c, n: stage_conf(report_plots.confs, c)),
        ("show.html_report", html_report.confs, lambda c, n: stage_conf(html_report.confs, c)),
        ("pipelines.batch", batch.confs, lambda c, n: stage_conf(batch.confs, c)),
        ("show.comparison", comparison.confs, lambda c, n: stage_conf(comparison.confs, c)),
        ("pipelines.error_surface", error_surface.confs,
         lambda c, n: stage_conf(error_surface.confs, c)),
    ]


PRESETS = [(stage, name) for stage, confs, _r in _resolvers() for name in confs]


@pytest.mark.parametrize("stage, name", PRESETS, ids=[f"{s}:{n}" for s, n in PRESETS])
def test_every_preset_resolves_to_itself_by_name_and_as_a_dict(stage, name):
    confs, resolve = {s: (c, r) for s, c, r in _resolvers()}[stage]
    want = json.dumps(confs[name], sort_keys=True)
    by_name = name.split("-", 1)[1] if stage == "extract" else name
    assert json.dumps(resolve(by_name, name), sort_keys=True) == want
    assert json.dumps(resolve(copy.deepcopy(confs[name]), name), sort_keys=True) == want


def test_confs_list_every_preset_of_every_kind():
    assert set(extract.confs) == {f"{k}-{n}" for k in extract.KINDS
                                  for n in extract.kind_confs(k)}
    assert {f"{m}-{n}" for m in localize.METHODS
            for n in localize.method_confs(m)} | {"default"} == set(localize.confs)
    assert all(localize.confs[n]["method"] == n.split("-")[0] for n in localize.confs
               if n != "default")
    assert {c["camera"] for c in simulate.confs.values()} == set(simulate.RENDERERS)


def test_partial_dicts_and_none_take_the_default_preset_of_their_kind(dataset):
    """The issue's cases: build_map.main({'resolution': 0.5}) raised KeyError 'border',
    simulate.main(None) a TypeError, extract needed a separate overrides argument."""
    assert stage_conf(build_map.confs, {"resolution": 0.5}) == {
        **build_map.confs["default"], "resolution": 0.5}
    assert simulate.resolve_simulate_conf(None) == simulate.confs["default"]
    persp = simulate.resolve_simulate_conf({"camera": "perspective", "frames": 2})
    assert persp == {**simulate.confs["perspective-default"], "frames": 2}
    assert localize.resolve_localize_conf({"method": "mcl", "init": "uniform"}) == \
        localize.confs["mcl-uniform"]
    assert extract.resolve_extract_conf("omni", {"max_white_m": 0.6}) == extract.confs["omni-real"]
    assert extract.resolve_extract_conf("omni", "omni-dense") == extract.confs["omni-dense"]
    with pytest.raises(FieldlocError, match="perspective cameras"):
        extract.resolve_extract_conf("omni", "perspective-default")
    with pytest.raises(FieldlocError, match="unknown method"):
        localize.resolve_localize_conf({"method": "nope"})
    with pytest.raises(FieldlocError, match="camera kind"):
        simulate.resolve_simulate_conf({"camera": "fisheye"})
