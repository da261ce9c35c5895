"""`fieldloc report`: one self-contained HTML page; every image embedded, the table's figures
those of report.json."""

import base64
import json
import shutil
from html.parser import HTMLParser

import numpy as np
import pytest
from click.testing import CliRunner

from fieldloc_cli.main import cli
from stages import extract, simulate
from stages.common.artifacts import file_hash, root_attrs
from stages.common.dataset import read_csv
from stages.common.poses_file import PoseTrack, write_poses
from stages.pipelines import evaluation
from stages.show.html_report import lookup


class _Page(HTMLParser):
    def __init__(self):
        super().__init__()
        self.images, self.links, self.cells, self._cell = [], [], [], None

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "img":
            self.images.append(a)
        for k in ("src", "href"):
            if k in a and tag != "img":
                self.links.append(a[k])
        if tag == "td" and "data-key" in a:
            self._cell = [a, ""]

    def handle_data(self, data):
        if self._cell is not None:
            self._cell[1] += data

    def handle_endtag(self, tag):
        if tag == "td" and self._cell is not None:
            self.cells.append(tuple(self._cell))
            self._cell = None


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A 4-frame rendered dataset with features, poses near the truth (one failed frame), and
    its evaluation report."""
    d = tmp_path_factory.mktemp("html")
    ds = simulate.main(dict(simulate.confs["omni-default"], frames=4, seed=3), "msl-2015",
                       d / "ds")
    feats = extract.main(None, ds, ds / "features.h5")
    truth = read_csv(ds / "truth.csv", "truth")
    rng = np.random.default_rng(1)
    track = PoseTrack()
    names = [p.stem for p in sorted((ds / "images").iterdir())]
    for i, name in enumerate(names):
        if i == 2:
            track.add(name, truth["stamp"][i], None, mode="failed")
            continue
        track.add(name, truth["stamp"][i], (truth["x"][i] + rng.normal(0, 0.1),
                                            truth["y"][i] + rng.normal(0, 0.1),
                                            truth["theta"][i]), confidence=0.8)
    attrs = root_attrs("fieldloc.poses", 2, {"method": "lut"},
                       {"features": str(feats), "features_hash": file_hash(feats)})
    attrs.update(method="lut", field="msl-2015", dataset=str(ds))
    (d / "runs" / "a").mkdir(parents=True)
    poses = write_poses(d / "runs" / "a" / "poses.h5", track, attrs)
    rep = evaluation.main(None, poses, ds, d / "runs" / "a" / "report")
    return d, rep


def test_page_is_self_contained_and_matches_report_json(run, tmp_path):
    d, rep = run
    # the lead's reliability diagram lands as plots/reliability.png: it must be embedded too
    shutil.copyfile(rep / "plots" / "error_cdf.png", rep / "plots" / "reliability.png")
    out = tmp_path / "report.html"
    res = CliRunner().invoke(cli, ["report", str(d / "runs"), "-o", str(out), "--worst", "2"])
    assert res.exit_code == 0, res.output
    page = _Page()
    page.feed(out.read_text())
    alts = [im.get("alt") for im in page.images]
    assert {"error_cdf.png", "trajectory.png", "error_over_time.png",
            "reliability.png"} <= set(alts)
    assert len(page.images) == 6  # four plots and two worst-frame overlays
    for im in page.images:
        src = im["src"]
        assert src.startswith("data:image/png;base64,")
        assert base64.b64decode(src.split(",", 1)[1])[:8] == b"\x89PNG\r\n\x1a\n"
    assert page.links == []  # nothing outside the page
    report = json.loads((rep / "report.json").read_text())
    assert len(page.cells) >= 15
    for attrs, text in page.cells:
        want = lookup(report, tuple(attrs["data-key"].split("/")))
        assert want is not None, attrs
        if want == "inf":
            assert attrs["data-value"] == "inf" and text == "inf"
            continue
        assert float(attrs["data-value"]) == pytest.approx(float(want)), attrs
        shown = float(text.split()[0])  # the displayed figure, rounded, in its unit
        digits = len(text.split()[0].split(".")[1]) if "." in text else 0
        assert abs(shown - float(want) * float(attrs["data-scale"])) <= 0.51 * 10 ** -digits
    # the failed frame is the worst one (infinite error) and shown at its true pose
    html = out.read_text()
    assert "frame 000002 at" in html and "failed (infinite error)" in html


def test_report_errors(tmp_path):
    runner = CliRunner()
    res = runner.invoke(cli, ["report", str(tmp_path), "-o", str(tmp_path / "r.html")])
    assert res.exit_code == 1 and "no report.json" in res.output
    res = runner.invoke(cli, ["report", str(tmp_path / "nope"), "-o", str(tmp_path / "r.html")])
    assert res.exit_code == 1 and "not found" in res.output
