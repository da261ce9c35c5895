"""Readable oracles of the field boundary's scans (numpy): the field's height per column
and the bounded white runs that fill_lines adds to the field."""

from __future__ import annotations

import numpy as np


def field_heights(field: np.ndarray, max_gap: int, from_lowest: bool) -> np.ndarray:
    """Per column, the rows from the bottom up to the first run of ``max_gap`` + 1 rows
    without field (cumulative sums of the empty rows); ``from_lowest``: every row above a
    column's lowest field cell counts as field."""
    h, w = field.shape
    run = max_gap + 1
    if from_lowest:
        at_or_below = np.logical_or.accumulate(field[::-1], axis=0)[::-1]
        field = field | (~at_or_below & field.any(axis=0)[None, :])
    empty = np.concatenate([~field[::-1], np.ones((run, w), bool)], axis=0)
    c = np.concatenate([np.zeros((1, w), np.int32), np.cumsum(empty, axis=0, dtype=np.int32)])
    return np.argmax((c[run:] - c[:-run]) == run, axis=0)


def bounded_runs(cand: np.ndarray, bound: np.ndarray, max_run: int) -> np.ndarray:
    """The runs of ``cand`` along each row, at most ``max_run`` long, with ``bound`` on both
    sides."""
    out = np.zeros(cand.shape, bool)
    for r in range(cand.shape[0]):
        row = np.concatenate([[False], cand[r], [False]]).astype(int)
        starts = np.nonzero(np.diff(row) == 1)[0]
        ends = np.nonzero(np.diff(row) == -1)[0]
        for s, e in zip(starts, ends):
            if e - s <= max_run and s > 0 and e < cand.shape[1] and bound[r, s - 1] \
                    and bound[r, e]:
                out[r, s:e] = True
    return out
