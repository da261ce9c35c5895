"""Hostile conf values: every numeric key of the perspective extractor's preset, of the
templates method's and of build-templates' (nested keys dotted, a list of numbers given one
number as ``-c key=V`` makes it), set to 0, -1, 1e12 (and 1e-12 for a real number), is either
refused where the conf is resolved, in one line naming the key (the method's or kind's BOUNDS,
common.conf.check_bounds), or runs to its end on a tiny rendered input: a traceback, a crash or
a run of hours is what a user must never get. The conf is resolved as the CLI resolves it
(``-c`` overrides parsed by common.conf.parse_overrides); each run is held to RUN_BUDGET_S.
The same sweep through the CLI, with a timeout per run, is the issue's fuzz table."""

from __future__ import annotations

import copy
import time

import pytest

from stages import build_templates, extract, localize, simulate
from stages.common.conf import parse_overrides, resolve_conf
from stages.common.dataset import open_dataset
from stages.common.errors import FieldlocError
from stages.localize import templates

HOSTILE = {"int": ("0", "-1", "1e12"), "float": ("0", "-1", "1e12", "1e-12"),
           "list": ("0", "-1", "1e12")}
# s a run of an accepted value may take: these inputs take 0.01-0.3 s; a value that makes a
# stage run for hours shows as far more (a run is not interrupted: the suite's time shows it)
RUN_BUDGET_S = 5.0
MAX_MESSAGE = 160  # characters of a refusal: one line


def numeric_keys(conf: dict, prefix: str = "") -> list[tuple[str, str]]:
    """(dotted key, "int" | "float" | "list") of every numeric key of a nested conf."""
    out = []
    for k, v in conf.items():
        path = f"{prefix}{k}"
        if isinstance(v, dict):
            out += numeric_keys(v, path + ".")
        elif isinstance(v, bool):
            continue
        elif isinstance(v, int):
            out.append((path, "int"))
        elif isinstance(v, float):
            out.append((path, "float"))
        elif isinstance(v, list) and v and all(
                isinstance(x, (int, float)) and not isinstance(x, bool) for x in v):
            out.append((path, "list"))
    return out


def hostile(conf: dict, only=lambda key: True) -> list[str]:
    return [f"{k}={v}" for k, t in numeric_keys(conf) if only(k) for v in HOSTILE[t]]


def sweep(cases: list[str], resolve, run) -> tuple[list[str], int]:
    """Each ``key=value`` resolved (``resolve(overrides)``) and, when not refused, run
    (``run(conf)``); (what went wrong, how many were refused)."""
    wrong, refused = [], 0
    for kv in cases:
        key = kv.split("=")[0]
        try:
            conf = resolve(parse_overrides([kv]))
        except FieldlocError as e:
            refused += 1
            msg = str(e)
            if f"'{key}" not in msg or "\n" in msg or len(msg) > MAX_MESSAGE:
                wrong.append(f"{kv}: refused as {msg[:MAX_MESSAGE]!r}")
            continue
        for attempt in range(2):
            t0 = time.perf_counter()
            try:
                run(conf)
            except FieldlocError:  # a frame or input refused in one line is no crash
                pass
            except Exception as e:  # noqa: BLE001 (what the test is for)
                wrong.append(f"{kv}: {type(e).__name__}: {str(e)[:80]}")
                break
            took = time.perf_counter() - t0
            # a value of another type than the preset's (an int where a float stood) may have
            # numba compile a kernel once, seconds on a busy machine: the second run is judged
            if took <= RUN_BUDGET_S:
                break
            if attempt:
                wrong.append(f"{kv}: ran {took:.0f} s twice")
    return wrong, refused


@pytest.fixture(scope="module")
def kid(tmp_path_factory):
    """A KidSize walk of 3 frames whose frames see crossings (1, 3, 2) besides lines and posts:
    the hostile values reach the crossing checks too."""
    conf = dict(simulate.confs["perspective-default"], frames=3, seed=2)
    return open_dataset(simulate.main(conf, "kidsize", tmp_path_factory.mktemp("kid") / "kid"))


@pytest.fixture(scope="module")
def grid(tmp_path_factory):
    """Template captures at the 4 nodes of a 1 m grid on spl (coarse world texture: fast), and
    their template database; localised against it, every frame matches."""
    root = tmp_path_factory.mktemp("grid")
    conf = copy.deepcopy(simulate.confs["omni-default"])
    conf.update(seed=5)
    conf["scene"]["texture_resolution"] = 0.02
    conf["trajectory"].update(kind="grid", grid_spacing=1.0, grid_centre=[1.5, 0.5],
                              grid_half_size=0.6)
    ds = simulate.main(conf, "spl", root / "grid")
    return ds, build_templates.main(None, ds, root / "templates.h5"), root


def test_every_perspective_key_set_hostile_runs_or_is_refused_in_one_line(kid):
    cases = hostile(extract.kind_confs("perspective")["default"])
    assert len(cases) >= 18  # 5 keys (the tuned numbers are named constants)

    def run(conf):  # the frame with three crossings
        extract.extract_dataset_frame(kid, 1, conf)

    wrong, refused = sweep(cases, lambda o: extract.resolve_extract_conf("perspective", None, o),
                           run)
    assert not wrong, wrong
    assert refused >= 12  # of 18: zero steps, negative sizes, 1e12 runs


def test_every_templates_key_set_hostile_runs_or_is_refused_in_one_line(grid):
    ds, db, root = grid
    cases = hostile(templates.confs["default"])
    assert len(cases) == 11  # hypotheses, min_confidence, stamp_tolerance: the user's keys

    def resolve(overrides):
        conf = localize.resolve_localize_conf({"method": "templates", **overrides})
        templates.check_conf(conf)
        return conf

    def run(conf):
        localize.main(conf, ds, None, root / "poses.h5", templates=db, overwrite=True)

    wrong, refused = sweep(cases, resolve, run)
    assert not wrong, wrong
    assert refused >= 6  # of 11


@pytest.mark.parametrize("features", ["surf", "sift", "orb"])
def test_every_build_templates_key_set_hostile_runs_or_is_refused_in_one_line(grid, features):
    ds, _db, root = grid
    preset = build_templates.FEATURE_PRESETS[features]
    conf = build_templates.confs[preset]
    # the keys every preset shares are swept once, with the default's features
    cases = hostile(conf, (lambda k: True) if preset == "default"
                    else (lambda k: k.startswith("features.")))

    def resolve(overrides):  # as the CLI does: the --features preset, then the stage's check
        return build_templates.resolve_build_conf(resolve_conf(build_templates.confs, preset,
                                                               overrides))

    def run(c):
        build_templates.main(c, ds, root / "t.h5", overwrite=True)

    wrong, _refused = sweep(cases, resolve, run)
    assert not wrong, wrong
