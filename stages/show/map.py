"""Pictures of a map for a person to check the tables by eye (``fieldloc show map``): the
distance table as a heat map (``draw_distance_table``), or the scan lines of one cell with the
crossings the tables hold for them (``draw_scanlines_from_cell``).

    main(conf, map_path, output, *, overwrite=False) -> Path
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..common.conf import stage_conf
from ..common.errors import FieldlocError
from ..common.map_file import MapFile
from ..common.scanlines import NO_HIT_MM
from .field import draw_field
from .figure import check_picture_output, new_figure, save_figure

TABLES = ("distance", "radial", "spiral")

confs = {
    "default": {
        "table": "distance",  # distance | radial | spiral
        "cell": None,  # [x, y] (m): the robot's position for radial and spiral
        "heading": 0.0,  # rad, rounded to the scan-line step as the tables serve it
        "family": "ccw",  # spirals: ccw | cw
        "spirals": 6,  # spirals: how many of the family's 36 to draw
    },
}


def draw_distance_table(ax, m: MapFile):
    """The distance table as a heat map under the field lines."""
    g = m.grid
    half = g.resolution / 2
    extent = (g.xs[0] - half, g.xs[-1] + half, g.ys[0] - half, g.ys[-1] + half)
    draw_field(ax, m.field, border=True, zorder=0)
    im = ax.imshow(m.table("distance"), origin="lower", extent=extent, cmap="magma",
                   alpha=0.85, zorder=1, interpolation="nearest")
    ax.figure.colorbar(im, ax=ax, label="distance to nearest line (m)", shrink=0.8)
    ax.set_xlim(extent[0], extent[1])
    ax.set_ylim(extent[2], extent[3])


FAMILIES = {"ccw": 0, "cw": 1}


def draw_scanlines_from_cell(ax, m: MapFile, x: float, y: float, heading: float,
                             kind: str = "radial", *, family: str = "ccw", spirals: int = 6):
    """The scan lines of a robot at the cell nearest (x, y) with ``heading`` (rounded to the
    scan-line step, as the tables serve it), and the crossings the table holds for them.

    Spirals: one ``family`` (ccw: counter-clockwise, cw: clockwise) at a time. All 36 spirals
    a robot walks that way are too dense to tell apart (a moire disc), so ``spirals`` of them,
    evenly spaced in start angle, are drawn, each in its own colour with its table crossing
    and a legend entry; the table crossings of all 36 are small dots."""
    sl = m.scanlines
    i, j = m.grid.cell_of(x, y)
    cx, cy = m.grid.centre_of(i, j)
    shift = sl.heading_index(heading)
    h = shift * sl.angle_step
    draw_field(ax, m.field, border=True)
    title_extra = ""
    if kind == "radial":
        hits = []
        rows = np.roll(m.table("radial")[:, :, i, j], -shift, axis=0)
        for k in range(sl.n_angles):
            a = h + k * sl.angle_step
            p0 = (cx + sl.robot_radius * math.cos(a), cy + sl.robot_radius * math.sin(a))
            p1 = (cx + sl.max_range * math.cos(a), cy + sl.max_range * math.sin(a))
            ax.plot([p0[0], p1[0]], [p0[1], p1[1]], color="0.2", lw=0.4, zorder=2)
            for v in rows[k]:
                if v != NO_HIT_MM:
                    hits.append((cx + v / 1000 * math.cos(a), cy + v / 1000 * math.sin(a)))
        if hits:
            hx, hy = np.asarray(hits).T
            ax.scatter(hx, hy, s=12, color="red", zorder=3, label="table crossings")
            ax.legend(loc="upper right", fontsize=8)
    else:
        if family not in FAMILIES:
            raise FieldlocError(f"unknown spiral family '{family}' (ccw or cw)")
        direction = FAMILIES[family]
        used = list(range(0, sl.n_angles, 2))  # the 36 a robot walks each way
        n_draw = max(1, min(int(spirals), len(used)))
        drawn = [used[int(round(q * len(used) / n_draw)) % len(used)] for q in range(n_draw)]
        rows = np.roll(m.table("spiral")[:, :, i, j], -shift, axis=1)
        r = sl.spiral_radius(sl.spiral_phi())
        dots = []
        colours = [f"C{q % 10}" for q in range(n_draw)]
        for k in used:
            pts = sl.spiral_points(direction, k, h) + (cx, cy)
            v = rows[direction, k]
            hit = None if v == NO_HIT_MM else tuple(pts[int(np.argmin(np.abs(r - v / 1000)))])
            if k in drawn:
                c = colours[drawn.index(k)]
                start = math.degrees(h + k * sl.angle_step) % 360
                label = (f"from {start:.0f} deg: " + ("no crossing" if hit is None else
                                                      f"first crossing r = {v / 1000:.2f} m"))
                ax.plot(pts[:, 0], pts[:, 1], color=c, lw=1.4, zorder=3, label=label)
                ax.plot(*pts[0], "o", color=c, ms=4, zorder=3)
                if hit is not None:
                    ax.plot(*hit, "o", ms=9, mfc="none", mec=c, mew=2, zorder=4)
            if hit is not None:
                dots.append(hit)
        if dots:
            hx, hy = np.asarray(dots).T
            ax.scatter(hx, hy, s=10, color="red", zorder=5,
                       label=f"table crossings of all {len(used)} {family} spirals")
        ax.legend(loc="upper right", fontsize=7, title=f"{n_draw} of {len(used)} {family}"
                  " spirals", title_fontsize=7)
        title_extra = f" ({family})"
    ax.annotate("", xy=(cx + 0.6 * math.cos(h), cy + 0.6 * math.sin(h)), xytext=(cx, cy),
                arrowprops={"arrowstyle": "-|>", "color": "k", "lw": 2}, zorder=6)
    span = (sl.max_range if kind == "radial" else sl.spiral_end_radius) + 0.5
    ax.set_xlim(cx - span, cx + span)
    ax.set_ylim(cy - span, cy + span)
    ax.set_title(f"{kind} scan lines{title_extra} from ({cx:.2f}, {cy:.2f}), heading "
                 f"{math.degrees(h):.0f} deg")


def main(conf: str | dict | None, map_path: str | Path, output: str | Path, *,
         overwrite: bool = False, progress: bool = False) -> Path:
    """Draw the map ``map_path`` into the PNG ``output``: the distance table as a heat map, or
    the radial/spiral scan lines and table crossings from one cell (``conf``: which table, the
    cell and heading, the spiral family and how many spirals; see ``draw_scanlines_from_cell``).
    An existing ``output`` is replaced only with ``overwrite``, and never the map itself.
    A cell, heading, family or spiral count given for the distance table is refused: it would
    be ignored, and the picture would not show what was asked."""
    given = set(conf) if isinstance(conf, dict) else set()
    conf = stage_conf(confs, conf)
    unused = sorted(given & {"cell", "heading", "family", "spirals"})
    if conf["table"] == "distance" and unused:
        raise FieldlocError(f"{', '.join(unused)}: drawn only from a cell of the radial or"
                            " spiral table, not on the distance table (give --table radial or"
                            " spiral)")
    if conf["table"] == "radial" and given & {"family", "spirals"}:
        raise FieldlocError("family, spirals: drawn only on the spiral table, not the radial"
                            " one (give --table spiral)")
    table, cell, family = conf["table"], conf["cell"], conf["family"]
    heading, spirals = float(conf["heading"]), int(conf["spirals"])
    check_picture_output(output, {"map": map_path}, overwrite=overwrite)
    if not math.isfinite(heading):
        raise FieldlocError(f"heading must be a finite angle, got {heading}")
    if cell is not None and not all(math.isfinite(v) for v in cell):
        raise FieldlocError(f"cell must be a finite position (m), got {tuple(cell)}")
    if table not in TABLES:
        raise FieldlocError(f"unknown table '{table}' (one of {', '.join(TABLES)})")
    if table != "distance" and cell is None:
        raise FieldlocError(f"--table {table} needs --cell X Y")
    if spirals < 1:
        raise FieldlocError(f"spirals must be at least 1, got {spirals}")
    with MapFile(map_path) as m:
        if cell is not None and table != "distance":
            g = m.grid
            x0, y0 = g.origin[0] - g.resolution / 2, g.origin[1] - g.resolution / 2
            x1, y1 = x0 + g.shape[1] * g.resolution, y0 + g.shape[0] * g.resolution
            if not (x0 <= cell[0] <= x1 and y0 <= cell[1] <= y1):
                raise FieldlocError(
                    f"cell ({cell[0]:.6g}, {cell[1]:.6g}) lies outside the map's world"
                    f" (x {x0:g}..{x1:g} m, y {y0:g}..{y1:g} m)")
        if table == "distance":
            fig = new_figure(11, 7.5)
            ax = fig.add_subplot(1, 1, 1)
            draw_distance_table(ax, m)
            ax.set_title(f"{m.field.name}: distance table ({m.grid.resolution:g} m cells)")
        else:
            fig = new_figure(8, 8)
            ax = fig.add_subplot(1, 1, 1)
            draw_scanlines_from_cell(ax, m, cell[0], cell[1], heading, table, family=family,
                                     spirals=spirals)
        return save_figure(fig, output)
