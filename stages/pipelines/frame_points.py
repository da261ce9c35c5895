"""One frame's extracted features for a person to check by eye (``fieldloc show points``):
the features from a features file, or extracted now from the frame's image (stages.extract,
as ``extract`` would: the omni mask, the perspective head angles of head.csv), drawn by
stages.show.points on the image and, at a pose, on the field.

    write_picture(conf, dataset_dir, output, *, frame=0, features=None, field=None,
                  pose=None, overwrite=False, field_file=None) -> (Path, summary)
    main(conf, dataset_dir, output, ...) -> Path

A chain: it may run extract, which no picture module does.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

from ..common.dataset import open_dataset, read_image, truth_at
from ..common.errors import FieldlocError
from ..common.features_file import FeaturesFile
from ..show.figure import check_picture_output, save_figure
from ..show.points import line_point_share, points_figure

log = logging.getLogger(__name__)


def frame_features(conf, ds, i: int, features=None) -> dict:
    """The features of frame ``i`` of the dataset ``ds``: read from ``features`` (a features
    file), else extracted now with ``conf`` (an extract preset name or dict of the dataset's
    camera kind, see stages.extract)."""
    name = ds.names[i]
    if features is not None:
        with FeaturesFile(features) as ff:
            ff.check_of(ds)
            if name not in ff.names:
                raise FieldlocError(f"{features}: no frame '{name}' (extract it first)")
            return ff.frame(name)
    from .. import extract

    return extract.extract_dataset_frame(ds, i, extract.resolve_extract_conf(ds.camera().kind,
                                                                             conf))


def check_pose(field, pose) -> None:
    """A pose given to draw the points at: its position on ``field`` or its border (where a
    robot can stand; farther, no point lands on the field drawn, and a far value overflows the
    distances to the lines) and its heading within a turn either way (FieldlocError)."""
    x, y, th = (float(v) for v in pose)
    x0, x1, y0, y1 = field.world_bounds()
    if not (x0 <= x <= x1 and y0 <= y <= y1):
        raise FieldlocError(f"pose ({x:.4g}, {y:.4g}) is off the field and its border (|x| <="
                            f" {x1:g}, |y| <= {y1:g} m)")
    if not abs(th) <= 2 * math.pi:
        raise FieldlocError(f"pose heading {math.degrees(th):.4g} deg is not within +-360 deg")


def write_picture(conf, dataset_dir, output, *, frame: str | int = 0, features=None,
                  field=None, pose=None, overwrite: bool = False,
                  field_file=None) -> tuple[Path, dict]:
    """``main``, returning the path and a summary of the frame drawn: its name, its number of
    line points, the pose used and the share of points near a line at that pose."""
    ds = open_dataset(dataset_dir)
    check_picture_output(output, {**ds.files(), "features": features,
                                  "map or field": field_file}, overwrite=overwrite)
    if pose is not None and field is not None:
        check_pose(field, pose)
    i = ds.frame_at(frame)
    name, stamp = ds.names[i], float(ds.stamps[i])
    image = read_image(ds.images[i])
    arrays = frame_features(conf, ds, i, features)
    if pose is None and field is not None:
        pose = truth_at(ds.optional("truth"), stamp)
        if pose is None:
            log.warning("no --pose and no truth at frame %s: drawing the image only", name)
    fig = points_figure(image, arrays, field_model=field, pose=pose,
                        title=f"{ds.root.name} frame {name}")
    path = save_figure(fig, output)
    summary = {"frame": name, "pose": pose}
    if "points" in arrays:  # omni: line points; perspective: lines (no share over no points)
        summary["points"] = int(len(arrays["points"]))
        if field is not None and pose is not None and len(arrays["points"]):
            summary["share_near_lines"] = line_point_share(field, pose, arrays["points"])
    else:
        summary["lines"] = int(len(arrays.get("lines", ())))
    return path, summary


def main(conf, dataset_dir, output, *, frame: str | int = 0, features=None, field=None,
         pose=None, overwrite: bool = False, field_file=None, progress: bool = False) -> Path:
    """Write the picture of one frame (name or position) of ``dataset_dir`` to ``output``
    (PNG). ``features``: a features file to read the frame from (default: extract it now with
    ``conf``, an extract preset name or dict, see stages.extract); ``field``: a FieldModel to
    place the points on; ``pose``: (x, y, theta) in metres and radians (default: truth.csv's
    pose at the frame, if any); ``field_file``: the map or field YAML the field came from.
    ``output`` is never an input, and an existing one is replaced only with ``overwrite``."""
    return write_picture(conf, dataset_dir, output, frame=frame, features=features,
                         field=field, pose=pose, overwrite=overwrite, field_file=field_file)[0]
