"""Control transfer: LiDAR roof corners measured automatically in the frames (``aerotri control``).

Modules: ``corners`` (corners.csv from ``lidarctl corners``), ``measure`` (corner in one frame: edge
segments, intersection, sub-pixel refinement), ``consistency`` (multi-ray intersection and rejection),
``layout`` (which corners become control, which check points), ``chips`` (review page),
``pipeline`` (the stage over a project folder), ``cli``.
"""
