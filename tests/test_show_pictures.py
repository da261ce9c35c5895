"""The `show map` spiral picture (one family, a few spirals, a legend) and the belief picture
(a colour bar, sparse arrows, empty panels that say so)."""

import math

import numpy as np
from click.testing import CliRunner

from fieldloc_cli.main import cli
from stages.common.field import load_field
from stages.common.map_file import MapFile
from stages.show.belief import draw_belief
from stages.show.figure import new_figure
from stages.show.map import draw_scanlines_from_cell


def test_spiral_picture_one_family_few_spirals(msl2015_map, tmp_path):
    with MapFile(msl2015_map) as m:
        for family, n in (("ccw", 6), ("cw", 3)):
            fig = new_figure(6, 6)
            ax = fig.add_subplot()
            draw_scanlines_from_cell(ax, m, -7.0, -2.0, math.radians(35), "spiral",
                                     family=family, spirals=n)
            handles, labels = ax.get_legend_handles_labels()
            spiral_labels = [lb for lb in labels if lb.startswith("from ")]
            assert len(spiral_labels) == n
            assert any(f"all 36 {family} spirals" in lb for lb in labels)
            # n spirals drawn (plus their start dots), not 72
            assert sum(1 for ln in ax.get_lines() if len(ln.get_xdata()) > 100) == n
            assert ax.get_legend().get_title().get_text() == f"{n} of 36 {family} spirals"
    res = CliRunner().invoke(cli, ["show", "map", str(msl2015_map), "--table", "spiral",
                                   "--cell", "1", "1", "--family", "cw", "--spirals", "4",
                                   "-o", str(tmp_path / "s.png")])
    assert res.exit_code == 0, res.output


def _grid(counts):
    xs = np.arange(-5.0, 5.01, 0.1)
    ys = np.arange(-3.5, 3.51, 0.1)
    gx, gy = np.meshgrid(xs, ys)
    bump = -((gx - 2.0) ** 2 + (gy + 1.0) ** 2) / 0.1
    grid = {"xs": xs, "ys": ys, "counts": counts}
    for k in ("lines", "crossings", "posts", "all"):
        n = sum(counts.values()) if k == "all" else counts[k]
        grid[k] = bump.copy() if n else np.zeros_like(bump)
        grid[f"{k}_theta"] = np.full_like(bump, 0.3)
    return grid


def test_belief_picture_colour_bar_sparse_arrows_and_empty_panel():
    fig = new_figure(12, 8.5)
    axes = draw_belief(fig.subplots(2, 2), load_field("kidsize"), _grid({"lines": 5, "crossings": 2,
                                                          "posts": 0}),
                       truth=(2.0, -1.0, 0.3), arrow_spacing=0.5, arrow_min=0.25)
    assert len(fig.axes) == 5  # four panels and one colour bar
    assert "likelihood relative" in fig.axes[4].get_ylabel()
    posts = axes[1, 0]
    assert any("no goal posts observed" in t.get_text() for t in posts.texts)
    assert not posts.images  # no likelihood image
    assert not any(c.__class__.__name__ == "Quiver" for c in posts.collections)
    assert not any(ln.get_marker() == "o" for ln in posts.get_lines())  # no "best pose"
    lines = axes[0, 0]
    quiver = [c for c in lines.collections if c.__class__.__name__ == "Quiver"][0]
    # arrows 0.5 m apart where the likelihood is >= 0.25 of the best: a handful near the peak
    assert 1 <= len(quiver.get_offsets()) <= 6
    off = quiver.get_offsets()
    if len(off) > 1:
        d = np.abs(off[:, None, :] - off[None, :, :]).max(-1)
        assert d[d > 0].min() >= 0.5 - 1e-9


def test_frame_by_name_or_position_and_truth_at_its_stamp(tmp_path):
    """The one frame lookup and truth lookup every picture uses (show points, belief,
    hypotheses): names first, then positions from 0 (a negative one is refused)."""
    import pytest

    from stages.common.dataset import frame_index, readable_truth, truth_at, write_csv
    from stages.common.errors import FieldlocError

    names = ["000000", "000001", "000005"]
    assert frame_index(names, "000005", "d") == 2 and frame_index(names, 1, "d") == 1
    assert frame_index(names + ["-1"], "-1", "d") == 3  # a frame named -1 is that frame
    for bad, msg in (("3", "out of range"), ("-1", "out of range"), ("-4", "out of range"),
                     ("x", "no frame named")):
        with pytest.raises(FieldlocError, match=msg):
            frame_index(names, bad, "d")
    write_csv(tmp_path / "truth.csv", "truth", {"stamp": [0.0, 0.1], "x": [1.0, 2.0],
                                                "y": [0.5, 0.6], "theta": [0.1, 0.2]})
    truth = readable_truth(tmp_path)
    assert np.allclose(truth_at(truth, 0.12), [2.0, 0.6, 0.2])
    assert truth_at(truth, 0.2) is None and truth_at(None, 0.0) is None
    (tmp_path / "truth.csv").write_text("stamp,x\n0,1\n")  # broken: the picture goes without
    assert readable_truth(tmp_path) is None and readable_truth(None) is None


def test_show_points_extracts_a_perspective_frame_with_its_head_angles(tmp_path, monkeypatch):
    """Without a features file, show points extracts the frame as extract.main does: the
    head.csv pitch and roll of its stamp reach the extractor (they did not before)."""
    import cv2
    import yaml

    from stages import extract
    from stages.common.dataset import write_csv
    from stages.pipelines import frame_points

    root = tmp_path / "persp"
    (root / "images").mkdir(parents=True)
    (root / "calib.yaml").write_text(yaml.safe_dump({
        "kind": "perspective", "image_size": [64, 48],
        "intrinsics": {"fx": 40.0, "fy": 40.0, "cx": 31.5, "cy": 23.5},
        "distortion": [0.0, 0.0, 0.0, 0.0, 0.0], "height": 0.5, "pitch": 0.4, "roll": 0.0}))
    for i in range(2):
        cv2.imwrite(str(root / "images" / f"{i:02d}.png"), np.full((48, 64, 3), 90, np.uint8))
    write_csv(root / "frames.csv", "frames", {"name": ["00.png", "01.png"],
                                             "stamp": [0.0, 0.1]})
    write_csv(root / "head.csv", "head", {"stamp": [0.0, 0.1], "pitch": [0.3, 0.35],
                                         "roll": [0.01, -0.02]})
    seen = []

    def record(image, camera, conf, pitch=None, roll=None, **info):
        seen.append((pitch, roll))
        return {"lines": np.zeros((0, 4)), "boundary": np.zeros((0, 2)),
                "points": np.zeros((0, 2))}

    monkeypatch.setattr(extract.kind_module("perspective"), "extract_frame", record)
    frame_points.write_picture(None, root, tmp_path / "p.png", frame=1)
    assert seen == [(0.35, -0.02)]
