"""Chains of stage mains: what a user runs end to end, and the checks of the product on real
recordings (realdata.py). Nothing below this package imports it."""
