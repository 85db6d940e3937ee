"""aerotri: frame-camera aerial triangulation with LiDAR control (photogrammetric core)."""

import logging

logging.getLogger("aerotri").addHandler(logging.NullHandler())

__version__ = "0.1.0"

# under a container's CPU quota, numba's, OpenMP's and OpenBLAS's pools take the cores the quota allows, not the
# host's (read when those libraries load: set before any of ours imports them)
from aerotri.core.limits import limit_library_threads  # noqa: E402

limit_library_threads()
