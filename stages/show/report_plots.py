"""The plots of an evaluation report (plots/ of a report folder): the error CDF, the
trajectories on the field, the errors over time and the reliability diagram. Every plot
function draws into a matplotlib ``ax`` it is given (as evo does), so callers compose figures.

    main(conf, report_dir, *, overwrite=False) -> Path   # the plots folder
    draw(report, report_dir, conf=None, *, overwrite=False) -> Path   # of a report not yet written

draws them from a report folder written by stages.evaluate: its frames are matched to the
truth again from the poses and truth files the report names, with the report's settings
(stamp tolerance, thresholds, dpi), so the plots show exactly what the report counts.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np

from ..common.artifacts import check_output
from ..common.conf import stage_conf
from ..common.dataset import read_csv
from ..common.errors import FieldlocError
from ..common.field import FieldModel, load_field
from ..common.poses_file import read_poses
from ..common.report_file import PLOT_NAMES, PLOTS_DIR, decode_numbers, load_report
from ..evaluate.metrics import FrameErrors, frame_errors
from .field import draw_field
from .figure import new_figure, save_figure

log = logging.getLogger("fieldloc.evaluate")

confs = {"default": {"dpi": None}}  # dpi None: the dpi the report was evaluated with

TRUTH_COLOUR = "black"
FAILURE_COLOUR = "#d62728"


# ---------------------------------------------------------------------------- error plots


def plot_error_cdf(ax, position_error, thresholds=(), *, label: str | None = None,
                   colour=None, annotate: bool = True):
    """Cumulative share of frames by position error (cm). Failures (inf) never arrive, so the
    curve ends below 1 by the failure share. Thresholds are drawn as vertical lines with the
    share within each."""
    e = np.sort(np.asarray(position_error, float)[~np.isnan(position_error)])
    n = e.size
    finite = e[np.isfinite(e)] * 100.0
    share = np.arange(1, finite.size + 1) / max(n, 1)
    t_max = max((float(t) for t in thresholds), default=0.0) * 100.0
    right = max(1.3 * t_max, 1.02 * finite[-1] if finite.size else 1.0, 1.0)
    # the curve runs on flat to the right edge: the share of failures never arrives
    xs = np.concatenate([[0.0], finite, [right]])
    ys = np.concatenate([[0.0], share, [share[-1] if share.size else 0.0]])
    fails = n - finite.size
    lab = label
    if fails and label is not None:
        lab = f"{label} ({fails} failed)"
    elif fails:
        lab = f"{fails} of {n} frames failed"
    (line,) = ax.step(xs, ys, where="post", color=colour, label=lab)
    for t in thresholds:
        within = float(np.mean(e <= t)) if n else math.nan
        ax.axvline(t * 100.0, color="0.6", linestyle=":", linewidth=1)
        if annotate:
            ax.annotate(f"{within:.0%} <= {t * 100:g} cm", (t * 100.0, within),
                        textcoords="offset points", xytext=(4, -12), fontsize=8,
                        color=line.get_color())
    if fails:
        ax.axhline(finite.size / n, color=FAILURE_COLOUR, linestyle="--", linewidth=0.8)
    ax.set_xlabel("position error (cm)")
    ax.set_ylabel("share of frames")
    ax.set_ylim(0.0, 1.02)
    ax.set_xlim(left=0.0)
    ax.grid(True, alpha=0.3)
    if lab:
        ax.legend(loc="lower right", fontsize=8)
    return ax


def plot_trajectories(ax, fe: FrameErrors, field_model: FieldModel | None = None, *,
                      truth_path=None, max_error: float = 0.4, heading_every: int = 0):
    """The true trajectory (black) and the estimates coloured by position error (0 to
    ``max_error`` m), failures as red crosses at the true position, drawn on the field when a
    field model is given. ``truth_path``: (x, y) arrays of the whole true trajectory in time
    order (default: the truth rows matched to frames). ``heading_every`` > 0 adds heading
    arrows every that many frames."""
    if field_model is not None:
        draw_field(ax, field_model)
    else:
        ax.set_aspect("equal")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.grid(True, alpha=0.3)
    m = fe.matched
    order = np.argsort(fe.stamp[m], kind="stable")
    if truth_path is None:
        tx, ty = fe.truth_x[m][order], fe.truth_y[m][order]
    else:
        tx, ty = (np.asarray(v, float) for v in truth_path)
    ax.plot(tx, ty, color=TRUTH_COLOUR, linewidth=1.0, alpha=0.8, label="truth", zorder=3.2)
    if tx.size:
        ax.plot(tx[:1], ty[:1], "o", color=TRUTH_COLOUR, markersize=5, zorder=3.3,
                label="start")
    ok = ~fe.failed
    ax.plot(fe.x[ok], fe.y[ok], color="0.9", linewidth=0.5, alpha=0.8, zorder=2.5)
    mo = m & ok
    sc = ax.scatter(fe.x[mo], fe.y[mo], c=fe.position_error[mo], s=10, cmap="plasma",
                    vmin=0.0, vmax=max_error, zorder=3, edgecolors="none")
    if np.any(mo):  # a colour-mapped scatter gives the legend no visible marker: a proxy does
        ax.plot([], [], "o", color=sc.cmap(0.5), markersize=4, linestyle="none",
                label="estimate (colour: error)")
    uo = ~m & ok
    if np.any(uo):
        ax.scatter(fe.x[uo], fe.y[uo], s=8, color="0.6", zorder=3, edgecolors="none",
                   label=f"estimate, no truth ({int(uo.sum())})")
    cb = ax.figure.colorbar(sc, ax=ax, fraction=0.03, pad=0.02)
    cb.set_label(f"position error (m, clipped at {max_error:g})")
    fm = m & fe.failed
    if np.any(fm):
        ax.scatter(fe.truth_x[fm], fe.truth_y[fm], marker="x", s=30, color=FAILURE_COLOUR,
                   label=f"failed ({int(fm.sum())})", zorder=4)
    if heading_every > 0:
        sel = np.flatnonzero(ok)[::heading_every]
        ax.quiver(fe.x[sel], fe.y[sel], np.cos(fe.theta[sel]), np.sin(fe.theta[sel]),
                  angles="xy", scale=40, width=0.002, color="0.95", zorder=3.5)
    if field_model is None and np.any(m):
        pts_x = np.concatenate([fe.truth_x[m], fe.x[ok]])
        pts_y = np.concatenate([fe.truth_y[m], fe.y[ok]])
        pad = 0.5
        ax.set_xlim(np.nanmin(pts_x) - pad, np.nanmax(pts_x) + pad)
        ax.set_ylim(np.nanmin(pts_y) - pad, np.nanmax(pts_y) + pad)
    ax.legend(loc="upper right", fontsize=8, framealpha=0.8)
    return ax


def _mark_failures(ax, t, failed):
    if np.any(failed):
        ax.scatter(t[failed], np.full(int(failed.sum()), 0.97), marker="v", s=14,
                   color=FAILURE_COLOUR, transform=ax.get_xaxis_transform(), clip_on=False,
                   label=f"failed ({int(failed.sum())})", zorder=4)


def plot_position_error_over_time(ax, fe: FrameErrors, thresholds=()):
    """Position error (cm) of matched frames against time; failures marked at the top."""
    m = fe.matched
    t0 = np.nanmin(fe.stamp) if len(fe) else 0.0
    t = fe.stamp - t0
    ok = m & ~fe.failed
    ax.plot(t[ok], fe.position_error[ok] * 100.0, ".-", markersize=3, linewidth=0.7,
            label="position error")
    for th in thresholds:
        ax.axhline(th * 100.0, color="0.6", linestyle=":", linewidth=1)
    _mark_failures(ax, t, m & fe.failed)
    ax.set_ylabel("position error (cm)")
    ax.set_ylim(bottom=0.0)
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper left", fontsize=8)
    return ax


def plot_heading_error_over_time(ax, fe: FrameErrors):
    """Heading error (deg) of matched frames against time; failures marked at the top."""
    m = fe.matched
    t0 = np.nanmin(fe.stamp) if len(fe) else 0.0
    t = fe.stamp - t0
    ok = m & ~fe.failed
    ax.plot(t[ok], np.degrees(fe.heading_error[ok]), ".-", markersize=3, linewidth=0.7,
            color="tab:orange", label="heading error")
    _mark_failures(ax, t, m & fe.failed)
    ax.set_ylabel("heading error (deg)")
    ax.set_xlabel("time since first frame (s)")
    ax.set_ylim(bottom=0.0)
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper left", fontsize=8)
    return ax


# ---------------------------------------------------------------------------- report figures


def plot_reliability(ax, calibration: dict):
    """The reliability diagram: per confidence bin the observed share of frames whose top
    hypothesis is within the calibration threshold (with binomial standard errors) against
    the bin's mean confidence, the diagonal of perfect calibration, and the bins' frame counts
    as bars."""
    rows = calibration.get("reliability") or []
    ax.plot([0, 1], [0, 1], color="0.6", lw=1, ls="--", label="calibrated")
    if rows:
        conf = np.array([r["confidence"] for r in rows])
        obs = np.array([r["observed"] for r in rows])
        err = np.array([r["stderr"] for r in rows])
        ax.errorbar(conf, obs, yerr=err, fmt="o-", color="tab:blue", capsize=3,
                    label="observed")
        counts = np.array([r["frames"] for r in rows], float)
        lo = np.array([r["bin"][0] for r in rows])
        ax2 = ax.twinx()
        ax2.bar(lo, counts, width=0.1, align="edge", color="tab:gray", alpha=0.25)
        ax2.set_ylabel("frames")
    else:
        ax.text(0.5, 0.5, "no frame with a hypothesis", ha="center", va="center",
                transform=ax.transAxes)
    thr = calibration.get("threshold_m", 0.4)
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1.02)
    ax.set_xlabel("confidence of the top hypothesis")
    ax.set_ylabel(f"share within {thr * 100:g} cm")
    auroc = calibration.get("auroc")
    if auroc is not None and np.isfinite(auroc):
        ax.set_title(f"reliability (AUROC {auroc:.3f})")
    ax.legend(loc="upper left")


def write_report_plots(fe: FrameErrors, out_dir: str | Path, *, thresholds, title: str = "",
                       field_model: FieldModel | None = None, truth_path=None,
                       dpi: int = 120, calibration: dict | None = None) -> list[Path]:
    """The report's PNGs in ``out_dir``: error_cdf.png, trajectory.png, error_over_time.png and,
    with ``calibration`` (metrics.calibration), reliability.png. ``truth_path``: see
    ``plot_trajectories``."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []

    fig = new_figure(6.0, 4.0, dpi)
    ax = fig.add_subplot()
    plot_error_cdf(ax, fe.position_error[fe.matched], thresholds)
    ax.set_title(f"{title}: position error CDF" if title else "position error CDF")
    written.append(save_figure(fig, out_dir / "error_cdf.png"))

    if field_model is not None:
        xmin, xmax, ymin, ymax = field_model.world_bounds()
        aspect = (ymax - ymin) / (xmax - xmin)
    else:
        aspect = 0.7
    fig = new_figure(9.0, max(3.0, 9.0 * aspect), dpi)
    ax = fig.add_subplot()
    plot_trajectories(ax, fe, field_model, truth_path=truth_path,
                      max_error=max(thresholds) if thresholds else 0.4)
    ax.set_title(f"{title}: trajectories" if title else "trajectories")
    written.append(save_figure(fig, out_dir / "trajectory.png"))

    fig = new_figure(9.0, 5.0, dpi)
    ax_pos = fig.add_subplot(2, 1, 1)
    ax_head = fig.add_subplot(2, 1, 2, sharex=ax_pos)
    plot_position_error_over_time(ax_pos, fe, thresholds)
    plot_heading_error_over_time(ax_head, fe)
    ax_pos.set_title(f"{title}: error over time" if title else "error over time")
    written.append(save_figure(fig, out_dir / "error_over_time.png"))

    if calibration is not None:
        fig = new_figure(5.5, 4.5, dpi)
        plot_reliability(fig.add_subplot(), calibration)
        written.append(save_figure(fig, out_dir / "reliability.png"))
    return written


# ---------------------------------------------------------------------------- main


def main(conf: str | dict | None, report_dir: str | Path, *, overwrite: bool = False,
         progress: bool = False) -> Path:
    """Draw the plots of the report folder ``report_dir`` (report.json) into its plots/ folder
    and return that folder. Existing plots are replaced only with ``overwrite``."""
    conf = stage_conf(confs, conf)  # a bad conf is refused before the report is read
    report_dir = Path(report_dir)
    return draw(load_report(report_dir, raw=True), report_dir, conf, overwrite=overwrite)


def draw(report: dict, report_dir: str | Path, conf: str | dict | None = None, *,
         overwrite: bool = False) -> Path:
    """Draw the plots of ``report`` (a report.json's content, as ``load_report(raw=True)``
    reads it) into ``report_dir``/plots and return that folder: evaluate draws them before it
    writes report.json, so that a report.json is there only beside its plots."""
    conf = stage_conf(confs, conf)
    report_dir = Path(report_dir)
    econf = report["evaluate_conf"]
    plots_dir = report_dir / PLOTS_DIR
    inputs = {"poses": report["poses"], "truth": report["truth"]}
    check_output(plots_dir, None, overwrite=None, kind="folder")
    plots_dir.mkdir(exist_ok=True)
    for name in PLOT_NAMES:
        check_output(plots_dir / name, inputs, overwrite=overwrite)
    columns, attrs = read_poses(report["poses"])
    truth = read_csv(report["truth"], "truth")
    tolerance = float(econf["stamp_tolerance"])
    fe = frame_errors(columns, truth, tolerance)
    write_report_plots(
        fe, plots_dir, thresholds=econf["thresholds"], title=plot_title(report),
        field_model=_field_model(report.get("field_override"), attrs),
        truth_path=truth_path_during(truth, fe, tolerance),
        dpi=int(conf["dpi"] if conf["dpi"] is not None else econf["dpi"]),
        calibration=decode_numbers(report["calibration"]))
    return plots_dir


def plot_title(report: dict) -> str:
    """What the plots are of: the method and the dataset it ran on (the folder's name), else
    the poses file; not the report folder, whose name says nothing of the run."""
    method = report.get("method") or "poses"
    dataset = report.get("dataset")
    if isinstance(dataset, str) and dataset.strip("/"):
        return f"{method} on {Path(dataset).name}"
    return f"{method}: {Path(str(report.get('poses') or '?')).name}"


def _field_model(override, attrs: dict):
    """The field to draw on: the one evaluate was given (errors are the user's), else the
    poses' own: the field of the map they were made with (a custom field's map carries it),
    else the field they name (a failure there is logged and the plot drawn without field
    lines)."""
    if override:
        return load_field(override)
    from .hypotheses import poses_field

    try:
        return poses_field(attrs)
    except FieldlocError as e:
        log.warning("%s; trajectories drawn without field lines", e)
        return None


def truth_path_during(truth: dict, fe: FrameErrors, tolerance: float):
    """(x, y) of the truth rows, in time order, from the first to the last frame."""
    t = truth["stamp"]
    ok = np.isfinite(t) & np.isfinite(truth["x"]) & np.isfinite(truth["y"])
    ok &= (t >= np.nanmin(fe.stamp) - tolerance) & (t <= np.nanmax(fe.stamp) + tolerance)
    order = np.argsort(t[ok], kind="stable")
    return truth["x"][ok][order], truth["y"][ok][order]
