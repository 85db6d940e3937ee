"""``aerotri`` command line: thin click subcommands over library functions."""

from __future__ import annotations

import click

from aerotri.core.commands import Group


@click.group(cls=Group)
@click.version_option(package_name="aerotri")
def main():
    """Aerial triangulation of frame-camera blocks with LiDAR control, and the truth simulator."""


from aerotri.sim.cli import sim  # noqa: E402
from aerotri.chain.cli import demo, init, run  # noqa: E402

main.add_command(init)
main.add_command(sim)
main.add_command(demo)
main.add_command(run)
# Further stages register here: main.add_command(<group or command>)
from aerotri.crs.cli import crs  # noqa: E402
main.add_command(crs)
from aerotri.adjust.cli import adjust  # noqa: E402
main.add_command(adjust)
from aerotri.match.cli import match  # noqa: E402
main.add_command(match)
from aerotri.control.cli import control  # noqa: E402
main.add_command(control)
from aerotri.qa.cli import report  # noqa: E402
main.add_command(report)
from aerotri.exchange.cli import export, import_  # noqa: E402
main.add_command(export)
main.add_command(import_)
