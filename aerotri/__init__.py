"""aerotri: frame-camera aerial triangulation with LiDAR control (photogrammetric core)."""

__version__ = "0.1.0"
