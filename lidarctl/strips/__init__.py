"""Strip-to-strip consistency of airborne LiDAR: overlap height differences (``check``) and strip
adjustment (``adjust``).

- ``overlap``: reading strips (separate files, or by ``point_source_id`` within one file) into
  per-cell planes of smooth single-return surfaces, and the differences of overlapping strips.
- ``check``: statistics per pair and per strip, differences against the scan angle, rasters, maps,
  ``strips.json`` and an HTML page.
- ``trajectory``: the trajectory text format (time, x, y, z, roll, pitch, heading).
- ``adjust``: per-strip shifts and attitude corrections (or boresight and range offset with a
  trajectory) by least squares on plane correspondences in the overlaps; corrected strips.
"""
