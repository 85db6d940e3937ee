"""``lidarctl`` command line: thin click subcommands over library functions."""

from __future__ import annotations

import click


@click.group()
@click.version_option(package_name="aerotri")
def main():
    """Airborne LiDAR: noise removal, ground filtering, classification, rasters, roof-corner control."""
