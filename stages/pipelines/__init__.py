"""Chains of stage mains: what a user runs end to end (``bench``, the real-data checks of
realdata.py). Nothing below this package imports it."""
