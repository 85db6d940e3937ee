"""Layer 2, geometry: camera models, rotations and exterior-orientation conventions, the local
adjustment frame, CRS handling with one coordinate-operation policy, image finding and reading.
Imports only ``aerotri.core`` and third-party packages."""
