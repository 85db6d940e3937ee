"""Options of the optional line-map stage of the chain (``[vectors]`` in project.toml)::

    [vectors]
    enabled = true                    # default false: the chain writes no map vectors
    reference = "survey/dlg.gpkg"     # reference vectors for the check (default: truth/buildings.geojson
                                      # of a simulated project, when present)
    check_json = "qa/dlg_check.json"  # or: a check-vectors result made elsewhere, read by the report

The stage writes lidar_out/vectors.gpkg (``lidarctl vectors`` on the classified strips) and, with a
reference, lidar_out/vectors_check.json (``lidarctl check-vectors`` with the map scale and terrain
class of ``[qa]``); the consolidated report turns the check into its "Line map (DLG) plan accuracy" row.
"""

from __future__ import annotations

import dataclasses
from typing import ClassVar
from pathlib import Path

from aerotri.core.settings import setting


@dataclasses.dataclass(frozen=True)
class VectorsSettings:
    """The line-map stage: off unless ``enabled``; the reference of its check; or a check made elsewhere."""

    SECTION: ClassVar[str] = "vectors"

    enabled: bool = setting(False, help="Write the line map (lidar_out/vectors.gpkg) and check it against the reference.")
    reference: Path | None = setting(None, path=True,
                                     help="Reference vectors (.gpkg/.geojson, layers named as lidarctl vectors "
                                          "writes them) [truth/buildings.geojson of a simulated project].")
    check_json: Path | None = setting(None, path=True,
                                      help="A check-vectors JSON made elsewhere: the report reads it when the chain "
                                           "made no check of its own.")
