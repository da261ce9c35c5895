"""fieldloc: self-localisation of RoboCup soccer robots from their camera images.

Every stage is callable from Python as ``main(conf, inputs..., output) -> Path`` and has a dict
of named presets ``confs``. The command line (``fieldloc_cli``) only parses and reports.
"""

import os

__version__ = "0.1.0"

# the most pixels OpenCV decodes an image to: stages.common.dataset.MAX_IMAGE_PIXELS (64 M;
# OpenCV's own default is 1 G). OpenCV checks an image's header against it before it reserves
# the memory: a TIFF or WebP file of a few hundred kilobytes that claims 20000 x 20000 px
# asked for 1.6-2.4 GB (a PNG's header fieldloc checks itself). OpenCV reads the setting
# once, as it is loaded, so it is set here, before any stage imports cv2; a user's own
# setting is kept.
os.environ.setdefault("OPENCV_IO_MAX_IMAGE_PIXELS", str(1 << 26))
