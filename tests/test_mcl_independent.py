"""`fieldloc localize --method mcl --independent`: every frame on its own (snapshots at
unknown poses, issue 25's real NAO frames), through the CLI.

- a frame's result does not depend on the other frames of its dataset (the same frame
  localised alone gives the same pose, confidence and hypotheses);
- the options that contradict it are refused in one line;
- on the real HULKs captures (skipped where ../shared/realdata is absent), a frame accepted up
  to the mirror has its pose or its mirror image within 0.5 m of the labels' pose: accepted
  where the pair is right. Every ninth capture (12 of 107) keeps the test near 15 s; on all 107
  (2026-12-07) 69 were accepted up to the mirror, the farthest 0.44 m from the labels' pose
  (median 0.07 m), none accepted as a pose alone (the pair shares the belief)."""

from __future__ import annotations

import math
import shutil

import numpy as np
import pytest
from click.testing import CliRunner
from conftest import REALDATA

from fieldloc_cli.main import cli
from stages import simulate
from stages.common.field import load_field
from stages.common.poses_file import read_poses

HULKS = REALDATA / "hulks-goalbox-labels" / "measurements"


def _run(*args):
    res = CliRunner().invoke(cli, ["-q", *map(str, args)])
    return res


@pytest.fixture(scope="module")
def nao(tmp_path_factory):
    root = tmp_path_factory.mktemp("mcl-independent")
    conf = dict(simulate.confs["perspective-nao"], frames=3, seed=31)
    data = simulate.main(conf, "spl", root / "walk")
    for args in (["build-map", "spl", "-o", root / "spl.map.h5"],
                 ["extract", data, "-o", root / "f.h5"]):
        assert _run(*args).exit_code == 0
    return root, data


def test_a_frame_alone_is_localised_as_among_others(nao):
    root, data = nao
    res = _run("localize", data, "--map", root / "spl.map.h5", "--features", root / "f.h5",
               "--method", "mcl", "--independent", "-o", root / "all.h5")
    assert res.exit_code == 0, res.output
    alone = root / "alone"
    shutil.copytree(data, alone)
    rows = (alone / "frames.csv").read_text().splitlines()
    (alone / "frames.csv").write_text("\n".join([rows[0], rows[3]]) + "\n")  # the last frame
    for row in rows[1:3]:
        (alone / "images" / row.split(",")[0]).unlink()
    assert _run("extract", alone, "-o", root / "alone-f.h5").exit_code == 0
    res = _run("localize", alone, "--map", root / "spl.map.h5", "--features",
               root / "alone-f.h5", "--method", "mcl", "--independent", "-o", root / "alone.h5")
    assert res.exit_code == 0, res.output
    every, _ = read_poses(root / "all.h5")
    one, attrs = read_poses(root / "alone.h5")
    assert len(one["name"]) == 1 and one["name"][0] == every["name"][2]
    assert math.isclose(one["confidence"][0], every["confidence"][2], abs_tol=1e-9)
    np.testing.assert_allclose(one["hypotheses"][0], every["hypotheses"][2], atol=1e-9)
    assert attrs["conf"]["independent"] is True


@pytest.mark.parametrize("extra, rc, said", [
    (["--init", "placement"], 2, "--independent starts every frame from a uniform belief"),
    (["--start-side", "left"], 2, "--independent starts every frame from a uniform belief"),
    (["--smooth"], 1, "it does not localise frames independently"),
    (["-c", "init=placement"], 1, "independent starts every frame from a uniform belief"
     " (init uniform, start_side any), not init 'placement'"),
    (["-c", "start_side=left"], 1, "not start_side 'left'"),
])
def test_options_against_independent_are_refused(nao, extra, rc, said):
    root, data = nao
    res = _run("localize", data, "--map", root / "spl.map.h5", "--features", root / "f.h5",
               "--method", "mcl", "--independent", *extra, "-o", root / "x.h5")
    assert res.exit_code == rc and said in res.output, res.output
    assert not (root / "x.h5").exists()


@pytest.mark.realdata
@pytest.mark.skipif(not HULKS.exists(), reason="../shared/realdata is absent")
def test_real_nao_stills_are_accepted_up_to_the_mirror_where_the_pair_is_right(tmp_path):
    from stages.pipelines.bench.mcl_hulks import label_pose

    captures = sorted(HULKS.glob("*.json"))[::9]
    folder = tmp_path / "captures"
    folder.mkdir()
    for js in captures:
        shutil.copyfile(js, folder / js.name)
        shutil.copyfile(js.with_suffix(".jpg"), folder / js.with_suffix(".jpg").name)
    data = tmp_path / "ds"
    for args in (["calibrate", "perspective", "--from-hulks", folder, "-o", data],
                 ["build-map", "spl", "-o", tmp_path / "spl.map.h5"],
                 ["extract", data, "-o", tmp_path / "f.h5"],
                 ["localize", data, "--map", tmp_path / "spl.map.h5", "--features",
                  tmp_path / "f.h5", "--method", "mcl", "--independent", "-o",
                  tmp_path / "p.h5"]):
        res = _run(*args)
        assert res.exit_code == 0, res.output
    cols, _ = read_poses(tmp_path / "p.h5")
    field = load_field("spl")
    errors = []
    for i, name in enumerate(cols["name"]):
        truth = label_pose(HULKS / f"{name}.json", field)
        if truth is None or not cols["accepted_up_to_mirror"][i]:
            continue
        top = np.array([cols["x"][i], cols["y"][i], cols["theta"][i]])
        errors.append(min(math.hypot(*(q[:2] - truth[:2])) for q in (top, field.mirror_pose(top))))
    assert not cols["accepted"].any()  # a still's pose and its mirror share the belief
    print(f"\n{len(errors)} of {len(captures)} accepted up to the mirror; errors {errors}")
    assert len(errors) >= len(captures) // 2, errors
    assert max(errors) <= 0.5, errors
