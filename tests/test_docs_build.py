"""The documentation site (mkdocs.yml over docs/) builds with ``mkdocs build --strict``: every
page in the navigation, no link to a missing page or anchor, and the CLI reference generated
from the click commands covers every command of ``fieldloc --help``."""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

_MISSING = [m for m in ("mkdocs", "material", "mkdocs_click")
            if importlib.util.find_spec(m) is None]
pytestmark = pytest.mark.skipif(
    bool(_MISSING),
    reason=f"the docs extra is not installed ({', '.join(_MISSING)} missing):"
           " pip install -e '.[docs]' (make install does)")


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("site")
    env = dict(os.environ, NO_MKDOCS_2_WARNING="1")
    r = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir",
                        str(out)], cwd=ROOT, env=env, capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, f"mkdocs build --strict failed:\n{r.stderr[-4000:]}"
    return out


def test_strict_build_has_every_page(site):
    pages = sorted(p.stem for p in (ROOT / "docs").glob("*.md"))
    for stem in pages:
        built = site / ("index.html" if stem == "index" else f"{stem}/index.html")
        assert built.is_file(), f"docs/{stem}.md was not built"


def test_cli_reference_lists_every_command(site):
    from fieldloc_cli.main import COMMANDS

    text = (site / "cli" / "index.html").read_text(encoding="utf-8")
    ids = set(re.findall(r'id="(fieldloc[-a-z]*)"', text))
    missing = [name for name in COMMANDS if f"fieldloc-{name}" not in ids]
    assert not missing, f"the CLI reference lacks {missing}"
