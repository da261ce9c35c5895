"""One frame's perspective observations in the robot frame on the floor (x forward, y left):
lines, crossings and goal posts as extract writes them into a features file
(stages.common.features_file) and as localize's observation model, the belief picture and the
synthetic observations of simulate read them. Columns:

    lines      (L, 4)  perpendicular distance r (m), angle of the perpendicular a (rad),
                       length (m), confidence
    line_ends  (L, 4)  optional end points x0, y0, x1, y1 (m)
    crossings  (C, 5)  type (CROSSING_CODES: 0 L, 1 T, 2 X), distance (m), bearing (rad),
                       orientation (rad: L bisector, T stem, X first arm mod 90 deg), confidence
    posts      (P, 3)  goal-post foot distance (m), bearing (rad), confidence
    view       (V, 2)  optional: the floor the image sees below the field boundary, a polygon
                       (m); where a line should have been seen (the observation model's
                       "unseen" term)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .features_file import CROSSING_CODES

__all__ = ["CROSSING_CODES", "Observations"]


@dataclass
class Observations:
    """One frame's egocentric observations (columns: the module doc)."""

    lines: np.ndarray
    line_ends: np.ndarray | None
    crossings: np.ndarray
    posts: np.ndarray
    view: np.ndarray | None = None

    @classmethod
    def empty(cls) -> Observations:
        return cls(np.zeros((0, 4)), None, np.zeros((0, 5)), np.zeros((0, 3)))

    @classmethod
    def from_features(cls, frame: dict) -> Observations:
        """From a features-file frame (stages.common.features_file.FeaturesFile.frame)."""

        def arr(key, cols):
            a = frame.get(key)
            if a is None:
                return np.zeros((0, cols))
            return np.asarray(a, dtype=float).reshape(-1, cols)

        lines = arr("lines", 4)
        ends = frame.get("line_ends")
        ends = None if ends is None else np.asarray(ends, dtype=float).reshape(-1, 4)
        if ends is not None and len(ends) != len(lines):
            ends = None
        view = frame.get("view")
        view = None if view is None else np.asarray(view, dtype=float).reshape(-1, 2)
        return cls(lines, ends, arr("crossings", 5), arr("posts", 3), view)

    def __len__(self) -> int:
        return len(self.lines) + len(self.crossings) + len(self.posts)

    def to_features(self) -> dict[str, np.ndarray]:
        """The per-frame datasets of a features file (stages.common.features_file)."""
        out = {"lines": self.lines.reshape(-1, 4), "crossings": self.crossings.reshape(-1, 5),
               "posts": self.posts.reshape(-1, 3)}
        if self.line_ends is not None:
            out["line_ends"] = self.line_ends.reshape(-1, 4)
        if self.view is not None:
            out["view"] = self.view.reshape(-1, 2)
        return out

    def select(self, lines: bool = True, crossings: bool = True, posts: bool = True):
        """A copy holding only the chosen kinds of observation."""
        e = Observations.empty()
        return Observations(
            self.lines if lines else e.lines,
            self.line_ends if lines else None,
            self.crossings if crossings else e.crossings,
            self.posts if posts else e.posts,
            self.view,
        )

    def finite(self) -> Observations:
        """Without rows holding NaN or infinite values."""
        ok_l = np.all(np.isfinite(self.lines), axis=1)
        ends = self.line_ends
        if ends is not None:
            ok_l &= np.all(np.isfinite(ends), axis=1)
            ends = ends[ok_l]
        return Observations(
            self.lines[ok_l], ends,
            self.crossings[np.all(np.isfinite(self.crossings), axis=1)],
            self.posts[np.all(np.isfinite(self.posts), axis=1)],
            self.view,
        )
