"""``aerotri`` command line: thin click subcommands over library functions."""

from __future__ import annotations

import click

from aerotri.core.commands import Command, LazyGroup


@click.group(cls=LazyGroup, lazy={
    "init": "aerotri.chain.cli:init", "sim": "aerotri.sim.cli:sim", "demo": "aerotri.chain.cli:demo",
    "run": "aerotri.chain.cli:run", "crs": "aerotri.crs.cli:crs", "adjust": "aerotri.adjust.cli:adjust",
    "match": "aerotri.match.cli:match", "control": "aerotri.control.cli:control", "report": "aerotri.qa.cli:report",
    "compare": "aerotri.qa.cli:compare",
    "export": "aerotri.exchange.cli:export", "import": "aerotri.exchange.cli:import_"})
@click.version_option(package_name="aerotri")
def main():
    """Aerial triangulation of frame-camera blocks with LiDAR control, and the truth simulator."""
# Further stages register in ``lazy`` above: "<name>": "<module>:<click command or group>"


@click.command(cls=Command, name="settings")
@click.argument("project", required=False, type=click.Path(file_okay=False, exists=True))
@click.option("--markdown", is_flag=True, help="Print the reference of every project.toml section (docs/settings.md).")
@click.option("--set", "items", multiple=True, metavar="SECTION.KEY=VALUE",
              help="Write a setting into PROJECT's project.toml (TOML syntax, or a bare word), checked as every command "
                   "checks the file, comments kept, e.g. --set flight.mean_terrain_height_m=411 (repeatable).")
def settings(project, markdown, items):
    """Every setting of PROJECT with where it came from (default or project.toml), or (--markdown) the reference
    of every project.toml section: type, unit, default, allowed values, command-line options, meaning. With --set,
    change settings in PROJECT's project.toml."""
    from aerotri.chain.options import project_settings_text, reference_page
    from aerotri.core.errors import OptionError
    from aerotri.core.project import Project

    if markdown == (project is not None):
        raise OptionError("give PROJECT or --markdown", param="--markdown")
    if items:
        if markdown:
            raise OptionError("--set changes a project's project.toml: give PROJECT, not --markdown", param="--set")
        from aerotri.chain.set_settings import set_in_project

        for line in set_in_project(Project.open(project), items):
            click.echo(line)
        return
    if markdown:
        click.echo(reference_page(command_groups()))
        return
    from aerotri.chain.options import read_options
    from aerotri.chain.stages import Chain

    p = Project.open(project)
    click.echo(project_settings_text(p, completed=Chain(p, read_options(p)).completed_settings()))


def command_groups() -> list:
    """The three command lines (program name, click group), for the reference page of the settings."""
    from lidarctl.cli.main import main as lidarctl_main
    from ortho.cli import main as ortho_main

    return [("aerotri", main), ("lidarctl", lidarctl_main), ("ortho", ortho_main)]


main.add_command(settings)
