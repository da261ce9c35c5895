"""The kidnapped-robot bench row's recordings (stages.pipelines.bench.mcl_walks._spliced): two
walks spliced at a stamp are one dataset folder, the first walk's frames and rows before the
stamp and the second's from it, which every command reads as any recording."""

from __future__ import annotations

import copy
import filecmp

import numpy as np

from stages import simulate
from stages.common.dataset import open_dataset, read_csv
from stages.pipelines.bench.mcl_walks import _spliced


def test_two_walks_spliced_at_a_stamp(tmp_path):
    walks = []
    for seed in (1, 2):
        conf = copy.deepcopy(simulate.confs["perspective-nao"])
        conf.update(frames=4, seed=seed)
        walks.append(simulate.main(conf, "spl", tmp_path / f"walk{seed}"))
    a, b = walks
    cut = float(read_csv(a / "frames.csv", "frames")["stamp"][2])
    out = _spliced(a, b, tmp_path / "kidnap", cut)
    assert not (tmp_path / "kidnap.part").exists()
    ds = open_dataset(out)  # a dataset folder as any other
    assert len(ds.names) == 4
    frames = read_csv(out / "frames.csv", "frames")
    assert np.all(np.diff(frames["stamp"]) > 0)
    for kind in ("truth", "odometry"):
        got = read_csv(out / f"{kind}.csv", kind)
        for src, rows in ((a, got["stamp"] < cut), (b, got["stamp"] >= cut)):
            want = read_csv(src / f"{kind}.csv", kind)
            pick = want["stamp"] < cut if src == a else want["stamp"] >= cut
            for col in want:
                np.testing.assert_allclose(got[col][rows], want[col][pick], atol=1e-6)
    for name, stamp in zip(frames["name"], frames["stamp"]):
        src = a if stamp < cut else b
        assert filecmp.cmp(out / "images" / name, src / "images" / name, shallow=False)
    # made once: a second call keeps the folder as it is
    before = (out / "truth.csv").read_bytes()
    assert _spliced(b, a, out, cut) == out
    assert (out / "truth.csv").read_bytes() == before
