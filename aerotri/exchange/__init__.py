"""Layer 3, exchange: project data to and from the formats other software reads (exports; imports come
with issue 22). Exporters read the project folder (``at/``, ``control/``, ``camera.toml``), never an
adjustment held in memory, so they run on any adjusted project, also one adjusted earlier.

The registry ``EXPORT_FORMATS`` maps a format name to its ``Exporter``: adding a format is one module
with a ``files(block) -> {relative path: text}`` function and one registry line.
"""

from aerotri.exchange.registry import EXPORT_FORMATS, Exporter, export_project

__all__ = ["EXPORT_FORMATS", "Exporter", "export_project"]
