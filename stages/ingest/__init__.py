"""Ingest: a team's own recordings and files into fieldloc's formats.

- ``stages.ingest.rosbag``: a ROS 1 bag or a ROS 2 bag (sqlite3 or mcap) into a dataset folder
  (GUIDE section 4), read with ``rosbags`` (pure Python, no ROS install);
- ``stages.ingest.ros_images``: sensor_msgs/Image and CompressedImage payloads as OpenCV images;
- ``stages.ingest.team_fields``: B-Human, bit-bots and Falcons field files into a field YAML.
"""
