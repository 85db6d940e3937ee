"""Automatic tie points across overlapping frames (``aerotri match PROJECT``).

Pipeline: strips from the GNSS track -> candidate pairs from predicted footprints -> SIFT with a
spatial budget on an image pyramid level -> mutual nearest neighbours with a ratio test ->
geometric verification (essential matrix, RANSAC, seeded) -> tracks (union-find, inconsistent
tracks dropped) -> weak-area analysis per stereo model (von Gruber regions) and across strips ->
densification where weak -> ``at/tiepoints.csv`` + connectivity report.
"""

__all__ = ["MatchReport", "MatchSettings", "match_project"]


def __getattr__(name):
    # Lazy: other packages import aerotri.geom.images alone, without the pipeline and matplotlib.
    if name in __all__:
        from aerotri.match import pipeline

        return getattr(pipeline, name)
    raise AttributeError(f"module 'aerotri.match' has no attribute {name!r}")
