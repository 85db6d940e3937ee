"""The LiDAR tests' helper modules, importable by name (the tests run with ``--import-mode=importlib``, which puts
no test folder on the path): ``import tile_faults``."""

import importlib.util
import sqlite3
import sys
from pathlib import Path

import pytest
import shapely.wkb

for _name in ("tile_faults",):
    _spec = importlib.util.spec_from_file_location(_name, Path(__file__).with_name(f"{_name}.py"))
    sys.modules[_name] = importlib.util.module_from_spec(_spec)
    _spec.loader.exec_module(sys.modules[_name])


@pytest.fixture(scope="session")
def bgt_footprints(shared_data) -> list:
    """The BGT building footprints of the AHN3 Delft crop (``ahn3_delft/bgt_pand.sqlite``, layer buildingpart) as
    shapely polygons, EPSG:28992."""
    con = sqlite3.connect(f"file:{shared_data / 'ahn3_delft' / 'bgt_pand.sqlite'}?mode=ro", uri=True)
    try:
        return [shapely.wkb.loads(bytes(b)) for (b,) in con.execute("SELECT GEOMETRY FROM buildingpart")]
    finally:
        con.close()
