"""`fieldloc --help`, `fieldloc --version` and the help of every command and subcommand import no
stage and none of the heavy libraries (the start-up goal: a help page must not cost seconds of CPU
and hundreds of MB, nor compile kernels on a fresh install). Each help runs in its own interpreter,
which then lists the modules it imported. The commands come from the command tables, so a new
command is checked without being named here.

What the help shows of the stages without importing them (the commands' short help in the
tables, the preset names and defaults in fieldloc_cli/stage_defaults.py) is checked against the
commands and stages it copies. Speed is measured by `fieldloc bench --only cli-help`, not here.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import click
import pytest

from fieldloc_cli import stage_defaults as shown
from fieldloc_cli.main import COMMANDS, LazyGroup, cli

ROOT = Path(__file__).resolve().parents[1]
HEAVY = ("numpy", "cv2", "numba", "h5py", "scipy", "matplotlib", "dask")
# the package root, its error classes, the formatting of the lines on stderr and the stops a
# signal's handler could not raise (stdlib only)
LIGHT_STAGE_MODULES = {"stages", "stages.common", "stages.common.errors",
                       "stages.common.one_line", "stages.common.stops"}

# runs the CLI on argv[1:] as the `fieldloc` script does, without exiting, then prints the
# exit code and the sorted names of the imported modules as the last line (JSON)
RUN = """\
import json, sys
from fieldloc_cli.main import cli
code = cli.main(sys.argv[1:], prog_name="fieldloc", standalone_mode=False)
print(json.dumps({"code": code, "modules": sorted(sys.modules)}))
"""


def _command_paths(group: click.Group, prefix: tuple[str, ...] = ()) -> list[tuple[str, ...]]:
    """Every command and subcommand below ``group`` (loaded, in this process), as argv."""
    ctx = click.Context(group)
    out = []
    for name in group.list_commands(ctx):
        cmd = group.get_command(ctx, name)
        out.append(prefix + (name,))
        if isinstance(cmd, click.Group):
            out += _command_paths(cmd, prefix + (name,))
    return out


PATHS = _command_paths(cli)
ARGVS = [["--help"], ["--version"]] + [list(p) + ["--help"] for p in PATHS]


def test_every_command_and_subcommand_is_checked():
    """The discovery walks the tables and the groups below them (not a hand list)."""
    assert {p[0] for p in PATHS} == set(COMMANDS)
    for sub in (("show", "map"), ("import", "rosbag"), ("field", "import"),
                ("simulate", "perspective"), ("calibrate", "omni")):
        assert sub in PATHS


def forbidden(modules: list[str]) -> list[str]:
    """Stage modules beyond LIGHT_STAGE_MODULES, and heavy libraries."""
    return [m for m in modules
            if (m.split(".")[0] == "stages" and m not in LIGHT_STAGE_MODULES)
            or m.split(".")[0] in HEAVY]


def test_forbidden_names_what_it_should():
    assert forbidden(["stages", "stages.common", "stages.common.errors", "click", "json"]) == []
    assert forbidden(["stages.common.conf", "stages.localize", "numpy.linalg", "cv2"]) == [
        "stages.common.conf", "stages.localize", "numpy.linalg", "cv2"]


@pytest.mark.parametrize("argv", ARGVS, ids=[" ".join(a) for a in ARGVS])
def test_help_imports_no_stage(argv):
    res = subprocess.run([sys.executable, "-c", RUN, *argv], cwd=ROOT, capture_output=True,
                         text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    *shown_lines, last = res.stdout.splitlines()
    report = json.loads(last)
    assert report["code"] == 0
    text = "\n".join(shown_lines)
    assert ("version" in text) if argv == ["--version"] else text.startswith("Usage: fieldloc")
    assert "stages" in report["modules"]  # the list is the CLI's, it imported the package
    assert forbidden(report["modules"]) == [], argv


LAZY_GROUPS = {"fieldloc": (cli, COMMANDS)} | {
    f"fieldloc {name}": (group, group.lazy_commands) for name in COMMANDS
    if isinstance(group := cli.get_command(click.Context(cli), name), LazyGroup)}


@pytest.mark.parametrize("group,table", LAZY_GROUPS.values(), ids=list(LAZY_GROUPS))
def test_the_tables_short_help_is_each_commands_own(group, table):
    """The listing made from a table is the one click makes from the loaded commands: each
    short help is the first sentence of the command's own help."""
    ctx = click.Context(group)
    for name, (_target, short_help) in table.items():
        assert short_help == group.get_command(ctx, name).get_short_help_str(10**6), name
    for width in (80, 10**4):
        ours, clicks = click.HelpFormatter(width=width), click.HelpFormatter(width=width)
        group.format_commands(ctx, ours)
        click.Group.format_commands(group, ctx, clicks)
        assert ours.getvalue() == clicks.getvalue()


def test_the_shown_defaults_are_the_stages():
    """Every copy in fieldloc_cli/stage_defaults.py equals the stage value its comment names."""
    from stages import build_map, build_templates, calibrate, evaluate, extract, localize, simulate
    from stages.common import camera
    from stages.common.describe import READS
    from stages.evaluate import export
    from stages.ingest import rosbag, team_fields
    from stages.pipelines import error_surface
    from stages.pipelines import frame_belief as belief
    from stages.show import map as show_map
    from stages.simulate.trajectory import PATH_KINDS

    assert shown.BUILD_MAP == {k: build_map.confs["default"][k] for k in shown.BUILD_MAP}
    assert shown.BUILD_TEMPLATES_FEATURES == tuple(build_templates.FEATURE_PRESETS)
    assert shown.CALIBRATE_PRESETS == tuple(sorted(calibrate.confs))
    assert shown.CALIBRATE_MAX_IMAGE_PX == camera.MAX_IMAGE_PX
    assert shown.EVALUATE_PRESETS == tuple(sorted(evaluate.confs))
    assert shown.EVALUATE_STAMP_TOLERANCE == evaluate.confs["default"]["stamp_tolerance"]
    assert shown.EXPORT_FORMATS == tuple(sorted(export.FORMATS))
    assert shown.EXTRACT_DEFAULT_PRESET == extract.DEFAULT_PRESET
    assert shown.EXTRACT_OMNI_PRESETS == tuple(sorted(extract.kind_confs("omni")))
    assert shown.FIELD_FORMATS == tuple(team_fields.FORMATS)
    assert shown.ROSBAG_PRESETS == tuple(sorted(rosbag.confs))
    assert shown.INSPECT_READS == READS
    assert shown.LOCALIZE_METHODS == tuple(localize.METHODS)
    assert shown.LOCALIZE_DEFAULT_METHOD == localize.DEFAULT_METHOD
    for (method, key), value in shown.LOCALIZE.items():
        assert localize.method_confs(method)["default"][key] == value, (method, key)
    b = belief.confs["default"]
    assert shown.SHOW_BELIEF == {"resolution": b["resolution"],
                                 "heading_step_deg": round(math.degrees(b["heading_step"]), 6)}
    assert shown.SHOW_ERROR_SURFACE == {k: error_surface.confs["default"][k]
                                        for k in shown.SHOW_ERROR_SURFACE}
    m = show_map.confs["default"]
    assert shown.SHOW_MAP == {"table": m["table"], "heading_deg": math.degrees(m["heading"]),
                              "family": m["family"], "spirals": m["spirals"]}
    assert shown.SHOW_MAP_TABLES == tuple(show_map.TABLES)
    assert shown.SHOW_MAP_FAMILIES == tuple(sorted(show_map.FAMILIES))
    assert shown.SIMULATE_PATH_KINDS == tuple(PATH_KINDS)
    assert shown.SIMULATE_PRESETS == {
        camera: tuple(sorted(k for k, v in simulate.confs.items() if v["camera"] == camera))
        for camera in {v["camera"] for v in simulate.confs.values()}}
    for preset, values in shown.SIMULATE.items():
        c = simulate.confs[preset]
        live = {"frames": c["frames"], "seed": c["seed"], "trajectory": c["trajectory"]["kind"],
                "calib_error": (*c["calib_error"]["centre_shift"], c["calib_error"]["scale"])}
        if "grid_headings" in values:
            live["grid_headings"] = c["trajectory"]["grid_headings"]
        if "height" in values:
            live["height"] = c["perspective"]["height"]
            live["pitch_deg"] = round(math.degrees(c["perspective"]["pitch"]), 1)
        assert values == live, preset


def test_errors_still_end_in_one_line():
    """The lazy commands' errors go through the group's one-line error handling."""
    res = subprocess.run([sys.executable, "-c", "import sys; from fieldloc_cli.main import cli;"
                          " sys.exit(cli())", "inspect", str(ROOT / "no-such-file.h5")],
                         cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert res.returncode == 1
    assert res.stderr.startswith("fieldloc: error: ") and res.stderr.count("\n") == 1, res.stderr


@pytest.mark.parametrize("cause, depth, code", [(KeyboardInterrupt(), 1, 130),
                                               (KeyboardInterrupt(), 6, 130),
                                               (ValueError("x"), 3, None)])
def test_an_interrupt_inside_a_kernel_is_an_interrupt(cause, depth, code):
    """Ctrl-C as a numba kernel returns reaches Python as a SystemError caused by the
    KeyboardInterrupt, or by a SystemError so caused, as deep as calls return (seen: six
    from numba's unpickling of a kernel's constants): the group says "interrupted" and exits
    130, as for any Ctrl-C; a SystemError with another cause is no interrupt and is not turned
    into one."""
    from click.testing import CliRunner

    group = LazyGroup("g")

    @group.command("work")
    def work():
        error = cause
        for _ in range(depth):
            try:
                raise error
            except BaseException as e:
                error = SystemError("returned a result with an exception set")
                error.__cause__ = e
        raise error

    res = CliRunner().invoke(group, ["work"])
    if code is None:
        assert isinstance(res.exception, SystemError)
    else:
        assert res.exit_code == code
        # output: stderr mixed in (click 8.1's default; 8.2 always has it there)
        assert res.output.startswith("fieldloc: interrupted") and res.output.count("\n") == 1
