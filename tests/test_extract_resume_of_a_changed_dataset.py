"""extract resuming a features file after its dataset changed (trial U2, U2-5 and U2-6): a
frame whose image was replaced is extracted again, one taken out of frames.csv is dropped, so
that the file holds the dataset's frames of its images only, as localize's check of them
(FeaturesFile.check_of) wants; the dataset's own files stay as they were."""

from __future__ import annotations

import shutil

import pytest
from click.testing import CliRunner
from unchanged_files import tree_hashes

from fieldloc_cli.main import cli
from stages import extract, simulate
from stages.common.dataset import open_dataset
from stages.common.features_file import FeaturesFile


@pytest.fixture(scope="module")
def extracted(tmp_path_factory):
    """A 4-frame omni dataset and its features.h5."""
    root = tmp_path_factory.mktemp("resume")
    ds = simulate.main(dict(simulate.confs["omni-default"], frames=4, seed=5), "spl",
                       root / "omni")
    extract.main(None, ds, ds / "features.h5")
    return ds


def _copy(ds, tmp_path):
    """The dataset copied, its features.h5 made again in the copy: a resume continues the
    features of its own folder only (another folder's are refused, trial Z2-2)."""
    dst = tmp_path / "ds"
    shutil.copytree(ds, dst)
    extract.main(None, dst, dst / "features.h5", overwrite=True)
    return dst


def _hashes(ds) -> dict[str, str]:
    """The dataset's own files' digests (its features.h5, the output, left out)."""
    return {k: v for k, v in tree_hashes(ds).items() if not k.endswith("features.h5")}


def _resume(ds):
    before = _hashes(ds)
    res = CliRunner().invoke(cli, ["extract", str(ds)])
    assert res.exit_code == 0, res.output
    assert _hashes(ds) == before  # the dataset's files untouched
    dataset = open_dataset(ds)
    with FeaturesFile(ds / "features.h5") as ff:
        names = list(ff.names)
        assert not ff.changed_images(dataset)
        ff.check_of(dataset)  # localize takes them
        assert len(ff.names) == len(names)  # none left out as not the dataset's
    assert sorted(names) == sorted(dataset.names)
    assert res.output.strip().endswith(f"{len(dataset.names)} frames (omni camera)"), res.output
    return names


def test_a_frame_whose_image_was_replaced_is_extracted_again(extracted, tmp_path):
    ds = _copy(extracted, tmp_path)
    with FeaturesFile(ds / "features.h5") as ff:
        old = ff.frame("000003")["points"]
    shutil.copyfile(ds / "images" / "000003.png", ds / "images" / "000002.png")
    _resume(ds)
    with FeaturesFile(ds / "features.h5") as ff:
        # frame 2 is now frame 3's image, and extracted from it: the same features
        assert (ff.frame("000002")["points"] == old).all()


def test_a_frame_taken_out_of_frames_csv_is_dropped(extracted, tmp_path):
    ds = _copy(extracted, tmp_path)
    lines = (ds / "frames.csv").read_text().splitlines(keepends=True)
    (ds / "frames.csv").write_text("".join(lines[:2] + lines[3:]))  # 000001.png
    (ds / "images" / "000001.png").unlink()
    assert "000001" not in _resume(ds)


def test_a_frame_whose_stamp_changed_is_extracted_again(extracted, tmp_path):
    """localize refuses a frame at another stamp than frames.csv's ("Extract the dataset
    again"): the resume takes it at the stamp frames.csv gives now."""
    ds = _copy(extracted, tmp_path)
    text = (ds / "frames.csv").read_text()
    assert "000002.png,0.200000" in text
    (ds / "frames.csv").write_text(text.replace("000002.png,0.200000", "000002.png,0.250000"))
    _resume(ds)
    with FeaturesFile(ds / "features.h5") as ff:
        assert ff.frame("000002")["stamp"] == pytest.approx(0.25)
