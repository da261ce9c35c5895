"""Feature extraction for a perspective (humanoid head) camera: Schulz et al. (2011),
sections 3 and 4.

``extract_frame`` runs the chain on one frame, each step in its own module:

1. colour classes per pixel and their counts per 8 x 8 cell (``stages.common.colour``); the
   white of the wide-angle lens's unreliable corners is deleted (``delete_unreliable_corners``);
2. the field boundary (``field_boundary``);
3. goal posts: white bars rising above the boundary (``goal_posts``), and white bars standing
   on the floor up to the boundary found among the line segments (``is_post_bar``);
4. the white cells inside the boundary, low-passed, the ranking-operator skeleton, nodes,
   connections, stretching and gap filling (``line_structure``);
5. the key structure and the L/T/X crossings verified in the colour images (``crossings``);
6. field lines by split-and-merge on undistorted node coordinates (``line_fit``);
7. everything projected to the floor with the camera model at the frame's head angles.

It returns the per-frame datasets of the features schema (stages.common.features_file):
boundary, line_ends, line_ends_px, lines, crossings, crossings_px, posts, posts_px, and the
view: the floor the image sees below the field boundary (``view_polygon``), where a line
that is there should have been found. ``debug_overlay`` draws them on the frame like the
paper's fig. 1.
"""

from __future__ import annotations

import copy
import functools
import math
from types import MappingProxyType

import cv2
import numpy as np

from ...common import colour
from ...common.errors import DatasetError, FieldlocError
from ...common.geometry import polar
from ...common.jit import njit
from ...common.numeric import median
from .crossing_kernels import floor_at
from .crossings import CROSSINGS, Finds, FrameGrid, find_crossings, floor_bundle
from .field_boundary import BOUNDARY, boundary_polyline
from .field_boundary import field_boundary as find_boundary
from .goal_posts import POSTS, is_leg_bar, is_post_bar
from .goal_posts import goal_posts as find_posts
from .line_fit import (
    LINES,
    LinesTuning,
    RefinedLine,
    distort_ideal,
    floor_line_parameters,
    floor_lines_parameters,
    lens_parameters,
    line_components,
    refine_segments,
    split_and_merge,
)
from .line_fit_kernels import distort_point
from .line_structure import KEY, SKELETON, key_structure, line_structure_graph, skeleton_grid
from .line_structure_kernels import bilinear_at

# the colour classes (stages.common.colour, whose defaults the omni extractor shares) with
# what the perspective cameras' frames need (tuned on the HULKs NAO frames, docs/manual.md
# "Perspective extraction on real frames"); read only, the colour functions take it as a conf
COLOUR = MappingProxyType({
    **copy.deepcopy(colour.confs["default"]),
    # green candidates need chroma >= this share of their luminance: lit white walls and grey
    # hall floors hold only a faint tint (saturation < 0.05 on the HULKs frames), carpet green
    # 0.2-0.6
    "green_min_saturation": 0.15,
    # green by hue and saturation around the frame's field green (colour.py): real carpet seen
    # near and far keeps its hue (+-8..15 deg on the HULKs frames) but its saturation spans a
    # factor 2.2..2.6 (p5..p95)
    "green_model": "hue",
    "green_hue_tolerance_deg": 15.0,
    "green_hue_k": 3.0,
    "green_saturation": [0.4, 2.5]})

# What the user chooses; the steps' tuned numbers are named constants beside their code:
# COLOUR here, field_boundary.BOUNDARY, goal_posts.POSTS, line_structure.SKELETON and KEY,
# crossings.CROSSINGS, line_fit.LINES.
confs = {
    "default": {
        # px per subsampled cell (the paper's 94 x 60 grid for 752 x 480): finer is slower
        "cell": 8,
        # classify every colour_step-th pixel of every colour_step-th row (1: all 64 pixels of
        # a cell, as the paper; 2: 16 per cell, counts scaled, see colour.classify_grid):
        # faster, coarser colour counts
        "colour_step": 1,
        # unreliable corners of the wide-angle lens: cells farther from the image centre than
        # this share of the half diagonal lose their white (the boundary scan keeps them);
        # 1 or more: a lens whose corners are sharp keeps them
        "corner_radius": 0.95,
        # the field's goal posts
        "posts": {
            "post_diameter": 0.1,  # m (KidSize goal posts; the MSL's are 0.125 m)
            "max_distance": 7.0,  # m: farther posts are not reported
        },
    },
}

def former_layout() -> dict:
    """The tuned constants at the conf keys they held before they left the preset. A features
    file written then stored them in its conf; extract compares them with these values to
    tell whether the file can be resumed or reused (stages.extract)."""
    return {"colour": dict(COLOUR), "boundary": BOUNDARY._asdict(), "posts": POSTS._asdict(),
            "skeleton": SKELETON._asdict(), "key": KEY._asdict(),
            "crossings": CROSSINGS._asdict(), "lines": LINES._asdict()}


# the ranges the extractor's numeric keys must lie in (common.conf.check_bounds, checked when
# the conf is resolved, before any frame). Found by fuzzing every key with 0, -1, 1e12 and
# 1e-12: a cell or step of 0 divides by zero, sizes or distances of 1e12 ran out of memory or
# for hours (the widest post sought, fx * post_diameter / POSTS.min_distance px, is the
# window of the post search). The upper bounds lie far beyond anything a frame can use:
MAX_M = 100.0  # m on the floor: farther than any field and its surroundings
BOUNDS = {
    "cell": (1, 64), "colour_step": (1, 64), "corner_radius": (0, None),
    # posts are thinner than 1 m
    "posts.post_diameter": ((0,), 1.0), "posts.max_distance": (0, MAX_M),
}


def check_conf(conf: dict) -> None:
    """What BOUNDS does not say (FieldlocError): the colour step subsamples whole cells."""
    step, cell, local = conf["colour_step"], conf["cell"], COLOUR["local_cell"]
    if step > 1 and (cell % step or local % step):
        raise FieldlocError(f"conf 'colour_step' must divide the cell ({cell} px) and the local"
                            f" green cell (COLOUR's local_cell, {local} px), got {step}")


def delete_unreliable_corners(counts: np.ndarray, radius_share: float) -> np.ndarray:
    """Zero the colour counts (H, W, ...) of cells beyond ``radius_share`` of the half diagonal
    from the image centre (the wide-angle lens's unreliable corners)."""
    if radius_share >= 1.0:
        return counts
    out = counts.copy()
    out[_far_cells(counts.shape[0], counts.shape[1], float(radius_share))] = 0
    return out


@functools.lru_cache(maxsize=8)
def _far_cells(h: int, w: int, radius_share: float) -> np.ndarray:
    """The cells (h, w) bool of delete_unreliable_corners (computed once per grid)."""
    y = (np.arange(h) + 0.5 - h / 2)[:, None]
    x = (np.arange(w) + 0.5 - w / 2)[None, :]
    far = np.hypot(x, y) > radius_share * math.hypot(w / 2, h / 2)
    far.setflags(write=False)
    return far


class IdealPixels:
    """Undistortion of one camera by table lookup: the camera's ideal (undistorted) pixel
    coordinates on a grid every ``stride`` pixels, interpolated bilinearly. The camera's own
    undistort_points (Newton iterations) runs once per camera instead of on every frame."""

    def __init__(self, camera, stride: int = 4):
        w, h = camera.image_size
        us = np.arange(0, w + stride, stride, dtype=float)
        vs = np.arange(0, h + stride, stride, dtype=float)
        grid = np.stack(np.meshgrid(us, vs), axis=-1)
        ideal = camera.undistort_points(grid)
        self.stride = stride
        # the intrinsics and their inverse (written out: K is upper triangular), for the
        # floor projections of every frame
        self.k = camera.camera_matrix
        self.k.setflags(write=False)
        fx, fy, cx, cy = camera.fx, camera.fy, camera.cx, camera.cy
        self.k_inv = np.array([[1.0 / fx, 0.0, -cx / fx], [0.0, 1.0 / fy, -cy / fy],
                               [0.0, 0.0, 1.0]])
        self.k_inv.setflags(write=False)
        self.map_u = ideal[..., 0].astype(np.float32)
        self.map_v = ideal[..., 1].astype(np.float32)
        self._cell_centres: dict[tuple, np.ndarray] = {}

    def cell_centres(self, shape, cell: int) -> np.ndarray:
        """Ideal pixels (hb * wb, 2) of the centres of the ``cell`` x ``cell`` blocks of an
        image of ``shape`` (h, w), row by row (computed once per grid)."""
        h, w = shape[:2]
        key = (h, w, cell)
        hit = self._cell_centres.get(key)
        if hit is None:
            hb, wb = -(-h // cell), -(-w // cell)
            gy, gx = np.mgrid[0:hb, 0:wb]
            hit = self(grid_to_pixels(np.stack([gx.ravel(), gy.ravel()], axis=1), cell))
            hit.setflags(write=False)
            self._cell_centres[key] = hit
        return hit

    def __call__(self, uv) -> np.ndarray:
        """Distorted pixels (N, 2) -> ideal pixels (N, 2); NaN outside the lens model. The
        tables are interpolated bilinearly (NaN beyond them), compiled (``_look_up``)."""
        p = np.ascontiguousarray(np.asarray(uv, np.float64).reshape(-1, 2))
        out = np.empty(p.shape)
        _look_up(p, float(self.stride), self.map_u, self.map_v, out)
        return out


@njit(cache=True, nogil=True)
def _look_up(p, stride, map_u, map_v, out):
    """IdealPixels on distorted pixels p (N, 2): each pixel over the tables' stride, both
    tables read there (bilinear_at, NaN beyond them)."""
    for i in range(p.shape[0]):
        x, y = p[i, 0] / stride, p[i, 1] / stride
        out[i, 0] = bilinear_at(map_u, x, y, np.nan)
        out[i, 1] = bilinear_at(map_v, x, y, np.nan)


_IDEAL_CACHE: dict[tuple, IdealPixels] = {}


def ideal_pixels(camera) -> IdealPixels:
    """The (cached) undistortion table of a camera's intrinsics and lens (the same for every
    pose of the head, see PerspectiveCamera.with_pose)."""
    key = (tuple(camera.image_size), camera.fx, camera.fy, camera.cx, camera.cy,
           tuple(camera.distortion.tolist()))
    hit = _IDEAL_CACHE.get(key)
    if hit is None:
        if len(_IDEAL_CACHE) > 8:
            _IDEAL_CACHE.clear()
        hit = _IDEAL_CACHE[key] = IdealPixels(camera)
    return hit


class FloorProjection:
    """Ideal (undistorted) pixels -> floor points in the robot frame for one frame's head
    angles: each pixel's pinhole ray turned by the camera's rotation and cut with the floor
    ``camera.height`` below the lens (NaN on or above the horizon). The rotation is computed
    once per frame: m = R K^-1 takes an ideal pixel (u, v, 1) to its ray, m_inv = K R^T
    back (R a rotation); both products written out element by element (matmul3)."""

    def __init__(self, camera, pitch=None, roll=None):
        undistort = ideal_pixels(camera)
        rotation = camera.rotation(pitch, roll)
        self.m = matmul3(rotation, undistort.k_inv)
        self.m_inv = matmul3(undistort.k, rotation.T)
        self.height = float(camera.height)
        self.position = np.asarray(camera.position, float)
        self._shifted = bool(self.position.any())

    def __call__(self, ideal) -> np.ndarray:
        p = np.ascontiguousarray(ideal, np.float64).reshape(-1, 2)
        out = np.empty_like(p)
        _to_floor(p, self.m, self.height, self.position, self._shifted, out)
        return out

    def to_ideal(self, floor) -> np.ndarray:
        """Floor points (N, 2) in the robot frame -> ideal pixels (N, 2) (NaN behind the
        camera)."""
        p = np.asarray(floor, float).reshape(-1, 2) - self.position
        mi, z = self.m_inv, -self.height
        # homogeneous ideal pixels m_inv (x, y, -height), row by row
        h = [mi[j, 0] * p[:, 0] + mi[j, 1] * p[:, 1] + mi[j, 2] * z for j in range(3)]
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where((h[2] > 1e-9)[:, None], np.stack([h[0], h[1]], 1) / h[2][:, None],
                            np.nan)


def matmul3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The product of two 3 x 3 matrices, each entry a0 b0 + a1 b1 + a2 b2 in this order
    (not BLAS, whose kernels round such sums differently on different processors)."""
    return (a[:, 0, None] * b[None, 0, :] + a[:, 1, None] * b[None, 1, :]
            + a[:, 2, None] * b[None, 2, :])


@njit(cache=True, nogil=True)
def _to_floor(p, m, height, position, shifted, out):
    """FloorProjection on ideal pixels p (N, 2) into ``out``: each pixel's ray m (u, v, 1)
    cut with the floor ``height`` below the lens (NaN unless the ray points down), plus the
    lens's ``position`` over the floor if ``shifted``."""
    for i in range(p.shape[0]):
        out[i, 0], out[i, 1] = floor_at(m, height, position, shifted, p[i, 0], p[i, 1])


def grid_to_pixels(pos, cell: int) -> np.ndarray:
    """Grid coordinates (x = column, y = row; cell centres at integers) -> full-resolution
    pixels (u, v) (pixel centres at integers)."""
    p = np.asarray(pos, float)
    return (p + 0.5) * cell - 0.5


def _empty(n: int) -> np.ndarray:
    return np.zeros((0, n), np.float32)


def below_horizon(camera, shape, cell: int, pitch=None, roll=None,
                  to_floor: FloorProjection | None = None) -> colour.BlockMask:
    """Mask (h, w, kept per block: colour.BlockMask) of the pixels whose cell (``cell`` x
    ``cell`` blocks) has its centre's viewing ray pointing below the horizon, where the floor
    can be (``to_floor``: the frame's FloorProjection at these angles, if already made)."""
    h, w = shape[:2]
    hb, wb = -(-h // cell), -(-w // cell)
    undistort = ideal_pixels(camera)
    m = (matmul3(camera.rotation(pitch, roll), undistort.k_inv) if to_floor is None
         else to_floor.m)
    ideal = undistort.cell_centres(shape, cell)
    # the ray's height; NaN (outside the lens model) compares False
    down = (m[2, 0] * ideal[:, 0] + m[2, 1] * ideal[:, 1] + m[2, 2]) < 0
    return colour.BlockMask(down.reshape(hb, wb), cell, (h, w))


def colour_shares(image_bgr: np.ndarray, conf: dict, camera=None, pitch=None, roll=None,
                  to_floor: FloorProjection | None = None) -> dict[str, np.ndarray]:
    """Step 1: the subsampled colour-class images as counts (0..cell^2) per class name. The
    field green is estimated from the floor below the horizon when the camera is given (walls
    and the hall's other floor hold large areas of faintly green-tinted grey; ``to_floor``:
    the frame's FloorProjection, if already made)."""
    cell = conf["cell"]
    floor = None if camera is None else below_horizon(camera, image_bgr.shape, cell, pitch,
                                                      roll, to_floor)
    step = int(conf.get("colour_step", 1))
    counts = None
    white_px = None
    if step == 1:  # the class kernel writes every row of whole cells; the rest stay 0
        white_px = np.empty(image_bgr.shape[:2], np.uint8)
        white_px[image_bgr.shape[0] // cell * cell:] = 0
    if step == 1:  # the compiled pass (the hue model of the green test)
        yuv = colour.to_yuv(image_bgr)
        fc = colour.estimate_field_colour(yuv, COLOUR, floor)
        counts = colour.classify_cells(yuv, fc, COLOUR, cell, white_px)
    if counts is None:
        white_bool = None if white_px is None else white_px.view(bool)
        counts, _ = colour.classify_grid(image_bgr, COLOUR, None, cell, step,
                                         green_from=floor, white_out=white_bool)
    out = {name: counts[..., i] for i, name in enumerate(colour.CLASS_NAMES)}
    if white_px is not None:
        out["white_px"] = white_px  # uint8, 1 = white (the refinement kernels read it as is)
    return out


def extract_frame(image_bgr: np.ndarray, camera, conf: dict, pitch: float | None = None,
                  roll: float | None = None, yaw: float | None = None,
                  height: float | None = None, x: float | None = None, y: float | None = None,
                  **frame_info) -> dict[str, np.ndarray]:
    """The chain of Schulz et al. (2011) on one BGR frame; ``camera`` is a PerspectiveCamera,
    ``pitch`` and ``roll`` the frame's head angles, ``yaw``, ``height`` and ``x``, ``y`` (the
    optical centre over the floor) the rest of its pose where the dataset records them (head.csv;
    default: the calibration's nominal values). A frame of another size than the
    calibration's is a DatasetError (the caller skips the frame)."""
    h, w = image_bgr.shape[:2]
    if (w, h) != tuple(camera.image_size):
        raise DatasetError(f"image is {w} x {h} px, the calibration is for "
                           f"{camera.image_size[0]} x {camera.image_size[1]} px")
    if yaw is not None or height is not None or x is not None or y is not None:
        position = None if x is None and y is None else (
            camera.position[0] if x is None else x, camera.position[1] if y is None else y)
        camera = camera.with_pose(yaw=yaw, height=height, position=position)
    to_floor = FloorProjection(camera, pitch, roll)  # the frame's rotation, made once
    counts = colour_shares(image_bgr, conf, camera, pitch, roll, to_floor)
    return extract_from_counts(counts, camera, conf, pitch, roll, to_floor=to_floor)


def extract_from_counts(counts: dict[str, np.ndarray], camera, conf: dict,
                        pitch: float | None = None, roll: float | None = None,
                        trace: dict | None = None,
                        to_floor: FloorProjection | None = None) -> dict[str, np.ndarray]:
    """Steps 2-7 on the subsampled colour counts (see extract_frame). ``trace``, if given, is
    filled with the intermediate images and graphs (for plots and tests); ``to_floor``: the
    frame's FloorProjection at these angles, if already made."""
    cell = int(conf["cell"])
    area = float(cell * cell)
    # the lens's unreliable corners lose their white (lines); the boundary scan keeps them
    white = delete_unreliable_corners(counts["white"], conf["corner_radius"]) / np.float32(area)
    green = counts["green"].astype(np.float32) / area

    # 2. field boundary
    top, field = find_boundary(counts, BOUNDARY, area)
    boundary = boundary_polyline(top, cell)

    # 3. goal posts rising above the boundary
    pc, diameter = POSTS, conf["posts"]["post_diameter"]
    # a post's width in cells at the nearest distance it is looked for
    max_width = int(math.ceil(camera.fx * diameter / pc.min_distance / cell)) + 1
    feet_px, heights, widths, groups, cut = find_posts(white, top, pc, cell, max_width)

    # 4. line structure graph (a post's lower part becomes a segment there: is_post_bar tells
    # it from a line, and crossings at a post's foot are not taken)
    sc = SKELETON
    # (the white shares are counts over the cell's area: exact binary fractions when the
    # cell is a power of two, and the compiled low-pass is then OpenCV's to the bit)
    inside, lp, ranked = skeleton_grid(white, top, sc.boundary_margin, sc.min_white,
                                       cell & (cell - 1) == 0 and cell <= 8)
    graph, skeleton, _ = line_structure_graph(lp, sc, ranked)

    # 5. key structure; 6. field lines (both on undistorted node coordinates)
    undistort = ideal_pixels(camera)
    to_floor = FloorProjection(camera, pitch, roll) if to_floor is None else to_floor

    def floor_of(grid_pos):
        return to_floor(undistort(grid_to_pixels(grid_pos, cell)))

    floor_angles = KEY.floor_angles
    ks = key_structure(graph, KEY, floor_of if floor_angles else None)
    node_px = grid_to_pixels(graph.pos, cell)
    ideal = undistort(node_px) if len(node_px) else node_px.reshape(-1, 2)
    other = counts["other"].astype(np.float32) / area
    frame = FrameGrid(camera, to_floor, cell, top, white, inside, green, other,
                      counts.get("white_px"))
    # the field boundary's floor range per column (inf where it is not on the floor)
    with np.errstate(invalid="ignore"):
        boundary_range = np.hypot(*to_floor(undistort(boundary)).T)
    boundary_range[~np.isfinite(boundary_range)] = np.inf
    lines, line_ends, line_ends_px, bar_posts, bar_posts_px, lines_ideal, line_widths = \
        find_lines(graph, ideal, frame, LINES, boundary_range, diameter, trace)
    # 6b. goal post feet on the floor (before the crossings: a post's foot on a line is no
    # crossing)
    posts, posts_px = [], []
    if len(feet_px):
        floor = to_floor(undistort(feet_px))
        for f, px, hgt, wid, out_of_sight in zip(floor, feet_px, heights, widths, cut):
            if not np.isfinite(f).all():
                continue
            d, b = polar(f[None])
            # the bar's width must fit a post of the conf's diameter at that distance, and it
            # must be as tall as a post's visible part at least where it ends in sight (white
            # socks and a robot's arms are not)
            expected = camera.fx * diameter / max(d[0], 1e-6)
            if d[0] > conf["posts"]["max_distance"] or not (
                    pc.width_ratio[0] <= wid / expected <= pc.width_ratio[1]):
                continue
            if not out_of_sight and hgt * cell < camera.fx * pc.min_height / d[0]:
                continue
            posts.append([d[0], b[0], min(1.0, hgt / pc.full_height)])
            posts_px.append(px)
    # bars standing on the field inside the boundary, unless already found above it
    for row, px in zip(bar_posts, bar_posts_px):
        if all(np.hypot(*(px - q)) > 2 * cell for q in posts_px):
            posts.append(row)
            posts_px.append(px)

    finds = Finds(np.asarray(lines_ideal, float).reshape(-1, 2, 2),
                  np.asarray(line_widths, float), posts_px)
    crossings, crossings_px = find_crossings(ks, graph, ideal, frame, CROSSINGS, trace,
                                             floor_of if floor_angles else None, finds)

    view = view_polygon(to_floor, undistort, boundary, camera.image_size)

    if trace is not None:
        trace.update(top=top, field=field, white=white, green=green, inside=inside, lp=lp,
                     skeleton=skeleton, graph=graph, key=ks, ideal=ideal, post_groups=groups)

    def arr(rows, n):
        return np.asarray(rows, np.float32).reshape(-1, n) if len(rows) else _empty(n)

    return {
        "boundary": boundary,
        "line_ends": arr(line_ends, 4),
        "line_ends_px": arr(line_ends_px, 4),
        "lines": arr(lines, 4),
        "crossings": arr(crossings, 5),
        "crossings_px": arr(crossings_px, 2),
        "posts": arr(posts, 3),
        "posts_px": arr(posts_px, 2),
        "view": view,
    }


# the view polygon: how far it reaches (the observation model ignores lines farther away:
# its max_line_distance) and its samples' spacing along the image's edges (the lens bends
# the edges on the floor; 16 px keeps the polygon within a few cm of them near the robot)
VIEW_RANGE = 6.0  # m
VIEW_STEP = 16  # px


def view_polygon(to_floor: FloorProjection, undistort, boundary: np.ndarray,
                 image_size: tuple[int, int]) -> np.ndarray:
    """The floor the image sees below the field boundary and within ``VIEW_RANGE``, as a
    polygon (V, 2) in the robot frame (m): the image's lower edge, its sides and, on top, per
    boundary column the lower of the boundary and the row whose floor point is VIEW_RANGE
    away (the rows above the horizon count as infinitely far). A line of the field
    inside it is one the extractor had the chance to find (the observation model's "unseen"
    term). Empty when the frame shows no floor within VIEW_RANGE. ``image_size``: (w, h)."""
    w, h = image_size
    every = max(1, int(round(VIEW_STEP / max(float(boundary[1, 0] - boundary[0, 0]), 1.0)))
                ) if len(boundary) > 1 else 1
    top = boundary[::every].astype(float)
    if not len(top):
        top = np.array([[0.0, 0.0], [w - 1.0, 0.0]])
    u = np.concatenate([[0.0], top[:, 0], [w - 1.0]])
    lo = np.clip(np.concatenate([top[:1, 1], top[:, 1], top[-1:, 1]]), 0.0, h - 1.0)
    v = np.empty(len(u))
    _view_top(u, lo, (float(h - 1), float(VIEW_STEP), VIEW_RANGE),
              (float(undistort.stride), undistort.map_u, undistort.map_v),
              floor_bundle(to_floor), v)
    if np.all(v >= h - 1.0):
        return _empty(2)

    def edge(v0, v1):
        return np.linspace(v0, v1, max(2, int(abs(v1 - v0) // VIEW_STEP) + 2))[1:-1]

    right = edge(v[-1], h - 1.0)
    along = np.linspace(w - 1.0, 0.0, max(2, int((w - 1) // VIEW_STEP) + 2))
    left = edge(h - 1.0, v[0])
    px = np.concatenate([
        np.stack([u, v], axis=1),
        np.stack([np.full(len(right), w - 1.0), right], axis=1),
        np.stack([along, np.full(len(along), h - 1.0)], axis=1),
        np.stack([np.zeros(len(left)), left], axis=1)])
    floor = to_floor(undistort(px))
    floor = floor[np.isfinite(floor).all(axis=1)]
    return floor.astype(np.float32) if len(floor) >= 3 else _empty(2)


@njit(cache=True, nogil=True)
def _view_top(u, lo, rows, lens, fl, out):
    """The view polygon's upper edge: per column u[i], the lower of row lo[i] and the first
    row whose floor point lies within ``max_range`` (the range falls monotonically down a
    column below the horizon): rows ``step`` apart, then linearly in 1 / range between the
    last row beyond and the first within; the bottom row where no row is within. ``rows``:
    (bottom row, step, max_range); ``lens``: IdealPixels' (stride, map_u, map_v);
    ``fl``: the frame's Floor (crossings.floor_bundle)."""
    bottom, step, max_range = rows
    stride, map_u, map_v = lens
    limit = 1.0 / max_range
    for i in range(u.shape[0]):
        out[i] = bottom
        prev_v, prev_inv = 0.0, 0.0
        v = 0.0
        while True:
            x, y = u[i] / stride, v / stride
            fx, fy = floor_at(fl.m, fl.height, fl.pos, fl.shifted,
                              bilinear_at(map_u, x, y, np.nan), bilinear_at(map_v, x, y, np.nan))
            d = math.sqrt(fx * fx + fy * fy)
            inv = 1.0 / d if d > 0.0 else 0.0  # NaN (above the horizon) compares False
            if inv >= limit:
                t = 0.0 if v == 0.0 else (limit - prev_inv) / max(inv - prev_inv, 1e-12)
                out[i] = max(lo[i], prev_v + min(max(t, 0.0), 1.0) * (v - prev_v))
                break
            if v >= bottom:
                break
            prev_v, prev_inv = v, inv
            v = min(v + step, bottom)


def find_lines(graph, ideal: np.ndarray, frame: FrameGrid, lc: LinesTuning,
               boundary_range: np.ndarray, post_diameter: float, trace: dict | None = None):
    """Section 4.2: split-and-merge lines on the undistorted node coordinates, end points
    projected on the fits (refined on the ``frame``'s full-resolution white mask), then onto
    the floor. A line is used for localisation (confidence > 0) when it is long enough, near
    enough, and not the field's edge (``field_edge``, from the frame's green share per cell
    and the floor range of the field boundary per column, ``boundary_range``).

    A segment that is a vertical bar standing on the floor (``is_post_bar``) is no field line:
    it is returned as a goal post instead (the goal's net lets the field boundary climb behind
    the posts, so they do not always rise above it; ``post_diameter`` m wide).

    Returns line rows [perpendicular distance, its angle, length, confidence], floor end
    points (L, 4), image end points (L, 4), post rows [distance, bearing, confidence] with
    their image foot points, and per line its ideal end points (L, 2, 2) and its white width
    across (px: the refined runs' median, else one cell)."""
    camera, to_floor, cell, top = frame.camera, frame.to_floor, frame.cell, frame.top
    white, green, white_px = frame.white, frame.green, frame.white_px
    segments = split_and_merge(ideal, line_components(graph), lc)
    lines, ends_m, ends_px, posts, posts_px, ends_ideal, widths = [], [], [], [], [], [], []
    if not segments:
        return lines, ends_m, ends_px, posts, posts_px, ends_ideal, widths
    refined = [None] * len(segments)
    lens = lens_parameters(camera)
    if white_px is not None and lc.refine:
        refined = refine_segments(np.stack([seg.ends for seg in segments]), white_px, lens,
                                  lc.refine_step, lc.refine_reach * cell,
                                  lc.refine_extend * cell, lc.refine_min_points,
                                  lc.refine_grow * cell)
    ratios = width_ratios([r for r in refined if r is not None], to_floor, lc.line_width)
    ends = np.concatenate([seg.ends if r is None else r.ends for seg, r in
                           zip(segments, refined)])
    all_px = distort_ideal(lens, ends).reshape(-1, 2, 2)
    all_floor = to_floor(ends).reshape(-1, 2, 2)
    # every line's floor parameters and end ranges at once (used where both ends are on it)
    params = zip(*(a.tolist() for a in floor_lines_parameters(all_floor[:, 0],
                                                              all_floor[:, 1])))
    all_ranges = np.hypot(all_floor[..., 0], all_floor[..., 1])
    nearest = all_ranges.min(axis=1).tolist()
    on_floor = np.isfinite(all_floor).all(axis=(1, 2)).tolist()
    beyond, gap = field_edge(all_floor, to_floor, lens, green, boundary_range, cell,
                             lc.green_beyond_m)
    edge = ((beyond < lc.min_green_beyond) & (gap < lc.edge_gap_m)).tolist()  # NaN: no
    ends = ends.reshape(-1, 2, 2)
    bottom = white.shape[0] * cell  # px: the image's lower edge
    kept = []  # the lines' indices
    for i, (seg, ref, (dist, angle, length), near, finite, at_edge) in enumerate(zip(
            segments, refined, params, nearest, on_floor, edge)):
        e_px = all_px[i]
        if not finite:
            # reaching above the horizon: no field line, but maybe a post (its foot on the
            # floor, the part below the horizon runs away from the robot)
            clipped = _below_horizon_part(ends[i], to_floor, lc.max_distance)
            if clipped is None:
                continue
            e_floor = to_floor(clipped)
            dist, _, _ = floor_line_parameters(e_floor[0], e_floor[1])
            ranges = np.hypot(*e_floor.T)
            if is_post_bar(dist, float(ranges.min()), e_px, top, white, camera.fx, cell, POSTS,
                           post_diameter):
                k = int(np.argmin(ranges))
                posts.append([float(ranges[k]), math.atan2(e_floor[k, 1], e_floor[k, 0]),
                              POSTS.bar_confidence])
                posts_px.append(camera.distort_points(clipped[k:k + 1])[0])
            continue
        if is_post_bar(dist, near, e_px, top, white, camera.fx, cell, POSTS, post_diameter):
            k = int(np.argmin(all_ranges[i]))
            e_floor = all_floor[i]
            posts.append([near, math.atan2(e_floor[k, 1], e_floor[k, 0]), POSTS.bar_confidence])
            posts_px.append(e_px[k])
            continue
        if is_leg_bar(dist, near, e_px[int(np.argmin(all_ranges[i])), 1], bottom, cell, POSTS):
            continue  # a robot's or a person's leg: a vertical bar short of the boundary
        if ref is not None:
            ratio = ratios[id(ref)]
            if not (lc.width_ratio[0] <= ratio <= lc.width_ratio[1]):
                continue  # a seam, a cable, a robot's leg: not of a field line's width
        rms = seg.fit.rms if ref is None else ref.fit.rms
        used = length >= lc.min_length and dist <= lc.max_distance \
            and near <= lc.max_distance and len(seg.nodes) >= lc.min_used_nodes \
            and not at_edge
        confidence = (min(1.0, len(seg.nodes) / lc.full_nodes)
                      * max(0.0, 1.0 - rms / lc.split_distance)) if used else 0.0
        lines.append([dist, angle, length, confidence])
        kept.append(i)
        widths.append(float(cell) if ref is None else float(median(ref.widths)))
    if trace is not None:
        trace.update(segments=segments, refined=refined)
    return (lines, all_floor[kept].reshape(-1, 4), all_px[kept].reshape(-1, 4), posts, posts_px,
            ends[kept], widths)


def field_edge(ends_floor: np.ndarray, to_floor: FloorProjection, lens: np.ndarray,
               green: np.ndarray, boundary_range: np.ndarray, cell: int, offset: float,
               samples: int = 9) -> tuple[np.ndarray, np.ndarray]:
    """Per floor segment (L, 2, 2 m, robot frame), at ``samples`` points along it (from 5 to
    95 % of its length) seen through the lens (``lens_parameters``) on the grid of cells of
    ``cell`` px:

    - the mean green share (``green``, per cell) at those points moved ``offset`` m across
      it, away from the robot (NaN where none is in the image): a painted line has carpet
      beyond it;
    - the median gap (m) from the segment to the field boundary beyond it: the boundary's
      floor range in each point's column (``boundary_range``, per column; inf where the
      boundary is not on the floor) less the point's range (NaN where none is in the image).

    The field's edge against a bright hall floor has neither carpet nor field beyond it. One
    compiled pass (``_field_edge``)."""
    e = np.ascontiguousarray(ends_floor, np.float64).reshape(-1, 2, 2)
    share, gap = np.empty(len(e)), np.empty(len(e))
    _field_edge(e, floor_bundle(to_floor), lens, np.ascontiguousarray(green, np.float32),
                np.ascontiguousarray(boundary_range, np.float64), int(cell),
                (float(offset), int(samples)), share, gap)
    return share, gap


@njit(cache=True, nogil=True, inline="always")
def _cell_of(fl, lens, cell, x, y):
    """The grid cell (row, column, as floats; NaN behind the camera) where the floor point
    (x, y) m of the robot frame is seen: FloorProjection.to_ideal (_to_ideal_at; ``fl`` the
    frame's crossings.Floor), then the lens."""
    ix, iy = _to_ideal_at(fl, x, y)
    u, v = distort_point(lens, ix, iy)
    return np.floor(v / cell), np.floor(u / cell)


@njit(cache=True, nogil=True)
def _field_edge(ends, fl, lens, green, boundary_range, cell, rule, share, gap):
    """field_edge's kernel (see there; ``fl``: the frame's crossings.Floor, ``rule``: the
    offset (m) of the carpet samples beyond the line and the samples per line)."""
    offset, samples = rule
    hb, wb = green.shape
    gaps = np.empty(samples)
    for k in range(ends.shape[0]):
        x0, y0, x1, y1 = ends[k, 0, 0], ends[k, 0, 1], ends[k, 1, 0], ends[k, 1, 1]
        dx, dy = x1 - x0, y1 - y0
        norm = max(math.hypot(dx, dy), 1e-9)
        nx, ny = -dy / norm, dx / norm
        if nx * (x0 + x1) + ny * (y0 + y1) < 0.0:  # across, away from the robot
            nx, ny = -nx, -ny
        total, count, n_gap = 0.0, 0, 0
        for s in range(samples):
            t = 0.05 + 0.9 * s / max(samples - 1, 1)
            x, y = x0 + t * dx, y0 + t * dy
            r, c = _cell_of(fl, lens, cell, x + offset * nx, y + offset * ny)
            if 0.0 <= r < hb and 0.0 <= c < wb:  # False for NaN
                total += green[int(r), int(c)]
                count += 1
            r, c = _cell_of(fl, lens, cell, x, y)
            if 0.0 <= r < hb and 0.0 <= c < boundary_range.shape[0]:
                gaps[n_gap] = boundary_range[int(c)] - math.hypot(x, y)
                n_gap += 1
        share[k] = total / count if count else np.nan
        gap[k] = np.median(gaps[:n_gap]) if n_gap else np.nan


def _below_horizon_part(ends: np.ndarray, to_floor: FloorProjection, max_range: float,
                        samples: int = 33) -> np.ndarray | None:
    """The part (2, 2 ideal px) of a segment whose floor projection lies within
    ``max_range`` m (a segment reaching above the horizon cut where it still meets the floor
    near enough), or None when less than two of ``samples`` points along it do."""
    t = np.linspace(0.0, 1.0, samples)[:, None]
    pts = ends[0] * (1 - t) + ends[1] * t
    f = to_floor(pts)
    ok = np.all(np.isfinite(f), axis=1)
    ok[ok] = np.hypot(*f[ok].T) <= max_range
    idx = np.nonzero(ok)[0]
    if len(idx) < 2:
        return None
    return np.stack([pts[idx[0]], pts[idx[-1]]])


def width_ratios(refs: list[RefinedLine], to_floor: FloorProjection, line_width: float
                 ) -> dict[int, float]:
    """Per refined line (by id): the median of its white runs' widths over the width a
    painted line of ``line_width`` metres has in the image at each run's floor position (both
    across the line, in ideal pixels); NaN where no run lies on the floor. All lines run in
    one compiled pass (``_width_ratios``: the floor projection and its inverse as
    FloorProjection and its to_ideal)."""
    if not refs:
        return {}
    start = np.zeros(len(refs) + 1, np.int64)
    np.add.accumulate([len(r.centres) for r in refs], out=start[1:])
    out = np.empty(len(refs))
    _width_ratios(np.concatenate([r.centres for r in refs]).astype(np.float64, copy=False),
                  start, np.array([r.ends for r in refs], np.float64),
                  np.array([r.fit.normal for r in refs], np.float64),
                  np.concatenate([r.widths for r in refs]).astype(np.float64, copy=False),
                  floor_bundle(to_floor), 0.5 * line_width, out)
    return {id(r): float(v) for r, v in zip(refs, out.tolist())}


@njit(cache=True, nogil=True)
def _to_ideal_at(fl, fx, fy):
    """FloorProjection.to_ideal at one floor point (fx, fy) (``fl``: crossings.Floor): the
    homogeneous pixel m_inv (fx - pos_x, fy - pos_y, -height), NaN behind the camera."""
    m_inv, pos = fl.m_inv, fl.pos
    r0, r1, r2 = fx - pos[0], fy - pos[1], -fl.height
    h0 = m_inv[0, 0] * r0 + m_inv[0, 1] * r1 + m_inv[0, 2] * r2
    h1 = m_inv[1, 0] * r0 + m_inv[1, 1] * r1 + m_inv[1, 2] * r2
    h2 = m_inv[2, 0] * r0 + m_inv[2, 1] * r1 + m_inv[2, 2] * r2
    if h2 > 1e-9:
        return h0 / h2, h1 / h2
    return np.nan, np.nan


@njit(cache=True, nogil=True)
def _width_ratios(centres, start, ends, normals, widths, fl, half, out):
    """width_ratios compiled: line k's runs are centres[start[k]:start[k + 1]] (ideal px)
    with their ``widths``; its median ratio into out[k] (``fl``: the frame's
    crossings.Floor)."""
    m, height, pos, shifted = fl.m, fl.height, fl.pos, fl.shifted
    n = centres.shape[0]
    floor = np.empty((n, 2))
    _to_floor(centres, m, height, pos, shifted, floor)
    fe = np.empty((2, 2))
    ratio = np.empty(n)
    for k in range(ends.shape[0]):
        _to_floor(ends[k], m, height, pos, shifted, fe)
        dx, dy = fe[1, 0] - fe[0, 0], fe[1, 1] - fe[0, 1]
        length = np.hypot(dx, dy)
        nx, ny = -dy / length, dx / length
        m_ok = 0
        for i in range(start[k], start[k + 1]):
            ax, ay = _to_ideal_at(fl, floor[i, 0] - half * nx, floor[i, 1] - half * ny)
            bx, by = _to_ideal_at(fl, floor[i, 0] + half * nx, floor[i, 1] + half * ny)
            expected = abs((bx - ax) * normals[k, 0] + (by - ay) * normals[k, 1])
            r = widths[i] / (expected if not expected < 1e-6 else 1e-6)  # np.maximum
            if np.isfinite(floor[i, 0]) and np.isfinite(floor[i, 1]) and np.isfinite(r):
                ratio[m_ok] = r
                m_ok += 1
        out[k] = median(ratio[:m_ok]) if m_ok else np.nan


# ---------------------------------------------------------------------------- debug images

_PURPLE, _RED, _GREEN, _YELLOW, _CYAN = (200, 0, 200), (0, 0, 255), (0, 200, 0), (0, 230, 255), (
    255, 255, 0)


def debug_overlay(image: np.ndarray, result: dict[str, np.ndarray]) -> np.ndarray:
    """A copy of the BGR frame with the extraction drawn like the paper's fig. 1: the field
    boundary in purple, field lines used for localisation in red and not used in green,
    crossings marked L, T or X (yellow), goal post feet (cyan)."""
    out = image.copy()
    b = result.get("boundary")
    if b is not None and len(b) > 1:
        cv2.polylines(out, [np.round(b).astype(np.int32).reshape(-1, 1, 2)], False, _PURPLE, 2)
    ends = result.get("line_ends_px", _empty(4))
    lines = result.get("lines", _empty(4))
    for e, ln in zip(ends, lines):
        if not np.isfinite(e).all():
            continue
        p0, p1 = tuple(int(round(v)) for v in e[:2]), tuple(int(round(v)) for v in e[2:])
        cv2.line(out, p0, p1, _RED if ln[3] > 0 else _GREEN, 2)
    for c, px in zip(result.get("crossings", _empty(5)), result.get("crossings_px", _empty(2))):
        u, v = int(round(px[0])), int(round(px[1]))
        cv2.circle(out, (u, v), 6, _YELLOW, 2)
        cv2.putText(out, "LTX"[int(c[0])], (u + 7, v - 7), cv2.FONT_HERSHEY_SIMPLEX, 0.7,
                    _YELLOW, 2)
    for px in result.get("posts_px", _empty(2)):
        u, v = int(round(px[0])), int(round(px[1]))
        cv2.drawMarker(out, (u, v), _CYAN, cv2.MARKER_TRIANGLE_UP, 14, 2)
    return out
