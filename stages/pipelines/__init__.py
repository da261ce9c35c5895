"""Chains of stage mains (and picture mains): what a user runs end to end.

- :mod:`.images_to_poses` a dataset's images to poses (extract, or reuse DIR/features.h5, then
  localize): ``fieldloc localize DIR`` without ``--features``;
- :mod:`.evaluation` the report of a run and its plots: ``fieldloc evaluate``;
- :mod:`.batch` (its SPEC read by :mod:`.batch_spec`) every method of a SPEC on every dataset,
  on Dask, and their comparison: ``fieldloc batch``;
- :mod:`.bench` (with :mod:`.bench_hypotheses`, :mod:`.bench_batch`,
  :mod:`.bench_perspective`, :mod:`.bench_mcl_nao`, :mod:`.bench_fit`) ``fieldloc bench``;
- :mod:`.realdata` the real-data checks of the omni chain.

Nothing below this package imports it."""
