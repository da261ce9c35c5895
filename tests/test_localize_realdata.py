"""Global localisation (lut, unknown heading) on the real minho-lab images (../shared/realdata,
read its README). No ground truth: a found pose is judged by the share of the frame's extracted
line points within 15 cm of a field line, next to the null baseline: random-bearing copies of
the same observations (radial lines and spiral start angles shuffled), searched the same way.

Setup: calib from mirror.cfg by ``calibrate omni --from-minho`` with its defaults (the monotone
table model; tests/test_extract_realdata.make_dataset), map and extraction with the 4 m
scan-line range (farther points are not used: beyond ~3.5 m one pixel spans 0.1-0.25 m),
extraction preset "real" (max_white_m 0.6)."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from test_extract_realdata import LAB_FIELD, LAB_RANGE, REALDATA, make_dataset

from stages import build_map, extract
from stages.common.features_file import FeaturesFile
from stages.common.field import field_from_spec
from stages.common.geometry import robot_to_field
from stages.common.map_file import MapFile
from stages.localize import lut
from stages.localize.lut_search import MatchingParams, Observation

pytestmark = pytest.mark.skipif(not REALDATA.exists(), reason="../shared/realdata is absent")

NEAR = 0.15  # m, a point is explained when this close to a field line
NULL_COPIES = 2


@pytest.fixture(scope="module")
def lab_global(tmp_path_factory):
    out = tmp_path_factory.mktemp("lab")
    ds = make_dataset(REALDATA / "minho-lab", out / "ds")
    fy = out / "lab.yaml"
    fy.write_text(yaml.safe_dump(LAB_FIELD))
    fm = field_from_spec(LAB_FIELD)
    mp = build_map.main(dict(build_map.confs["default"], max_range=LAB_RANGE), fy,
                        out / "lab.map.h5")
    econf = extract.resolve_extract_conf("omni", "real", {"scanlines": {"max_range": LAB_RANGE}})
    feats = extract.main(econf, ds, ds / "features.h5")
    params = MatchingParams.from_conf(lut.confs["default"]["search"])
    search = lut.table_search(MapFile(mp), params)
    sl = search.scanlines
    rng = np.random.default_rng(0)

    def observe(radial, spiral):
        return Observation.from_scanlines(radial, spiral, params, sl.max_range,
                                          sl.spiral_end_radius, sl.robot_radius)

    def share(pose, pts):
        return float(np.mean(fm.distance_to_lines(robot_to_field(pose, pts)) <= NEAR))

    rows = {}
    with FeaturesFile(feats) as ff:
        for name in ff.names:
            fr = ff.frame(name)
            pts = fr["points"].astype(float)
            found = search.unknown_heading_search(observe(fr["radial"], fr["spiral"]))
            nulls = []
            for _ in range(NULL_COPIES):
                nobs = observe(fr["radial"][rng.permutation(72)],
                               fr["spiral"][:, rng.permutation(72)])
                nulls.append(share(search.unknown_heading_search(nobs).pose, nobs.points(sl)))
            rows[name] = {"points": len(pts), "share": share(found.pose, pts),
                          "null": float(np.mean(nulls)), "pose": found.pose}
    print("\nminho-lab global lut search (4 m range, far points dropped):")
    print("image points  share  null   pose (x, y, theta deg)")
    for n, r in rows.items():
        x, y, th = r["pose"]
        print(f"{n:>5} {r['points']:6d}  {r['share']:.2f}  {r['null']:.2f}"
              f"   {x:5.2f} {y:5.2f} {np.degrees(th):7.1f}")
    return rows


def test_minho_lab_global_search_explains_the_line_points(lab_global):
    """Issue 3 goal: >= 70 % of the points within 15 cm on >= 8 of the 10 images; and clearly
    above the null baseline (median share at least 0.25 above the median null)."""
    share = np.array([r["share"] for r in lab_global.values()])
    null = np.array([r["null"] for r in lab_global.values()])
    assert len(share) == 10
    assert np.sum(share >= 0.7) >= 8, np.round(share, 2)
    assert np.median(share) - np.median(null) >= 0.25, (np.round(share, 2), np.round(null, 2))
