"""The real-data checks of the omni chain, run as a user runs it: stage mains with the CLI's
defaults on ../shared/realdata (read its README), judged by the brute-force line share
(stages.evaluate.line_share), never by the method under test.

``minho_lab(realdata, work)``: the 10 minho-lab images as one dataset of independent frames:
``calibrate.from_minho`` on the team's mirror.cfg / image.cfg, the lab field imported from
Lar.view (``field import``),
``build_map``, ``extract`` (preset real), ``localize`` (lut, histogram heading, independent);
per image the share of its line points within 15 cm at the top hypothesis, the null baseline
(random-bearing copies at their best pose), the brute-force best pose, whether the top or second
hypothesis is that pose (or its mirror) within 15 cm / 2 deg, and whether that pose is what the
points decide or one of a few (LineRaster.rivals: poses elsewhere within 0.03 of its share),
and by how many points it beats the best pose elsewhere (apart from it and its mirror: what
the image says about its pose pair); the same with the range limit at
3.5, 4 and 5 m (how far the found pose, or its mirror, moves); and the line points of each
image as a ``frame,x,y`` CSV through ``--points --independent``.
"""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np

# the real recordings beside the repository (../shared/realdata; read its README)
REALDATA = Path(__file__).resolve().parents[3] / "shared" / "realdata"

LAB_FIELD_NAME = "minho-lab"


def lab_field(realdata: Path = REALDATA) -> dict:
    """The minho-lab field spec: the team's own ``Lar.view`` read by ``fieldloc field import``
    (stages.ingest.team_fields, format minho)."""
    from ..ingest.team_fields import read_team_field

    return read_team_field(Path(realdata) / "minho-lab" / "Lar.view", "minho",
                           name=LAB_FIELD_NAME).spec


NEAR = 0.15  # m
RANGES = (3.5, 4.0, 5.0)  # m, range limits of the stability check
RIVAL_MARGIN = 0.03  # a pose explaining within this share of the best is one of a few


def lab_dataset(realdata: Path, out: Path) -> tuple[Path, Path]:
    """(dataset folder, field YAML) of minho-lab: images, mask and a calib.yaml made by
    ``calibrate.from_minho`` with its defaults."""
    from .. import calibrate
    from ..ingest import team_fields

    src = Path(realdata) / "minho-lab"
    ds = Path(out) / "minho-lab"
    (ds / "images").mkdir(parents=True, exist_ok=True)
    for p in sorted((src / "images").glob("*.png")):
        shutil.copyfile(p, ds / "images" / p.name)  # not the source's read-only mode
    shutil.copyfile(src / "mask.png", ds / "mask.png")
    calibrate.from_minho(None, src, ds / "calib.yaml", overwrite=True)
    field = team_fields.main(None, src / "Lar.view", Path(out) / "minho-lab.yaml", fmt="minho",
                             name=LAB_FIELD_NAME, overwrite=True)
    return ds, field


def _localise(ds: Path, field: Path, work: Path, max_range: float | None = None,
              points: Path | None = None, method: str = "lut"):
    """(poses columns, features path) of the lab images by ``method``, independent frames,
    histogram heading, with the map's and the scan lines' range at ``max_range`` (None:
    defaults)."""
    from .. import build_map, extract, localize
    from ..common.poses_file import read_poses

    tag = "default" if max_range is None else f"{max_range:g}"
    bconf = None if max_range is None else {"max_range": max_range}
    mp = build_map.main(bconf, field, work / f"lab-{tag}.map.h5", overwrite=True)
    econf = extract.resolve_extract_conf(
        "omni", "real", None if max_range is None else {"scanlines": {"max_range": max_range}})
    feats = extract.main(econf, ds, work / f"lab-{tag}.features.h5", overwrite=True)
    conf = {"method": method, "heading": "histogram", "independent": True}
    out = work / f"lab-{method}-{tag}{'-points' if points else ''}.poses.h5"
    localize.main(conf, ds, mp, out, features=localize.LinePoints(points) if points else feats,
                  overwrite=True)
    return read_poses(out)[0], feats


def minho_lab(realdata: Path, work: Path, method: str = "lut") -> dict:
    """The minho-lab figures (module doc) of ``method`` (lut, fit)."""
    from ..common.features_file import FeaturesFile
    from ..common.field import load_field
    from ..common.geometry import robot_to_field, wrap_angle
    from ..evaluate.line_share import LineRaster

    work = Path(work)
    work.mkdir(parents=True, exist_ok=True)
    ds, field = lab_dataset(realdata, work)
    fm = load_field(field)
    raster = LineRaster(fm)
    cols, feats = _localise(ds, field, work, method=method)
    with FeaturesFile(feats) as ff:
        names = list(ff.names)
        pts = {n: np.asarray(ff.frame(n)["points"], float) for n in names}

    def share(pose, p):
        return float(np.mean(fm.distance_to_lines(robot_to_field(pose, p)) <= NEAR))

    def near(a, b):
        return (math.hypot(a[0] - b[0], a[1] - b[1]) <= NEAR
                and abs(float(wrap_angle(a[2] - b[2]))) <= math.radians(2.0))

    def at_best(h, best):
        mb = fm.mirror_pose(best)
        return any(np.isfinite(h[k, 0]) and (near(h[k, :3], best) or near(h[k, :3], mb))
                   for k in range(min(2, len(h))))

    rows = {}
    for i, n in enumerate(cols["name"]):
        p = pts[str(n)]
        best_share, best = raster.best_pose(p, NEAR)
        # the best poses elsewhere (apart from the best and its mirror), best first; those
        # within RIVAL_MARGIN of its share are its rivals
        elsewhere = raster.rivals(p, (best_share, best), NEAR, within=1.0)
        rivals = [r for r in elsewhere if r[0] >= best_share - RIVAL_MARGIN]
        elsewhere_share = elsewhere[0][0] if elsewhere else 0.0
        h = cols["hypotheses"][i]
        top = h[0, :3]
        rows[str(n)] = {
            "points": len(p), "failed": bool(cols["failed"][i]),
            "confidence": float(cols["confidence"][i]),
            # what the image decides on the symmetric lab field (stages.localize.symmetry)
            "confidence_up_to_mirror": float(cols["confidence_up_to_mirror"][i]),
            "accepted_up_to_mirror": bool(cols["accepted_up_to_mirror"][i]),
            "share": share(top, p) if np.isfinite(top[0]) else math.nan,
            "null": raster.null_share(p, 3, NEAR, seed=i), "best_share": best_share,
            "best_pose": [float(v) for v in best], "top": [float(v) for v in top],
            "top_or_second_at_best": bool(at_best(h, best)),
            # poses elsewhere within 0.03 of the best share: the best is one of a few
            "rivals": len(rivals),
            # how many of the image's points the best pose explains beyond the best pose
            # elsewhere: what the image says about its pose pair against every other place
            "best_elsewhere_share": elsewhere_share,
            "margin_points": int(round((best_share - elsewhere_share) * len(p))),
        }
    # range stability: the top pose (or its mirror) at each range limit against the default's,
    # and the same of the brute-force best pose of each range's points (the judge's own)
    def move(a, b):
        if not (np.isfinite(a[0]) and np.isfinite(b[0])):
            return math.inf, math.inf
        d = min((math.hypot(a[0] - q[0], a[1] - q[1]), abs(float(wrap_angle(a[2] - q[2]))))
                for q in (b, fm.mirror_pose(b)))
        return d[0], math.degrees(d[1])

    moves = {str(n): [] for n in cols["name"]}
    best_moves = {str(n): [] for n in cols["name"]}
    for r in RANGES:
        c2, f2 = _localise(ds, field, work, max_range=r, method=method)
        with FeaturesFile(f2) as ff:
            pts_r = {n: np.asarray(ff.frame(n)["points"], float) for n in ff.names}
        for i, n in enumerate(c2["name"]):
            moves[str(n)].append(move(rows[str(n)]["top"], c2["hypotheses"][i][0, :3]))
            best_moves[str(n)].append(move(rows[str(n)]["best_pose"],
                                           raster.best_pose(pts_r[str(n)], NEAR)[1]))
    for n, m in moves.items():
        rows[n]["range_move_m"] = max(v[0] for v in m)
        rows[n]["range_move_deg"] = max(v[1] for v in m)
        rows[n]["best_range_move_m"] = max(v[0] for v in best_moves[n])
        rows[n]["best_range_move_deg"] = max(v[1] for v in best_moves[n])
    # the same points through --points
    csv_path = work / "lab-points.csv"
    with open(csv_path, "w", newline="\n") as f:
        f.write("frame,x,y\n")
        for n in names:
            for x, y in pts[n]:
                f.write(f"{n},{x:.4f},{y:.4f}\n")
    cp, _ = _localise(ds, field, work, points=csv_path, method=method)
    for i, n in enumerate(cp["name"]):
        rows[str(n)]["points_top_or_second_at_best"] = bool(
            at_best(cp["hypotheses"][i], np.asarray(rows[str(n)]["best_pose"])))
    good = [r for r in rows.values() if r["share"] >= 0.7 and r["share"] >= r["null"] + 0.15]
    return {
        "images": len(rows),
        "with_pose": sum(not r["failed"] for r in rows.values()),
        "explained": len(good),  # >= 70 % within 15 cm and >= null + 0.15
        "stable": sum(_still(r, "range_move") for r in rows.values()),
        # the images whose brute-force best pose itself stays put across the range limits
        # (elsewhere the points of one range limit decide another place), and of them those
        # where the method's pose does
        "best_stable": sum(_still(r, "best_range_move") for r in rows.values()),
        "stable_where_best_stable": sum(_still(r, "range_move") and _still(r, "best_range_move")
                                        for r in rows.values()),
        "top_or_second_at_best": sum(r["top_or_second_at_best"] for r in rows.values()),
        "points_top_or_second_at_best": sum(r["points_top_or_second_at_best"]
                                            for r in rows.values()),
        "accepted_up_to_mirror": sum(r["accepted_up_to_mirror"] for r in rows.values()),
        "unique_best": sum(r["rivals"] == 0 for r in rows.values()),
        # the most points by which an image's best pose pair beats every other place
        "largest_margin_points": max(r["margin_points"] for r in rows.values()),
        "top_or_second_at_unique_best": sum(r["top_or_second_at_best"] and r["rivals"] == 0
                                            for r in rows.values()),
        # the top pose explains as many points as the best, up to the rivals' margin (0.03):
        # it is one of the poses the judge cannot tell from its best
        "top_as_good_as_best": sum(r["share"] >= r["best_share"] - RIVAL_MARGIN
                                   for r in rows.values()),
        "rows": rows,
    }


def _still(row: dict, key: str) -> bool:
    """Whether a pose moved at most 30 cm and 5 deg (``key``_m, ``key``_deg of ``row``)."""
    return row[f"{key}_m"] <= 0.3 and row[f"{key}_deg"] <= 5.0
