"""Automatic tie points across overlapping frames (``aerotri match PROJECT``).

Pipeline: strips from the GNSS track -> candidate pairs from predicted footprints -> SIFT with a
spatial budget on an image pyramid level -> mutual nearest neighbours with a ratio test ->
geometric verification (essential matrix, RANSAC, seeded) -> tracks (union-find, inconsistent
tracks dropped) -> weak-area analysis per stereo model (von Gruber regions) and across strips ->
densification where weak -> ``at/tiepoints.csv`` + connectivity report.
"""

from aerotri.match.pipeline import MatchSettings, match_project

__all__ = ["MatchSettings", "match_project"]
