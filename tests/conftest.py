import importlib
import os
import signal
from pathlib import Path

import pytest
from exact_comparisons import GUARDED, guarded
from hypothesis import settings

# Property tests draw their examples from a fixed seed, so a run is reproducible on any machine
# (every random choice takes a seed); FIELDLOC_HYPOTHESIS=explore draws fresh examples each run
# to search for new counterexamples.
settings.register_profile("reproducible", derandomize=True)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("FIELDLOC_HYPOTHESIS", "reproducible"))

REALDATA = Path(__file__).resolve().parents[2] / "shared" / "realdata"

# The tests of interrupts send SIGINT to fieldloc (in this process or a child) and expect
# Python's KeyboardInterrupt. A shell that starts a job in the background without job control
# (`make test &` in a script, nohup) starts it with SIGINT ignored, which the children inherit,
# and Python then installs no handler: nine such tests failed that way. Ignoring SIGINT is the
# launcher's wish for itself, not a condition of the product under test.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture(scope="session", autouse=True)
def no_bit_for_bit_float_comparisons():
    """numpy's exact comparisons (np.array_equal, np.array_equiv,
    np.testing.assert_array_equal, np.testing.assert_equal), when a test module calls them,
    fail on floating-point values that are not integers unless the call is marked
    ``# exact same-run: ...`` (tests/exact_comparisons.py states the rule and why)."""
    with pytest.MonkeyPatch.context() as mp:
        for module, name in GUARDED:
            mod = importlib.import_module(module)
            mp.setattr(mod, name, guarded(getattr(mod, name), f"{module}.{name}"))
        yield


@pytest.fixture(scope="session")
def msl2015_map(tmp_path_factory):
    """The default msl-2015 map, built once per test session."""
    from stages import build_map

    out = tmp_path_factory.mktemp("maps") / "msl-2015.map.h5"
    return build_map.main(None, "msl-2015", out)


@pytest.fixture(scope="session")
def omni_default_rendered(tmp_path_factory):
    """40 rendered omni-default frames of msl-2015, seed 3 (a busy lab field: other robots,
    clutter, lighting changes, a team's imperfect calibration, odometry slip, IMU bias and
    collisions) and their features, once per session: (dataset folder, features.h5). Tests
    read them and write elsewhere."""
    import copy

    from stages import extract, simulate

    conf = copy.deepcopy(simulate.confs["omni-default"])
    conf.update(frames=40, seed=3)
    ds = simulate.main(conf, "msl-2015", tmp_path_factory.mktemp("sim") / "omni")
    return ds, extract.main(None, ds, ds / "features.h5")


@pytest.fixture(scope="session")
def hulks_extracted(tmp_path_factory):
    """The HULKs folder (realdata/hulks-goalbox-labels) imported and extracted by the CLI with
    its defaults, once per session: (dataset folder, features.h5)."""
    from click.testing import CliRunner

    from fieldloc_cli.main import cli

    data = tmp_path_factory.mktemp("hulks") / "hulks"
    runner = CliRunner()
    res = runner.invoke(cli, ["-q", "calibrate", "perspective", "--from-hulks",
                              str(REALDATA / "hulks-goalbox-labels" / "measurements"),
                              "-o", str(data)])
    assert res.exit_code == 0, res.output
    res = runner.invoke(cli, ["-q", "extract", str(data)])
    assert res.exit_code == 0, res.output
    return data, data / "features.h5"


@pytest.fixture(scope="session")
def small_omni_run(tmp_path_factory):
    """A 2-frame omni dataset on spl (omni-clean, seed 1813), its features, a coarse (0.5 m)
    map and lut's poses: inputs of the tests of outputs and faults, which only read them."""
    from stages import build_map, extract, localize, simulate

    root = tmp_path_factory.mktemp("small-omni-run")
    ds = simulate.main(dict(simulate.confs["omni-clean"], frames=2, seed=1813), "spl",
                       root / "omni")
    feats = extract.main(None, ds, root / "omni.f.h5")
    mp = build_map.main({"resolution": 0.5}, "spl", root / "spl.map.h5")
    poses = localize.main({"method": "lut"}, ds, mp, root / "p.h5", features=feats)
    return {"root": root, "ds": ds, "features": feats, "map": mp, "poses": poses}
