"""The SURF template paper's comparison of its two methods, computed (``fieldloc show
error-surface`` draws it with stages.show.error_surface): one template of a templates file and a
query dataset with truth (omni frames near the template, e.g. ``simulate omni --grid 0.2``
around it).

- (a) figure 3: eq. 1 of the white points extracted from the query frame nearest the template
  (stages.extract, omni) against the white-point table Dm (stages.build_map.white_points,
  built on the spot around the query's true pose), over (dx, dy) at the true heading and over
  dtheta at the true position;
- (b) figure 4: eq. 4 of the same query's pairs matched to the template (the template method's
  matching and consensus fit, stages.localize.error_surface) for the query displaced by (dx, dy,
  dtheta) from its true pose;
- (c) figure 5: every query fitted against the template: position error against the query's
  distance from the template, heading error against the query's heading from the template's.

The local minima of (a) and (b) are counted (stages.common.surfaces: strict minima of the
8-neighbourhood, 2 in 1D, 26 over (dx, dy, dtheta), on the sampled grid, border samples
excluded), all of them and those below the surface's median; (c) is summarised per ring of
distance from the template.

    measure(conf, templates, queries) -> dict  (the surfaces, the query errors, their numbers;
        stages.show.error_surface.summary_lines prints them)
    main(conf, templates, queries, output, *, overwrite=False, progress=False) -> Path
        (``measure``, then the picture of stages.show.error_surface)

A chain: it runs extract, build_map's white-point table and localize's template matching, which
no picture module may run.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..common.camera import camera_can
from ..common.conf import stage_conf
from ..common.dataset import open_dataset, truth_at
from ..common.errors import FieldlocError
from ..common.field import load_field
from ..common.resources import check_memory
from ..common.surfaces import count_minima
from ..common.templates import read_templates

confs = {
    "default": {
        "template": None,  # index into the templates file; None: nearest the queries' centre
        "half_size": 1.5,  # m, (dx, dy) of the surfaces (a) and (b)
        "step": 0.1,  # m, their sampling (the paper's table interval)
        "dtheta_deg": 30.0,  # deg, dtheta of the surfaces
        "angle_step_deg": 1.0,  # deg, Dm's angle bins and the dtheta sampling
        "e_none": 1.0,  # m, eq. 1's penalty of a point with no table point at its angle
        "limits": [0.5, 1.0, 1.5, 2.0],  # m, rings of distance from the template for (c)
    },
}


def _conf(conf) -> dict:
    c = stage_conf(confs, conf)
    try:
        ok = (float(c["half_size"]) > 0 and float(c["step"]) > 0 and float(c["dtheta_deg"]) > 0
              and float(c["angle_step_deg"]) > 0 and float(c["e_none"]) >= 0
              and len(c["limits"]) >= 1 and all(float(v) > 0 for v in c["limits"]))
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise FieldlocError("error-surface conf: half_size, step, dtheta_deg, angle_step_deg"
                            " must be > 0, e_none >= 0 and limits a list of distances > 0")
    if c["template"] is not None and (not isinstance(c["template"], int)
                                      or isinstance(c["template"], bool)):
        raise FieldlocError(f"template must be an index, not {c['template']!r}")
    check_memory(f"error-surface of +-{float(c['half_size']):g} m at {float(c['step']):g} m"
                 f" steps and +-{float(c['dtheta_deg']):g} deg", surface_memory(c))
    return c


# the crossings of one ray that the white-point table keeps, at most (its segments plus twice
# its arcs: 27 on msl-2015, the largest built-in field), and the bytes of the table per cell,
# angle bin and crossing: the uint16 radial table, its float32 radii and their transposed copy
BYTES_PER_CROSSING = 2 + 4 + 4
CROSSINGS = 32


def surface_memory(c: dict) -> dict[str, float]:
    """Memory (purpose -> bytes) of the surfaces (a) and (b) of the checked conf ``c``, from
    the sizes alone (before any is made): the white-point table over the (dx, dy) cells, and
    the surfaces' (dtheta, dy, dx) arrays of float64, one each."""
    side = 2 * float(np.floor(float(c["half_size"]) / float(c["step"]) + 1e-9)) + 1
    headings = 2 * float(np.floor(float(c["dtheta_deg"]) / float(c["angle_step_deg"]) + 1e-9)) + 1
    angles = 360.0 / float(c["angle_step_deg"])
    cells = side * side  # float products: inf, not an OverflowError, past the largest float
    return {"white-point table": cells * angles * CROSSINGS * BYTES_PER_CROSSING,
            "surfaces": 2.0 * cells * headings * 8}


def _truth(ds) -> np.ndarray:
    truth = ds.optional("truth")
    if truth is None:
        raise FieldlocError(f"{ds.root}: the queries need truth.csv (their true poses)")
    rows = [truth_at(truth, float(s)) for s in ds.stamps]
    if any(r is None for r in rows):
        bad = ds.names[next(i for i, r in enumerate(rows) if r is None)]
        raise FieldlocError(f"{ds.root}: no truth row at frame {bad}")
    return np.asarray(rows, float)


def _surface_numbers(s: dict) -> dict:
    """Minima counts of a surface pair (module doc) and where the lowest sample lies."""
    xy, th = s["xy"], s["theta"]
    i, j = np.unravel_index(int(np.argmin(xy)), xy.shape)
    return {"minima_xyt": count_minima(s["xyt"]),
            "minima_xyt_below_median": count_minima(s["xyt"], float(np.median(s["xyt"]))),
            "minima_xy": count_minima(xy),
            "minima_xy_below_median": count_minima(xy, float(np.median(xy))),
            "minima_theta": count_minima(th),
            "minima_theta_below_median": count_minima(th, float(np.median(th))),
            "lowest_dxy": (float(s["dx"][j]), float(s["dy"][i])),
            "lowest_dtheta": float(s["dtheta"][int(np.argmin(th))])}


def measure(conf, templates, queries, *, progress: bool = False) -> dict:
    """The surfaces (a), (b), the query errors (c) and their numbers (module doc)."""
    from ..build_map import white_points
    from ..extract import extract_dataset_frame, resolve_extract_conf
    from ..localize import error_surface as tes

    c = _conf(conf)
    db = read_templates(templates)
    if not len(db):
        raise FieldlocError(f"{templates}: the template database is empty")
    ds = open_dataset(queries)
    if not camera_can(ds.camera().kind, "ground_image") or not len(ds.names):
        raise FieldlocError(f"{ds.root}: the queries must be omni frames")
    truth = _truth(ds)
    if c["template"] is None:
        centre = truth[:, :2].mean(0)
        k = int(np.argmin(np.hypot(*(db.poses[:, :2] - centre).T)))
    else:
        k = int(c["template"])
        if not 0 <= k < len(db):
            raise FieldlocError(f"template {k} is not in {templates} ({len(db)} templates)")
    tp = db.poses[k]
    if not db.field.get("name"):
        raise FieldlocError(f"{templates}: the templates do not name their field")
    fm = load_field(db.field["name"])
    # (c) first: the fits of every query, the nearest one's fix reused for (b)
    fits = tes.fit_queries(db, k, ds, truth)
    gap = fits["distance"] + 0.1 * np.abs(fits["dheading"])  # nearest, then least turned
    qi = int(np.argmin(gap))
    qpose = truth[qi]
    # (a) the white points of that query against Dm around its true pose
    arrays = extract_dataset_frame(ds, qi, resolve_extract_conf("omni", None))
    pts = np.asarray(arrays.get("points", np.zeros((0, 2))), float)
    a = white_points.error_surface(fm, qpose, pts, half_size=float(c["half_size"]),
                                   step=float(c["step"]), dtheta_deg=float(c["dtheta_deg"]),
                                   angle_step_deg=float(c["angle_step_deg"]),
                                   e_none=float(c["e_none"]))
    # (b) its pairs with the template, displaced from the true relative pose
    fix = fits["fixes"][qi]
    if fix is None:
        raise FieldlocError(f"{ds.root}: query {ds.names[qi]}, the nearest to template {k},"
                            " does not match it (too few pairs): no surface (b)")
    inl = fix.fit.inliers
    pose0 = (qpose[0] - tp[0], qpose[1] - tp[1], float(np.angle(np.exp(1j * (qpose[2]
                                                                              - fix.heading)))))
    b = tes.template_surface(fix.pairs_t[inl], fix.pairs_q[inl], pose0,
                             half_size=float(c["half_size"]), step=float(c["step"]),
                             dtheta_deg=float(c["dtheta_deg"]),
                             dtheta_step_deg=float(c["angle_step_deg"]))
    rings = tes.distance_summary(fits["distance"], fits["position_error"],
                                 fits["heading_error"], tuple(float(v) for v in c["limits"]))
    return {"template": k, "template_pose": tp, "query": ds.names[qi], "query_pose": qpose,
            "white_points": a, "template_pairs": b, "fits": fits,
            "a": _surface_numbers(a), "b": _surface_numbers(b), "rings": rings,
            "field": fm, "conf": c}


def write_picture(conf, templates, queries, output, *, overwrite: bool = False,
                  progress: bool = False) -> tuple[Path, dict]:
    """``main``, returning the path and ``measure``'s result."""
    from ..show.error_surface import error_surface_figure
    from ..show.figure import check_picture_output, save_figure

    conf = _conf(conf)  # the conf before the inputs (the stage contract)
    ds = open_dataset(queries)
    check_picture_output(output, {**ds.files(), "templates": Path(templates)},
                         overwrite=overwrite)
    m = measure(conf, templates, queries, progress=progress)
    return save_figure(error_surface_figure(m), output), m


def main(conf, templates, queries, output, *, overwrite: bool = False,
         progress: bool = False) -> Path:
    """Write the picture of template ``conf['template']`` of ``templates`` against the query
    dataset ``queries`` (module doc) to ``output`` (PNG)."""
    return write_picture(conf, templates, queries, output, overwrite=overwrite,
                         progress=progress)[0]
