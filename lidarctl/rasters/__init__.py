"""Rasters from a classified cloud: DEM, DSM, nDSM, CHM, intensity, tree heights."""
