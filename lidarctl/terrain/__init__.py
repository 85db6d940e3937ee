"""Terrain products of a DEM: smoothing, contours, drainage."""
