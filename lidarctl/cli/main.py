"""``lidarctl`` command line: thin click subcommands over library functions.

Every length option is in metres (``_m`` in its name), whatever the CRS of the cloud: clouds in
feet are scaled to metres as they are read (``lidarctl.io``) and outputs are written back in the
cloud's CRS and units, which the outputs name (raster tags, JSON keys, printed labels).

Each subcommand lives in a module of this package and is imported when it runs (``LazyGroup``): its
options take their defaults from settings classes whose modules import numba, scipy and GDAL, and
``lidarctl contours`` need not wait for the classifier's.
"""

from __future__ import annotations

import click

from aerotri.core.commands import LazyGroup


@click.group(cls=LazyGroup, lazy={
    "classify": "lidarctl.cli.classify:classify", "rasters": "lidarctl.cli.rasters:rasters",
    "crowns": "lidarctl.cli.rasters:crowns", "evaluate": "lidarctl.cli.evaluate:evaluate",
    "check-heights": "lidarctl.cli.checks:check_heights", "check-plan": "lidarctl.cli.checks:check_plan",
    "check-vectors": "lidarctl.cli.checks:check_vectors", "smooth": "lidarctl.cli.terrain:smooth",
    "hydro-flatten": "lidarctl.cli.terrain:hydro_flatten", "contours": "lidarctl.cli.terrain:contours",
    "drainage": "lidarctl.cli.terrain:drainage", "vectors": "lidarctl.cli.vectors:vectors",
    "corners": "lidarctl.cli.corners:corners", "merge": "lidarctl.cli.merge:merge",
    "strips": "lidarctl.cli.strips:strips", "trees": "lidarctl.cli.trees:trees"})
@click.version_option(package_name="aerotri")
def main():
    """Airborne LiDAR: noise removal, ground filtering, classification, rasters, roof-corner control."""
