"""Roof corners and roof planes as LiDAR ground control."""
