"""ortho: orthorectification on a LiDAR DEM, seamlines, mosaics and DOM accuracy."""

__version__ = "0.1.0"
