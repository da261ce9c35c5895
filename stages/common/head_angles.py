"""A perspective camera's per-frame head pose from DIR/head.csv (stages.common.dataset): the
rows sorted by stamp and the row of a frame's stamp, as extract uses them to project a frame's
pixels to the floor and as anything that projects those pixels again (the mount calibration
of stages.localize) must.

head.csv holds pitch and roll (rad) and optionally yaw (rad), height (m) and x, y (m, the
optical centre over the floor); a frame takes the row nearest its stamp within
``HEAD_STAMP_TOLERANCE``, or none (the calibration's nominal pose).
"""

from __future__ import annotations

import math

import numpy as np

from .errors import DatasetError
from .perspective_camera import MAX_HEIGHT_M, MIN_HEIGHT_M

HEAD_STAMP_TOLERANCE = 0.05  # s, head.csv row to frame matching
# head.csv's columns as they may be (low, high, unit): angles in radians, heights in metres
# above the floor (the calibration's own bounds, perspective_camera); a value outside is most
# likely in degrees or millimetres, and would silently place every line point wrong. A head
# pitched or rolled beyond a quarter turn looks at the sky, behind it or upside down: no
# robot's head does, and its frame's pixels would be projected to a floor it cannot see
# (trial U2, U2-8: pitch 1.6 rad, roll 3.14 rad taken)
HEAD_LIMITS = {"pitch": (-math.pi / 2, math.pi / 2, "rad"),
               "roll": (-math.pi / 2, math.pi / 2, "rad"),
               "yaw": (-math.pi, math.pi, "rad"), "height": (MIN_HEIGHT_M, MAX_HEIGHT_M, "m")}
QUARTER_TURN_WHY = " (beyond a quarter turn the camera faces the sky, or is upside down)"


def head_table(ds) -> tuple[np.ndarray, dict[str, np.ndarray]] | None:
    """head.csv of the dataset ``ds`` sorted by stamp: (stamps, {column: values}) of the pose
    columns it holds (pitch, roll and the optional yaw, height, x, y); None without one."""
    head = ds.optional("head")
    if head is None or len(head["stamp"]) == 0:
        return None
    for name, (low, high, unit) in HEAD_LIMITS.items():
        v = head.get(name)
        bad = np.flatnonzero(~((v >= low) & (v <= high))) if v is not None else []
        if len(bad):  # degrees or millimetres given where radians or metres are read
            raise DatasetError(f"{ds.root / 'head.csv'}: line {int(bad[0]) + 2}: {name}"
                               f" {float(v[bad[0]]):g} is not within [{low:g}, {high:g}] {unit}"
                               + (QUARTER_TURN_WHY if name in ("pitch", "roll")
                                  and abs(v[bad[0]]) <= math.pi else ""))
    order = np.argsort(head["stamp"])
    return head["stamp"][order], {k: v[order] for k, v in head.items() if k != "stamp"}


def frames_without_head(head, stamps) -> int:
    """How many of the frame ``stamps`` have no row of ``head_table``'s result within
    HEAD_STAMP_TOLERANCE (0 without a head.csv): those frames take the calibration's nominal
    head pose, which a head.csv of other stamps (another clock, another recording) gives all
    of them without a word (trial U2, U2-7)."""
    if head is None:
        return 0
    return sum(not head_at(head, float(s)) for s in stamps)


def head_at(head, stamp: float) -> dict:
    """The head pose of the frame at ``stamp`` ({column: value}) from ``head_table``'s
    result: the nearest row within HEAD_STAMP_TOLERANCE, else {} (nominal pose)."""
    if head is None:
        return {}
    stamps, columns = head
    n = len(stamps)
    i = min(max(int(stamps.searchsorted(stamp)), 1), n - 1) if n > 1 else 0
    if n > 1 and abs(stamps[i - 1] - stamp) <= abs(stamps[i] - stamp):
        i -= 1
    if abs(stamps[i] - stamp) > HEAD_STAMP_TOLERANCE:
        return {}
    return {k: float(v[i]) for k, v in columns.items()}
