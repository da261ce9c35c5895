"""What a frame decides on a point-symmetric field: its pose up to the field's 180 deg turn.

On a field that looks the same after a half turn about the centre spot
(``FieldModel.is_point_symmetric``: MSL, SPL and KidSize fields are), a pose and its mirror
image (``FieldModel.mirror_pose``) explain every observation equally. A frame localised on its
own (a snapshot, ``--independent``, the first frames of a run with no ``start_half`` and no
field-aligned heading) therefore holds about half its probability on each, and its top
hypothesis is never accepted, however well the pair is determined. What the frame does decide
is the pair: its *confidence up to the mirror* is the probability of the top hypothesis plus
that of the hypotheses at the top's mirror image, and the frame is *accepted up to the mirror*
when that reaches the method's ``min_confidence``. On a field without the symmetry both equal
the plain confidence and acceptance.

Every method lists ranked hypotheses with their probabilities (lut, fit and templates their
tracks and the mirrors TrackBank lists, mcl its particle clusters), so this is computed here,
once, from the listing (``localize.main`` fills the poses file's ``confidence_up_to_mirror``
and ``accepted_up_to_mirror`` columns). ``evaluate --up-to-mirror`` scores such frames against
the truth or its mirror, and ``export`` writes the mirror pose beside the pose.

``start_half_warning``: a run given a start half whose track starts on the other half (its
frames, through a field-aligned heading, overruled the given half); localize.main logs it.
"""

from __future__ import annotations

import numpy as np

from ..common.geometry import wrap_angle
from ..common.poses_file import PoseTrack
from .start_half import HALF_DECIDES, StartHalf

# A hypothesis is the top's mirror image when it lies within half the global search's
# ambiguity_distance (1 m: the spacing of the separated minima a search proposes) and within
# 0.3 rad of it; two basins of the search are never nearer than that, and an mcl cluster's mean
# sits within a few centimetres of its basin's centre.
MIRROR_MATCH_M = 0.5
MIRROR_MATCH_RAD = 0.3


def confidence_up_to_mirror(hypotheses: np.ndarray, symmetric: bool) -> np.ndarray:
    """(N,) probability of the top hypothesis or its mirror image, per frame, of ranked
    hypotheses (N, K, 4) = (x, y, theta, probability), NaN rows padding. A frame with no
    hypothesis gets 0; on a field without the symmetry (``symmetric`` False) the top's own
    probability."""
    h = np.asarray(hypotheses, dtype=float).reshape(len(hypotheses), -1, 4)
    top = h[:, 0, :]
    p = np.where(np.isfinite(h[..., 3]), h[..., 3], 0.0)
    out = p[:, 0].copy()
    if not symmetric or h.shape[1] < 2:
        return out
    mx, my = -top[:, 0:1], -top[:, 1:2]
    mth = wrap_angle(top[:, 2:3] + np.pi)
    rest = h[:, 1:, :]
    with np.errstate(invalid="ignore"):
        at_mirror = ((np.hypot(rest[..., 0] - mx, rest[..., 1] - my) < MIRROR_MATCH_M)
                     & (np.abs(wrap_angle(rest[..., 2] - mth)) < MIRROR_MATCH_RAD))
    return out + np.sum(np.where(at_mirror, p[:, 1:], 0.0), axis=1)


def set_up_to_mirror(track: PoseTrack, symmetric: bool, min_confidence: float) -> None:
    """Fill ``track``'s confidence and acceptance up to the mirror (module doc) from its
    hypotheses: accepted up to the mirror when not failed and the confidence up to the mirror
    reaches ``min_confidence`` (or the frame is accepted as it is)."""
    if not len(track):
        return
    arr = track.arrays()
    conf = np.minimum(confidence_up_to_mirror(arr["hypotheses"], symmetric), 1.0)
    conf = np.maximum(conf, arr["confidence"])  # never below the top's own probability
    failed = arr["failed"]
    accepted = ~failed & (arr["accepted"] | (conf >= float(min_confidence)))
    track.confidence_up_to_mirror = [float(c) for c in conf]
    track.accepted_up_to_mirror = [bool(a) for a in accepted]


HALVES = {"own": "own half (x < 0)", "opponent": "opponent half (x > 0)"}
MIN_HALF_FRAMES = 5  # the first accepted frames that say where the track started
# m: a pose this near the halfway line may lie on either side of it (a kick-off stands at the
# centre circle), so it says nothing about the half
CENTRE_MARGIN_M = 0.5


def start_half_warning(columns: dict, attrs: dict, increments=None) -> str | None:
    """One line when the run's first MIN_HALF_FRAMES accepted poses mostly put the robot's
    start in the other half than the ``start_half`` its conf gave, beyond CENTRE_MARGIN_M of
    the halfway line (None otherwise, and for ``any``).

    start_half chooses between a pose and its mirror where the frames cannot; where they can
    (a field-aligned IMU heading tells the two apart), they overrule it, and the track starts
    on the other half: the given half, or the heading's alignment, is wrong, and only the user
    can tell which. Only the start is judged: a robot walks across the halfway line as it
    plays, and a track held on the given half says nothing either way (with no heading to
    tell, a wrong start half gives the mirror image of the whole track, which no frame can
    reveal; evaluate warns of it where a truth is given). With ``increments`` (the odometry
    between the track's frames, (F, 3)) each pose is judged by the first pose it implies
    (start_half.StartHalf: the odometry undone from it), counted where that lies beyond the
    margin on the other half and the odometry's error leaves odds of HALF_DECIDES or more:
    a robot may have walked across the line before its first accepted frame."""
    half = (attrs.get("conf") or {}).get("start_half")
    if half not in HALVES:
        return None
    x = np.asarray(columns["x"], float)
    acc = np.asarray(columns["accepted"], bool) & np.isfinite(x)
    at = np.flatnonzero(acc)[:MIN_HALF_FRAMES]
    if len(at) < MIN_HALF_FRAMES:
        return None
    sign = 1.0 if half == "own" else -1.0  # the other half's side of x
    if increments is None:
        other = int(np.sum(sign * x[at] > CENTRE_MARGIN_M))
    else:
        poses = np.stack([x, np.asarray(columns["y"], float),
                          np.asarray(columns["theta"], float)], axis=1)
        stamps = np.asarray(columns["stamp"], float)
        carried, other, k = StartHalf(half, 0.0), 0, 0
        for i in range(at[-1] + 1):
            if i:
                carried.move(increments[i], max(float(stamps[i] - stamps[i - 1]), 0.0))
            if i == at[k]:
                k += 1
                beyond = sign * carried.first_x(poses[i:i + 1])[0] > CENTRE_MARGIN_M
                other += int(beyond and carried.log_odds(poses[i:i + 1])[0] <= -HALF_DECIDES)
    if 2 * other <= len(at):
        return None
    return (f"start_half {half}, yet {other} of the run's first {len(at)} accepted poses place"
            f" its start in the {HALVES['opponent' if half == 'own' else 'own']}: the frames (a"
            " field-aligned heading) overruled the given half; check it, or the heading's"
            " alignment (--start-half any lets the frames decide)")
