"""Layer 3, exchange: project data to and from the formats other software reads (exports and imports).
Exporters read the project folder (``at/``, ``control/``, ``camera.toml``), never an
adjustment held in memory, so they run on any adjusted project, also one adjusted earlier.

The registry ``EXPORT_FORMATS`` maps a format name to its ``Exporter``: adding a format is one module
with a ``files(block, project) -> list[ExportFile]`` function (each file's path relative to the output folder
and its text or bytes) and one registry line. ``IMPORT_FORMATS`` does the
same for importers (``read(files, project, options) -> ImportedBlock``), whose blocks ``write_imported`` turns
into the project's own files.
"""

from aerotri.exchange.commit import ExportFile
from aerotri.exchange.import_registry import IMPORT_FORMATS, Importer, import_files
from aerotri.exchange.imported import ImportedBlock, ImportSettings, write_imported
from aerotri.exchange.registry import EXPORT_FORMATS, Exporter, export_project

__all__ = ["EXPORT_FORMATS", "ExportFile", "Exporter", "export_project", "IMPORT_FORMATS", "Importer", "import_files",
           "ImportedBlock", "ImportSettings", "write_imported"]
