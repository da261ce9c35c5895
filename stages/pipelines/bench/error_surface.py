"""``fieldloc bench`` row of the SURF template paper's comparison (its figures 3-5,
stages.pipelines.error_surface) on rendered msl-2015 (omni-default): one template captured at
TEMPLATE_POSE, queries of the same robot in the same venue (another session: clutter, lighting,
noise) on a 0.2 m grid of +-2 m around it at the template's heading, and at the 9 nodes of +-0.2 m
around it at headings every 10 deg. Printed: the local minima of the white-point table's surface (a)
and the template pairs' surface (b), and the position and heading error of the queries per
ring of distance from the template (c)."""

from __future__ import annotations

import math

from .harness import Row
from .inputs import work_dir

TEMPLATE_POSE = (2.0, 1.0)  # m on msl-2015: the centre circle, the halfway line within 2 m
CALIB_SEED, WORLD_SEED = 61, 61  # one robot, one venue (as inputs' template robot)
TEMPLATE_SEED, GRID_SEED, HEADING_SEED = 71, 72, 73
QUERY_SPACING, QUERY_HALF = 0.2, 2.0  # m, the paper's query grid
HEADINGS = 36  # every 10 deg


def error_surface_inputs() -> dict:
    """The template capture and its templates.h5, the two query sets (built once)."""
    from ... import build_templates, simulate

    d = work_dir() / "error-surface"
    d.mkdir(exist_ok=True)
    base = {"calib_seed": CALIB_SEED, "world_seed": WORLD_SEED}

    def grid(name, seed, spacing, half, headings):
        out = d / name
        if not out.exists():
            conf = dict(simulate.confs["omni-default"], seed=seed, **base)
            conf["trajectory"] = {**conf["trajectory"], "kind": "grid", "grid_spacing": spacing,
                                  "grid_centre": list(TEMPLATE_POSE), "grid_half_size": half,
                                  "grid_headings": headings}
            simulate.main(conf, "msl-2015", out)
        return out

    capture = grid("template", TEMPLATE_SEED, 1.0, 0.0, 1)
    db = d / "template.h5"
    if not db.exists():
        build_templates.main(None, capture, db)
    return {"templates": db,
            "positions": grid("positions", GRID_SEED, QUERY_SPACING, QUERY_HALF, 1),
            "headings": grid("headings", HEADING_SEED, QUERY_SPACING, QUERY_SPACING, HEADINGS)}


def rows(repeat: int) -> list[Row]:
    """The minima counts of (a) and (b), the (c) summary (module doc)."""
    from .. import error_surface as es

    inp = error_surface_inputs()
    m = es.measure(None, inp["templates"], inp["positions"])
    h = es.measure(None, inp["templates"], inp["headings"])
    a, b = m["a"], m["b"]
    rows = [Row(
        name="error surfaces (the SURF template paper, figs 3, 4): local minima, +-1.5 m at 10 cm,"
             " +-30 deg",
        goal="(a) many minima, (b) one (over dx, dy, dtheta)",
        meets_goal=a["minima_xyt"] > 1 and b["minima_xyt"] == 1,
        repeats=1,
        note=f"(a) white-point table: {a['minima_xyt']} ({a['minima_xyt_below_median']} below the"
             f" median) over (dx, dy, dtheta), {a['minima_xy']}"
             f" over (dx, dy) ({a['minima_xy_below_median']} below the median),"
             f" {a['minima_theta']} over dtheta, lowest at ({100 * a['lowest_dxy'][0]:.0f},"
             f" {100 * a['lowest_dxy'][1]:.0f}) cm; (b) template pairs: {b['minima_xyt']} over"
             f" (dx, dy, dtheta), {b['minima_xy']} over (dx, dy), {b['minima_theta']}"
             f" over dtheta, lowest at ({100 * b['lowest_dxy'][0]:.0f},"
             f" {100 * b['lowest_dxy'][1]:.0f}) cm {math.degrees(b['lowest_dtheta']):.0f} deg"
             f" of the truth")]
    ring = " / ".join(
        f"<= {r['to']:g} m {100 * r['median_m']:.1f} cm ({r['failed']}/{r['queries']} failed)"
        for r in m["rings"])
    hd = [r for r in h["rings"] if r["queries"]]
    worst = max((r["max_heading"] for r in hd), default=math.nan)
    fails = sum(r["failed"] for r in hd)
    n = sum(r["queries"] for r in hd)
    far = m["rings"][-1]
    rows.append(Row(
        name="error against distance from the template (the SURF template paper, fig 5), 0.2 m"
             " grid +-2 m",
        goal="error grows beyond 1.5 m; |heading error| <= 15 deg at every heading",
        meets_goal=bool(far["median_m"] > max(r["median_m"] for r in m["rings"][:-1])
                        and worst <= math.radians(15)),
        repeats=1,
        note=f"median position error per ring {ring}; largest {100 * far['max_m']:.0f} cm"
             f" beyond 1.5 m; headings every 10 deg at {n // HEADINGS} nodes within 0.3 m:"
             f" |heading error| max {math.degrees(worst):.1f} deg, {fails} of {n} failed"))
    rows.append(_real_row())
    return rows


def _real_row() -> Row:
    """Surface (a) on the real minho-lab images (real_white_point_surfaces), when
    ../shared/realdata is present."""
    import numpy as np

    from ..realdata import REALDATA

    name = "error surface (a) on real minho-lab images, at the line-share best pose"
    if not (REALDATA / "minho-lab").exists():
        return Row(name=name, note=f"skipped: {REALDATA} is absent")
    work = work_dir() / "error-surface-real"
    work.mkdir(exist_ok=True)
    r = real_white_point_surfaces(REALDATA, work)
    parts = []
    for e in (1.0, 0.25):
        xyt = [v[e]["minima_xyt"] for v in r]
        xy = [v[e]["minima_xy"] for v in r]
        at = sum(v[e]["lowest_m"] <= 0.15 for v in r)
        parts.append(f"e_none {e:g} m: minima over (dx, dy, dtheta) {min(xyt)}-{max(xyt)}"
                     f" (median {np.median(xyt):.0f}), over (dx, dy) {min(xy)}-{max(xy)};"
                     f" lowest sample within 15 cm of the pose in {at} of {len(r)}")
    return Row(name=name, goal="many minima; the lowest at the pose (e_none 1 m)",
               meets_goal=bool(min(v[1.0]["minima_xyt"] for v in r) > 1
                               and sum(v[1.0]["lowest_m"] <= 0.15 for v in r) >= 0.8 * len(r)),
               repeats=1, note="; ".join(parts))


def real_white_point_surfaces(realdata, work, e_nones=(1.0, 0.25)) -> list[dict]:
    """Surface (a) on the real minho-lab images (no pose known): each image's line points
    (extract preset real, the team's mirror calibration) against Dm of the lab field around
    the brute-force best pose of evaluate.line_share (the pose that puts most points within
    15 cm of a line), at each ``e_none``: minima over (dx, dy, dtheta) and (dx, dy), and
    where the lowest sample of (dx, dy) lies from that pose (m)."""
    import numpy as np

    from ... import extract
    from ...build_map import white_points
    from ...common.features_file import FeaturesFile
    from ...common.field import load_field
    from ...common.surfaces import count_minima
    from ...evaluate.line_share import LineRaster
    from ..realdata import lab_dataset

    ds, field = lab_dataset(realdata, work)
    feats = extract.main(extract.resolve_extract_conf("omni", "real"), ds,
                         work / "lab-real.features.h5", overwrite=True)
    fm = load_field(field)
    raster = LineRaster(fm)
    out = []
    with FeaturesFile(feats) as ff:
        for name in ff.names:
            p = np.asarray(ff.frame(name)["points"], float)
            share, pose = raster.best_pose(p)
            row = {"image": name, "points": len(p), "share": share}
            for e in e_nones:
                s = white_points.error_surface(fm, pose, p, e_none=e)
                i, j = np.unravel_index(int(np.argmin(s["xy"])), s["xy"].shape)
                row[e] = {"minima_xyt": count_minima(s["xyt"]),
                          "minima_xy": count_minima(s["xy"]),
                          "lowest_m": float(np.hypot(s["dx"][j], s["dy"][i]))}
            out.append(row)
    return out
