"""`fieldloc import rosbag BAG -o DIR --image-topic T [--odom-topic T] [--imu-topic T]`: a ROS 1
or ROS 2 bag into a dataset folder."""

from __future__ import annotations

import click

from .common import (
    FilePath,
    WholeNumber,
    conf_option,
    count,
    overrides_dict,
    progress_enabled,
    summary,
)
from .lazy_group import outputs_complete
from .stage_defaults import ROSBAG_PRESETS


@click.group("import")
def import_group():
    """Turn a team's recordings into a dataset folder."""


@import_group.command("rosbag")
@click.argument("bag", type=FilePath())
@click.option("-o", "--output", required=True, type=FilePath(file_okay=False),
              help="Dataset folder to write (images/, frames.csv, odometry.csv, imu.csv).")
@click.option("--image-topic", required=True, metavar="T",
              help="sensor_msgs/Image or CompressedImage topic.")
@click.option("--odom-topic", metavar="T", help="nav_msgs/Odometry topic -> odometry.csv.")
@click.option("--imu-topic", metavar="T", help="sensor_msgs/Imu topic -> imu.csv (yaw).")
@click.option("--every", type=WholeNumber(), default=1, show_default=True,
              help="Keep every N-th image message.")
@click.option("--calib", type=FilePath(dir_okay=False),
              help="calib.yaml to copy into the dataset folder.")
@click.option("--preset", default="default", show_default=True, type=click.Choice(ROSBAG_PRESETS),
              help="Conf preset ('fast': raw frames as uncompressed PNG).")
@click.option("--overwrite", is_flag=True, help="Replace OUTPUT if it exists.")
@conf_option
@click.pass_context
def import_rosbag(ctx, bag, output, image_topic, odom_topic, imu_topic, every, calib, preset,
                  overwrite, overrides):
    """Images, stamps, odometry and IMU yaw from a ROS bag (ROS 1 .bag, or a ROS 2 bag folder
    with sqlite3 or mcap storage), read with rosbags: no ROS install needed.

    \b
    Examples:
      fieldloc import rosbag run3.bag -o run3 --image-topic /omni/image_raw/compressed \\
          --odom-topic /odom --imu-topic /imu
      fieldloc import rosbag rosbag2_2026_03_01/ -o run4 --image-topic /camera/image --every 3
    """
    from stages.common.conf import resolve_conf
    from stages.ingest.rosbag import confs, describe, main

    conf = resolve_conf(confs, preset, overrides_dict(overrides))
    out = main(conf, bag, output, image_topic=image_topic, odom_topic=odom_topic,
               imu_topic=imu_topic, every=every, calib=calib, overwrite=overwrite,
               progress=progress_enabled(ctx))
    outputs_complete(ctx)
    rec = describe(out)
    parts = [f"{count(rec['frames'], 'frame')} of {count(rec['image_messages'], 'image message')}"]
    if "odometry_rows" in rec:
        parts.append(f"{rec['odometry_rows']} odometry increments from"
                     f" {rec['odometry_messages']} messages")
    if "imu_rows" in rec:
        parts.append(f"{rec['imu_rows']} IMU yaws from {rec['imu_messages']} messages")
    if rec["skipped"]:
        parts.append(f"{len(rec['skipped'])} frame(s) skipped (see import.yaml)")
    enc = ", ".join(f"{k} x{v}" for k, v in rec["encodings"].items())
    summary(ctx, f"wrote {out} ({rec['bag_format']}; {enc}): " + "; ".join(parts))
    if "calib" not in rec:
        summary(ctx, f"next: put the camera's calib.yaml into {out} (fieldloc calibrate omni"
                " ...)")
