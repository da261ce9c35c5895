from pathlib import Path

import pytest

REALDATA = Path(__file__).resolve().parents[2] / "shared" / "realdata"


@pytest.fixture(scope="session")
def msl2015_map(tmp_path_factory):
    """The default msl-2015 map, built once per test session."""
    from stages import build_map

    out = tmp_path_factory.mktemp("maps") / "msl-2015.map.h5"
    return build_map.main(None, "msl-2015", out)
