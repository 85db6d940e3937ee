"""Coordinate reference systems, datums, projections and heights: the toolkit's one home for
coordinate reference code (geometry layer: imports ``aerotri.core``, ``aerotri.geom.las`` and
``aerotri.geom.inputs`` only). One module per concept; import from the module, this package
re-exports nothing.

- ``definition``: parsing a CRS (EPSG code, WKT, PROJ text), its label, horizontal/vertical parts,
  units, comparisons, the project's CRS and heights, plausibility of coordinates for a CRS.
- ``ellipsoid``: reference ellipsoids and geodetic <-> geocentric conversions.
- ``datum``: parameter sets (helmert2d, affine2d, bursa-wolf7, translation3) and height anomaly
  models: applying, inverting, reading their files.
- ``transform``: ``CrsTransformer``, the one coordinate-operation policy (PROJ operations, fitted
  parameter sets, height models; never a silent ballpark operation).
- ``fit``: parameter sets from common points (Gauss-Markov least squares).
- ``heights``: height anomaly surfaces fitted from GNSS levelling points, H = h - zeta.
- ``gauss_kruger``: own Gauss-Krueger / transverse Mercator and the Chinese 3-/6-degree zones.
- ``raster_warp``: grids through a coordinate operation (anchor grids), north-up raster reading.
- ``files``: common-point and height-point tables, point lists and LAS/LAZ files transformed.
- ``raster``: raster files warped to another CRS (COG output).
- ``synthetic``: common points through known parameter sets (truth for tests and benchmarks).

The ``aerotri crs`` command (interfaces layer) is ``aerotri.crs.cli``.
"""
