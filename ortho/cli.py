"""``ortho`` command line: thin click subcommands over library functions."""

from __future__ import annotations

import click


@click.group()
@click.version_option(package_name="aerotri")
def main():
    """Orthorectification on the LiDAR DEM, seamlines, mosaics and DOM accuracy checks."""
