"""Layer 2, geometry: camera models, rotations and exterior-orientation conventions, the local
adjustment frame, CRS handling with one coordinate-operation policy (``aerotri.geom.crs``, the one home of
coordinate reference code), image finding and reading.
Imports only ``aerotri.core`` and third-party packages."""
