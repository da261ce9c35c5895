"""The smoother (smooth.py) for the methods of tracking.TrackBank (lut, fit, templates): the
bank's tuned constants its motion and jump models read."""

from __future__ import annotations

from dataclasses import asdict

from ..common.poses_file import PoseTrack
from . import smooth
from .tracking import FUSION, KIDNAP_PROBABILITY


def smoothed(scorer, causal: PoseTrack, conf: dict, *, increments, has_odometry, stamps,
             collision, area: float, correlation_s: float = 0.0) -> PoseTrack:
    """The causal run's track smoothed with the whole recording (smooth.smooth_track) from a
    method's ``scorer``: the run's motion (odometry ``increments`` where ``has_odometry``,
    frame ``stamps``, IMU ``collision`` flags) under the bank's fusion noise (FUSION), the
    jump model's KIDNAP_PROBABILITY, the method's ``min_confidence``, ``hypotheses`` and
    ``start_half`` (with ``start_half_error``) from ``conf``; ``area``: m^2 a kidnap may put
    the robot on; ``correlation_s``: the method's correlation time of its frames' evidence
    (smooth.evidence_temperature; 0: every frame independent)."""
    motion = smooth.motion_of(increments, has_odometry, stamps, asdict(FUSION), collision)
    return smooth.smooth_track(scorer, causal, motion, conf,
                               kidnap_probability=KIDNAP_PROBABILITY, area=area,
                               log_prior0=smooth.start_half_prior(conf, scorer.mirrored),
                               temperature=smooth.evidence_temperature(stamps, correlation_s))
