"""aerotri: frame-camera aerial triangulation with LiDAR control (photogrammetric core)."""

import logging

logging.getLogger("aerotri").addHandler(logging.NullHandler())

__version__ = "0.1.0"
