"""The files of a dataset folder (GUIDE section 4; stages.common.dataset reads them): the
columns of its CSV files and the names of the files that are the recording's own, which no
command writes over (stages.common.artifacts.check_output refuses them)."""

from __future__ import annotations

SIMULATION_RECORD = "simulation.yaml"  # written by fieldloc simulate: how the dataset was made

CSV_COLUMNS = {
    "frames": ("name", "stamp"),
    "odometry": ("stamp", "dx", "dy", "dtheta"),
    "imu": ("stamp", "yaw", "collision"),
    "truth": ("stamp", "x", "y", "theta"),
    "head": ("stamp", "pitch", "roll"),  # perspective cameras: head angles per frame
}
# columns a file may add after the required ones (any of them, in this order)
CSV_OPTIONAL_COLUMNS = {
    "head": ("yaw", "height", "x", "y"),
}

# a recording's own files beside images/ (calib.yaml is written by a calibration)
OWN_FILES = ("calib.yaml", "mask.png", SIMULATION_RECORD, *(f"{k}.csv" for k in CSV_COLUMNS))
