"""``aerotri`` command line: thin click subcommands over library functions."""

from __future__ import annotations

import click

from aerotri.core.commands import Command, Group


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


@click.command(cls=Command, name="settings")
@click.argument("project", required=False, type=click.Path(file_okay=False, exists=True))
@click.option("--markdown", is_flag=True, help="Print the reference of every project.toml section (docs/settings.md).")
def settings(project, markdown):
    """Every setting of PROJECT with where it came from (default or project.toml), or (--markdown) the reference
    of every project.toml section: type, unit, default, allowed values, command-line options, meaning."""
    from aerotri.chain.options import project_settings_text, reference_page
    from aerotri.core.errors import OptionError
    from aerotri.core.project import Project

    if markdown == (project is not None):
        raise OptionError("give PROJECT or --markdown", param="--markdown")
    click.echo(reference_page(command_groups()) if markdown else project_settings_text(Project.open(project)))


def command_groups() -> list:
    """The three command lines (program name, click group), for the reference page of the settings."""
    from lidarctl.cli import main as lidarctl_main
    from ortho.cli import main as ortho_main

    return [("aerotri", main), ("lidarctl", lidarctl_main), ("ortho", ortho_main)]


main.add_command(settings)
