"""lidarctl: airborne LiDAR processing (noise, ground, classes, rasters, roof-corner control)."""

__version__ = "0.1.0"
