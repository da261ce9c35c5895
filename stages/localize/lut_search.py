"""Pose search in the scan-line tables of Ribeiro et al. (2015), section IV-B: the table
search as lut, fit, the grid belief and the mirror calibration use it.

``TableSearch`` is built once per map and matching parameters and answers every frame. It
composes the parts of the search, each in its own module so that each can be read, tested and
timed alone:

- lut_matching.py: the error term of an observed crossing distance against the tables (the
  paper's eq. 5 with range weights), its parameters (``MatchingParams``) and a frame's
  observations (``Observation``, their evidence weights, their null copies);
- lut_tables.py: the map's data (``LutTables``): the tables in millimetres, the quantised
  errors, the min-pooled error lookup (mapped from the cache beside the map), and the errors
  and inliers of observations at a pose;
- lut_global.py: the searches over the whole field: a known heading's separated minima, the
  whole error surface, the search with no heading known;
- lut_local.py: the search in a window around a prior and the refinement every search ends
  with (sub-cell position, heading between table steps; ``SearchResult``);
- lut_tracked.py: a track's fix, its window ranked by the posterior, in one compiled call;
- lut_kernels.py: the numba kernels they all call.

The searches are functions of the tables: a frame's data passes through their arguments and
an Observation's own conversion for the kernels, never through the search's state, so one
TableSearch serves any number of frames, hypotheses and threads. ``TableSearch``'s methods
are those functions with its tables (``tables``) bound, and its attributes the tables'.
"""

from __future__ import annotations

import functools

import numpy as np

from ..common.map_file import MapFile
from . import lut_global, lut_local, lut_tracked
from .lut_local import SearchResult
from .lut_matching import (
    EVIDENCE,
    EvidenceTuning,
    MatchingParams,
    Observation,
    random_bearing_points,
)
from .lut_tables import LutTables, Support

__all__ = ["EVIDENCE", "EvidenceTuning", "MatchingParams", "Observation", "SearchResult",
           "Support", "TableSearch", "frame_observations", "random_bearing_points"]


def frame_observations(fr: dict, search: TableSearch, radial, evidence: EvidenceTuning
                       ) -> tuple[Observation, np.ndarray]:
    """A features frame's scan-line observations for the table search, and their distances
    as observed: the calibration's error removed when ``radial`` (a RadialCorrection or None)
    is active, then weighted as evidence (``evidence``: EvidenceTuning;
    Observation.with_evidence)."""
    sl = search.scanlines
    obs = Observation.from_scanlines(fr.get("radial", np.zeros((0, 4))), fr.get("spiral"),
                                     search.params, sl.max_range, sl.spiral_end_radius,
                                     sl.robot_radius)
    raw_distance = obs.distance
    if radial is not None and radial.active:
        d = radial.correct(raw_distance)
        obs = Observation(family=obs.family, angle_index=obs.angle_index, distance=d,
                          weight=search.params.weight(d), lookup_weight=obs.lookup_weight)
    obs = obs.with_evidence(sl, evidence.per_structure, evidence.link, evidence.link_per_m)
    return obs, raw_distance


class _OnTables:
    """A method of TableSearch: ``function`` with the search's tables as its first argument.
    Bound on first use (functools.partial) and kept on the instance, so that a call costs what
    a call of ``function`` does: the searches run several times a frame."""

    def __init__(self, function):
        self.function = function
        self.__doc__ = function.__doc__

    def __set_name__(self, owner, name: str):
        self.name = name

    def __get__(self, search, owner=None):
        if search is None:
            return self.function
        bound = search.__dict__[self.name] = functools.partial(self.function, search.tables)
        return bound


def _of_tables(name: str) -> property:
    """An attribute of TableSearch: the tables' ``name``."""
    return property(lambda self: getattr(self.tables, name), doc=f"LutTables.{name}")


class TableSearch:
    """The table search of a map (module doc): the map's tables (``tables``, a LutTables)
    and the searches over them. Build once per map and matching parameters; reuse over
    frames. The tables and the min-pooled lookup are mapped from their cache beside the map
    (lookup_cache) when they were built before, and written there otherwise; ``cache=False``
    builds them in memory only (``lookup_source`` says which happened to the min-pooled
    lookup)."""

    def __init__(self, map_file: MapFile, params: MatchingParams | None = None, *,
                 cache: bool = True):
        self.tables = t = LutTables(map_file, params, cache=cache)
        # the map's geometry and the matching parameters, as plain attributes: the callers
        # read them every frame
        self.params, self.grid, self.scanlines, self.field = t.params, t.grid, t.scanlines, t.field
        self.ny, self.nx, self.ncell = t.ny, t.nx, t.ncell
        self.n_angles, self.step, self.q_levels = t.n_angles, t.step, t.q_levels

    # the tables, the error lookup's layout and the errors at a pose (lut_tables)
    radial_table = _of_tables("radial_table")
    spiral_table = _of_tables("spiral_table")
    radial_mm = _of_tables("radial_mm")
    spiral_mm = _of_tables("spiral_mm")
    quantised = _of_tables("quantised")
    coarse_lookup = _of_tables("coarse_lookup")
    min_pooled = _of_tables("min_pooled")
    coarse_shape = _of_tables("coarse_shape")
    nb_radial = _of_tables("nb_radial")
    nb_spiral = _of_tables("nb_spiral")
    lookup_source = _of_tables("lookup_source")
    lookup_nbytes = _of_tables("lookup_nbytes")
    lookup_rows = _OnTables(LutTables.lookup_rows)
    exact_errors = _OnTables(LutTables.exact_errors)
    exact_error = _OnTables(LutTables.exact_error)
    exact_error_at_heading = _OnTables(LutTables.exact_error_at_heading)
    observation_errors = _OnTables(LutTables.observation_errors)
    observation_predictions = _OnTables(LutTables.observation_predictions)
    inliers = _OnTables(LutTables.inliers)
    support = _OnTables(LutTables.support)
    cell_of = _OnTables(LutTables.cell_of)

    # over the whole field (lut_global)
    global_search = _OnTables(lut_global.global_search)
    surface = _OnTables(lut_global.surface)
    separated_minima = _OnTables(lut_global.separated_minima)
    unknown_heading_search = _OnTables(lut_global.unknown_heading_search)

    # in a window around a prior, and the refinement (lut_local)
    local_search = _OnTables(lut_local.local_search)
    local_surface = _OnTables(lut_local.local_surface)
    local_window = _OnTables(lut_local.local_window)
    refine = _OnTables(lut_local.refine)
    refine_heading = _OnTables(lut_local.refine_heading)

    # a track's fix (lut_tracked)
    tracked_fix = _OnTables(lut_tracked.tracked_fix)
    tracked_score = _OnTables(lut_tracked.tracked_score)
    tracked_score_bound = _OnTables(lut_tracked.tracked_score_bound)
