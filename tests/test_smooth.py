"""The whole-recording smoother (stages/localize/smooth.py, pose_graph.py): the discrete pass
against an enumeration of every path, the transition model's properties, the pose graph on
chains whose answer is known, and `fieldloc localize --smooth` on a rendered run."""

from __future__ import annotations

import math

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st

from fieldloc_cli.main import cli
from stages.common.geometry import compose, inverse
from stages.common.poses_file import read_poses
from stages.localize import smooth
from stages.localize.pose_graph import refine_path
from tests.oracles.hmm_paths import enumerate_paths

MODEL = smooth.Transition.of(1e-3, 100.0)


def _cands(poses, nll, sigma=0.05):
    poses = np.asarray(poses, float).reshape(-1, 3)
    cov = np.tile(np.diag([sigma**2, sigma**2, 0.01**2]), (len(poses), 1, 1))
    return smooth.FrameCandidates(poses, np.asarray(nll, float), cov, np.zeros(len(poses)))


def _motion(n, step=(0.1, 0.0, 0.0), sigma=0.01):
    inc = np.tile(np.asarray(step, float), (n, 1))
    inc[0] = 0.0
    cov = np.tile(np.diag([sigma**2, sigma**2, 0.005**2]), (n, 1, 1))
    return smooth.Motion(inc, cov)


@settings(max_examples=40, deadline=None)
@given(st.integers(2, 4), st.data())
def test_discrete_pass_matches_the_enumeration_of_every_path(n, data):
    """Forward-backward's marginals equal those of every path enumerated (within 1e-9), and
    Viterbi's path is the most probable one wherever it beats the runner-up by 1e-6 nats."""
    rng = np.random.default_rng(data.draw(st.integers(0, 2**16)))
    sets = []
    for _t in range(n):
        k = data.draw(st.integers(1, 3))
        poses = np.column_stack([rng.uniform(-1, 1, k), rng.uniform(-1, 1, k),
                                 rng.uniform(-0.2, 0.2, k)])
        sets.append(_cands(poses, rng.uniform(0, 3, k), sigma=rng.uniform(0.02, 0.3)))
    motion = _motion(n, step=(0.05, 0.0, 0.0), sigma=0.2)
    frames = list(range(n))
    p = smooth.discrete_pass(frames, sets, motion, MODEL)
    trans = [smooth.transition_log(sets[t - 1], sets[t], motion.between(t - 1, t), MODEL)
             for t in range(1, n)]
    marg, best, lp_best, lp_second = enumerate_paths([-s.nll for s in sets], trans)
    for t in range(n):
        np.testing.assert_allclose(p.posterior[t], marg[t], atol=1e-9)
    if lp_best - lp_second > 1e-6:
        assert tuple(p.path) == tuple(best)


def test_transition_prefers_the_odometry_and_never_falls_below_the_floor():
    """A candidate where the odometry moves the previous one is likelier than one 0.5 m off,
    which is likelier than one 5 m off; none is below the outlier floor (a kidnap anywhere)."""
    a = _cands([[0.0, 0.0, 0.0]], [0.0])
    b = _cands([[0.1, 0.0, 0.0], [0.1, 0.5, 0.0], [5.1, 0.0, 0.0]], [0.0, 0.0, 0.0])
    motion = _motion(2)
    t = smooth.transition_log(a, b, motion.between(0, 1), MODEL)[0]
    assert t[0] > t[1] > t[2]
    assert np.all(t >= MODEL.log_outlier - 1e-9)
    assert t[2] == pytest.approx(np.logaddexp(MODEL.log_outlier, -np.inf), abs=1e-3)


def test_a_run_of_evidence_overturns_a_better_first_frame():
    """Two places along a run: the first frame favours the wrong one by 3 nats, the next ten
    favour the right one by 1 nat each. The smoother puts the first frame at the right place
    too (the causal answer at frame 0 is the wrong one)."""
    n = 11
    motion = _motion(n)
    sets = []
    for t in range(n):
        right = [0.1 * t, 0.0, 0.0]
        wrong = [0.1 * t, 3.0, 0.0]
        nll = [3.0, 0.0] if t == 0 else [0.0, 1.0]
        sets.append(_cands([right, wrong], nll))
    p = smooth.discrete_pass(list(range(n)), sets, motion, MODEL)
    assert p.path[0] == 0 and np.all(p.path == 0)
    assert p.posterior[0][0] > 0.99


def test_pose_graph_follows_exact_fixes_and_bridges_gaps_by_odometry():
    """Fixes on a straight run with the odometry that joins them: the graph keeps them (1 mm);
    frames without a fix get the odometry's pose from their neighbours (1 mm) and a larger
    covariance than fixed frames."""
    n = 12
    motion = _motion(n, step=(0.1, 0.02, 0.03))
    truth = [np.zeros(3)]
    for i in range(1, n):
        truth.append(compose(truth[-1], motion.increments[i]))
    truth = np.array(truth) + np.array([1.0, -2.0, 0.0])
    fixes = truth.copy()
    fixes[4:7] = np.nan
    cov = np.tile(np.diag([0.03**2, 0.03**2, 0.01**2]), (n, 1, 1))
    poses, covs = refine_path(fixes, cov, motion)
    np.testing.assert_allclose(poses[:, :2], truth[:, :2], atol=1e-3)
    assert np.trace(covs[5, :2, :2]) > np.trace(covs[1, :2, :2])


def test_pose_graph_is_robust_to_one_wild_fix():
    """One fix 2 m off in a run of good ones moves that frame's pose by less than 0.3 m
    (a Gaussian prior would move it by about 1 m; Huber bounds its pull)."""
    n = 15
    motion = _motion(n)
    truth = np.array([[0.1 * i, 0.0, 0.0] for i in range(n)])
    fixes = truth.copy()
    fixes[7, 1] += 2.0
    cov = np.tile(np.diag([0.05**2, 0.05**2, 0.01**2]), (n, 1, 1))
    poses, _covs = refine_path(fixes, cov, motion)
    assert abs(poses[7, 1]) < 0.3
    assert np.max(np.abs(poses[[0, 14], 1])) < 0.05


class _LineScorer:
    """A straight run along x whose frames each fix one pose at the truth: tight (3 cm) on
    frames outside ``thin``, and on those only across the run (2 m along x, as a frame that
    sees a single line along the run)."""

    mirrored = False

    def __init__(self, truth, thin):
        self.truth, self.thin, self.frames = truth, thin, len(truth)

    def failed(self, i):
        return None

    def global_candidates(self, i):
        c = _cands([self.truth[i]], [0.0], sigma=0.03)
        if i in self.thin:
            c.cov[0, 0, 0] = 2.0**2
        return c

    def local_candidates(self, i, starts):
        c = self.global_candidates(i)
        k = len(starts)
        return smooth.FrameCandidates(np.repeat(c.poses, k, 0), np.repeat(c.nll, k),
                                      np.repeat(c.cov, k, 0), np.zeros(k), np.arange(k))


def test_a_pose_the_frames_pin_loosely_is_not_confident():
    """Ten frames in the middle of a run fix the pose only across it and the odometry slips
    0.2 m a frame: the one place is certain (posterior 1), the pose along the run is not. Their
    confidence falls below the frames pinned on both axes and never exceeds what the frame's
    marginal covariance allows within CONFIDENCE_RADIUS_M; the pinned frames stay sure."""
    from stages.common.poses_file import PoseTrack

    n = 30
    truth = np.array([[0.1 * i - 1.5, 0.5, 0.0] for i in range(n)])
    scorer = _LineScorer(truth, thin=set(range(10, 20)))
    causal = PoseTrack()
    for i in range(n):
        causal.add(f"{i:04d}", 0.1 * i, truth[i])
    out = smooth.smooth_track(scorer, causal, _motion(n, sigma=0.2),
                              {"min_confidence": 0.8, "hypotheses": 3},
                              kidnap_probability=1e-3, area=100.0)
    a = out.arrays()
    conf, cov = a["confidence"].astype(float), a["covariance"][:, :2, :2].astype(float)
    widest = np.linalg.eigvalsh(cov)[:, -1]  # float32 columns: compared to 1e-6
    assert np.all(conf <= 1.0 - np.exp(-smooth.CONFIDENCE_RADIUS_M**2 / (2 * widest)) + 1e-6)
    assert np.all(conf[[0, 1, 2, n - 3, n - 2, n - 1]] > 0.99)
    assert np.max(conf[13:17]) < 0.9 < np.min(conf[:5])
    np.testing.assert_allclose(a["hypotheses"][:, 0, 3], conf, rtol=1e-6)


class _LookAlikeScorer:
    """A straight run along x at y = 0 and a look-alike 3 m away (y = 3): frames 0-39 favour
    the look-alike by 1.5 nats each (a slight, repeated misfit, as a camera's calibration error
    gives), frames 40-59 see what only the truth explains (the look-alike 10 nats worse).
    The odometry joins each place to itself only."""

    mirrored = False
    frames = 60

    def failed(self, i):
        return None

    def global_candidates(self, i):
        x = 0.1 * i
        return _cands([[x, 0.0, 0.0], [x, 3.0, 0.0]], [1.5, 0.0] if i < 40 else [0.0, 10.0])

    def local_candidates(self, i, starts):
        g = self.global_candidates(i)
        k = np.argmin(np.abs(g.poses[None, :, 1] - np.asarray(starts)[:, None, 1]), axis=1)
        return smooth.FrameCandidates(g.poses[k], g.nll[k], g.cov[k], g.error[k],
                                      np.arange(len(starts)))


def _look_alike_path(temperature):
    scorer = _LookAlikeScorer()
    model = smooth.Transition.of(1e-5, 100.0)
    motion = _motion(scorer.frames)
    frames, sets = smooth.candidate_sets(scorer, motion, model, temperature=temperature)
    p = smooth.discrete_pass(frames, sets, motion, model)
    return np.array([sets[k].poses[p.path[k], 1] for k in range(len(frames))])


def test_correlated_frames_do_not_outvote_the_odometry():
    """Forty frames that each favour a look-alike by 1.5 nats (60 nats in all) against a
    jump of about 24 nats: counted as independent they hold the look-alike until the truth's
    frames make the path jump; counted as one frame in eight (evidence_temperature), the path
    stays at the truth, which the odometry joins to the frames that decide."""
    assert np.all(np.abs(_look_alike_path(1.0)[:40] - 3.0) < 0.5)  # the look-alike
    assert np.all(np.abs(_look_alike_path(8.0)) < 0.5)  # the truth, on every frame


@settings(max_examples=60, deadline=None)
@given(st.floats(0.01, 1.0), st.floats(0.0, 3.0), st.floats(0.1, 10.0),
       st.integers(2, 50))
def test_evidence_temperature_counts_frames_of_the_correlation_time(dt, corr, scale, n):
    """T is at least 1, grows with the correlation time, and depends on time only through
    the ratio of the correlation time to the frame interval (the same recording at another
    time unit: stamps and correlation time scaled alike)."""
    stamps = dt * np.arange(n)
    t = smooth.evidence_temperature(stamps, corr)
    assert t >= 1.0
    assert smooth.evidence_temperature(stamps, corr + 0.5) >= t
    assert smooth.evidence_temperature(scale * stamps, scale * corr) == pytest.approx(t)
    assert smooth.evidence_temperature(stamps, 0.0) == pytest.approx(1.0)


def _errors(path, truth_csv):
    cols, _attrs = read_poses(path)
    t = np.loadtxt(truth_csv, delimiter=",", skiprows=1)
    idx = np.clip(np.searchsorted(t[:, 0], cols["stamp"] - 0.01), 0, len(t) - 1)
    return np.hypot(cols["x"] - t[idx, 1], cols["y"] - t[idx, 2]), cols


@pytest.fixture(scope="module")
def wrong_first_fix(tmp_path_factory):
    """30 rendered omni-default frames of msl-2015, seed 1 (a tuning seed): the causal lut
    and fit put the first frames at a look-alike place (lut 77 %, fit 63 % within 40 cm,
    fit 10 frames accepted and more than 1 m off)."""
    import copy

    from stages import extract, simulate

    conf = copy.deepcopy(simulate.confs["omni-default"])
    conf.update(frames=30, seed=1)
    ds = simulate.main(conf, "msl-2015", tmp_path_factory.mktemp("sim") / "omni")
    return ds, extract.main(None, ds, ds / "features.h5")


@pytest.mark.parametrize("method", ["lut", "fit"])
def test_localize_smooth_through_the_cli(wrong_first_fix, msl2015_map, tmp_path, method):
    """`fieldloc localize --smooth` on a run whose causal first fix is wrong: every frame
    smoothed, confidences in [0, 1], the smoothing's costs in the method report; at least 95 %
    of the frames within 40 cm where the causal run has fewer than 90 %, and no accepted frame
    more than 1 m off."""
    ds, feats = wrong_first_fix
    runner = CliRunner()
    out = {}
    for tag, extra in (("causal", []), ("smoothed", ["--smooth"])):
        out[tag] = tmp_path / f"{tag}.h5"
        r = runner.invoke(cli, ["-q", "localize", str(ds), "--map", str(msl2015_map),
                                "--features", str(feats), "--method", method,
                                "-o", str(out[tag]), *extra])
        assert r.exit_code == 0, r.output
    e_c, _c = _errors(out["causal"], ds / "truth.csv")
    e_s, cols = _errors(out["smoothed"], ds / "truth.csv")
    assert np.mean(e_c <= 0.4) < 0.9  # the case: the causal run is wrong for a while
    assert not cols["failed"].any()
    assert set(cols["mode"]) == {"smoothed"}
    assert np.all((cols["confidence"] >= 0) & (cols["confidence"] <= 1))
    assert np.mean(e_s <= 0.4) >= 0.95
    assert not np.any(cols["accepted"] & (e_s > 1.0))
    _cols, attrs = read_poses(out["smoothed"])
    assert "smoothing" in attrs["method_report"]


@pytest.mark.parametrize("method", ["lut", "fit"])
def test_smooth_with_the_histogram_heading_through_the_cli(omni_default_rendered, msl2015_map,
                                                           tmp_path, method):
    """`--heading histogram --smooth`: the heading says nothing of the field's 180 deg turn,
    so the smoother fixes each global candidate's mirror image too; every frame is smoothed
    and no accepted frame is more than 1 m off, up to the mirror (a traceback before: the
    mirror of a candidate was taken with the pose's numbers as separate arguments)."""
    ds, feats = omni_default_rendered
    out = tmp_path / "p.h5"
    r = CliRunner().invoke(cli, ["-q", "localize", str(ds), "--map", str(msl2015_map),
                                 "--features", str(feats), "--method", method, "--heading",
                                 "histogram", "--smooth", "-c", "recalibrate=false",
                                 "-o", str(out)])
    assert r.exit_code == 0, r.output
    e, cols = _errors(out, ds / "truth.csv")
    t = np.loadtxt(ds / "truth.csv", delimiter=",", skiprows=1)
    idx = np.clip(np.searchsorted(t[:, 0], cols["stamp"] - 0.01), 0, len(t) - 1)
    mirrored = np.hypot(cols["x"] + t[idx, 1], cols["y"] + t[idx, 2])
    assert set(cols["mode"]) <= {"smoothed", "failed"}
    assert not np.any(cols["accepted_up_to_mirror"] & (np.minimum(e, mirrored) > 1.0))


def test_smooth_is_refused_where_it_does_not_apply(omni_default_rendered, msl2015_map, tmp_path):
    """--smooth with --independent (frames on their own), and a smooth value that is not a
    bool, are one line each and a non-zero exit."""
    ds, feats = omni_default_rendered
    runner = CliRunner()
    r = runner.invoke(cli, ["localize", str(ds), "--map", str(msl2015_map), "--features",
                            str(feats), "--smooth", "--independent", "-o", str(tmp_path / "p.h5")])
    assert r.exit_code != 0 and "does not localise frames independently" in r.output
    assert len(r.output.strip().splitlines()) == 1
    r = runner.invoke(cli, ["localize", str(ds), "--map", str(msl2015_map), "--features",
                            str(feats), "-c", "smooth=maybe", "-o", str(tmp_path / "q.h5")])
    assert r.exit_code != 0 and "'smooth' must be true or false" in r.output
    assert "Traceback" not in r.output


def test_batch_reads_a_smoothed_method_name(tmp_path):
    """A SPEC's method 'lut+smooth' is lut with smooth: true, named as written."""
    from stages.pipelines.batch_spec import read_spec

    spec = tmp_path / "spec.yaml"
    spec.write_text("field: msl-2015\ndatasets:\n  - name: a\n    simulate: {preset: omni-clean,"
                    " field: msl-2015, frames: 5, seed: 1}\nmethods:\n  - lut\n  - lut+smooth\n")
    s = read_spec(spec, tmp_path / "results")
    by_name = {m.name: m for m in s.methods}
    assert by_name["lut+smooth"].conf["smooth"] is True
    assert by_name["lut"].conf["smooth"] is False
    assert math.isfinite(len(by_name))


def test_write_calib_through_the_cli(wrong_first_fix, msl2015_map, tmp_path):
    """`localize --smooth --write-calib F`: F is an omni calib.yaml that reads back, records
    how it was made (method recording, the poses it came from) and differs from the
    dataset's; the dataset's own calib.yaml is refused as the output, unchanged."""
    import hashlib

    import yaml

    from stages.common.camera import OmniCamera

    ds, feats = wrong_first_fix
    own = ds / "calib.yaml"
    # exact bytes: the user's calib.yaml checked unchanged
    before = hashlib.sha256(own.read_bytes()).hexdigest()
    runner = CliRunner()
    out = tmp_path / "calib-recording.yaml"
    r = runner.invoke(cli, ["-q", "localize", str(ds), "--map", str(msl2015_map), "--features",
                            str(feats), "--smooth", "--write-calib", str(out),
                            "-o", str(tmp_path / "p.h5")])
    assert r.exit_code == 0, r.output
    new = yaml.safe_load(out.read_text())
    assert new["calibration"]["method"] == "recording"
    assert new["calibration"]["source"].endswith("p.h5")
    cam_new, cam_old = (OmniCamera.from_dict(c, "x") for c in
                        (new, yaml.safe_load(own.read_text())))
    r_px = np.linspace(60.0, 150.0, 10)
    assert np.max(np.abs(cam_new.distance_of_radius(r_px) - cam_old.distance_of_radius(r_px))
                  ) > 0.005
    r = runner.invoke(cli, ["localize", str(ds), "--map", str(msl2015_map), "--features",
                            str(feats), "--write-calib", str(own), "--overwrite",
                            "-o", str(tmp_path / "q.h5")])
    assert r.exit_code != 0 and "never written over" in r.output
    # exact bytes: the user's calib.yaml checked unchanged
    assert hashlib.sha256(own.read_bytes()).hexdigest() == before


@settings(max_examples=50, deadline=None)
@given(st.tuples(*[st.floats(-5, 5)] * 2, st.floats(-3.1, 3.1)),
       st.tuples(*[st.floats(-1, 1)] * 2, st.floats(-3.1, 3.1)))
def test_an_increment_and_its_inverse_cancel(pose, inc):
    """Moving a pose by an odometry increment and then by its inverse (how the smoother's
    backward beam, the pose graph's first poses and mcl's rivals go back in time) returns it,
    within 1e-9 m and rad."""
    back = compose(compose(np.array(pose), np.array(inc)), inverse(inc))
    np.testing.assert_allclose(back[:2], pose[:2], atol=1e-9)
    assert abs(float(np.angle(np.exp(1j * (back[2] - pose[2]))))) < 1e-9


def test_a_fix_along_a_line_stays_where_the_odometry_moved_its_start():
    """A fix metres uncertain along x and sure across (a frame that sees one line along x),
    0.8 m along and 0.05 m across its start: the candidate keeps the fix across the line
    (within 1 cm) and takes the start's place along it (within 5 cm); a fix sure to 2 cm in
    both directions moves less than 5 % of the way to its start (the start's spread is 10 cm:
    the gain 0.02^2 / (0.02^2 + 0.1^2) is 4 %)."""
    start = np.array([[1.0, 2.0, 0.3]])
    line = smooth.FrameCandidates(np.array([[1.8, 2.05, 0.3]]), np.zeros(1),
                                  np.diag([3.0**2, 0.02**2, 0.01**2])[None], np.zeros(1),
                                  start=np.zeros(1, int))
    step = (np.zeros(3), np.diag([0.01**2, 0.01**2, 0.005**2]))
    fused = smooth._fused(line, start, step)
    assert abs(fused.poses[0, 1] - 2.05) < 0.01
    assert abs(fused.poses[0, 0] - 1.0) < 0.05
    sure = smooth.FrameCandidates(line.poses.copy(), np.zeros(1),
                                  np.diag([0.02**2, 0.02**2, 0.01**2])[None], np.zeros(1),
                                  start=np.zeros(1, int))
    moved = smooth._fused(sure, start, step).poses[0, :2] - sure.poses[0, :2]
    assert np.hypot(*moved) < 0.05 * np.hypot(*(start[0, :2] - sure.poses[0, :2]))


def test_a_fix_follows_its_own_start_not_the_nearest():
    """Two starts 1 m apart on one line along x; the fix started from the second slid 0.9 m
    along the line to within 0.1 m of the first. It goes back along the line to its own start
    (within 5 cm), not to the nearer start."""
    starts = np.array([[1.0, 2.0, 0.3], [2.0, 2.0, 0.3]])
    fixes = smooth.FrameCandidates(np.array([[1.1, 2.02, 0.3]]), np.zeros(1),
                                   np.diag([3.0**2, 0.02**2, 0.01**2])[None], np.zeros(1),
                                   start=np.array([1]))
    step = (np.zeros(3), np.diag([0.01**2, 0.01**2, 0.005**2]))
    fused = smooth._fused(fixes, starts, step)
    assert abs(fused.poses[0, 0] - 2.0) < 0.05
    assert abs(fused.poses[0, 1] - 2.02) < 0.01


@settings(max_examples=60, deadline=None)
@given(st.floats(0.0, 2.5), st.floats(-0.5, 0.5), st.floats(0.03, 0.2))
def test_a_collision_loosens_the_odometry_but_is_no_free_walk(speed, turn, dt):
    """On a collision frame the odometry still says where the robot went, only less surely:
    its position noise grows by the fusion's process noise (model_xy per second, with the
    speed) and lies well below a random walk at max_speed over the same interval; its turn is
    free up to max_turn_rate. A frame with no odometry at all is that free walk."""
    from dataclasses import asdict

    from stages.localize.tracking import FUSION

    fusion = asdict(FUSION)
    step = speed * dt  # m/s over the frame interval: a robot's speed, below max_speed
    inc = np.array([[0.0, 0.0, 0.0], [step, 0.0, turn]] * 3)
    stamps = np.arange(6) * dt
    has = np.array([True, True, True, True, False, False])
    collision = np.array([False, False, True, True, False, True])
    m = smooth.motion_of(inc, has, stamps, fusion, collision)
    sxy = np.sqrt(m.cov[:, 0, 0])
    sth = np.sqrt(m.cov[:, 2, 2])
    free = fusion["max_speed"] * dt
    assert sxy[3] > sxy[1]  # a collision loosens the same increment
    assert sxy[3] <= 0.5 * free  # not a walk at max_speed
    assert sth[3] >= fusion["max_turn_rate"] * dt - 1e-9
    assert sxy[5] >= free - 1e-9 and sxy[4] >= free - 1e-9  # no odometry: the free walk
    assert np.all(np.isfinite(m.cov))
