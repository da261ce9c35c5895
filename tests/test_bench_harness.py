"""The bench harness's judgement of a method's confidence (stages.pipelines.bench.harness)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from stages.pipelines.bench import harness


def _frames(confidence, top_error):
    n = len(confidence)
    return SimpleNamespace(matched=np.ones(n, bool), failed=np.zeros(n, bool),
                           confidence=np.asarray(confidence, float),
                           top_error=np.asarray(top_error, float),
                           accepted=np.asarray(confidence, float) >= 0.8,
                           position_error=np.asarray(top_error, float)), None


def test_a_run_without_a_miss_is_judged_by_its_reliability(monkeypatch):
    """Every top pose within 40 cm: the AUROC is undefined and nothing is left to rank
    (ranks_well, as the walk rows judge it), so the calibration row rests on its bins; one
    confident miss ranked above the hits fails it."""
    hits = _frames(np.full(40, 0.99), np.full(40, 0.05))
    monkeypatch.setattr(harness, "run_errors", lambda out, data: hits)
    row = harness.calibration_rows("mcl", [("a", "b")], "test", 1.0)[0]
    assert np.isnan(row.extra["auroc"]) and row.meets_goal
    conf = np.r_[np.full(39, 0.9), 0.99]
    miss = _frames(conf, np.r_[np.full(39, 0.05), 2.0])
    monkeypatch.setattr(harness, "run_errors", lambda out, data: miss)
    row = harness.calibration_rows("mcl", [("a", "b")], "test", 1.0)[0]
    assert row.extra["auroc"] < 0.95 and not row.meets_goal
