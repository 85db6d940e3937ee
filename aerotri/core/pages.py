"""HTML pages: every page the packages write is a jinja2 template rendered here.

Templates live in each package's ``templates/`` folder (``aerotri/templates``, ``lidarctl/templates``) and
shipped with the wheel; ``aerotri/templates/macros.html.j2`` holds the pieces pages share (a table of
``report_figures.Table``, a figure with its scale key, the flight acceptance tables). Values are escaped by
the template (autoescape), so the Python side passes plain text and typed tables, never markup. A key a
record leaves out is an empty value in the template (``{% if s.overview_png %}``), as jinja2's default has it.
"""

from __future__ import annotations

import functools


@functools.cache
def _environment(package: str):
    import jinja2

    loaders = [jinja2.PackageLoader(package, "templates")]
    if package != "aerotri":
        loaders.append(jinja2.PackageLoader("aerotri", "templates"))  # the shared macros
    return jinja2.Environment(loader=jinja2.ChoiceLoader(loaders), autoescape=True, trim_blocks=True, lstrip_blocks=True,
                              keep_trailing_newline=True)


def render(template: str, package: str = "aerotri", **context) -> str:
    """The page ``template`` (a file of ``<package>/templates``) rendered with ``context``."""
    return _environment(package).get_template(template).render(**context)
