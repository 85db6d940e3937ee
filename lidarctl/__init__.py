"""lidarctl: airborne LiDAR processing (noise, ground, classes, rasters, roof-corner control)."""

import logging

logging.getLogger("lidarctl").addHandler(logging.NullHandler())

from aerotri import __version__  # noqa: E402,F401  one version for the whole distribution
