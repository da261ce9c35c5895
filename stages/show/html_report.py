"""One self-contained HTML page of evaluation reports, to send to a teammate.

    main(conf, source, output, *, overwrite=False) -> Path

``source``: a report folder (report.json, errors.csv, plots/ written by ``fieldloc evaluate``)
or a results folder holding report folders anywhere below it (each becomes a section, with a
table of all runs at the top). Per report the page holds:

- the figures of report.json in a table (every number cell carries ``data-key``, its path in
  report.json with '/' between the keys, and ``data-value``, the number as report.json has
  it, so a script can check the page against the report);
- the report's plots (error CDF, trajectory on the field, error over time, and
  ``plots/reliability.png`` when the report has it) and the reliability table of
  ``calibration.reliability`` when report.json has one;
- the ``worst`` frames by position error (failures first: they are infinitely wrong) with
  their overlays: the image with its extracted line points, and the points put on the field
  at the estimated pose beside the true one (from the features file the poses file names,
  else DATASET/features.h5; a frame whose image or features cannot be found is listed
  without a picture, saying why).

Every picture is embedded as a base64 PNG (``data:image/png``): the page needs no other file.
A plot that is not a PNG file inside the report folder (an empty file, a link to a file
elsewhere) is not embedded: the page and a warning say so
(stages.common.report_file.read_plot).
"""

from __future__ import annotations

import base64
import datetime as _dt
import html
import io
import logging
import math
from pathlib import Path

import numpy as np

from .. import __version__
from ..common.artifacts import atomic_path, check_output, storable_text
from ..common.conf import stage_conf
from ..common.errors import FieldlocError, check_file, file_problem
from ..common.report_file import REPORT_NAME, load_report, read_errors_csv, read_plot
from ..evaluate.report import table_rows

log = logging.getLogger(__name__)

confs = {"default": {"worst": 4, "plots": ["error_cdf.png", "trajectory.png",
                                           "error_over_time.png", "reliability.png"],
                     "overlay_dpi": 80}}

# (label, key path in report.json, scale, digits, unit)
FIGURES = [
    ("frames", ("frames",), 1, 0, ""),
    ("matched to truth", ("matched",), 1, 0, ""),
    ("failures", ("failures",), 1, 0, ""),
    ("accepted", ("accepted",), 1, 0, ""),
    ("position error median", ("position_error_m", "median"), 100, 1, "cm"),
    ("position error p90", ("position_error_m", "p90"), 100, 1, "cm"),
    ("position error RMSE", ("position_error_m", "rmse"), 100, 1, "cm"),
    ("heading error median", ("heading_error_deg", "median"), 1, 2, "deg"),
    ("localised frames", ("localised", "frames"), 1, 0, ""),
    ("localised: position median", ("localised", "position_error_m", "median"), 100, 1, "cm"),
    ("localised: position RMSE", ("localised", "position_error_m", "rmse"), 100, 1, "cm"),
    ("localised: position max", ("localised", "position_error_m", "max"), 100, 1, "cm"),
    ("localised: heading median", ("localised", "heading_error_deg", "median"), 1, 2, "deg"),
    ("confidently wrong (> 1 m, accepted)", ("confidently_wrong",), 1, 0, ""),
    ("calibration AUROC", ("calibration", "auroc"), 1, 3, ""),
    ("runtime median", ("runtime_ms", "median"), 1, 3, "ms"),
]

_CSS = """
body{font-family:sans-serif;margin:2em;max-width:1100px;color:#222}
h1{font-size:1.5em}h2{font-size:1.25em;border-bottom:1px solid #ccc;margin-top:2em}
table{border-collapse:collapse;margin:0.5em 0}td,th{border:1px solid #ccc;padding:3px 8px}
td.num{text-align:right;font-variant-numeric:tabular-nums}th{background:#f3f3f3}
img{max-width:100%;border:1px solid #ddd;margin:4px 0}.note{color:#666;font-size:0.9em}
figure{margin:0.5em 0}figcaption{font-size:0.9em;color:#444}
"""


# how every page starts: the generator names fieldloc, so --overwrite can tell its own pages
PAGE_HEAD = ("<!DOCTYPE html><html><head><meta charset='utf-8'>"
             "<meta name='generator' content='fieldloc report'>")
_OLDER_PAGE_HEAD = "<!DOCTYPE html><html><head><meta charset='utf-8'><title>fieldloc report:"


def is_report_page(path: Path) -> bool:
    """Whether ``path`` is a page this module wrote (what --overwrite may replace)."""
    try:
        with open(path, "rb") as f:
            head = f.read(len(PAGE_HEAD) + len(_OLDER_PAGE_HEAD))
    except OSError:
        return False
    return head.startswith(PAGE_HEAD.encode()) or head.startswith(_OLDER_PAGE_HEAD.encode())


def report_inputs(dirs: list[Path]) -> dict[str, list[Path]]:
    """What the page is made from, which its output may never be: every file of the report
    folders (report.json, errors.csv, plots) and the poses and features files they name."""
    from ..common.poses_file import read_poses

    files, runs = [], []
    for d in dirs:
        files += [p for p in d.rglob("*") if p.is_file()]
        try:
            report = load_report(d, raw=True)
        except FieldlocError:
            continue
        poses = report.get("poses")
        if isinstance(poses, str) and Path(poses).is_file():
            runs.append(Path(poses))
            try:
                f = ((read_poses(poses)[1].get("inputs") or {}).get("features"))
            except FieldlocError:
                f = None
            if isinstance(f, str):
                runs.append(Path(f))
    return {"a file of the report": files, "the run's poses or features": runs}


def find_reports(source) -> list[Path]:
    """Report folders: ``source`` itself if it holds report.json, else every folder below it
    that does (sorted)."""
    source = Path(source)
    if not source.exists():
        check_file(source, "report folder")  # absent, or a link loop
    if source.is_file():
        if source.name == REPORT_NAME:
            return [source.parent]
        raise FieldlocError(f"{source}: give a report folder or a folder of reports")
    if file_problem(source / REPORT_NAME) != "not found":  # a link loop is no absent report
        check_file(source / REPORT_NAME, "report")
        return [source]
    found = sorted(p.parent for p in source.rglob(REPORT_NAME))
    if not found:
        raise FieldlocError(f"{source}: no {REPORT_NAME} in it or below it (run fieldloc"
                            " evaluate first)")
    return found


def lookup(report: dict, path: tuple):
    """The value at a key path of report.json (list items by index), or None."""
    d = report
    for k in path:
        if isinstance(d, list) and str(k).isdigit() and int(k) < len(d):
            d = d[int(k)]
        elif isinstance(d, dict) and k in d:
            d = d[k]
        else:
            return None
    return d


def _fmt(v, scale, digits, unit) -> str:
    if v is None:
        return "-"
    v = float(v)
    if math.isnan(v):
        return "-"
    if math.isinf(v):
        return "inf"
    return f"{v * scale:.{digits}f}" + (f" {unit}" if unit else "")


def _data_value(v) -> str:
    if v is None:
        return ""
    v = float(v)
    return "nan" if math.isnan(v) else ("inf" if math.isinf(v) else repr(v))


def _img(data: bytes, alt: str) -> str:
    return (f'<img alt="{html.escape(alt)}" src="data:image/png;base64,'
            f'{base64.b64encode(data).decode()}">')


def _figure_png(fig, dpi) -> bytes:
    from .figure import drawable_texts

    buf = io.BytesIO()
    drawable_texts(fig).savefig(buf, format="png", dpi=dpi, bbox_inches="tight")
    return buf.getvalue()


def figures_table(report: dict) -> str:
    rows = []
    for label, path, scale, digits, unit in FIGURES:
        v = lookup(report, path)
        if v is None:
            continue
        rows.append(f'<tr><th>{html.escape(label)}</th><td class="num" data-key='
                    f'"{"/".join(path)}" data-value="{_data_value(v)}" data-scale="{scale}">'
                    f"{_fmt(v, scale, digits, unit)}</td></tr>")
    for k, v in sorted((report.get("within") or {}).items(), key=lambda kv: float(kv[0])):
        rows.append(f'<tr><th>within {float(k) * 100:g} cm</th><td class="num" data-key='
                    f'"within/{k}" data-value="{_data_value(v)}" data-scale="100">'
                    f"{_fmt(v, 100, 1, '%')}</td></tr>")
    return "<table>" + "".join(rows) + "</table>"


def reliability_table(report: dict) -> str:
    table = lookup(report, ("calibration", "reliability"))
    if not isinstance(table, list) or not table:
        return ""
    keys = [k for k in table[0] if not isinstance(table[0][k], (list, dict))]
    head = "".join(f"<th>{html.escape(str(k))}</th>" for k in keys)
    body = []
    for i, row in enumerate(table):
        cells = []
        for k in keys:
            v = row.get(k)
            if isinstance(v, (int, float)) and not isinstance(v, bool):
                cells.append(f'<td class="num" data-key="calibration/reliability/{i}/{k}"'
                             f' data-value="{_data_value(v)}" data-scale="1">'
                             f"{_fmt(v, 1, 3 if isinstance(v, float) else 0, '')}</td>")
            else:
                cells.append(f"<td>{html.escape(str(v))}</td>")
        body.append("<tr>" + "".join(cells) + "</tr>")
    return ("<h3>Reliability (confidence against the share of correct frames)</h3><table><tr>"
            + head + "</tr>" + "".join(body) + "</table>")


def worst_frames(report_dir: Path, n: int) -> list[dict]:
    """The ``n`` matched frames with the largest position error (failures first)."""
    errors = report_dir / "errors.csv"
    if n <= 0 or not errors.is_file():
        return []
    e = read_errors_csv(errors)
    matched = e["matched"] > 0
    idx = np.flatnonzero(matched)
    err = e["position_error_m"][idx]
    order = idx[np.argsort(-np.nan_to_num(err, nan=-1.0), kind="stable")][:n]
    return [{"name": str(e["name"][i]), "stamp": float(e["stamp"][i]),
             "failed": bool(e["failed"][i]), "error_m": float(e["position_error_m"][i]),
             "pose": (float(e["x"][i]), float(e["y"][i]), float(e["theta"][i])),
             "truth": (float(e["truth_x"][i]), float(e["truth_y"][i]),
                       float(e["truth_theta"][i]))} for i in order]


def _poses_attrs(report: dict) -> dict:
    """The attributes of a report's poses file, or {} where it cannot be read."""
    from ..common.poses_file import read_poses

    poses = report.get("poses")
    if poses and Path(poses).is_file():
        try:
            return read_poses(poses)[1]
        except FieldlocError:
            pass
    return {}


def _frame_sources(report: dict, attrs: dict):
    """(dataset folder, features file or None) of a report's run from the report and its
    poses file's ``attrs``, or (None, None)."""
    dataset = Path(report["dataset"]) if report.get("dataset") else None
    f = (attrs.get("inputs") or {}).get("features")
    features = Path(f) if f and Path(f).is_file() else None
    if dataset is None and attrs.get("dataset"):
        dataset = Path(attrs["dataset"])
    if features is None and dataset is not None and (dataset / "features.h5").is_file():
        features = dataset / "features.h5"
    return dataset, features


def overlay_png(dataset, features, frame: dict, field_model, dpi: int) -> tuple[bytes | None,
                                                                               str]:
    """The overlay of one worst frame, or (None, why not)."""
    from ..common.dataset import open_dataset, read_image
    from ..common.features_file import FeaturesFile
    from .points import points_figure

    if dataset is None or not Path(dataset).is_dir():
        return None, "the run's dataset folder is not at hand"
    if features is None:
        return None, "no features file for the run"
    try:
        ds = open_dataset(dataset)
        names = ds.names
        if frame["name"] not in names:
            return None, f"no image of frame {frame['name']} in {dataset}"
        image = read_image(ds.images[names.index(frame["name"])])
        with FeaturesFile(features) as ff:
            if frame["name"] not in ff.names:
                return None, f"frame {frame['name']} is not in {features}"
            arrays = ff.frame(frame["name"])
    except FieldlocError as e:
        return None, str(e)
    pose = None if frame["failed"] else frame["pose"]
    shown = pose if pose is not None else frame["truth"]
    fig = points_figure(image, arrays, field_model=field_model, pose=shown,
                        title=f"frame {frame['name']}")
    if field_model is not None and len(fig.axes) > 1:
        ax = fig.axes[1]
        tx, ty, tt = frame["truth"]
        ax.plot([tx], [ty], "s", color="yellow", ms=7, zorder=7, label="truth")
        ax.arrow(tx, ty, 0.5 * math.cos(tt), 0.5 * math.sin(tt), width=0.03, color="yellow",
                 zorder=7)
        ax.legend(loc="upper right", fontsize=7)
        if pose is None:
            ax.set_title("failed frame: points at the true pose", fontsize=9)
    return _figure_png(fig, dpi), ""


def report_section(report_dir: Path, conf: dict, index: int) -> str:
    report = load_report(report_dir, raw=True)
    title = html.escape(str(report.get("run") or report_dir.name))
    parts = [f'<section id="report-{index}"><h2>{title}</h2>',
             f'<p class="note">method {html.escape(str(report.get("method", "")))}, field'
             f' {html.escape(str(report.get("field", "")))}; poses'
             f' {html.escape(str(report.get("poses", "")))}; truth'
             f' {html.escape(str(report.get("truth", "")))}; report'
             f' {html.escape(str(report_dir))}</p>', figures_table(report)]
    plots_dir = report_dir / "plots"
    for name in conf["plots"]:
        png, why = read_plot(report_dir, name)
        if png is not None:
            parts.append(f"<figure>{_img(png, name)}<figcaption>"
                         f"{html.escape(name)}</figcaption></figure>")
        elif why != "no such file":
            log.warning("report: %s not shown: %s", plots_dir / name, why)
            parts.append(f"<p>{html.escape(name)} not shown: {html.escape(why)}</p>")
    parts.append(reliability_table(report))
    worst = worst_frames(report_dir, int(conf["worst"]))
    if worst:
        parts.append(f"<h3>The {len(worst)} worst frames</h3>")
        from .hypotheses import poses_field

        attrs = _poses_attrs(report)
        dataset, features = _frame_sources(report, attrs)
        try:  # the field evaluate was given, else the poses' own (their map's, their name's)
            fm = poses_field(attrs or {"field": report.get("field") or ""},
                             report.get("field_override"))
        except FieldlocError:
            fm = None  # the frames are drawn without field lines
        for fr in worst:
            err = ("failed (infinite error)" if fr["failed"] else
                   "not accepted (counted as infinite error)" if math.isinf(fr["error_m"])
                   else f"{fr['error_m'] * 100:.1f} cm")
            png, why = overlay_png(dataset, features, fr, fm, int(conf["overlay_dpi"]))
            cap = f"frame {html.escape(fr['name'])} at {fr['stamp']:.3f} s: {err}"
            parts.append(f"<figure>{_img(png, fr['name'])}<figcaption>{cap}</figcaption>"
                         "</figure>" if png else f"<p>{cap}; no overlay: {html.escape(why)}</p>")
    parts.append("</section>")
    return "\n".join(parts)


def main(conf: str | dict | None, source, output, *, overwrite: bool = False,
         progress: bool = False) -> Path:
    """Write the HTML page of the report(s) in ``source`` to ``output``; returns it."""
    conf = stage_conf(confs, conf)
    if int(conf["worst"]) < 0:
        raise FieldlocError(f"worst must be 0 or more frames, got {conf['worst']}")
    output = Path(output)
    dirs = find_reports(source)
    check_output(output, report_inputs(dirs), overwrite=overwrite, ours=is_report_page)
    if output.suffix.lower() not in (".html", ".htm"):  # r.pdf would hold HTML
        raise FieldlocError(f"{output}: the report is an HTML page; name it .html")
    header, rows = table_rows(dirs)
    runs = ("<table><tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in header) + "</tr>"
            + "".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>"
                      for r in rows) + "</table>")
    sections = [report_section(d, conf, i) for i, d in enumerate(dirs)]
    created = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
    page = (f"{PAGE_HEAD}<title>fieldloc report:"
            f" {html.escape(Path(source).name)}</title><style>{_CSS}</style></head><body>"
            f"<h1>fieldloc report: {html.escape(str(source))}</h1><p class='note'>{len(dirs)}"
            f" run(s); written {created} by fieldloc {__version__}. Distances between line"
            " centre lines; failures count as infinite error.</p>" + runs
            + "\n".join(sections) + "</body></html>\n")
    with atomic_path(output, suffix=".html") as tmp:  # a name that is no UTF-8 as \xff
        tmp.write_text(storable_text(page), encoding="utf-8")
    return output
