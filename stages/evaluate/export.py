"""Poses out of fieldloc: ``poses.h5`` as CSV, TUM or JSON for a team's own plotting, and the
truth as TUM beside a report so that evo reads both.

    main(conf, poses, output=None, *, fmt, overwrite=False) -> Path
    write_truth_tum(path, truth_columns) -> Path

Formats (``fmt``):

- ``csv``: one row per frame: name, stamp, x, y, theta, accepted, failed, confidence, error,
  mode, runtime, hypotheses (how many), the covariance's six distinct entries (cov_xx, cov_xy,
  cov_xt, cov_yy, cov_yt, cov_tt; m^2, m rad, rad^2), flags, and what the frame decides up to
  a point-symmetric field's 180 deg turn (stages.localize.symmetry): accepted_up_to_mirror,
  confidence_up_to_mirror and, for a frame accepted only up to the mirror, the other pose of
  the pair (mirror_x, mirror_y, mirror_theta; else missing). Metres, radians, seconds; a
  missing number (a failed frame's pose) is ``nan``; booleans are 0/1;
- ``tum``: "stamp x y z qx qy qz qw" rows of the *accepted* frames only, as ``poses.tum``
  (stages.common.poses_file.write_tum): what evo and other trajectory tools read;
- ``json``: ``{"schema": "fieldloc.poses-export", "version": 1, "source", "method", "field",
  "dataset", "min_confidence", "frames": [...]}``, each frame with the csv's values, its
  covariance (3 x 3, or null) and ``hypotheses``: the ranked list of [x, y, theta,
  probability] (poses v2; a version 1 file gives the pose with its confidence). NaN is null.

``output`` None: beside the poses file with the format's suffix (poses.csv, poses.tum,
poses.json). An existing file is replaced only with ``overwrite``; never the poses file nor
a file the poses were made from (``run_inputs``).
"""

from __future__ import annotations

import csv
import json
import math
import sys
from pathlib import Path

import numpy as np

from ..common.artifacts import atomic_path, check_output, starts_with
from ..common.errors import FieldlocError, real_path
from ..common.field import FieldModel
from ..common.poses_file import (
    is_fieldloc_tum,
    read_poses,
    run_inputs,
    write_tum,
    write_tum_to,
)

FORMATS = {"csv": ".csv", "tum": ".tum", "json": ".json"}
JSON_SCHEMA = "fieldloc.poses-export"
JSON_VERSION = 1
CSV_COLUMNS = ("name", "stamp", "x", "y", "theta", "accepted", "failed", "confidence", "error",
               "mode", "runtime", "hypotheses", "cov_xx", "cov_xy", "cov_xt", "cov_yy",
               "cov_yt", "cov_tt", "flags", "accepted_up_to_mirror", "confidence_up_to_mirror",
               "mirror_x", "mirror_y", "mirror_theta")
_COV = {"cov_xx": (0, 0), "cov_xy": (0, 1), "cov_xt": (0, 2), "cov_yy": (1, 1),
        "cov_yt": (1, 2), "cov_tt": (2, 2)}

confs = {"default": {"decimals": 6}}


def exported(path: Path) -> bool:
    """Whether ``path`` is a file ``main`` wrote, in any format (what --overwrite replaces):
    a TUM file with write_tum's header, a CSV with these columns, this schema's JSON."""
    return (is_fieldloc_tum(path) or starts_with(path, ",".join(CSV_COLUMNS).encode())
            or starts_with(path, f'{{\n "schema": "{JSON_SCHEMA}"'.encode()))


def default_output(poses, fmt: str) -> Path:
    return Path(poses).with_suffix(FORMATS[fmt])


def _num(v, decimals: int):
    v = float(v)
    return round(v, decimals) if math.isfinite(v) else None


def frames(columns: dict, decimals: int = 6) -> list[dict]:
    """Per frame a dict of the exported values (NaN as None)."""
    n = len(columns["stamp"])
    cov = columns.get("covariance")
    hyps = columns["hypotheses"]
    acc_m = np.asarray(columns.get("accepted_up_to_mirror", columns["accepted"]), bool)
    conf_m = columns.get("confidence_up_to_mirror", columns.get("confidence", np.full(n, np.nan)))
    pair = acc_m & ~np.asarray(columns["accepted"], bool)  # the frame decides the pair only
    mirror = FieldModel.mirror_pose(np.stack([columns["x"], columns["y"], columns["theta"]],
                                             axis=-1))
    out = []
    for i in range(n):
        h = hyps[i]
        h = h[np.all(np.isfinite(h), axis=1)]
        c = None if cov is None else np.asarray(cov[i], float)
        rec = {
            "name": str(columns["name"][i]) if "name" in columns else str(i),
            "stamp": _num(columns["stamp"][i], 9),
            "x": _num(columns["x"][i], decimals),
            "y": _num(columns["y"][i], decimals),
            "theta": _num(columns["theta"][i], decimals),
            "accepted": bool(columns["accepted"][i]),
            "failed": bool(columns["failed"][i]),
            "confidence": _num(columns.get("confidence", np.full(n, np.nan))[i], decimals),
            "error": _num(columns.get("error", np.full(n, np.nan))[i], decimals),
            "mode": str(columns["mode"][i]) if "mode" in columns else "",
            "runtime": _num(columns.get("runtime", np.full(n, np.nan))[i], 9),
            "flags": str(columns["flags"][i]) if "flags" in columns else "",
            "covariance": (None if c is None or not np.all(np.isfinite(c))
                           else [[_num(v, 12) for v in row] for row in c]),
            "hypotheses": [[_num(v, decimals) for v in row] for row in h],
            "accepted_up_to_mirror": bool(acc_m[i]),
            "confidence_up_to_mirror": _num(conf_m[i], decimals),
            "mirror_x": _num(mirror[i, 0], decimals) if pair[i] else None,
            "mirror_y": _num(mirror[i, 1], decimals) if pair[i] else None,
            "mirror_theta": _num(mirror[i, 2], decimals) if pair[i] else None,
        }
        out.append(rec)
    return out


def _csv_value(v):
    if v is None:
        return "nan"
    if isinstance(v, bool):
        return "1" if v else "0"
    return v if isinstance(v, str) else repr(v) if isinstance(v, float) else str(v)


STDOUT = "-"  # the output name that writes to standard output, for a pipe


def main(conf: str | dict | None, poses, output=None, *, fmt: str, overwrite: bool = False,
         progress: bool = False) -> Path:
    """Write ``poses`` (poses.h5) as ``fmt`` (csv, tum or json) to ``output`` (``STDOUT``:
    to standard output); returns it."""
    from ..common.conf import stage_conf

    if fmt not in FORMATS:
        raise FieldlocError(f"unknown export format '{fmt}' ({', '.join(FORMATS)})")
    conf = stage_conf(confs, conf)
    poses = Path(poses)
    output = Path(output) if output is not None else default_output(poses, fmt)
    to_stdout = str(output) == STDOUT
    if not to_stdout and real_path(output) == real_path(poses):
        raise FieldlocError(f"{output}: the export would replace the poses file itself")
    columns, attrs = read_poses(poses)
    if to_stdout:
        _write(sys.stdout, fmt, columns, attrs, poses, int(conf["decimals"]))
        sys.stdout.flush()
        return output
    check_output(output, run_inputs(attrs), overwrite=overwrite, ours=exported)
    with atomic_path(output, suffix=FORMATS[fmt]) as tmp:
        with open(tmp, "w", newline="\n" if fmt == "tum" else "") as f:
            _write(f, fmt, columns, attrs, poses, int(conf["decimals"]))
    return output


def _write(stream, fmt: str, columns: dict, attrs: dict, poses: Path, decimals: int) -> None:
    """The text of the export of ``columns`` (with ``attrs``, read from ``poses``) as
    ``fmt``, written to the open text ``stream``."""
    if fmt == "tum":
        write_tum_to(stream, columns)
        return
    recs = frames(columns, decimals)
    if fmt == "json":
        doc = {"schema": JSON_SCHEMA, "version": JSON_VERSION, "source": str(poses),
               "method": attrs.get("method", ""), "field": attrs.get("field", ""),
               "dataset": attrs.get("dataset", ""),
               "min_confidence": _num(attrs.get("min_confidence", math.nan), decimals),
               "units": {"x": "m", "y": "m", "theta": "rad", "stamp": "s", "runtime": "s",
                         "hypotheses": "x m, y m, theta rad, probability"},
               "frames": recs}
        stream.write(json.dumps(doc, indent=1, allow_nan=False) + "\n")
        return
    w = csv.writer(stream)
    w.writerow(CSV_COLUMNS)
    for r in recs:
        cov = r["covariance"]
        row = dict(r, hypotheses=len(r["hypotheses"]))
        for k, (a, b) in _COV.items():
            row[k] = None if cov is None else cov[a][b]
        w.writerow([_csv_value(row[k]) for k in CSV_COLUMNS])


def write_truth_tum(path, truth: dict) -> Path:
    """The truth rows (stamp, x, y, theta; non-finite rows dropped, as the evaluation drops
    them) as a TUM trajectory, so that ``evo_ape tum truth.tum poses.tum`` compares the same
    poses as ``fieldloc evaluate``."""
    t = np.asarray(truth["stamp"], float)
    x, y, th = (np.asarray(truth[k], float) for k in ("x", "y", "theta"))
    ok = np.isfinite(t) & np.isfinite(x) & np.isfinite(y) & np.isfinite(th)
    order = np.argsort(t[ok], kind="stable")
    return write_tum(path, {"stamp": t[ok][order], "x": x[ok][order], "y": y[ok][order],
                            "theta": th[ok][order], "accepted": np.ones(int(ok.sum()), bool)})
