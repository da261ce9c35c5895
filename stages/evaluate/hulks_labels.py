"""The hand-clicked labels of the HULKs goal-box recordings (../shared/realdata/
hulks-goalbox-labels: per capture, two points on each of the goal line, the goal area's front
line and its side line), and the robot pose they give: the truth that the perspective
extractor's and mcl's checks on those real frames are held to.

Label pixels are HULKs' (origin at the top-left pixel's corner) and are moved by half a pixel
to fieldloc's (origin at its centre), as the camera import does with the principal point. Four
captures hold the front and side labels swapped (the recordings' SOURCE.txt); ``read_labels``
swaps them back.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

SWAPPED = {"1687083970", "1687083999", "1687084023", "1687084029"}  # SOURCE.txt
# our names of the labelled lines -> HULKs'
LABEL_KEYS = {"goal": "border_line", "front": "goal_box_line", "side": "connecting_line"}


def read_labels(path: str | Path) -> dict[str, np.ndarray]:
    """The three labelled lines of a capture's JSON, each (2, 2) in fieldloc pixels."""
    path = Path(path)
    d = json.loads(path.read_text())["crossings"]
    out = {k: np.array([d[f"{v}_0"], d[f"{v}_1"]], float) - 0.5 for k, v in LABEL_KEYS.items()}
    if path.stem in SWAPPED:
        out["front"], out["side"] = out["side"], out["front"]
    return out


def intersect(a: np.ndarray, b: np.ndarray) -> np.ndarray | None:
    """Where the lines through the segments ``a`` and ``b`` ((2, 2) each) meet; None when
    they are parallel."""
    da, db = a[1] - a[0], b[1] - b[0]
    den = da[0] * db[1] - da[1] * db[0]
    if abs(den) < 1e-9:
        return None
    t = ((b[0] - a[0])[0] * db[1] - (b[0] - a[0])[1] * db[0]) / den
    return a[0] + t * da


def field_pose_from_labels(floor: dict[str, np.ndarray], field) -> np.ndarray | None:
    """The robot's pose (x, y, theta) from the labelled lines on the floor (robot frame; as
    ``read_labels`` names them), in a field frame whose goal at x = +length / 2 is the one the
    labels show: the T (goal x side line) is the goal area's corner on the goal line, the side
    line leads from it into the field, and the front line leaves the L corner towards the goal
    area's inside (which says on which side of the goal the labelled side line is). None where
    the lines do not meet."""
    t = intersect(floor["goal"], floor["side"])
    corner = intersect(floor["front"], floor["side"])
    if t is None or corner is None:
        return None
    inward = corner - t
    if np.hypot(*inward) < 1e-6:
        return None
    ex = -inward / np.hypot(*inward)  # field +x: towards the goal
    ey = np.array([-ex[1], ex[0]])
    far = floor["front"][np.argmax(np.hypot(*(floor["front"] - corner).T))]
    inside = far - corner  # along the front line, into the goal area
    half_w = field.spec["goal_area"]["width"] / 2
    t_field = np.array([field.length / 2, half_w if inside @ ey < 0 else -half_w])
    theta = math.atan2(ey[0], ex[0])
    origin = t_field - np.array([ex @ t, ey @ t])
    return np.array([origin[0], origin[1], theta])
