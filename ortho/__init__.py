"""ortho: orthorectification on a LiDAR DEM, seamlines, mosaics and DOM accuracy."""

import logging
import os

logging.getLogger("ortho").addHandler(logging.NullHandler())

# numba's OpenMP threading layer spin-waits between parallel loops by default; on a machine whose
# cores are shared with other jobs that makes parallel kernels 10-15x slower than one thread.
# Passive waiting costs nothing when the cores are free. (Read when libgomp loads: set it first.)
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from aerotri import __version__  # noqa: E402,F401  one version for the whole distribution
