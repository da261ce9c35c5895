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
        fm = self.field
        points = np.asarray(points, float).reshape(-1, 2)
        hx, hy = fm.length / 2, fm.width / 2
        grid = np.stack(np.meshgrid(np.arange(-hx, hx + 1e-9, 0.35),
                                    np.arange(-hy, hy + 1e-9, 0.35),
                                    np.radians(np.arange(0, 360, 6)), indexing="ij"),
                        axis=-1).reshape(-1, 3)
        rng = np.random.default_rng(seed)
        few = points[rng.permutation(len(points))[:80]]
        coarse = np.concatenate([self.share_near(few, grid[k:k + 8000], 0.3)
                                 for k in range(0, len(grid), 8000)])
        d = np.arange(-0.18, 0.181, 0.045)
        local = np.stack(np.meshgrid(d, d, np.radians(np.arange(-3, 3.1, 1.5)),
                                     indexing="ij"), axis=-1).reshape(-1, 3)
        best = (-1.0, None)
        for p in grid[np.argsort(-coarse)[:12]]:
            s = self.share_near(points, p + local, near)
            k = int(np.argmax(s))
            if s[k] > best[0]:
                best = (float(s[k]), p + local[k])
        return best

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
