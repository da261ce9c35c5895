"""The pictures and lines of the SURF template paper's comparison of its two methods (``fieldloc
show error-surface``), drawn from what stages.pipelines.error_surface.measure computed (this
module runs no stage):

- (a) figure 3: eq. 1 of the white points of the query frame nearest the template against the
  white-point table Dm, over (dx, dy) at the true heading and over dtheta at the true position;
- (b) figure 4: eq. 4 of the same query's pairs matched to the template, for the query
  displaced by (dx, dy, dtheta) from its true pose;
- (c) figure 5: every query fitted against the template: position error against the query's
  distance from the template, heading error against the query's heading from the template's.

The local minima of (a) and (b) are marked (stages.common.surfaces); ``summary_lines`` gives
the numbers a line each.

    error_surface_figure(m) -> Figure  (``measure``'s result; the chain saves it)
"""

from __future__ import annotations

import math

import numpy as np

from ..common.surfaces import local_minima
from .figure import new_figure


def summary_lines(m: dict) -> list[str]:
    """The numbers of ``measure``, a line each."""
    a, b = m["a"], m["b"]
    tp, qp = m["template_pose"], m["query_pose"]
    out = [f"template {m['template']} at ({tp[0]:.2f}, {tp[1]:.2f}) m,"
           f" {math.degrees(tp[2]):.0f} deg; query {m['query']} at ({qp[0]:.2f}, {qp[1]:.2f})"
           f" m, {math.degrees(qp[2]):.0f} deg"]
    for tag, name, s in (("a", "white-point table (eq. 1)", a), ("b", "template pairs (eq. 4)",
                                                                   b)):
        out.append(
            f"({tag}) {name}, local minima (below the median): {s['minima_xyt']}"
            f" ({s['minima_xyt_below_median']}) over (dx, dy, dtheta), {s['minima_xy']}"
            f" ({s['minima_xy_below_median']}) over (dx, dy), {s['minima_theta']}"
            f" ({s['minima_theta_below_median']}) over dtheta; lowest at"
            f" ({100 * s['lowest_dxy'][0]:.0f}, {100 * s['lowest_dxy'][1]:.0f}) cm,"
            f" {math.degrees(s['lowest_dtheta']):.0f} deg")
    out[-2] += f"; {m['white_points']['points']} white points"
    out[-1] += f"; {m['template_pairs']['pairs']} inlier pairs"
    for r in m["rings"]:
        out.append(
            f"(c) {r['from']:.1f}-{r['to']:.1f} m from the template: {r['queries']} queries,"
            f" {r['failed']} failed, position error median {100 * r['median_m']:.1f} cm max"
            f" {100 * r['max_m']:.1f} cm, |heading error| max"
            f" {math.degrees(r['max_heading']):.1f} deg")
    return out


# ---------------------------------------------------------------------------- drawing


def draw_surface(ax, s: dict, title: str):
    """A (dx, dy) surface as a heat map (cm), its local minima as white dots and the lowest as
    a red circle."""
    d = s["dx"]
    h = (d[1] - d[0]) / 2 if len(d) > 1 else 0.05
    ext = (100 * (d[0] - h), 100 * (d[-1] + h), 100 * (s["dy"][0] - h), 100 * (s["dy"][-1] + h))
    im = ax.imshow(s["xy"], origin="lower", extent=ext, cmap="viridis", interpolation="nearest")
    ax.figure.colorbar(im, ax=ax, shrink=0.8)
    mins = local_minima(s["xy"])
    if len(mins):
        ax.scatter(100 * s["dx"][mins[:, 1]], 100 * s["dy"][mins[:, 0]], s=8, c="white",
                   edgecolors="none")
        ax.scatter([100 * s["dx"][mins[0, 1]]], [100 * s["dy"][mins[0, 0]]], s=90,
                   facecolors="none", edgecolors="red", lw=1.5)
    ax.set_xlabel("dx (cm)")
    ax.set_ylabel("dy (cm)")
    ax.set_title(f"{title}: {len(mins)} local minima", fontsize=9)


def draw_theta(ax, s: dict, title: str):
    """A surface over dtheta, its local minima marked."""
    deg = np.degrees(s["dtheta"])
    ax.plot(deg, s["theta"], "-", color="tab:blue")
    mins = local_minima(s["theta"])
    if len(mins):
        ax.plot(deg[mins[:, 0]], s["theta"][mins[:, 0]], "o", color="red", ms=4)
    ax.set_xlabel("dtheta (deg)")
    ax.set_title(f"{title}: {len(mins)} local minima", fontsize=9)


def draw_query_errors(ax_position, ax_heading, fits: dict):
    """Figure 5: position error (cm) against the distance from the template, and heading error
    (deg) against the query's heading from the template's (against the distance when all
    queries share one heading); failures as crosses on the axis."""
    d = fits["distance"]
    e = fits["position_error"]
    ok = np.isfinite(e)
    ax_position.scatter(d[ok], 100 * e[ok], s=8, c="tab:blue", edgecolors="none")
    ax_position.scatter(d[~ok], np.zeros((~ok).sum()), s=20, marker="x", c="red",
                        label=f"{(~ok).sum()} failed")
    ax_position.set_xlabel("query distance from the template (m)")
    ax_position.set_ylabel("position error (cm)")
    ax_position.set_yscale("symlog", linthresh=10)
    ax_position.legend(fontsize=8)
    ax_position.set_title("(c) position error", fontsize=9)
    h = np.degrees(fits["heading_error"])
    turned = np.ptp(fits["dheading"]) > 1e-6  # queries at several headings
    x = np.degrees(fits["dheading"]) if turned else d
    colour = {"c": d[ok], "cmap": "plasma"} if turned else {"c": "tab:blue"}
    ax_heading.scatter(x[ok], h[ok], s=8, edgecolors="none", **colour)
    ax_heading.axhline(15, color="grey", lw=0.8, ls="--")
    ax_heading.axhline(-15, color="grey", lw=0.8, ls="--")
    ax_heading.set_xlabel("query heading from the template's (deg)" if turned
                          else "query distance from the template (m)")
    ax_heading.set_ylabel("heading error (deg)")
    ax_heading.set_title("(c) heading error" + (" (colour: distance)" if turned else ""),
                         fontsize=9)


def error_surface_figure(m: dict):
    """The figure of ``measure``'s result: (a) and (b) over (dx, dy) and dtheta, (c)."""
    fig = new_figure(15.0, 10.0)
    draw_surface(fig.add_subplot(2, 3, 1), m["white_points"], "(a) white-point table, eq. 1 (m)")
    draw_surface(fig.add_subplot(2, 3, 2), m["template_pairs"], "(b) template pairs, eq. 4 (m^2)")
    ax = fig.add_subplot(2, 3, 3)
    draw_theta(ax, m["white_points"], "(a) over dtheta")
    ax2 = ax.twinx()
    ax2.plot(np.degrees(m["template_pairs"]["dtheta"]), m["template_pairs"]["theta"], "-",
             color="tab:orange")
    ax.set_ylabel("(a) eq. 1 (m)", color="tab:blue")
    ax2.set_ylabel("(b) eq. 4 (m^2)", color="tab:orange")
    ax.set_title(f"dtheta: (a) {m['a']['minima_theta']} minima, (b) {m['b']['minima_theta']}",
                 fontsize=9)
    draw_query_errors(fig.add_subplot(2, 3, 4), fig.add_subplot(2, 3, 5), m["fits"])
    ax = fig.add_subplot(2, 3, 6)
    ax.set_axis_off()
    ax.text(0, 1, "\n".join(summary_lines(m)), va="top", fontsize=6.5, family="monospace",
            wrap=True)
    return fig
