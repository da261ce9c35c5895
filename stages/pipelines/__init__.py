"""Chains of stage mains (and picture mains): what a user runs end to end.

- :mod:`.images_to_poses` a dataset's images to poses (extract, or reuse DIR/features.h5, then
  localize): ``fieldloc localize DIR`` without ``--features``;
- :mod:`.evaluation` the report of a run and its plots: ``fieldloc evaluate``;
- :mod:`.batch` (its SPEC read by :mod:`.batch_spec`) every method of a SPEC on every dataset,
  on Dask, and their comparison: ``fieldloc batch``;
- :mod:`.bench` ``fieldloc bench``: a package of its registry of rows (``bench.ROWS``), the
  harness (:mod:`.bench.harness`: Row, timing, table, JSON), the inputs the rows share
  (:mod:`.bench.inputs`) and one module per family of rows;
- :mod:`.realdata` the real-data checks of the omni chain.

Nothing below this package imports it."""
