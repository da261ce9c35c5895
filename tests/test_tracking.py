"""The belief every pose-fixing method shares (stages.localize.tracking): hand-computable
posteriors, the mirror listing, fusion only of fixes that beat the null, failed frames."""

import math
from types import SimpleNamespace

import numpy as np
import pytest

from stages.common.errors import FieldlocError
from stages.localize import tracking
from stages.localize.tracking import Candidate, TrackBank


def _bank(symmetric=True, **over):
    conf = {**tracking.DEFAULTS, **over}
    # a 10 x 10 m world of 1 m basins: log_basins = log 100
    return TrackBank(conf, area=100.0, reach=1.0, reach_cells=441, symmetric=symmetric)


def _cand(x, y, th, nll, log_prior, track=None, mirror=0.0):
    fix = SimpleNamespace(pose=np.array([x, y, th], float), mode="global")
    return Candidate(fix=fix, R=np.diag([0.01**2, 0.01**2, 0.01**2]), log_prior=log_prior,
                     nll=nll, track=track, mirror=mirror)


def test_global_posterior_against_hand_computed_values():
    """Two candidates and elsewhere: p_k = exp(lp_k - nll_k) / Z with elsewhere's term the
    null's likelihood over one basin, exactly as the module doc states."""
    bank = _bank(symmetric=False)
    op = bank.other_prior()
    assert op == 0.0  # no track yet: all the mass is elsewhere
    lp = bank.global_log_prior(op)
    assert lp == pytest.approx(-math.log(100.0))
    a, b = _cand(1, 1, 0, 10.0, lp), _cand(-3, 2, 1, 12.0, lp)
    other = bank.posterior([], [a, b], op, null_nll=30.0)
    terms = np.array([lp - 10.0, lp - 12.0, -math.log(100.0) - 30.0])
    p = np.exp(terms) / np.exp(terms).sum()
    assert math.exp(a.log_post) == pytest.approx(p[0])
    assert math.exp(b.log_post) == pytest.approx(p[1])
    assert math.exp(other) == pytest.approx(p[2])


def test_a_frame_chance_explains_as_well_gets_a_low_confidence():
    bank = _bank(symmetric=False)
    lp = bank.global_log_prior(bank.other_prior())
    c = _cand(1, 1, 0, 20.0, lp)
    bank.posterior([], [c], 0.0, null_nll=20.0)  # the best pose is as good as chance
    assert math.exp(c.log_post) == pytest.approx(0.5)
    top = bank.update(0, [c], math.log(0.5), 0.1, None, False)
    hyps = bank.hypotheses()
    pose, _cov, confidence, accepted = bank.conclude(hyps, top, False, flags := [])
    assert confidence == pytest.approx(0.5) and not accepted and "low-confidence" in flags
    np.testing.assert_allclose(pose, [1, 1, 0])


def test_the_top_mirror_is_always_listed_on_a_symmetric_field():
    bank = _bank(symmetric=True, hypotheses=2)
    lp = bank.global_log_prior(0.0)
    cands = [_cand(1, 1, 0, 1.0, lp, mirror=0.25), _cand(3, -2, 0.5, 1.5, lp),
             _cand(-4, 0, 2.0, 1.6, lp)]
    other = bank.posterior([], cands, 0.0, null_nll=50.0)
    bank.update(0, cands, other, 0.1, None, False)
    hyps = bank.hypotheses()
    assert len(hyps) == 2
    np.testing.assert_allclose(hyps[0, :3], [1, 1, 0])
    np.testing.assert_allclose(hyps[1, :3], [-1, -1, -math.pi], atol=1e-12)
    w = math.exp(cands[0].log_post)
    assert hyps[0, 3] == pytest.approx(0.75 * w) and hyps[1, 3] == pytest.approx(0.25 * w)


def test_a_mirror_pair_is_confident_as_one_belief():
    """A pose and its mirror image sharing a track's weight half and half: neither
    hypothesis reaches min_confidence, the pair does (TrackBank.confident); without a mirror
    share the pair is the top hypothesis. finish_global without a field-aligned heading
    gives every new candidate its mirror's equal share, searched or not."""
    bank = _bank(symmetric=True)
    lp = bank.global_log_prior(0.0)
    cands = [_cand(1, 1, 0, 1.0, lp), _cand(3, -2, 0.5, 9.0, lp)]
    bank.finish_global(cands, heading_known=False)
    assert [c.mirror for c in cands] == [0.5, 0.5]
    other = bank.posterior([], cands, 0.0, null_nll=50.0)
    top = bank.update(0, cands, other, 0.1, None, False)
    hyps = bank.hypotheses()
    _pose, _cov, confidence, accepted = bank.conclude(hyps, top, False, [])
    assert confidence < 0.5 and not accepted
    assert bank.confident() and math.exp(bank.tracks[0].log_weight) > 0.99
    single = _bank(symmetric=True)
    c = [_cand(1, 1, 0, 1.0, lp), _cand(3, -2, 0.5, 1.2, lp)]
    single.finish_global(c, heading_known=True)
    assert [x.mirror for x in c] == [0.0, 0.0]
    single.update(0, c, single.posterior([], c, 0.0, null_nll=50.0), 0.1, None, False)
    assert not single.confident()  # 0.55 / 0.45: neither reaches 0.8


def test_a_tracked_fix_that_does_not_beat_the_null_is_not_fused():
    bank = _bank(symmetric=False, fusion={"enabled": False})
    lp = bank.global_log_prior(0.0)
    c = _cand(0, 0, 0, 1.0, lp)
    bank.update(0, [c], bank.posterior([], [c], 0.0, 40.0), 0.1, None, False)
    t = bank.tracks[0]
    odo = np.array([0.5, 0.0, 0.0])
    prior, _cov = bank.prior(t, 0.1, odo, False)
    np.testing.assert_allclose(prior, [0.5, 0, 0])  # moved by the odometry
    fix = _cand(0.6, 0.1, 0.0, 1.0, bank.tracked_log_prior(t, np.array([0.1, 0.1]), _cov,
                                                           c.R), track=t)
    fix.beats_null = False
    bank.update(1, [fix], bank.posterior([fix], [], bank.other_prior(), None), 0.1, odo,
                False)
    # without fusion the track keeps its last pose when the fix is not used, and counts a miss
    np.testing.assert_allclose(bank.tracks[0].pose, [0, 0, 0])
    assert bank.tracks[0].misses == 1
    fix.beats_null = True
    bank.update(2, [fix], bank.posterior([fix], [], bank.other_prior(), None), 0.1, odo,
                False)
    np.testing.assert_allclose(bank.tracks[0].pose, [0.6, 0.1, 0.0])


def test_failed_frames_predict_then_drop_the_tracks():
    bank = _bank(symmetric=False)
    bank.max_predicted_frames = 2  # (tracking.MAX_PREDICTED_FRAMES: 30)
    lp = bank.global_log_prior(0.0)
    c = _cand(0, 0, 0, 1.0, lp)
    bank.update(0, [c], bank.posterior([], [c], 0.0, 40.0), 0.1, None, False)
    odo = np.array([0.2, 0.0, 0.0])
    bank.failed(0.1, odo, False)
    bank.failed(0.1, odo, False)
    assert len(bank.tracks) == 1 and bank.tracks[0].pose[0] > 0.3  # predicted twice
    bank.failed(0.1, odo, False)
    assert bank.tracks == [] and bank.other == 1.0


def test_start_half_moves_a_candidate_onto_the_stated_half():
    bank = _bank(symmetric=True)
    c = _cand(2.0, 1.0, 0.3, 5.0, 0.0, mirror=0.5)
    moved_to = []

    def mirrored(cand, pose):
        moved_to.append(pose)
        cand.fix = SimpleNamespace(pose=np.asarray(pose, float), mode="global")

    assert bank.start_half(c, "own", 1e-3, mirrored)  # own half: x < 0
    np.testing.assert_allclose(moved_to[0][:2], [-2.0, -1.0])
    assert c.mirror == pytest.approx(1e-3 / (1 + 1e-3))
    c2 = _cand(-2.0, 1.0, 0.3, 5.0, 0.0, mirror=0.5)
    assert not bank.start_half(c2, "own", 1e-3, mirrored)


def test_fold_adds_duplicates_and_mirrors_to_a_better_candidate():
    bank = _bank(symmetric=True)
    out = [_cand(1, 1, 0, 2.0, 0.0)]
    assert bank.fold(out, np.array([1.1, 1.0, 0.05]), 3.0)  # the same basin
    assert out[0].own_mass == pytest.approx(1 + math.exp(-1.0))
    assert bank.fold(out, np.array([-1.0, -1.0, math.pi]), 2.0)  # its mirror image
    assert out[0].mirror_mass == pytest.approx(1.0)
    assert not bank.fold(out, np.array([4.0, 1.0, 0.0]), 2.0)
    bank.finish_global(out, heading_known=True)
    assert out[0].mirror == pytest.approx(1.0 / (2 + math.exp(-1.0)))


def test_bad_bank_keys_are_one_clear_error():
    with pytest.raises(FieldlocError, match="min_confidence"):
        tracking.check_conf({**tracking.DEFAULTS, "min_confidence": 1.5})
    with pytest.raises(FieldlocError, match="hypotheses"):
        tracking.check_conf({**tracking.DEFAULTS, "hypotheses": 0})
