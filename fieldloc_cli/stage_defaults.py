"""The stages' preset names, defaults and accepted names as the help texts and click's choices
show them, written out here so that `fieldloc --help` and `fieldloc COMMAND --help` import no
stage: a stage's import loads numpy, OpenCV, h5py and numba's cached kernels, seconds of CPU
and hundreds of MB for a help page.

These are copies for display and for click's choice lists only. The values a command runs with
come from the stage: an option the user leaves out is not passed (``default=None``), so the
stage's own preset applies. tests/test_cli_startup.py checks every copy here against the stage
value it names, so a preset changed in a stage fails there until it is changed here too.
"""

from __future__ import annotations

# stages.build_map.confs["default"]
BUILD_MAP = {"resolution": 0.1, "border": 1.0, "max_range": 4.0, "robot_radius": 0.25,
             "spiral_end_radius": 2.0}

# list(stages.build_templates.FEATURE_PRESETS)
BUILD_TEMPLATES_FEATURES = ("surf", "surf-rotating", "sift", "orb")

# sorted(stages.calibrate.confs)
CALIBRATE_PRESETS = ("cnc", "default", "minho", "nubot")

# stages.common.camera.MAX_IMAGE_PX: the longest image side (px) a calibration may give
CALIBRATE_MAX_IMAGE_PX = 8192

# sorted(stages.evaluate.confs); stages.evaluate.confs["default"]["stamp_tolerance"]
EVALUATE_PRESETS = ("default", "loose", "numbers")
EVALUATE_STAMP_TOLERANCE = 0.02

# sorted(stages.evaluate.export.FORMATS)
EXPORT_FORMATS = ("csv", "json", "tum")

# stages.extract.DEFAULT_PRESET; sorted(stages.extract.kind_confs("omni"))
EXTRACT_DEFAULT_PRESET = "default"
EXTRACT_OMNI_PRESETS = ("default", "dense", "real")

# stages.ingest.team_fields.FORMATS
FIELD_FORMATS = ("bhuman", "bitbots", "falcons", "minho", "carpenoctem", "cambada", "hulks")

# sorted(stages.ingest.rosbag.confs)
ROSBAG_PRESETS = ("default", "fast")

# stages.common.describe.READS
INSPECT_READS = ("HDF5 artifacts (map, features, poses, templates), report.json, bench JSON,"
                 " calib.yaml, simulation.yaml, field YAML, the dataset CSVs, points and"
                 " calibration CSVs, errors.csv, poses.tum, PNG/JPG images, dataset and report"
                 " folders")

# list(stages.localize.METHODS); stages.localize.DEFAULT_METHOD
LOCALIZE_METHODS = ("lut", "mcl", "templates", "fit")
LOCALIZE_DEFAULT_METHOD = "lut"
# (method, key) -> stages.localize.method_confs(method)["default"][key]
LOCALIZE = {("lut", "heading"): "imu", ("fit", "start_half"): "any",
            ("mcl", "init"): "placement", ("mcl", "start_side"): "any",
            ("lut", "min_confidence"): 0.8,
            ("fit", "min_confidence"): 0.8}

# stages.pipelines.frame_belief.confs["default"]: resolution (m), heading_step in degrees
SHOW_BELIEF = {"resolution": 0.1, "heading_step_deg": 5.0}

# stages.pipelines.error_surface.confs["default"]
SHOW_ERROR_SURFACE = {"half_size": 1.5, "step": 0.1, "dtheta_deg": 30.0, "e_none": 1.0}

# stages.show.map.confs["default"] (heading in degrees); stages.show.map.TABLES;
# sorted(stages.show.map.FAMILIES)
SHOW_MAP = {"table": "distance", "heading_deg": 0.0, "family": "ccw", "spirals": 6}
SHOW_MAP_TABLES = ("distance", "radial", "spiral")
SHOW_MAP_FAMILIES = ("ccw", "cw")

# stages.simulate.trajectory.PATH_KINDS
SIMULATE_PATH_KINDS = ("random", "loop")
# camera -> sorted names of stages.simulate.confs whose "camera" is it
SIMULATE_PRESETS = {"omni": ("default", "omni-clean", "omni-default", "omni-hard"),
                    "perspective": ("perspective-clean", "perspective-default",
                                    "perspective-nao")}
# preset -> what the help shows of stages.simulate.confs[preset]
SIMULATE = {
    "omni-default": {"frames": 300, "seed": 0, "trajectory": "random",
                     "calib_error": (0.0, 0.0, 1.0), "grid_headings": 1},
    "perspective-default": {"frames": 300, "seed": 0, "trajectory": "random",
                            "calib_error": (0.0, 0.0, 1.0), "height": 0.55,
                            "pitch_deg": 25.8},
}
