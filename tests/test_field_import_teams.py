"""`fieldloc field import` of MINHO .view, Carpe Noctem FootballField.conf, CAMBADA and HULKs
files (the real ones in ../shared/realdata), through the CLI: each writes a field YAML that
`build-map` turns into a map whose field has the file's dimensions within 1 mm."""

from pathlib import Path

import pytest
from click.testing import CliRunner

from fieldloc_cli.main import cli
from stages.common.field import load_field
from stages.common.map_file import MapFile
from stages.ingest.field_formats import FieldFormatError, detect_format

REALDATA = Path(__file__).resolve().parents[2] / "shared" / "realdata"
DIMS = REALDATA / "field-dimensions"
MM = 1e-3  # the tolerance: the files give millimetres
FAST_MAP = ["--resolution", "0.5", "--max-range", "3"]


def _need(path):
    if not path.exists():
        pytest.skip(f"{path} not present")
    return path


def _import_and_map(tmp_path, src, *args):
    """field import (format told from the file) -> YAML -> build-map; the map's field."""
    runner = CliRunner()
    out = tmp_path / f"{src.stem}.yaml"
    res = runner.invoke(cli, ["field", "import", str(src), "-o", str(out), *args])
    assert res.exit_code == 0, res.output
    mp = tmp_path / f"{src.stem}.map.h5"
    res = runner.invoke(cli, ["build-map", str(out), "-o", str(mp), *FAST_MAP])
    assert res.exit_code == 0, res.output
    with MapFile(mp) as m:
        fm = m.field
    assert fm.spec == load_field(out).spec  # the map holds the YAML's field unchanged
    return fm


def _dims(fm) -> dict:
    s = fm.spec
    out = {"length": s["length"], "width": s["width"], "line_width": s["line_width"],
           "border": s["border"], "centre_circle_diameter": s["centre_circle_diameter"],
           "corner_arc_radius": s.get("corner_arc_radius", 0.0)}
    for group in ("goal_area", "penalty_area", "penalty_mark", "goal"):
        for k, v in s.get(group, {}).items():
            out[f"{group}.{k}"] = v
    return out


def _assert_dims(fm, expected: dict):
    got = _dims(fm)
    for key, value in expected.items():
        assert got[key] == pytest.approx(value, abs=MM), key


def _view(path) -> dict:
    return {k: float(v) / 1000 for k, v in (ln.split("=") for ln in
                                            Path(path).read_text().split() if "=" in ln)}


@pytest.mark.realdata
@pytest.mark.parametrize("name", ["Lar.view", "Official.view"])
def test_minho_view_round_trips(tmp_path, name):
    src = _need(REALDATA / "minho-lab" / name)
    v = _view(src)
    fm = _import_and_map(tmp_path, src)
    _assert_dims(fm, {
        "length": v["LENGTH"], "width": v["WIDTH"], "line_width": v["LINE_WIDTH"],
        "border": min(v["TOTAL_LENGTH"] - v["LENGTH"], v["TOTAL_WIDTH"] - v["WIDTH"]) / 2,
        "centre_circle_diameter": 2 * v["CENTER_RADIUS"],
        "corner_arc_radius": v["RADIUS_CORNER"],
        "goal_area.length": v["AREA_LENGTH1"], "goal_area.width": v["AREA_WIDTH1"],
        "penalty_area.length": v["AREA_LENGTH2"], "penalty_area.width": v["AREA_WIDTH2"],
        "penalty_mark.distance": v["DISTANCE_PENALTY"], "penalty_mark.size": v["SPOTS"],
        "goal.width": v["GOAL_WIDTH"] + v["GOALIE_POST_WIDTH"],
        "goal.depth": v["GOAL_LENGTH"], "goal.post_diameter": v["GOALIE_POST_WIDTH"]})
    rec = fm.spec["imported"]
    assert rec["format"] == "minho" and rec["unknown"] == {}
    assert set(rec["values"]) | set(rec["not_geometry"]) == set(
        ln.split("=")[0] for ln in src.read_text().split() if "=" in ln)
    assert fm.summary()["crossings"] == {"L": 12, "T": 18, "X": 2}


@pytest.mark.realdata
def test_lab_view_is_the_field_the_realdata_checks_use():
    """The realdata checks take the lab field from the importer: the field the project wrote
    by hand before (10.2 x 7.54 m, circle 2.74 m, areas 0.7 x 3.2 and 1.55 x 4.42 m) is
    what Lar.view says; the border is the file's narrower strip (0.73 m, was typed 0.7)."""
    from stages.pipelines.realdata import lab_field

    _need(REALDATA / "minho-lab" / "Lar.view")
    spec = lab_field()
    assert spec["name"] == "minho-lab"
    assert (spec["length"], spec["width"], spec["centre_circle_diameter"]) == pytest.approx(
        (10.2, 7.54, 2.74), abs=MM)
    assert spec["goal_area"] == pytest.approx({"length": 0.7, "width": 3.2}, abs=MM)
    assert spec["penalty_area"] == pytest.approx({"length": 1.55, "width": 4.42}, abs=MM)
    assert spec["border"] == pytest.approx(0.73, abs=MM)


CNC_SECTIONS = {  # section -> the file's values (mm) of the keys this test checks
    "Lab": dict(FieldLength=8900, FieldWidth=5580, MiddleCircleRadius=1000, GoalAreaXSize=400,
                GoalAreaYSize=2800, PenaltySpot=2000, PenaltyAreaXSize=1290,
                PenaltyAreaYSize=3600, CornerCircleRadius=350, Surrounding=1000, GoalWidth=2000,
                GoalDepth=580, GoalPostWidth=125, LineWidth=122.3),
    "Official": dict(FieldLength=18000, FieldWidth=12000, MiddleCircleRadius=2000,
                     GoalAreaXSize=750, GoalAreaYSize=3500, PenaltySpot=3000,
                     PenaltyAreaXSize=2250, PenaltyAreaYSize=6500, CornerCircleRadius=750,
                     Surrounding=1500, GoalWidth=2000, GoalDepth=580, GoalPostWidth=125,
                     LineWidth=122.3),
}


@pytest.mark.realdata
@pytest.mark.parametrize("section", ["Lab", "Official"])
def test_carpenoctem_sections_round_trip(tmp_path, section):
    src = _need(DIMS / "cnc_msl" / "FootballField.conf")
    c = {k: v / 1000 for k, v in CNC_SECTIONS[section].items()}
    fm = _import_and_map(tmp_path, src, "--section", section, "--base", "msl-2015")
    _assert_dims(fm, {
        "length": c["FieldLength"], "width": c["FieldWidth"], "line_width": c["LineWidth"],
        "border": c["Surrounding"], "centre_circle_diameter": 2 * c["MiddleCircleRadius"],
        "corner_arc_radius": c["CornerCircleRadius"],
        "goal_area.length": c["GoalAreaXSize"], "goal_area.width": c["GoalAreaYSize"],
        "penalty_area.length": c["PenaltyAreaXSize"], "penalty_area.width": c["PenaltyAreaYSize"],
        "penalty_mark.distance": c["PenaltySpot"],
        "penalty_mark.size": 0.15,  # not in the file: msl-2015's J
        "goal.width": c["GoalWidth"] + c["GoalPostWidth"], "goal.depth": c["GoalDepth"],
        "goal.post_diameter": c["GoalPostWidth"]})
    rec = fm.spec["imported"]
    assert rec["section"] == section and rec["unknown"] == {}
    assert rec["from_base"]["keys"] == ["penalty_mark.size"]
    assert fm.name == f"carpenoctem-{section}"


@pytest.mark.realdata
def test_every_carpenoctem_section_imports(tmp_path):
    """All five fields of the team's file; [ASML_VDL] lists MiddleCircleRadius twice with one
    value (noted); without --base the missing mark size is named."""
    from stages.ingest.team_fields import TeamFieldError, read_team_field

    src = _need(DIMS / "cnc_msl" / "FootballField.conf")
    for section in ("Lab", "Tournament", "Official", "Carpet", "ASML_VDL"):
        imp = read_team_field(src, section=section, base="msl-2015")
        assert imp.record["format"] == "carpenoctem" and imp.unknown == {}
        assert any("given twice" in w for w in imp.warnings) == (section == "ASML_VDL")
    assert read_team_field(src, base="msl-2015").record["section"] == "Official"  # CurrentField
    with pytest.raises(TeamFieldError, match="penalty_mark.size; pass --base"):
        read_team_field(src)


def test_carpenoctem_section_choice_and_errors(tmp_path):
    """Without --section the file's CurrentField; a missing section, a key given twice with
    two values and an unclosed section are one-line errors."""
    body = ("\t[{n}]\n\t\tFieldWidth = 4000\n\t\tFieldLength = 6000\n\t\tMiddleCircleRadius ="
            " 600\n\t\tGoalAreaXSize = 300\n\t\tGoalAreaYSize = 1500\n\t\tPenaltySpot = 1000\n"
            "\t\tPenaltyAreaXSize = 800\n\t\tPenaltyAreaYSize = 2500\n\t\tCornerCircleRadius ="
            " 0\n\t\tSurrounding = 500\n\t\tGoalWidth = 1000\n\t\tGoalDepth = 400\n"
            "\t\tGoalPostWidth = 50\n\t\tLineWidth = 50\n\t\tFieldSize = 3\n\t[!{n}]\n")
    conf = tmp_path / "FootballField.conf"
    conf.write_text("[FootballField]\n\tCurrentField = B\n" + body.format(n="A")
                    + body.format(n="B").replace("6000", "7000") + "[!FootballField]\n")
    runner = CliRunner()
    res = runner.invoke(cli, ["field", "import", str(conf), "-o", str(tmp_path / "b.yaml"),
                              "--base", "kidsize"])
    assert res.exit_code == 0, res.output
    fm = load_field(tmp_path / "b.yaml")
    assert fm.length == pytest.approx(7.0) and "corner_arc_radius" not in fm.spec
    assert fm.spec["imported"]["unknown"] == {"FieldSize": "3"}
    assert "unknown keys (1" in res.output
    res = runner.invoke(cli, ["field", "import", str(conf), "-o", str(tmp_path / "c.yaml"),
                              "--section", "C"])
    assert res.exit_code == 1 and "no section [C] (sections: A, B)" in res.output
    conf.write_text(conf.read_text().replace("FieldSize = 3", "FieldWidth = 4100"))
    res = runner.invoke(cli, ["field", "import", str(conf), "-o", str(tmp_path / "d.yaml"),
                              "--base", "kidsize"])
    assert res.exit_code == 1 and "'FieldWidth' given twice in [B] with two values" in res.output
    conf.write_text("[FootballField]\n" + body.format(n="A").replace("[!A]", ""))
    res = runner.invoke(cli, ["field", "import", str(conf), "-o", str(tmp_path / "e.yaml")])
    assert res.exit_code == 1 and "never closed" in res.output
    for out in "bcde":  # refused imports leave nothing behind
        assert (tmp_path / f"{out}.yaml").exists() == (out == "b")


@pytest.mark.realdata
def test_cambada_round_trips(tmp_path):
    import json

    src = _need(DIMS / "cambada" / "cambada_conf_field.json")
    c = {k: v / 1000 for k, v in json.loads(src.read_text()).items() if k != "source"}
    fm = _import_and_map(tmp_path, src, "--base", "msl-2015")
    _assert_dims(fm, {
        "length": c["field_length"], "width": c["field_width"], "line_width": c["line_thickness"],
        "border": min(c["goal_band_width"], c["side_band_width"]),
        "centre_circle_diameter": 2 * c["center_circle_radius"],
        "corner_arc_radius": c["corner_arc_radius"],
        "goal_area.length": c["goal_area_length"], "goal_area.width": c["goal_area_width"],
        "penalty_area.length": c["penalty_area_length"],
        "penalty_area.width": c["penalty_area_width"],
        "penalty_mark.distance": c["penalty_marker_distance"],
        "goal.width": c["goal_width"], "goal.depth": c["goal_length"]})
    rec = fm.spec["imported"]
    assert rec["format"] == "cambada" and rec["unknown"] == {}
    assert sorted(rec["from_base"]["keys"]) == ["goal.post_diameter", "penalty_mark.size"]
    # 17.875 m between the goal lines' centres: the 18 m MSL field less one 0.125 m line, as
    # msl-2015 builds it from the rulebook's letters (measured to the lines' outer side)
    assert fm.length == pytest.approx(load_field("msl-2015").length, abs=MM)


@pytest.mark.realdata
@pytest.mark.parametrize("name", sorted(p.name for p in (DIMS / "hulks").glob("*.json*"))
                         if (DIMS / "hulks").exists() else ["absent.json"])
def test_hulks_files_round_trip(tmp_path, name):
    import json

    from stages.ingest.field_formats import _json5

    src = _need(DIMS / "hulks" / name)
    h = _json5(src.read_text(), name)["field_dimensions"]
    fm = _import_and_map(tmp_path, src)
    expected = {
        "length": h["length"], "width": h["width"], "line_width": h["line_width"],
        "border": h["border_strip_width"], "centre_circle_diameter": h["center_circle_diameter"],
        "corner_arc_radius": h.get("corner_arc_radius", 0.0),
        "goal_area.length": h["goal_box_area_length"], "goal_area.width": h["goal_box_area_width"],
        "penalty_area.length": h["penalty_area_length"],
        "penalty_area.width": h["penalty_area_width"],
        "penalty_mark.distance": h["penalty_marker_distance"],
        "penalty_mark.size": h["penalty_marker_size"],
        "goal.width": h["goal_inner_width"] + h["goal_post_diameter"],
        "goal.depth": h["goal_depth"], "goal.post_diameter": h["goal_post_diameter"]}
    _assert_dims(fm, expected)
    assert fm.spec["imported"]["unknown"] == {}
    assert set(fm.spec["imported"]["values"]) | {"ball_radius"} == set(h)
    if name.startswith("default"):  # the SPL field: the spl preset's lines
        spl = load_field("spl")
        assert len(fm.segments) == len(spl.segments)
        assert json.dumps(fm.summary()["crossings"]) == json.dumps(spl.summary()["crossings"])


def test_hulks_json5_comments_and_trailing_commas(tmp_path):
    src = tmp_path / "field.json5"
    src.write_text('{\n  // the lab\n  field_dimensions: {\n    "length": 6.0, "width": 4.0,'
                   ' "line_width": 0.05, /* tape */\n    "penalty_marker_size": 0.1,'
                   ' "goal_box_area_length": 0.5, "goal_box_area_width": 2.0,'
                   ' "penalty_area_length": 1.0, "penalty_area_width": 3.0,'
                   ' "penalty_marker_distance": 1.0, "center_circle_diameter": 1.2,'
                   ' "border_strip_width": 0.5, "goal_inner_width": 1.0,'
                   ' "goal_post_diameter": 0.1, "goal_depth": 0.4, "tilt": 3,\n  },\n}\n')
    runner = CliRunner()
    res = runner.invoke(cli, ["field", "import", str(src), "-o", str(tmp_path / "f.yaml")])
    assert res.exit_code == 0, res.output
    assert "unknown keys (1" in res.output and "tilt=3" in res.output
    fm = load_field(tmp_path / "f.yaml")
    assert fm.length == 6.0 and fm.spec["goal"]["width"] == pytest.approx(1.1)


def test_hulks_json5_hexadecimal_numbers(tmp_path):
    """JSON5's hexadecimal numbers (``"length": 0x9``) were refused as "not valid JSON or
    JSON5" (trial U2-12): read as the numbers they stand for, in values only (not in strings
    or keys); one beyond any field's size is refused as such, in one line."""
    body = ('{field_dimensions: {"length": LEN, "width": 0X4, "line_width": 0.05,'
            ' "penalty_marker_size": 0.1, "goal_box_area_length": 0.5,'
            ' "goal_box_area_width": 2.0, "penalty_area_length": 1.0,'
            ' "penalty_area_width": 3.0, "penalty_marker_distance": 1.0,'
            ' "center_circle_diameter": 1.2, "border_strip_width": 0.5,'
            ' "goal_inner_width": 1.0, "goal_post_diameter": 0.1, "goal_depth": 0.4,'
            ' "note": "0x9 in a string", x0x1: 2}}')
    runner = CliRunner()
    src = tmp_path / "field.json5"
    src.write_text(body.replace("LEN", "0x9"))
    res = runner.invoke(cli, ["field", "import", str(src), "--format", "hulks", "-o",
                              str(tmp_path / "f.yaml")])
    assert res.exit_code == 0, res.output
    assert "unknown keys (2, kept under imported.unknown): note=0x9 in a string, x0x1=2" in (
        res.output)
    fm = load_field(tmp_path / "f.yaml")
    assert (fm.length, fm.width) == (9.0, 4.0)
    src.write_text(body.replace("LEN", "0x" + "f" * 300))
    res = runner.invoke(cli, ["field", "import", str(src), "--format", "hulks", "-o",
                              str(tmp_path / "g.yaml")])
    assert res.exit_code == 1 and res.stderr.strip().splitlines() == [
        f"fieldloc: error: {src}: 'length' must be a finite number, got inf"], res.stderr


def test_format_told_by_file_or_refused(tmp_path):
    (tmp_path / "a.view").write_text("TOTAL_LENGTH=1\n")
    (tmp_path / "b.json").write_text('{"field_dimensions": {}}')
    (tmp_path / "c.json").write_text('{"field_length": 1, "line_thickness": 1}')
    (tmp_path / "d.conf").write_text("[FootballField]\n[!FootballField]\n")
    (tmp_path / "e.txt").write_text("length: 9\n")
    assert [detect_format(tmp_path / n) for n in ("a.view", "b.json", "c.json", "d.conf")] == [
        "minho", "hulks", "cambada", "carpenoctem"]
    with pytest.raises(FieldFormatError, match="pass --format"):
        detect_format(tmp_path / "e.txt")
    runner = CliRunner()
    res = runner.invoke(cli, ["field", "import", str(tmp_path / "e.txt"), "-o",
                              str(tmp_path / "e.yaml")])
    assert res.exit_code == 1 and "cannot tell the field file's format" in res.output
    res = runner.invoke(cli, ["field", "import", str(tmp_path / "a.view"), "-o",
                              str(tmp_path / "a.yaml")])
    assert res.exit_code == 1 and "needs TOTAL_WIDTH" in res.output
    assert "Traceback" not in res.output
    # hostile files: one line each, nothing written
    (tmp_path / "deep.json").write_text("[" * 100_000 + "]" * 100_000)
    (tmp_path / "noise.view").write_bytes(bytes(range(256)) * 8)
    (tmp_path / "inf.view").write_text("TOTAL_LENGTH=1e400\n")
    for name, fmt, message in (("deep.json", "hulks", "nested too deep"),
                               ("noise.view", None, "unreadable"),
                               ("inf.view", None, "needs TOTAL_WIDTH")):
        args = ["field", "import", str(tmp_path / name), "-o", str(tmp_path / "h.yaml")]
        res = runner.invoke(cli, args + (["--format", fmt] if fmt else []))
        assert res.exit_code == 1 and message in res.output, res.output
        assert len(res.output.strip().splitlines()) == 1 and not (tmp_path / "h.yaml").exists()


@pytest.mark.realdata
@pytest.mark.parametrize("rel, fmt", [
    ("field-dimensions/bhuman/fieldDimensions_SPL2020-2024.cfg", "bhuman"),
    ("minho-lab/Lar.view", "minho"),
    ("field-dimensions/cnc_msl/FootballField.conf", "carpenoctem"),
    ("field-dimensions/hulks/default_HEAD_field_dimensions.json", "hulks"),
    ("field-dimensions/cambada/cambada_conf_field.json", "cambada")])
def test_a_byte_order_mark_is_read_as_the_other_readers_read_it(tmp_path, rel, fmt):
    """A team file saved with a UTF-8 byte-order mark and CRLF line ends (an editor on
    Windows) imports as the file itself: B-Human's, MINHO's and Carpe Noctem's readers
    refused it quoting the invisible mark ("cannot read '\\ufeffTOTAL_LENGTH=12100'", trial
    N7), where the JSON, YAML, dataset and MINHO calibration readers read it."""
    src = _need(REALDATA / rel)
    bom = tmp_path / src.name
    bom.write_bytes(b"\xef\xbb\xbf" + src.read_bytes().replace(b"\r\n", b"\n")
                    .replace(b"\n", b"\r\n"))
    runner = CliRunner()
    specs = []
    for path, out in ((src, tmp_path / "plain.yaml"), (bom, tmp_path / "bom.yaml")):
        res = runner.invoke(cli, ["field", "import", str(path), "--format", fmt, "--base",
                                  "msl-2015", "--name", "f", "-o", str(out)])
        assert res.exit_code == 0, res.output
        spec = load_field(out).spec
        spec.pop("imported"), spec.pop("source")
        specs.append(spec)
    assert specs[0] == specs[1]
