"""``lidarctl`` command line: thin click subcommands over library functions."""

from __future__ import annotations

import click


@click.group()
@click.version_option(package_name="aerotri")
def main():
    """Airborne LiDAR: noise removal, ground filtering, classification, rasters, roof-corner control."""


from lidarctl.corners_cli import corners  # noqa: E402

main.add_command(corners)
