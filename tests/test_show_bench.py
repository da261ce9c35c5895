"""`fieldloc show map` pictures and the bench table plumbing (speed itself is not tested)."""

import json
import math

from click.testing import CliRunner

from fieldloc_cli.main import cli
from stages.pipelines.bench import harness


def test_show_map_pictures(msl2015_map, tmp_path):
    runner = CliRunner()
    for args in (["--table", "distance"], ["--table", "radial", "--cell", "1", "2"],
                 ["--table", "spiral", "--cell", "-7", "-2", "--heading-deg", "35"]):
        out = tmp_path / f"{args[1]}.png"
        res = runner.invoke(cli, ["show", "map", str(msl2015_map), *args, "-o", str(out)])
        assert res.exit_code == 0, res.output
        assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    res = runner.invoke(cli, ["show", "map", str(msl2015_map), "--table", "radial",
                              "-o", str(tmp_path / "x.png")])
    assert res.exit_code == 1 and "needs --cell" in res.output


def test_bench_rows_interleave_and_format(tmp_path):
    calls = []
    a, b = harness.time_interleaved(lambda: calls.append("a"), lambda: calls.append("b"),
                                  repeat=3, warmup=1)
    assert calls == ["a", "b"] * 4 and len(a) == len(b) == 3
    rows = [harness.Row(name="x", median_ms=2.0, baseline="y", baseline_ms=4.0, ratio=0.5,
                      goal="<= 3 ms", meets_goal=True),
            harness.Row(name="z", median_ms=math.nan)]
    table = harness.format_table(rows)
    assert "x" in table and "0.5" in table and "yes" in table
    path = harness.write_json(rows, tmp_path / "b.json")
    data = json.loads(path.read_text())
    assert data["rows"][1]["median_ms"] is None


def test_bench_only_naming_no_row_is_refused():
    """`--only` with a name no row contains ends in one line and exit code 1, not an empty
    table with exit code 0 (a comma-separated list is one name)."""
    from click.testing import CliRunner

    from fieldloc_cli.main import cli

    res = CliRunner().invoke(cli, ["bench", "--only", "lut-accuracy,fit"])
    assert res.exit_code == 1
    lines = res.output.strip().splitlines()
    assert len(lines) == 1 and "no bench row matches 'lut-accuracy,fit'" in lines[0]


def test_bench_tables_of_several_runs_merge_by_row_name(tmp_path):
    """`bench --from-json FULL --from-json AGAIN`: the full run's rows in their order, each
    replaced by the later run's row of the same name, then the rows only the later run has;
    with --json the merged rows are written, and never over one of the runs read."""
    full = harness.write_json([harness.Row("a", median_ms=1.0), harness.Row("b", median_ms=2.0),
                               harness.Row("c", median_ms=3.0)], tmp_path / "full.json")
    again = harness.write_json([harness.Row("b", median_ms=5.0, goal="<= 6 ms",
                                            meets_goal=True),
                                harness.Row("d", median_ms=4.0)], tmp_path / "again.json")
    before = full.read_bytes()
    runner = CliRunner()
    merged = tmp_path / "merged.json"
    r = runner.invoke(cli, ["bench", "--from-json", str(full), "--from-json", str(again),
                            "--json", str(merged)])
    assert r.exit_code == 0, r.output
    rows = harness.read_json(merged)
    assert [x.name for x in rows] == ["a", "b", "c", "d"]
    assert rows[1].median_ms == 5.0 and rows[1].meets_goal is True  # exact: read back as written
    lines = r.stdout.splitlines()
    assert [ln.split()[0] for ln in lines[2:6]] == ["a", "b", "c", "d"]
    r = runner.invoke(cli, ["bench", "--from-json", str(full), "--from-json", str(again),
                            "--json", str(full), "--overwrite"])
    assert r.exit_code != 0 and "is an input of this command" in r.output
    assert full.read_bytes() == before
