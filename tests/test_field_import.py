"""`fieldloc field import`: B-Human, bit-bots and Falcons field files (the real ones in
../shared/realdata where present, small written ones otherwise) into field YAMLs."""

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from fieldloc_cli.main import cli
from stages.common.field import load_field
from stages.ingest.team_fields import TeamFieldError, main, read_team_field

REALDATA = Path(__file__).resolve().parents[2] / "shared" / "realdata"

DIMS = REALDATA / "field-dimensions"
MULTICAM = REALDATA / "falcons-msl-frontcam" / "multiCam.yaml"
BHUMAN_SPL = DIMS / "bhuman" / "fieldDimensions_SPL2020-2024.cfg"


def _need(path):
    if not path.exists():
        pytest.skip(f"{path} not present")
    return path


def _same_geometry(a, b, tol=1e-3):
    """Segments (either direction), arcs, marks and posts of two models within ``tol``."""
    def canon(seg):
        seg = np.asarray(seg).reshape(-1, 2, 2)
        return sorted(tuple(np.round(sorted(map(tuple, s)), 6).ravel()) for s in seg)

    for x, y in [(canon(a.segments), canon(b.segments)),
                 (sorted(map(tuple, a.arcs)), sorted(map(tuple, b.arcs))),
                 (sorted(map(tuple, a.penalty_marks)), sorted(map(tuple, b.penalty_marks))),
                 (sorted(map(tuple, a.goal_posts)), sorted(map(tuple, b.goal_posts)))]:
        assert len(x) == len(y)
        np.testing.assert_allclose(np.asarray(x, float), np.asarray(y, float), atol=tol)
    assert abs(a.line_width - b.line_width) <= tol and abs(a.border - b.border) <= tol


@pytest.mark.realdata
def test_bhuman_spl_equals_the_spl_preset(tmp_path):
    out = main(None, _need(BHUMAN_SPL), tmp_path / "spl.yaml", fmt="bhuman")
    imported, preset = load_field(out), load_field("spl")
    _same_geometry(imported, preset)
    rec = imported.spec["imported"]
    assert rec["unknown"] == {}
    assert rec["field_lines_check"].startswith("every model line")
    # every key of the file is accounted for: used, or known to describe no line
    assert set(rec["values"]) | set(rec["not_geometry"]) >= {"fieldLines", "goalHeight",
                                                             "xPosOwnGoalLine"}
    for key in ("goal_area", "penalty_area", "penalty_mark"):
        for k, v in preset.spec[key].items():
            assert abs(imported.spec[key][k] - v) <= 1e-3
    # the one number the preset does not share: B-Human's goal is 0.555 m deep (to the middle
    # of its back), the preset says 0.5; the goal depth draws no white line
    assert imported.spec["goal"]["depth"] == pytest.approx(0.555)


@pytest.mark.realdata
def test_falcons_de_locht_is_an_18_by_12_field_with_13_cm_lines(tmp_path):
    out = main(None, _need(MULTICAM), tmp_path / "delocht.yaml", fmt="falcons",
               venue="DeLocht")
    fm = load_field(out)
    # MSL measures to the outer side of the lines: 18 x 12 m outside = centre lines + one width
    assert fm.line_width == pytest.approx(0.13)
    assert fm.length + fm.line_width == pytest.approx(18.0, abs=1e-3)
    assert fm.width + fm.line_width == pytest.approx(12.0, abs=1e-3)
    pa = fm.spec["penalty_area"]
    assert pa["width"] + 0.13 == pytest.approx(6.506) and pa["length"] + 0.13 == pytest.approx(
        2.253)
    rec = fm.spec["imported"]
    assert rec["venue"] == "DeLocht" and rec["unknown"] == {}
    assert "K" in rec["not_geometry"]  # the centre mark diameter: recorded, not dropped
    assert fm.summary()["crossings"] == {"L": 12, "T": 18, "X": 2}


@pytest.mark.realdata
def test_every_real_team_file_round_trips(tmp_path):
    """Each real file imports, writes, and reads back as the same field."""
    cases = [(p, "bhuman", {}) for p in sorted((DIMS / "bhuman").glob("*.cfg"))]
    cases += [(p, "bitbots", {"base": "kidsize"})
              for p in sorted((DIMS / "bitbots").glob("*/*.yaml"))]
    cases += [(_need(DIMS / "falcons_mra" / "DefaultParams.json"), "falcons", {"base": "msl"})]
    venues = [k[len("dimensions"):] for k in yaml.safe_load(
        "\n".join(ln for ln in _need(MULTICAM).read_text().splitlines()
                  if not ln.startswith("%YAML"))) if k.startswith("dimensions")]
    assert len(venues) >= 15
    cases += [(MULTICAM, "falcons", {"venue": v, "base": "msl-2015"}) for v in venues]
    expected_errors = {"labor": "penalty_area.width",  # a 5.45 x 3.88 m lab: kidsize's areas
                       "FalconsDemoFull": "no lineThickness",
                       "FalconsDemoFullMinusTwoTilesInLength": "no lineThickness"}
    for n, (path, fmt, kw) in enumerate(cases):
        key = kw.get("venue", path.parent.name)
        if key in expected_errors:
            with pytest.raises(TeamFieldError, match=expected_errors[key]):
                main(None, path, tmp_path / f"f{n}.yaml", fmt=fmt, **kw)
            continue
        if key == "Porto2019":  # the file has a typo 'goalW': reported, goal width from base
            imp = read_team_field(path, fmt, **kw)
            assert imp.unknown == {"goalW": 2.254} and "goal.width" in imp.from_base
        out = main(None, path, tmp_path / f"f{n}.yaml", fmt=fmt, **kw)
        first = load_field(out)
        spec = dict(first.spec)
        (tmp_path / f"h{n}.yaml").write_text(yaml.safe_dump(spec, sort_keys=False))
        _same_geometry(first, load_field(tmp_path / f"h{n}.yaml"), tol=1e-9)


def test_bhuman_unknown_and_mirror_keys_reported(tmp_path):
    src = tmp_path / "fd.cfg"
    keys = {"xPosOpponentFieldBorder": 5200, "xPosOpponentGoal": 5055,
            "xPosOpponentGoalLine": 4500, "xPosOpponentGoalArea": 3900,
            "xPosOpponentPenaltyMark": 3200, "xPosOpponentPenaltyArea": 2850,
            "yPosLeftFieldBorder": 3600, "yPosLeftTouchline": 3000, "yPosLeftPenaltyArea": 2000,
            "yPosLeftGoalArea": 1100, "yPosLeftGoal": 800, "fieldLinesWidth": 50,
            "centerCircleRadius": 750, "goalPostRadius": 50, "penaltyMarkSize": 100}
    text = "".join(f"{k} = {v}; // a comment\n" for k, v in keys.items())
    text += "xPosOwnGoalLine = -xPosOpponentGoalLine;\nyPosRightGoal = -790;\n"
    text += "ballRadius = 50;\n/* block\ncomment */ obstacles = [ {x = 1; y = 2;} ];\n"
    src.write_text(text)
    runner = CliRunner()
    res = runner.invoke(cli, ["field", "import", str(src), "--format", "bhuman", "-o",
                              str(tmp_path / "f.yaml")])
    assert res.exit_code == 0, res.output
    assert "unknown keys (2" in res.output and "ballRadius=50" in res.output
    assert "border strips differ" in res.output and "not the mirror" in res.output
    rec = load_field(tmp_path / "f.yaml").spec["imported"]
    assert set(rec["unknown"]) == {"ballRadius", "obstacles"}
    assert rec["not_geometry"]["xPosOwnGoalLine"] == "mirror of xPosOpponentGoalLine"
    assert load_field(tmp_path / "f.yaml").border == pytest.approx(0.6)
    src.write_text(text.replace("fieldLinesWidth = 50;", ""))
    with pytest.raises(TeamFieldError, match="missing key 'fieldLinesWidth'"):
        read_team_field(src, "bhuman")


def test_bitbots_both_kinds_and_missing_dimensions(tmp_path):
    gen = {"header": {"version": "1.0", "type": "map_generator_config"},
           "parameters": {"map_type": "line", "penalty_mark": True, "stroke_width": 5,
                          "field_length": 900, "field_width": 600, "goal_depth": 60,
                          "goal_width": 260, "goal_area_length": 100, "goal_area_width": 300,
                          "penalty_mark_distance": 150, "center_circle_diameter": 150,
                          "border_strip_width": 100, "penalty_area_length": 200,
                          "penalty_area_width": 500, "field_feature_size": 10,
                          "robot_count": 4}}
    (tmp_path / "gen.yaml").write_text(yaml.safe_dump(gen))
    imp = read_team_field(tmp_path / "gen.yaml", "bitbots", base="kidsize")
    assert imp.from_base == ["goal.post_diameter"] and imp.unknown == {"robot_count": 4}
    spec = {k: v for k, v in imp.spec.items() if k != "imported"}
    _same_geometry(load_field("kidsize"), load_field(_write(tmp_path / "k.yaml", spec)))
    params = {"parameter_blackboard": {"ros__parameters": {"field": {
        "size": {"x": 8.0, "y": 5.5, "padding": 0.1},
        "markings": {"penalty_area": {"size": {"x": 1.5}}},
        "goal": {"width": 2.25, "depth": 0.6}, "colour": "green"}}}}
    (tmp_path / "config.yaml").write_text(yaml.safe_dump(params))
    with pytest.raises(TeamFieldError, match="gives no line_width.*--base"):
        read_team_field(tmp_path / "config.yaml", "bitbots")
    imp = read_team_field(tmp_path / "config.yaml", "bitbots", base="kidsize")
    assert imp.spec["length"] == 8.0 and imp.spec["border"] == 0.1
    assert "line_width" in imp.from_base and imp.unknown == {"colour": "green"}


def _write(path, spec):
    path.write_text(yaml.safe_dump(spec))
    return path


def test_falcons_letters_list_and_bad_input(tmp_path):
    letters = {"model": {"A": 18.0, "B": 12.0, "C": 6.5, "D": 3.5, "E": 2.25, "F": 0.75,
                         "G": 0.75, "H": 4.0, "I": 3.0, "J": 0.15, "K": 0.125, "L": 1.0,
                         "M": 1.0}, "solver": {"x": 1}}
    (tmp_path / "p.json").write_text(json.dumps(letters))
    imp = read_team_field(tmp_path / "p.json", "falcons", base="msl-2015")
    assert imp.spec["length"] == pytest.approx(17.875)
    assert imp.spec["penalty_area"]["width"] == pytest.approx(6.375)
    assert set(imp.from_base) == {"goal.width", "goal.depth", "goal.post_diameter"}
    assert imp.record["not_geometry"]["M"] == 1.0
    (tmp_path / "bad.yaml").write_text("%YAML:1.0\ndimensionsX: {A: 18}\ndimensionsY: {B: 1}\n")
    runner = CliRunner()
    res = runner.invoke(cli, ["field", "import", str(tmp_path / "bad.yaml"), "--format",
                              "falcons", "-o", str(tmp_path / "o.yaml")])
    assert res.exit_code == 1 and "choose one with --venue (X, Y)" in res.output
    res = runner.invoke(cli, ["field", "import", str(tmp_path / "bad.yaml"), "--format",
                              "falcons", "--venue", "X", "-o", str(tmp_path / "o.yaml")])
    assert res.exit_code == 1 and "no lineThickness" in res.output
    assert not (tmp_path / "o.yaml").exists()
