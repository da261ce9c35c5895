"""The pictures of a batch comparison (``fieldloc batch``): per dataset the error CDFs of its
methods overlaid, and one summary of every method on every dataset.

    draw_error_cdfs(ax, curves, thresholds)     curves: [(label, position errors (m))]
    draw_summary(ax, rows)                      rows: stages.evaluate.report.comparison_rows
    draw_dataset_cdf(results_dir, dataset, runs, conf=None) -> Path | None
    main(conf, results_dir, *, overwrite=False, progress=False, drawn=()) -> Path  # RESULTS/plots

The CDFs are drawn from each run's errors.csv (position errors of the matched frames, a frame
without an accepted pose at inf: the curve ends below 1 by the share of failures), the
summary from the figures of the comparison table itself, so a picture never says what the
table does not.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np

from ..common.artifacts import check_output
from ..common.batch_file import load_batch
from ..common.conf import stage_conf
from ..common.report_file import ERRORS_NAME, load_report, read_errors_csv
from .figure import new_figure, save_figure
from .report_plots import plot_error_cdf

log = logging.getLogger("fieldloc.batch")

confs = {"default": {"dpi": 110, "thresholds": [0.1, 0.2, 0.4]}}

PLOTS_DIR = "plots"
SUMMARY_NAME = "summary.png"


def draw_error_cdfs(ax, curves, thresholds=()):
    """Overlaid CDFs of the position error (cm), one per (label, errors) curve; the threshold
    lines once."""
    colours = _colours(len(curves))
    for k, (label, errors) in enumerate(curves):
        plot_error_cdf(ax, errors, thresholds if k == 0 else (), label=label,
                       colour=colours[k], annotate=False)
    return ax


def draw_summary(ax, rows, threshold: str = "0.4"):
    """Methods (rows) x datasets (columns): the colour is the share within 40 cm (failures
    counted), the text that share and the median error; a failed run is marked "failed", a run
    without truth "no truth", a run none of whose matched frames was accepted "none accepted"
    (its share 0 and median infinite say nothing more)."""
    datasets = list(dict.fromkeys(r["dataset"] for r in rows))
    methods = list(dict.fromkeys(r["method"] for r in rows))
    grid = np.full((len(methods), len(datasets)), np.nan)
    text = [["" for _ in datasets] for _ in methods]
    for r in rows:
        i, j = methods.index(r["method"]), datasets.index(r["dataset"])
        rep = r["report"]
        if rep is None:
            text[i][j] = "failed"
            continue
        within = rep.get("within", {}).get(threshold)
        median = rep.get("position_error_m", {}).get("median")
        if within is None:
            text[i][j] = "no truth"
            continue
        grid[i, j] = float(within)
        if rep.get("accepted") == 0 and rep.get("matched", 0):
            text[i][j] = "none\naccepted"
            continue
        med = "inf" if median is not None and math.isinf(median) else (
            "-" if median is None or math.isnan(median) else f"{median * 100:.1f} cm")
        text[i][j] = f"{float(within):.0%}\n{med}"
    im = ax.imshow(np.ma.masked_invalid(grid), vmin=0.0, vmax=1.0, cmap="viridis",
                   aspect="auto")
    for i in range(len(methods)):
        for j in range(len(datasets)):
            v = grid[i, j]
            ax.text(j, i, text[i][j], ha="center", va="center", fontsize=8,
                    color="white" if not np.isfinite(v) or v < 0.6 else "black")
    ax.set_xticks(range(len(datasets)), datasets, rotation=30, ha="right", fontsize=8)
    ax.set_yticks(range(len(methods)), methods, fontsize=8)
    ax.set_title(f"share within {float(threshold) * 100:g} cm (failures counted), median error",
                 fontsize=9)
    cb = ax.figure.colorbar(im, ax=ax, fraction=0.04, pad=0.02)
    cb.set_label(f"within {float(threshold) * 100:g} cm")
    return ax


def _colours(n: int):
    from matplotlib import colormaps

    cmap = colormaps["tab10"]
    return [cmap(k % 10) for k in range(n)]


def main(conf, results_dir, *, overwrite: bool = False, progress: bool = False,
         drawn=()) -> Path:
    """The comparison pictures of the batch results folder ``results_dir`` into its plots/:
    cdf-<dataset>.png per dataset with truth, summary.png. Returns the plots folder.
    ``drawn``: datasets whose CDF ``draw_dataset_cdf`` wrote already, from the runs this index
    holds (a Dask batch draws each dataset's as soon as its runs are done)."""
    from ..evaluate.report import comparison_rows

    conf = stage_conf(confs, conf)
    results_dir = Path(results_dir)
    index = load_batch(results_dir)
    out = results_dir / PLOTS_DIR
    check_output(out, None, overwrite=None, kind="folder")
    rows = comparison_rows(results_dir)
    names = {f"cdf-{d}.png" for d in index.get("datasets", {})} | {SUMMARY_NAME}
    if not overwrite:
        for n in names:
            if (out / n).exists():
                raise_exists(out / n)
    out.mkdir(parents=True, exist_ok=True)
    for dataset in dict.fromkeys(r["dataset"] for r in rows):
        if dataset not in drawn:
            draw_dataset_cdf(results_dir, dataset, index["runs"], conf)
    n_ds = len({r["dataset"] for r in rows})
    n_m = len({r["method"] for r in rows})
    fig = new_figure(max(5.0, 1.3 * n_ds + 2.5), max(2.5, 0.7 * n_m + 1.8), conf["dpi"])
    draw_summary(fig.add_subplot(1, 1, 1), rows)
    save_figure(fig, out / SUMMARY_NAME)
    return out


def draw_dataset_cdf(results_dir, dataset: str, runs: list[dict], conf=None) -> Path | None:
    """plots/cdf-<dataset>.png of a batch results folder: the overlaid error CDFs of the
    dataset's finished runs with truth, from ``runs`` (run records as the batch index holds
    them, in its order; other datasets' are ignored). None, and an older picture removed, when
    no run of the dataset has position errors."""
    conf = stage_conf(confs, conf)
    results_dir = Path(results_dir)
    curves = []
    for run in runs:
        if run["dataset"] != dataset or run["status"] != "ok" or not run.get("report"):
            continue
        if "position_error_m" not in load_report(results_dir / run["report"]):
            continue
        err = read_errors_csv(results_dir / run["report"] / ERRORS_NAME)
        matched = err["matched"] > 0
        curves.append((run["method"], err["position_error_m"][matched]))
    target = results_dir / PLOTS_DIR / f"cdf-{dataset}.png"
    if not curves:
        target.unlink(missing_ok=True)
        return None
    target.parent.mkdir(parents=True, exist_ok=True)
    thresholds = [float(t) for t in conf["thresholds"]]
    fig = new_figure(7.0, 4.2, conf["dpi"])
    ax = fig.add_subplot(1, 1, 1)
    draw_error_cdfs(ax, curves, thresholds)
    ax.set_title(f"{dataset}: position error", fontsize=10)
    ax.set_xlim(0.0, 100.0 * max(1.3 * max(thresholds), 0.5))
    return save_figure(fig, target)


def raise_exists(path: Path):
    from ..common.errors import FieldlocError

    raise FieldlocError(f"{path} exists (use --overwrite to replace it)")
