"""Simulate: render a dataset folder (GUIDE section 4) with its ground truth.

    main(conf, field, output_dir, *, overwrite=False, progress=False) -> Path

writes ``output_dir`` with images/000000.png ..., frames.csv (name, stamp), calib.yaml (the
camera as written, possibly miscalibrated on purpose), odometry.csv, imu.csv, truth.csv and
simulation.yaml (the resolved conf, the field, the seed and the true camera, for provenance).
The same conf and seed give the same files. The folder is built in a temporary folder beside the
target and renamed at the end, so an interrupted run leaves nothing under the real name; the
next run onto the same target removes what a killed run left there (``.<name>.fieldloc-<pid>-*
.part``), with a warning.

Template captures (the SURF template paper): with trajectory kind ``grid`` the robot is placed
at the nodes of a grid (``trajectory.grid_poses``; ``frames`` is then the number of
placements), one frame per node and heading, and the dataset has no odometry.csv (the robot was
carried from node to node).
``calib_seed`` (None: ``seed``) draws the calibration error calib.yaml states: two datasets of
the same ``calib_seed`` and different seeds are one robot recorded twice (another scene, path,
sensor noise), as a template grid and a run localised against it are; ``world_seed`` (None:
``seed``) likewise draws the venue (carpet, paint, walls; simulate.scene), so that both are
recorded in one lab, with the clutter, movers and lighting of their own seeds.

simulation.yaml is also the marker of a dataset made here: ``overwrite`` replaces an existing
folder only if it holds that marker (``generator: fieldloc simulate``), never another folder (a
user's files, the folder holding the field YAML), never one that holds an input, and never one
that holds anything simulate did not write (``not_simulated``: notes, or features and poses
made from the dataset, which the replacement would delete). Before
anything is rendered, the memory the scene needs (ground textures grow with the field's area)
and the disk the frames need are estimated, and a run that cannot fit is refused with the
estimate.

Pieces, each reusable on its own:
- :mod:`.trajectory` the robot's smooth path (speeds, turns, heading behaviour as conf values);
- :mod:`.sensors` odometry and IMU from the true motion, with slip, drift, bias, collisions;
- :mod:`.scene` the camera-independent world (ground textures, lines, goals, walls, other
  robots, people, clutter, lighting over time);
- one renderer per camera kind, registered in ``RENDERERS`` (kind -> "module:Class"), with
  ``Renderer(conf_section, scene, seed)``, ``.camera`` (the true camera model),
  ``.render(pose, frame) -> BGR uint8`` and a module function ``perturbed_camera(camera,
  calib_error)`` (given ``rng=``, a generator seeded from the dataset seed, when it takes one:
  the omni calibration error is a team's mirror table read off with random errors; see
  ``written_camera``). A preset names its camera kind in ``camera`` and holds the renderer's
  conf under that kind's name (``omni``, ``perspective``, ...). A renderer may also have
  ``.prepare(path) -> {stem: (csv kind, columns)}``, called once with the whole path, whose
  CSV files are written beside the others (the perspective renderer's head motion: head.csv,
  the measured head angles, and head_truth.csv);
- :mod:`.walk` the walking humanoid: entry at a touch line (trajectory ``start: touchline``)
  and head motion;
- :mod:`.synthetic_observations` what a perspective camera would report (lines, crossings,
  goal posts in the robot frame) made from the field model without images, and walks with
  truth and odometry (a dataset with features.h5 and no images): for the particle filter's
  tests and bench.
"""

from __future__ import annotations

import copy
import importlib
import inspect
import logging
import math
import re
import shutil
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import yaml

from ..common.artifacts import (
    WRITTEN_FILES,
    cannot_read,
    check_output,
    commit_dir,
    give_default_mode,
    part_dir,
    record_text,
    refuse_edited,
    remove_stale_parts,
    restore_interrupted_replacement,
    text_hash,
    writing,
    written_files,
)
from ..common.camera import MAX_IMAGE_PX, save_calib
from ..common.conf import check_bounds, stage_conf
from ..common.dataset import SIMULATION_RECORD, read_simulation_record, write_csv
from ..common.errors import FieldlocError, real_path, shown
from ..common.field import FieldModel, load_field
from ..common.png import write_png
from ..common.resources import check_disk, check_memory
from . import scene as scene_mod
from . import sensors, trajectory, walk
from .omni_renderer import CALIB_ERROR_DEFAULTS, OMNI_DEFAULTS, TEAM_MIRROR_POLYNOMIAL
from .perspective_renderer import PERSPECTIVE_DEFAULTS

log = logging.getLogger(__name__)

# camera kind -> "module:Class" of its renderer (module relative to this package)
RENDERERS = {
    "omni": ".omni_renderer:OmniRenderer",
    "perspective": ".perspective_renderer:PerspectiveRenderer",
}

_OMNI_BASE = {
    "camera": "omni",
    "frames": 300,
    "seed": 0,
    "calib_seed": None,  # seed of calib.yaml's calibration error (None: seed)
    "world_seed": None,  # seed of the venue: carpet, paint, walls (None: seed; scene.build)
    "rate_hz": 10.0,  # frames per second
    "trajectory": dict(trajectory.DEFAULTS),
    "odometry": dict(sensors.ODOMETRY_DEFAULTS),
    "imu": dict(sensors.IMU_DEFAULTS),
    "scene": copy.deepcopy(scene_mod.SCENE_DEFAULTS),
    "omni": copy.deepcopy(OMNI_DEFAULTS),
    # what calib.yaml says relative to the rendering camera: centre shift (px), f(r) scale
    "calib_error": copy.deepcopy(CALIB_ERROR_DEFAULTS),
}


# what real catadioptric frames of the MINHO team (Ribeiro et al. 2015) show (../shared/realdata,
# measured by
# tests/test_realism_omni.py and tests/test_extract_realdata.py): the team's mirror (its
# mirror.cfg, smoothed), a calibration off by 0.15 m rms over 0.3-4 m (minho-distance: the
# team's table places a line at a known distance 4-16 cm too far from 1 to 2 m, growing with
# distance), soft lines (10-90 % edges of 2.5-6 px; far lines as dim as minho-distance's),
# highlights that clip, and people's shadows reaching well beyond their feet
_OMNI_REAL = {
    "calib_error": {"distance_error": 0.15},
    "omni": {"polynomial": list(TEAM_MIRROR_POLYNOMIAL), "valid_radius": [40.0, 193.0],
             "outer_elevation_rate": 0.01, "shadow_length": 0.35, "shadow_depth": 0.6,
             "imaging": {**OMNI_DEFAULTS["imaging"], "blur_sigma": 1.5, "knee": 0.9}},
}


def _preset(base: dict, **changes) -> dict:
    out = copy.deepcopy(base)
    for key, value in changes.items():
        if isinstance(value, dict):
            out[key].update(value)
        else:
            out[key] = value
    return out


_OMNI_DEFAULT = _preset(_OMNI_BASE, **_OMNI_REAL)

confs = {
    # a MSL robot with an omnidirectional camera on a busy lab field, with the seed team's
    # mirror, its blur and a calibration as imperfect as a team's (_OMNI_REAL)
    "omni-default": _OMNI_DEFAULT,
    # a designed mirror (DEFAULT_POLYNOMIAL) without clutter, movers, noise, lighting changes
    # or calibration error: for checking geometry
    "omni-clean": _preset(
        _OMNI_BASE,
        scene={"robots": 0, "people": 0, "handlers": 0, "balls": 0, "cables": 0, "sticks": 0,
               "papers": 0, "tapes": 0, "line_wear": 0.0, "line_edge_noise": 0.0,
               "lighting": {"gain": [1.0, 1.0], "periods": [3.0, 25.0],
                            "colour_temperature": 0.0, "tint": 0.0}},
        omni={"imaging": {"vignetting": 0.0, "blur_sigma": 0.0, "exposure_time": 0.0,
                          "saturation": 1.0, "knee": 1.0, "chroma_subsample": 1,
                          "noise_sigma": 0.0, "shot_noise": 0.0, "jpeg_quality": 0}},
        imu={"collision_rate_hz": 0.0},
    ),
    # harder than omni-default: more robots and people, more clutter, stronger light changes,
    # JPEG artefacts
    "omni-hard": _preset(
        _OMNI_DEFAULT,
        scene={"robots": 6, "people": 2, "handlers": 2, "cables": 8, "sticks": 6, "papers": 5,
               "tapes": 10, "line_wear": 0.7,
               "lighting": {"gain": [0.45, 1.7], "periods": [2.0, 15.0],
                            "colour_temperature": 0.18, "tint": 0.1}},
        omni={"imaging": {**_OMNI_DEFAULT["omni"]["imaging"], "jpeg_quality": 70,
                          "noise_sigma": 3.0}},
        imu={"collision_rate_hz": 0.15},
    ),
}
confs["default"] = copy.deepcopy(confs["omni-default"])

# Schulz et al. (2011): a KidSize humanoid walking at about 0.2 m/s with a wide-angle head camera;
# it enters the field at a touch line of its own half ("start": "touchline", see walk.py)
_PERSPECTIVE_BASE = {
    "camera": "perspective",
    "frames": 300,
    "seed": 0,
    "calib_seed": None,  # seed of calib.yaml's calibration error (None: seed)
    "world_seed": None,  # seed of the venue: carpet, paint, walls (None: seed; scene.build)
    "rate_hz": 10.0,
    "trajectory": {**trajectory.DEFAULTS, "speed_min": 0.17, "speed_max": 0.24,
                   "accel_max": 0.3, "lateral_accel_max": 0.08, "turn_rate_max": 0.6,
                   "heading": "along", "waypoint_margin": 0.5, "start": "touchline"},
    # walking: feet slip and the step length varies far more than a wheel's turn
    "odometry": {**sensors.ODOMETRY_DEFAULTS, "scale_sigma": 0.08, "rotation_scale_sigma": 0.1,
                 "slip_sigma": 0.15, "slip_rotation": 0.15, "drift": 0.05, "noise_xy": 0.004,
                 "noise_theta": 0.006, "collision_xy": 0.05, "collision_theta": 0.2},
    "imu": {**sensors.IMU_DEFAULTS, "yaw_noise": 0.01, "bias_sigma": 0.02, "bias_walk": 0.003,
            "collision_rate_hz": 0.02, "contact_distance": 0.35},
    "scene": {**copy.deepcopy(scene_mod.SCENE_DEFAULTS), "robots": 3, "robot_radius": 0.12,
              "robot_height": 0.6, "robot_speed": [0.1, 0.3], "goal_height": 1.2},
    "perspective": copy.deepcopy(PERSPECTIVE_DEFAULTS),
    # what calib.yaml says relative to the rendering camera: principal point shift (px),
    # focal length scale, the mount's pitch and roll offsets (rad) recorded while the rendering
    # camera has none, and the height off by height_offset (m)
    "calib_error": {"centre_shift": [0.0, 0.0], "scale": 1.0, "pitch_offset": 0.0,
                    "roll_offset": 0.0, "height_offset": 0.0},
}
confs["perspective-default"] = _preset(_PERSPECTIVE_BASE)
# without movers, clutter, lighting changes or imaging defects: for checking geometry
confs["perspective-clean"] = _preset(
    _PERSPECTIVE_BASE,
    scene={"robots": 0, "people": 0, "handlers": 0, "balls": 0, "cables": 0, "sticks": 0,
           "papers": 0, "tapes": 0, "line_wear": 0.0, "line_edge_noise": 0.0,
           "lighting": {"gain": [1.0, 1.0], "periods": [3.0, 25.0],
                        "colour_temperature": 0.0, "tint": 0.0}},
    perspective={"imaging": {**PERSPECTIVE_DEFAULTS["imaging"], "blur": 0.0,
                             "corner_blur": 0.0, "vignetting": 0.0,
                             "chromatic_aberration": 0.0, "exposure_time": 0.0,
                             "noise_sigma": 0.0, "shot_noise": 0.0, "bayer": False,
                             "chroma_subsample": 1}},
    imu={"collision_rate_hz": 0.0},
)


# a NAO v6 (SPL) with its top camera (640 x 480, no wide-angle lens, HULKs' intrinsics
# fx 608, fy 609.6 px; the camera about 0.45 m high, looking 11 deg down as HULKs' top frames
# do in the median) on an SPL field in a hall: sun patches and shadows across the lines, the
# carpet's sheen, over-exposed white, white balls, other NAOs' white legs, lines of uneven
# width and brightness, JPEG frames
confs["perspective-nao"] = _preset(
    _PERSPECTIVE_BASE,
    trajectory={"speed_min": 0.1, "speed_max": 0.25, "turn_rate_max": 0.8},
    scene={"robots": 4, "robot_radius": 0.1, "robot_height": 0.57, "robot_speed": [0.05, 0.25],
           "robot_style": "nao", "people": 1, "handlers": 1, "balls": 2,
           "ball_bgr": [222, 226, 228], "goal_height": 0.8, "cables": 0, "sticks": 0,
           "papers": 0, "tapes": 2, "carpet_bgr": [43, 127, 68], "carpet_variation": 0.14,
           "carpet_hue_variation": 0.08, "stripe_contrast": 0.03, "floor_bgr": [160, 150, 140],
           "line_brightness": [0.8, 1.1], "line_wear": 0.3, "line_width_variation": 0.3,
           "sun_patches": 24, "sun_strength": [0.8, 1.8], "shadows": 10,
           "shadow_strength": [0.2, 0.45], "lamp_contrast": 0.3,
           "lighting": {"gain": [0.45, 1.5], "periods": [3.0, 25.0],
                        "colour_temperature": 0.12, "tint": 0.08}},
    perspective={"image_size": [640, 480],
                 "intrinsics": {"fx": 608.0, "fy": 609.6, "cx": 319.5, "cy": 239.5},
                 "distortion": [0.0, 0.0, 0.0, 0.0, 0.0], "height": 0.45, "pitch": 0.19,
                 "roll": 0.0,
                 "imaging": {**PERSPECTIVE_DEFAULTS["imaging"], "blur": 0.7, "corner_blur": 1.0,
                             "vignetting": 0.25, "chromatic_aberration": 0.4,
                             "jpeg_quality": 85},
                 "sheen": 0.45, "sheen_power": 4.0},
)


def resolve_simulate_conf(conf: str | dict | None) -> dict:
    """The conf of a run: a preset name of ``confs``, None ("default"), or a dict of overrides
    on the default preset of its ``camera`` kind (``<camera>-default``; "default" without a
    ``camera``)."""
    if isinstance(conf, dict) and "camera" in conf:
        kind = conf["camera"]
        if not isinstance(kind, str) or f"{kind}-default" not in confs:
            raise FieldlocError(f"no renderer for camera kind {kind!r} (known:"
                                f" {', '.join(sorted(RENDERERS))})")
        return stage_conf(confs, conf, default=f"{kind}-default")
    return stage_conf(confs, conf)


def renderer_class(kind: str):
    if kind not in RENDERERS:
        raise FieldlocError(
            f"no renderer for camera kind '{kind}' (known: {', '.join(sorted(RENDERERS))})"
        )
    mod, cls = RENDERERS[kind].split(":")
    module = importlib.import_module(mod, __name__)
    return module, getattr(module, cls)


def written_camera(module, camera, calib_error: dict, seed: int):
    """The camera calib.yaml states for the true ``camera``: the renderer module's
    ``perturbed_camera``, given a generator seeded from the dataset seed when it takes one (the
    omni calibration error is a team's mirror table read off with random errors)."""
    if "rng" in inspect.signature(module.perturbed_camera).parameters:
        return module.perturbed_camera(camera, calib_error,
                                       rng=np.random.default_rng([int(seed), 0xCA11B]))
    return module.perturbed_camera(camera, calib_error)


GENERATOR = "fieldloc simulate"  # simulation.yaml's generator: the marker of our datasets
# measured peak memory of the scene per texel: ground colour (float32 temporaries of the
# carpet) and line field; per frame: the paths of the robot and the movers, sensors
BYTES_PER_GROUND_TEXEL = 50.0
BYTES_PER_LINE_TEXEL = 40.0
BYTES_PER_FRAME = 1024.0
PNG_RATIO = 0.6  # a rendered PNG's size / raw BGR size (noisy carpet compresses poorly)


def _record(folder: Path) -> dict | None:
    """``folder``'s simulation.yaml, or None where it is missing or damaged (one fieldloc is
    not allowed to read: FieldlocError, ``cannot_read``)."""
    rec = folder / SIMULATION_RECORD
    if not rec.is_file():
        return None
    try:
        d = read_simulation_record(folder)
    except PermissionError as e:
        raise cannot_read(rec, e) from None
    except (OSError, UnicodeDecodeError, yaml.YAMLError, FieldlocError):
        return None
    return d if isinstance(d, dict) else None


def is_simulated_dataset(folder: Path) -> bool:
    """Whether ``folder`` is a dataset written by simulate (its simulation.yaml says so)."""
    rec = _record(folder)
    return rec is not None and rec.get("generator") == GENERATOR


# what simulate may write into a dataset folder (the perspective renderer adds head.csv and
# head_truth.csv, a grid has no odometry.csv): simulation.yaml lists under ``files`` those a
# run wrote, and its ``frames`` gives its images' names (FRAME_NAME, from 000000.png on)
WRITTEN = ("images", "frames.csv", "truth.csv", "odometry.csv", "imu.csv", "head.csv",
           "head_truth.csv", "calib.yaml", SIMULATION_RECORD)
FRAME_NAME = re.compile(r"[0-9]{6}\.png")


def _frame_names(n: int) -> list[str]:
    return [f"{i:06d}.png" for i in range(n)]


def not_simulated(folder: Path) -> Path | None:
    """The first file or folder in the dataset ``folder``, at its top or in images/, that
    simulate did not write, or None: what replacing the folder would delete of a user's
    (notes, a picture added to images/, features and poses made from it). What it wrote is
    what its simulation.yaml records (``files``, and ``frames`` images); a record of an older
    version without ``files`` allows WRITTEN and any frame name. Where the record has a
    WRITTEN_FILES table (a mapping), a file it does not list is not simulate's either,
    whatever ``files`` and ``frames`` say (a damaged count must not make a user's picture
    simulate's)."""
    rec = _record(folder) or {}
    table = rec.get(WRITTEN_FILES)
    if isinstance(table, Mapping):
        extra = next((n for n in _dataset_files(folder) if n not in table), None)
        if extra is not None:
            return folder / extra
    files = rec.get("files")
    files = set(files) if isinstance(files, list) else set(WRITTEN)
    for entry in sorted(folder.iterdir()):
        if entry.name not in files:
            return entry
    images = folder / "images"
    if not images.is_dir():
        return None
    n = rec.get("frames")
    # a record's frame count beyond what simulate renders (MAX_FRAMES) is a damaged record:
    # its names are not listed (1e8 of them took minutes), the names' pattern decides
    frames = (set(_frame_names(n)) if isinstance(n, int) and not isinstance(n, bool)
              and 0 <= n <= MAX_FRAMES else None)
    return next((e for e in sorted(images.iterdir())
                 if not e.is_file() or e.is_symlink()
                 or not (e.name in frames if frames is not None
                         else FRAME_NAME.fullmatch(e.name))), None)


def _dataset_files(folder: Path) -> list[str]:
    """The files of a dataset folder simulate writes and lists under WRITTEN_FILES (relative
    names): those at its top but the record, and its images."""
    images = folder / "images"
    return ([e.name for e in sorted(folder.iterdir())
             if e.name not in ("images", SIMULATION_RECORD)]
            + ([f"images/{e.name}" for e in sorted(images.iterdir())] if images.is_dir()
               else []))


def _check_target(output_dir: Path, overwrite: bool, field_file: Path | None):
    check_output(output_dir, {"field YAML": field_file}, overwrite=None, kind="folder",
                 recording=True)
    if output_dir.is_dir() and any(output_dir.iterdir()):
        if not overwrite:
            raise FieldlocError(
                f"dataset folder {output_dir} exists and is not empty (use --overwrite to"
                " replace it)")
        if not is_simulated_dataset(output_dir):
            raise FieldlocError(
                f"{output_dir} is not a dataset made by fieldloc simulate (no {SIMULATION_RECORD}"
                " marker); --overwrite replaces only those: choose another folder or remove it"
                " yourself")
        other = not_simulated(output_dir)
        if other is not None:
            raise FieldlocError(
                f"{output_dir} holds {other}, which simulate did not write: --overwrite would"
                " delete it; move it out of the folder or choose another one")
        rec = _record(output_dir) or {}
        refuse_edited(output_dir, rec.get(WRITTEN_FILES), _dataset_files(output_dir),
                      record=SIMULATION_RECORD)
        if real_path(Path.cwd()).is_relative_to(real_path(output_dir)):
            raise FieldlocError(
                f"{output_dir} holds the current folder; run simulate from elsewhere to replace"
                " it")


def estimate_needs(conf: dict, field: FieldModel) -> tuple[dict, float]:
    """(memory by purpose in bytes, disk bytes) of simulating ``conf`` on ``field``."""
    sc = {**scene_mod.SCENE_DEFAULTS, **conf.get("scene", {})}
    x0, x1, y0, y1 = field.world_bounds()
    gap = float(sc["wall_gap"])
    ground = (x1 - x0 + 2 * gap) * (y1 - y0 + 2 * gap) / float(sc["texture_resolution"]) ** 2
    lines = (x1 - x0) * (y1 - y0) / float(sc["line_resolution"]) ** 2
    n = float(conf["frames"])
    w, h = conf[conf["camera"]]["image_size"]
    memory = {"ground texture": ground * BYTES_PER_GROUND_TEXEL,
              "line field": lines * BYTES_PER_LINE_TEXEL,
              f"{n:.0f} frames of paths and sensors": n * BYTES_PER_FRAME}
    return memory, n * float(w) * float(h) * 3 * PNG_RATIO


def check_conf(conf: dict) -> None:
    """The counts and seeds of a resolved simulate conf (frames, rate, seeds), the ranges of its
    scalar keys (SCALAR_BOUNDS), the shapes and ranges of its list-valued keys (``bounds``:
    colours, ranges drawn from, the camera's sizes) and the camera the renderer would build,
    checked before anything is rendered; FieldlocError names the key."""
    _check_conf(conf)


# frames of one rendered dataset at most: a day at 10 Hz is 864 000; beyond, a run would render
# for weeks (the disk and memory checks would refuse it only after the plan is made)
MAX_FRAMES = 1_000_000


def _check_conf(conf: dict):
    n = conf["frames"]
    if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= MAX_FRAMES:
        raise FieldlocError(f"frames must be a whole number from 1 to {MAX_FRAMES}, got"
                            f" {shown(n, 40)}")
    if not 0 < float(conf["rate_hz"]) < math.inf:
        raise FieldlocError(f"rate_hz must be > 0, got {conf['rate_hz']!r}")
    s = conf["seed"]
    if isinstance(s, bool) or not isinstance(s, int) or s < 0:
        raise FieldlocError(f"seed must be a whole number >= 0, got {str(s)[:40]!r}")
    for key in ("calib_seed", "world_seed"):
        v = conf.get(key)
        if v is not None and (isinstance(v, bool) or not isinstance(v, int) or v < 0):
            raise FieldlocError(f"{key} must be a whole number >= 0 or null, got"
                                f" {str(v)[:40]!r}")
    module = renderer_class(conf["camera"])[0]
    check_bounds(conf, SCALAR_BOUNDS, optional=True)
    check_bounds(conf, bounds(conf["camera"], module), optional=True)
    _check_start(conf)
    if hasattr(module, "check_conf"):
        module.check_conf(conf.get(conf["camera"]))
    check = getattr(module, "check_calib_error", None)
    if check is not None:
        check(conf["calib_error"])


def bounds(kind: str, module) -> dict:
    """The ranges of a conf's list-valued keys (common.conf.check_bounds): the scene's, the
    trajectory's, the IMU's, the calibration error's and the renderer's of camera ``kind``
    (its module's BOUNDS, under the kind's name)."""
    return {**{f"scene.{k}": b for k, b in scene_mod.BOUNDS.items()},
            **{f"trajectory.{k}": b for k, b in trajectory.BOUNDS.items()},
            **{f"imu.{k}": b for k, b in sensors.IMU_BOUNDS.items()},
            "calib_error.centre_shift": (None, None, 2),  # px [du, dv]
            **{f"{kind}.{k}": b for k, b in getattr(module, "BOUNDS", {}).items()}}


# the ranges of simulate's scalar conf keys (common.conf.check_bounds), held with the list keys'
# (``bounds``) before anything is rendered: the physical or practical range each value must lie
# in for a run to mean anything, stated once here for every camera kind's preset (a key a conf
# does not hold, e.g. the other kind's section, is passed over). A one-element tuple (x,) is a
# strict bound. The mount's calibration errors, frames, seeds, the rate and the camera's own
# geometry (focal lengths, principal point, height, angles) are held by their own checks
# (check_calib_error, _check_conf, camera_from_conf).
MAX_COUNT = 1000  # scene objects of one kind: a field holds a few dozen; 1e9 builds for hours
MAX_LENGTH_M = 100.0  # m: longer than any field with its border (about 25 m diagonal) and hall
MAX_HEIGHT_M = 10.0  # m: a camera, robot, goal or wall above the floor, indoors
MAX_ACCEL = 100.0  # m/s^2 (10 g) along or across the path; 0 divides by zero
MAX_SPEED = 10.0  # m/s: a sprinter's; MSL robots drive at up to 4 m/s, humanoids walk at 0.5
MAX_RATE = 100.0  # rad/s (or steps, collisions per s): far beyond any robot's turn or gait
MAX_ANGLE_NOISE = math.pi  # rad: a noise or swing of more than half a turn is no longer noise
MAX_HEAD_SWING = 0.5  # rad (29 deg): a walking head sways a few deg; beyond, it sees the sky
MAX_TEXEL_M = 0.5  # m per texel: coarser than 0.5 m loses the lines (5-12 cm wide) altogether
MAX_BLUR_PX = 50.0  # px (Gaussian sigma): a blur of 50 px erases a frame; 1e9 filters for hours
MAX_CHROMA_SUBSAMPLE = 16  # px a chroma sample spans (4:2:2 is 2, 4:1:1 is 4)
MAX_EXPOSURE_S = 1.0  # s: ten frames at 10 Hz; a longer exposure smears a whole turn
MAX_GREY_NOISE = 255.0  # grey levels: read noise as large as the full scale
MAX_SHOT_NOISE = 16.0  # shot_noise * sqrt(255) ~ 255 grey levels at full scale
MAX_POLAR_BEARINGS = 16384  # columns: 13 times the presets' 1280; OpenCV's remap refuses a
# polar grid of 32768 columns, and 1e9 never fit in memory
MAX_POLAR_STEP_PX = 8.0  # px between rows: coarser leaves too few rows between body and rim
MAX_ELEVATION_RATE = 0.5  # rad/px: rays up from the floor to the zenith within 3 px
MAX_STRUT_WIDTH_PX = 100.0  # px: a bar wider than that hides most of the mirror
SIGMA = (0, None)  # a spread or noise: >= 0 (a negative one is refused by numpy deep inside)
SHARE = (0, 1)  # a share, probability or relative strength of an effect: 0..1
COUNT = (0, MAX_COUNT)
SCALAR_BOUNDS = {
    # trajectory: speeds, accelerations and turn rates > 0 (they divide), margins inside the
    # field (speed_min <= speed_max: trajectory.generate)
    "trajectory.speed_min": ((0,), MAX_SPEED),
    "trajectory.speed_max": ((0,), MAX_SPEED),
    "trajectory.accel_max": ((0,), MAX_ACCEL),
    "trajectory.lateral_accel_max": ((0,), MAX_ACCEL),
    "trajectory.turn_rate_max": ((0,), MAX_RATE),
    "trajectory.yaw_rate_max": (0, MAX_RATE),  # 0: the heading never turns (free heading)
    "trajectory.yaw_accel_max": ((0,), MAX_RATE),
    "trajectory.margin": (0, MAX_LENGTH_M),
    "trajectory.waypoint_margin": (0, MAX_LENGTH_M),
    "trajectory.substeps": (1, 1000),  # integration steps per frame
    "trajectory.grid_spacing": ((0,), MAX_LENGTH_M),
    "trajectory.grid_headings": (1, 360),  # at most one heading per degree
    "trajectory.grid_heading": (-2 * math.pi, 2 * math.pi),  # rad
    "trajectory.grid_half_size": (0, MAX_LENGTH_M),  # 0: the centre node alone
    # the written calibration's error (omni; the mount's: check_calib_error): f(r) scaled by
    # at most 2 either way (a team keeps no calibration that far off), a team's mirror table
    # out to a field's length, its reading error correlated over up to the image's size
    "calib_error.scale": (0.5, 2.0),
    "calib_error.distance_error": (0, (0.5,)),  # m rms; 0: the true f(r) is written
    "calib_error.radius_error_length_px": ((0,), MAX_IMAGE_PX),
    "calib_error.table_step": ((0,), MAX_LENGTH_M),
    "calib_error.table_range": ((0,), MAX_LENGTH_M),
    # odometry: relative spreads up to 100 %, per-frame noises of at most a metre or half a
    # turn; drift is a size (its sign is drawn per run)
    "odometry.scale_sigma": SHARE,
    "odometry.rotation_scale_sigma": SHARE,
    "odometry.slip_sigma": SHARE,
    "odometry.slip_rotation": (0, MAX_ANGLE_NOISE),  # rad per metre
    "odometry.drift": (0, MAX_ANGLE_NOISE),  # rad per metre
    "odometry.noise_xy": (0, 1.0),  # m per frame
    "odometry.noise_theta": (0, MAX_ANGLE_NOISE),
    "odometry.collision_xy": (0, 1.0),  # m per collision frame
    "odometry.collision_theta": (0, MAX_ANGLE_NOISE),
    # IMU: noises in rad, collisions per second, a contact distance on the field
    "imu.yaw_noise": (0, MAX_ANGLE_NOISE),
    "imu.bias_sigma": (0, MAX_ANGLE_NOISE),
    "imu.bias_walk": (0, MAX_ANGLE_NOISE),
    "imu.collision_yaw": (0, MAX_ANGLE_NOISE),
    "imu.collision_rate_hz": (0, MAX_RATE),
    "imu.contact_distance": (0, MAX_LENGTH_M),
    # scene: resolutions and sizes > 0 and below their maxima, relative strengths 0..1, counts
    "scene.texture_resolution": ((0,), MAX_TEXEL_M),
    "scene.line_resolution": ((0,), MAX_TEXEL_M),
    "scene.wall_gap": (0, MAX_LENGTH_M),
    "scene.wall_height": ((0,), MAX_LENGTH_M),
    "scene.goal_height": ((0,), MAX_HEIGHT_M),
    "scene.carpet_variation": SHARE,
    "scene.carpet_hue_variation": SHARE,
    "scene.carpet_grain": SHARE,
    "scene.stripe_width": ((0,), MAX_LENGTH_M),
    "scene.stripe_contrast": SHARE,
    "scene.line_wear": SHARE,
    "scene.line_edge_noise": (0, 1.0),  # m
    "scene.line_width_variation": SHARE,
    "scene.lamp_spacing": ((0,), MAX_LENGTH_M),
    "scene.lamp_contrast": SHARE,
    "scene.robot_radius": ((0,), MAX_HEIGHT_M),
    "scene.robot_height": ((0,), MAX_HEIGHT_M),
    "scene.lighting.colour_temperature": SHARE,  # +- relative swing
    "scene.lighting.tint": SHARE,
    **{f"scene.{k}": COUNT for k in ("robots", "people", "handlers", "balls", "cables",
                                     "sticks", "papers", "tapes", "audience", "sun_patches",
                                     "shadows")},
    # the omni renderer's mirror, body and polar grid (px) and its imaging chain
    "omni.viewpoint_height": ((0,), MAX_HEIGHT_M),
    "omni.rim_radius": ((0,), MAX_IMAGE_PX),
    "omni.body_radius": ((0,), MAX_IMAGE_PX),  # it divides; below the valid ring: check_conf
    "omni.outer_elevation_rate": (0, MAX_ELEVATION_RATE),
    "omni.strut_width": ((0,), MAX_STRUT_WIDTH_PX),
    "omni.shadow_depth": SHARE,
    "omni.shadow_length": (0, MAX_HEIGHT_M),  # m of shadow per m of height
    "omni.polar_bearings": (1, MAX_POLAR_BEARINGS),
    "omni.polar_step": ((0,), MAX_POLAR_STEP_PX),
    # the perspective renderer's head and sheen
    "perspective.head.step_hz": (0, MAX_RATE),
    "perspective.head.sway_roll": (0, MAX_HEAD_SWING),
    "perspective.head.bob_pitch": (0, MAX_HEAD_SWING),
    "perspective.head.tilt": (0, MAX_HEAD_SWING),
    "perspective.head.jitter": (0, MAX_HEAD_SWING),
    "perspective.head.measurement_noise": (0, MAX_HEAD_SWING),
    "perspective.head.walk_speed": ((0,), MAX_RATE),  # m/s: it divides
    "perspective.head.turn_speed": ((0,), MAX_RATE),  # rad/s: it divides
    "perspective.sheen": SHARE,
    "perspective.sheen_power": (0, 100.0),  # exponent of the fall-off
    # the imaging chains: blurs (px), the keys both renderers have (imaging.py), omni's tone
    "omni.imaging.blur_sigma": (0, MAX_BLUR_PX),
    "omni.imaging.saturation": (0, 2.0),  # chroma kept: 0 grey .. 2 twice as vivid
    "omni.imaging.knee": SHARE,  # share of full scale where highlights start to be compressed
    "perspective.imaging.blur": (0, MAX_BLUR_PX),
    "perspective.imaging.corner_blur": (0, MAX_BLUR_PX),
    "perspective.imaging.chromatic_aberration": (0, MAX_BLUR_PX),
    **{f"{kind}.imaging.{k}": b for kind in RENDERERS for k, b in {
        "vignetting": SHARE, "exposure_time": (0, MAX_EXPOSURE_S),
        "chroma_subsample": (1, MAX_CHROMA_SUBSAMPLE), "noise_sigma": (0, MAX_GREY_NOISE),
        "shot_noise": (0, MAX_SHOT_NOISE),
        "jpeg_quality": (0, 100)}.items()},  # 0: no JPEG round trip; OpenCV takes 1..100
}


def _check_start(conf: dict) -> None:
    """trajectory.start: None (random), "touchline" (walk.touchline_start) or [x, y, theta];
    trajectory.grid_centre: None or [x, y] (a start or centre off the field is refused where
    the field is known: trajectory.generate, grid_poses)."""
    start = conf["trajectory"].get("start")
    if isinstance(start, str) and start == "touchline":
        start = None
    elif start is not None and not isinstance(start, list):
        raise FieldlocError(f"conf 'trajectory.start' must be [x, y, theta] or touchline, got"
                            f" {shown(start, 40)}")
    held = {"trajectory.grid_centre": (None, None, 2),
            **({"trajectory.start": (None, None, 3)} if start is not None else {})}
    check_bounds(conf, held, optional=True)


def _check_written_calib(camera) -> None:
    """The calib.yaml that calib_error makes must be one extract reads: read back as extract
    reads it (the model's own from_dict checks) before a frame is rendered."""
    d = yaml.safe_load(yaml.safe_dump(camera.to_dict()))
    try:
        type(camera).from_dict(d, "calib.yaml")
    except FieldlocError as e:
        raise FieldlocError(f"calib_error would write a calibration extract refuses: {e}"
                            ) from None
    except (TypeError, ValueError, IndexError, AttributeError) as e:
        raise FieldlocError(f"calib_error would write a malformed calibration ({e})") from None


def main(conf: str | dict | None, field, output_dir, *, overwrite: bool = False,
         progress: bool = False) -> Path:
    """Render a dataset of ``conf['frames']`` frames on ``field`` (a FieldModel, preset name or
    field YAML path) into ``output_dir``; returns ``output_dir``. ``conf``: see
    ``resolve_simulate_conf``."""
    from tqdm import tqdm

    conf = resolve_simulate_conf(conf)
    output_dir = Path(output_dir)
    field_file = None
    if not isinstance(field, FieldModel):
        p = Path(field)
        field_file = p if p.suffix.lower() in (".yaml", ".yml") or p.exists() else None
        field = load_field(field)
    grid = conf["trajectory"].get("kind") == "grid"
    if grid:  # one frame per placement (its centre and spacing checked first)
        check_bounds(conf, SCALAR_BOUNDS, optional=True)
        _check_start(conf)
        conf["frames"] = trajectory.grid_count(field, conf["trajectory"])
    _check_conf(conf)
    restore_interrupted_replacement(output_dir)
    _check_target(output_dir, overwrite, field_file)
    remove_stale_parts(output_dir)
    memory, disk = estimate_needs(conf, field)
    what = (f"simulate of {conf['frames']} frames on {field.name}"
            f" ({field.length:g} x {field.width:g} m)")
    check_memory(what, memory)
    check_disk(what, output_dir.parent if str(output_dir.parent) else Path("."), disk)
    kind = conf["camera"]
    module, renderer_cls = renderer_class(kind)
    n = int(conf["frames"])
    seed = int(conf["seed"])
    rate = float(conf["rate_hz"])
    ss = np.random.SeedSequence([seed, 0x51A])
    rng_traj, rng_odo, rng_imu, rng_coll = (np.random.default_rng(s) for s in ss.spawn(4))

    traj_conf = conf["trajectory"]
    if traj_conf.get("start") == "touchline":  # enter at a touch line, own half
        traj_conf = {**traj_conf, "start": walk.touchline_start(
            field, float(traj_conf.get("margin", trajectory.DEFAULTS["margin"])),
            np.random.default_rng([seed, 0x57A27]))}
    path = trajectory.generate(field, n, rate, traj_conf, rng_traj)
    venue = {} if conf.get("world_seed") is None else {"world_seed": int(conf["world_seed"])}
    world = scene_mod.build(field, conf["scene"], path.stamps, seed, robot_poses=path.poses,
                            **venue)
    renderer = renderer_cls(conf[kind], world, seed)
    # renderers that need the whole path first (the perspective head motion) return extra
    # CSV files to write: {stem: (csv kind, columns)}
    extra_csv = renderer.prepare(path) if hasattr(renderer, "prepare") else {}
    calib_seed = seed if conf.get("calib_seed") is None else int(conf["calib_seed"])
    written = written_camera(module, renderer.camera, conf["calib_error"], calib_seed)
    _check_written_calib(written)

    others = world.robot_positions()  # (K, N, 2)
    contact = float(conf["imu"].get("contact_distance", sensors.IMU_DEFAULTS["contact_distance"]))
    contacts = (np.linalg.norm(others - path.poses[None, :, :2], axis=-1) < contact).any(0) \
        if len(others) else np.zeros(n, dtype=bool)
    collisions = sensors.collision_flags(n, rate, conf["imu"], rng_coll, contacts)
    odo = sensors.odometry(path.poses, conf["odometry"], rng_odo, collisions)
    yaw = sensors.imu_yaw(path.poses, path.stamps, conf["imu"], rng_imu, collisions)

    tmp = part_dir(output_dir)
    try:
        # a full disk is reported as the output's, not its temporary folder's
        with writing(output_dir):
            (tmp / "images").mkdir()
            names = _frame_names(n)
            for i in tqdm(range(n), desc=f"simulate {kind}", unit="frame", disable=not progress):
                img = renderer.render(path.poses[i], i)
                write_png(tmp / "images" / names[i], img)
            stamps = path.stamps
            write_csv(tmp / "frames.csv", "frames", {"name": names, "stamp": stamps})
            write_csv(tmp / "truth.csv", "truth", {
                "stamp": stamps, "x": path.poses[:, 0], "y": path.poses[:, 1],
                "theta": path.poses[:, 2]})
            if not grid:  # placements have no odometry between them
                write_csv(tmp / "odometry.csv", "odometry", {
                    "stamp": stamps, "dx": odo[:, 0], "dy": odo[:, 1], "dtheta": odo[:, 2]})
            write_csv(tmp / "imu.csv", "imu", {"stamp": stamps, "yaw": yaw,
                                               "collision": collisions.astype(float)})
            for stem, (csv_kind, columns) in extra_csv.items():
                write_csv(tmp / f"{stem}.csv", csv_kind, columns)
            save_calib(written, tmp / "calib.yaml")
            info = {
                "generator": GENERATOR,
                "field": field.name,
                "field_source": field.source,
                "field_size": [float(field.length), float(field.width)],
                "field_yaml_hash": text_hash(field.spec_text),
                "camera": kind,
                "seed": seed,
                "calib_seed": calib_seed,
                "world_seed": seed if conf.get("world_seed") is None else int(conf["world_seed"]),
                "frames": n,
                # what this run wrote (with the n images): all --overwrite may delete
                "files": sorted([p.name for p in tmp.iterdir()] + [SIMULATION_RECORD]),
                "true_camera": renderer.camera.to_dict(),
                "conf": _plain(conf),
            }
            info[WRITTEN_FILES] = written_files(tmp, _dataset_files(tmp))  # --overwrite's test
            (tmp / SIMULATION_RECORD).write_bytes(record_text(info, SIMULATION_RECORD).encode())
            give_default_mode(tmp)
            commit_dir(tmp, output_dir, replace=overwrite)  # never a dataset written meanwhile
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    log.info("simulated %d frames on %s into %s (path %.1f m, %d collision frames)", n,
             field.name, output_dir, path.length, int(collisions.sum()))
    return output_dir


def _plain(o):
    """The conf as plain YAML-able values."""
    if isinstance(o, dict):
        return {str(k): _plain(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_plain(v) for v in o]
    if isinstance(o, (np.floating, float)):
        return float(o) if math.isfinite(float(o)) else str(o)
    if isinstance(o, (np.integer,)):
        return int(o)
    return o
