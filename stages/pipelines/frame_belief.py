"""The belief of one frame's observations on a grid of poses (``fieldloc show belief``): the
likelihood of the frame's observations under the particle filter's observation model
(stages.localize.belief.belief_grid) per kind of observation, drawn by stages.show.belief as
fig. 3 of Schulz et al. (2011) draws it. The observations come from a features file, else
DIR/features.h5, else are extracted now from the frame's image (stages.extract).

    from stages.pipelines import frame_belief
    frame_belief.main(None, "data/walk", "kidsize.map.h5", "belief.png", frame=12)

A chain: it runs extract and the observation model, which no picture module does.
"""

from __future__ import annotations

import copy
import math
from pathlib import Path

from ..common.conf import check_bounds, stage_conf
from ..common.dataset import frame_index, open_dataset, readable_truth, truth_at
from ..common.errors import DatasetError, FieldlocError
from ..common.features_file import REQUIRED, FeaturesFile
from ..common.map_file import MapFile
from ..common.observations import Observations
from ..localize.belief import belief_grid, grid_axes
from ..localize.observation_model import BOUNDS as OBSERVATION_BOUNDS
from ..localize.observation_model import DEFAULTS as OBSERVATION_DEFAULTS
from ..localize.observation_model import ObservationModel
from ..show.belief import draw_belief
from ..show.figure import check_picture_output, new_figure, save_figure

confs = {
    "default": {
        "resolution": 0.1,  # m between grid positions
        "heading_step": math.radians(5.0),  # rad between grid headings
        "margin": 0.5,  # m of surroundings shown around the field
        "arrow_spacing": 0.5,  # m between the arrows of the best heading
        "arrow_min": 0.25,  # arrows only where the likelihood is this share of the best
        "observation": copy.deepcopy(OBSERVATION_DEFAULTS),
    },
}


# the ranges of the keys (common.conf.check_bounds; resolution and heading_step: the grid's own
# check, belief.grid_axes): surroundings and arrows of a few metres (MAX_MARGIN_M: a field's
# border is a metre or two, more shows empty floor), an arrow share of the best likelihood
MAX_MARGIN_M = 10.0
BOUNDS = {"margin": (0, MAX_MARGIN_M), "arrow_spacing": ((0,), MAX_MARGIN_M),
          "arrow_min": (0, 1), **{f"observation.{k}": b for k, b in OBSERVATION_BOUNDS.items()}}


def check_conf(conf: dict) -> None:
    """The ranges of a resolved conf's keys checked (FieldlocError, one line) before anything
    is read; the grid's size is checked on the map's field (belief.grid_axes)."""
    check_bounds(conf, BOUNDS)


def frame_observations(dataset_dir: Path, frame: str | int, features: Path | None):
    """(name, stamp, Observations) of one frame: from ``features``, else DIR/features.h5 if
    present, else extracted from the frame's image on the fly (extract's default conf)."""
    if features is None and (dataset_dir / "features.h5").is_file():
        features = dataset_dir / "features.h5"
    if features is not None:
        ds = open_dataset(dataset_dir, need_images=False)
        with FeaturesFile(features) as ff:
            ff.check_of(ds)
            if ds.images:  # the frame the dataset's --frame is (show points' too)
                name = ds.names[ds.frame_at(frame)]
                if name not in ff.names:  # a frame whose extraction failed: not another
                    raise FieldlocError(f"{features}: no frame '{name[:40]}' (its extraction"
                                        " failed, or extract it first)")
            else:  # a dataset given its features only: the file's frames are its frames
                name = ff.names[frame_index(ff.names, frame, str(features))]
            data = ff.frame(name)
            return name, float(data["stamp"]), Observations.from_features(data)
    from .. import extract

    ds = open_dataset(dataset_dir)
    i = ds.frame_at(frame)
    camera = ds.camera()
    if not {"lines", "crossings", "posts"} <= set(REQUIRED.get(camera.kind, ())):
        raise FieldlocError(
            f"{dataset_dir}: a '{camera.kind}' camera; the belief needs perspective features"
            " (lines, crossings, goal posts)")
    result = extract.extract_dataset_frame(ds, i, extract.resolve_extract_conf(camera.kind))
    return ds.names[i], float(ds.stamps[i]), Observations.from_features(result)


def main(conf: dict | str | None, dataset_dir: str | Path, map_path: str | Path,
         output: str | Path, *, frame: str | int = 0, features: str | Path | None = None,
         overwrite: bool = False, progress: bool = False) -> Path:
    """Draw the belief of one frame's observations on the map's field into ``output`` (PNG).
    ``frame``: a frame name or position."""
    return write_picture(conf, dataset_dir, map_path, output, frame=frame, features=features,
                         overwrite=overwrite)[0]


def write_picture(conf: dict | str | None, dataset_dir: str | Path, map_path: str | Path,
                  output: str | Path, *, frame: str | int = 0,
                  features: str | Path | None = None,
                  overwrite: bool = False) -> tuple[Path, str]:
    """``main``, returning the path and the name of the frame drawn (``frame`` may be a
    position: the summary names the frame)."""
    conf = stage_conf(confs, conf)
    check_conf(conf)
    output = Path(output)
    dataset_dir = Path(dataset_dir)
    if not dataset_dir.is_dir():
        raise DatasetError(f"dataset folder not found: {dataset_dir}")
    check_picture_output(output, {**open_dataset(dataset_dir, need_images=False).files(),
                                  "map": map_path, "features": features}, overwrite=overwrite)
    grid_conf = {"resolution": float(conf["resolution"]),
                 "heading_step": float(conf["heading_step"]), "margin": float(conf["margin"])}
    with MapFile(map_path) as mf:
        grid_axes(mf.field.length, mf.field.width, **grid_conf)  # before a frame is extracted
        name, stamp, obs = frame_observations(dataset_dir, frame,
                                              None if features is None else Path(features))
        model = ObservationModel.from_map(mf, conf["observation"])
        grid = belief_grid(model, obs, **grid_conf)
        fig = new_figure(12.0, 8.5)
        draw_belief(fig.subplots(2, 2), mf.field, grid,
                    truth=truth_at(readable_truth(dataset_dir), stamp),
                    arrow_spacing=float(conf["arrow_spacing"]),
                    arrow_min=float(conf["arrow_min"]),
                    title=f"{dataset_dir.name} frame {name} (t = {stamp:.2f} s): belief from"
                    " one frame's observations; yellow: best pose, white: truth")
    return save_figure(fig, output), name
