"""The table search's tables and min-pooled error lookup (and the point fit's distance raster)
cached beside the map
(stages.localize.lookup_cache): mapped when present, identical to a fresh build, built again
when the map changes, and never a reason to fail."""

from __future__ import annotations

import os

import numpy as np
import pytest

from stages import build_map
from stages.common.map_file import MapFile
from stages.localize import lookup_cache
from stages.localize.lut_search import MatchingParams, TableSearch
from stages.localize.point_fit import PointFit


@pytest.fixture
def small_map(tmp_path):
    return build_map.main({"resolution": 0.2}, "kidsize", tmp_path / "kid.map.h5")


def _search(path, **kw):
    with MapFile(path) as mf:
        return TableSearch(mf, MatchingParams(), **kw)


def test_the_lookup_is_mapped_from_disk_and_equals_a_fresh_build(small_map):
    first = _search(small_map)
    assert first.lookup_source == "built"
    files = sorted(p.name for p in lookup_cache.cache_folder(small_map).iterdir())
    assert any(n.endswith(".radial.npy") for n in files)
    assert any(n.endswith(".coarse.npy") for n in files)
    assert not any(n.endswith(".error.npy") for n in files)  # the fine lookup is not stored
    again = _search(small_map)
    assert again.lookup_source == "mapped"
    fresh = _search(small_map, cache=False)
    assert fresh.lookup_source == "built, not cached"
    # exact integers: uint16 millimetres, read back
    assert np.array_equal(again.radial_table, fresh.radial_table)
    # exact integers: uint8 quantised errors, read back
    assert np.array_equal(again.coarse_lookup, fresh.coarse_lookup)
    assert again.coarse_lookup.flags.writeable  # the numba kernels take it as it is
    # other matching parameters are another key; those the lookup does not read are not
    with MapFile(small_map) as mf:
        assert TableSearch(mf, MatchingParams(c=0.3)).lookup_source == "built"
        assert TableSearch(mf, MatchingParams(pair_tolerance=0.5)).lookup_source == "mapped"


def test_a_changed_map_is_built_again_and_its_old_lookup_removed(small_map):
    old = _search(small_map)
    old_files = {p.name for p in lookup_cache.cache_folder(small_map).iterdir()}
    # the same path, another map: the lines of another field on the same grid size
    build_map.main({"resolution": 0.2, "max_range": 3.0}, "kidsize", small_map, overwrite=True)
    new = _search(small_map)
    assert new.lookup_source == "built"
    # exact integers: uint8 quantised errors of two maps
    assert not np.array_equal(new.coarse_lookup, old.coarse_lookup)
    fresh = _search(small_map, cache=False)
    # exact integers: uint8 quantised errors, read back
    assert np.array_equal(new.coarse_lookup, fresh.coarse_lookup)
    now = {p.name for p in lookup_cache.cache_folder(small_map).iterdir()}
    assert not (now & old_files), "the lookup of the earlier map is left behind"


def test_a_damaged_cache_file_is_built_again(small_map):
    _search(small_map)
    err = next(lookup_cache.cache_folder(small_map).glob("*.coarse.npy"))
    err.write_bytes(b"not an array")
    s = _search(small_map)
    assert s.lookup_source == "built"
    # exact integers: uint8 quantised errors, read back
    assert np.array_equal(s.coarse_lookup, _search(small_map, cache=False).coarse_lookup)


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_an_unwritable_folder_leaves_the_lookup_in_memory(small_map, caplog):
    os.chmod(small_map.parent, 0o555)
    try:
        s = _search(small_map)
    finally:
        os.chmod(small_map.parent, 0o755)
    assert s.lookup_source == "built, not cached"
    assert "cannot cache" in caplog.text


def test_a_disk_without_room_leaves_the_lookup_in_memory(small_map, monkeypatch, caplog):
    import shutil

    usage = shutil.disk_usage(small_map.parent)
    monkeypatch.setattr(lookup_cache.shutil, "disk_usage",
                        lambda p: usage._replace(free=1000))
    s = _search(small_map)
    assert s.lookup_source == "built, not cached"
    assert "cannot cache" in caplog.text
    assert not list(lookup_cache.cache_folder(small_map).glob("*.npy"))


def test_the_point_fit_raster_is_cached_beside_the_map(small_map):
    with MapFile(small_map) as mf:
        a = PointFit(mf.field, map_path=small_map)
        b = PointFit(mf.field, map_path=small_map)
        c = PointFit(mf.field)
    # exact same-run: built here, cached, read back
    assert np.array_equal(a.table, c.table) and np.array_equal(b.table, c.table)
    assert len(list(lookup_cache.cache_folder(small_map).glob("*.distance.npy"))) == 1
