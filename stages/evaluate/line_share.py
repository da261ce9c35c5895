"""Judging a pose on real images without ground truth: the share of a frame's line points
that lie within ``near`` (15 cm) of a field line at the pose, beside the share that random-
bearing copies of the same points reach at their best pose (the null baseline: with few
points, or points at a few ranges, a share of 0.5 or more comes by chance).

``LineRaster`` holds the distance to the nearest line on a 2 cm raster of the world, to score
many poses at once; ``best_pose`` is an exhaustive search (a coarse grid of positions and
headings, then a local refinement of the best) that maximises the share itself. It is the
independent judge the real-data checks compare the localisers with: it shares no code with
them but the field model.
"""

from __future__ import annotations

import numpy as np

from ..common.field import FieldModel
from ..common.geometry import wrap_scalar


class LineRaster:
    """Distance to the nearest line centre line on a raster of the world."""

    def __init__(self, fm: FieldModel, res: float = 0.02, margin: float = 3.0):
        xmin, xmax, ymin, ymax = fm.world_bounds(margin)
        xs, ys = np.arange(xmin, xmax, res), np.arange(ymin, ymax, res)
        self.dist = fm.distance_to_lines(np.stack(np.meshgrid(xs, ys), axis=-1))
        self.origin, self.res = (xmin, ymin), res
        self.field = fm

    def share_near(self, points, poses, near: float) -> np.ndarray:
        """Per pose (M, 3), the share of robot-frame points (N, 2) within ``near`` of a
        line."""
        poses = np.asarray(poses, float).reshape(-1, 3)
        c, s = np.cos(poses[:, 2:3]), np.sin(poses[:, 2:3])
        fx = poses[:, :1] + c * points[None, :, 0] - s * points[None, :, 1]
        fy = poses[:, 1:2] + s * points[None, :, 0] + c * points[None, :, 1]
        j = np.clip(((fx - self.origin[0]) / self.res).astype(int), 0, self.dist.shape[1] - 1)
        i = np.clip(((fy - self.origin[1]) / self.res).astype(int), 0, self.dist.shape[0] - 1)
        return (self.dist[i, j] <= near).mean(axis=1)

    def best_pose(self, points, near: float = 0.15, seed: int = 0):
        """(share, pose) of the pose on the field that puts the largest share of points
        within ``near`` of a line: a coarse grid (0.35 m, 6 deg, scored with 0.3 m on at most
        80 of the points), then a local refinement of the 12 best with all points."""
        return self._refined(points, near, seed, 12)[0]

    def _refined(self, points, near: float, seed: int, k: int) -> list:
        """The ``k`` best poses of the coarse grid (best_pose), each refined locally with all
        points: [(share, pose)], best first."""
        fm = self.field
        points = np.asarray(points, float).reshape(-1, 2)
        hx, hy = fm.length / 2, fm.width / 2
        grid = np.stack(np.meshgrid(np.arange(-hx, hx + 1e-9, 0.35),
                                    np.arange(-hy, hy + 1e-9, 0.35),
                                    np.radians(np.arange(0, 360, 6)), indexing="ij"),
                        axis=-1).reshape(-1, 3)
        rng = np.random.default_rng(seed)
        few = points[rng.permutation(len(points))[:80]]
        coarse = np.concatenate([self.share_near(few, grid[j:j + 8000], 0.3)
                                 for j in range(0, len(grid), 8000)])
        d = np.arange(-0.18, 0.181, 0.045)
        local = np.stack(np.meshgrid(d, d, np.radians(np.arange(-3, 3.1, 1.5)),
                                     indexing="ij"), axis=-1).reshape(-1, 3)
        out = []
        for p in grid[np.argsort(-coarse)[:k]]:
            s = self.share_near(points, p + local, near)
            j = int(np.argmax(s))
            out.append((float(s[j]), p + local[j]))
        out.sort(key=lambda e: -e[0])  # stable: of equal shares the coarse grid's order
        return out

    def rivals(self, points, best, near: float = 0.15, within: float = 0.03,
               apart: float = 0.5, apart_rad: float = np.radians(10.0), seed: int = 0,
               k: int = 200) -> list:
        """Poses that explain the points about as well as ``best`` (share, pose) does
        elsewhere: the 200 best coarse poses refined (best_pose's search, wider), those
        within ``within`` of its share and more than ``apart`` m or ``apart_rad`` from it, from
        its mirror image and from each other ([(share, pose)], best first). When the list is
        not empty the best pose is not what the points decide, only one of a few."""
        fm = self.field

        def far(a, b):
            return (np.hypot(a[0] - b[0], a[1] - b[1]) > apart
                    or abs(wrap_scalar(a[2] - b[2])) > apart_rad)

        share, pose = best
        out: list = []
        for s, q in self._refined(points, near, seed, k):
            if s < share - within:
                break
            if all(far(q, r) and far(q, fm.mirror_pose(r)) for r in [pose] + [r for _, r in out]):
                out.append((s, q))
        return out

    def null_share(self, points, copies: int = 3, near: float = 0.15, seed: int = 0) -> float:
        """The null baseline: the mean best share of ``copies`` copies of the points at
        random bearings (each point keeps its range)."""
        points = np.asarray(points, float).reshape(-1, 2)
        rng = np.random.default_rng(seed)
        rho = np.hypot(points[:, 0], points[:, 1])
        out = []
        for _ in range(copies):
            b = rng.uniform(0, 2 * np.pi, len(points))
            out.append(self.best_pose(np.stack([rho * np.cos(b), rho * np.sin(b)], axis=1),
                                      near, seed)[0])
        return float(np.mean(out))
