"""The one vector writer (aerotri/core/vector_files.py): GeoPackage 1.2 that GDAL 3.6 (QGIS 3.28 LTR) opens
without "may only be partially supported", every layer named, in its CRS, with a spatial index, written atomically;
and no other module writes vector files."""

from __future__ import annotations

import re
import shutil
import sqlite3
import struct
import subprocess
from pathlib import Path

import numpy as np
import pytest
import shapely

from aerotri.core.vector_files import GPKG_USER_VERSION, VectorLayer, write_layers

REPO = Path(__file__).resolve().parents[3]


def _header(path: Path) -> tuple[bytes, int]:
    """(application_id, user_version) of a SQLite file: header bytes 68-71 and 60-63, big-endian."""
    with open(path, "rb") as f:
        h = f.read(100)
    return h[68:72], struct.unpack(">i", h[60:64])[0]


def _layers() -> list[VectorLayer]:
    return [VectorLayer("spot_heights", "Point", shapely.points([[500010.0, 3400020.0], [500030.5, 3400040.25]]),
                        {"height_m": np.array([101.5, 99.25]), "name": np.array(["a", "b"], dtype=object)}),
            VectorLayer("buildings", "MultiPolygon", [shapely.box(500000, 3400000, 500012, 3400008)],
                        {"building_id": np.array([7], np.int32)}),
            VectorLayer("roads", "LineString", [], {"width_m": np.array([], float)})]


def test_geopackage_is_version_1_2_in_its_crs_with_named_indexed_layers(tmp_path):
    path = write_layers(tmp_path / "map.gpkg", _layers(), crs="EPSG:32649")
    assert _header(path) == (b"GPKG", GPKG_USER_VERSION) == (b"GPKG", 10200)
    import pyogrio
    from pyogrio.raw import read

    assert [str(n) for n, _ in pyogrio.list_layers(path)] == ["spot_heights", "buildings", "roads"]
    pts = pyogrio.read_info(path, layer="spot_heights")
    assert pts["crs"] == "EPSG:32649" and pts["geometry_type"] == "Point" and pts["features"] == 2
    assert list(pts["fields"]) == ["height_m", "name"]
    _, _, wkb, fields = read(path, layer="spot_heights")
    assert shapely.get_coordinates(shapely.from_wkb(wkb)).tolist() == [[500010.0, 3400020.0], [500030.5, 3400040.25]]
    assert fields[0].tolist() == [101.5, 99.25] and fields[1].tolist() == ["a", "b"]
    bld = pyogrio.read_info(path, layer="buildings")
    assert bld["geometry_type"] == "MultiPolygon" and list(bld["dtypes"]) == ["int32"]
    roads = pyogrio.read_info(path, layer="roads")  # an empty layer keeps its fields and CRS
    assert roads["features"] == 0 and list(roads["fields"]) == ["width_m"] and roads["crs"] == "EPSG:32649"
    with sqlite3.connect(path) as db:
        indexed = {r[0] for r in db.execute("SELECT table_name FROM gpkg_extensions WHERE extension_name = "
                                            "'gpkg_rtree_index'")}
        srs = {r[0] for r in db.execute("SELECT srs_id FROM gpkg_geometry_columns")}
    assert indexed == {"spot_heights", "buildings", "roads"} and srs == {32649}
    assert [p.name for p in tmp_path.iterdir()] == ["map.gpkg"]  # no temporary left

    ogrinfo = shutil.which("ogrinfo")
    if ogrinfo is not None:  # Debian's gdal-bin (GDAL 3.6 on bookworm, as QGIS 3.28 LTR): no warning on open
        r = subprocess.run([ogrinfo, "-so", "-al", str(path)], capture_output=True, text=True, timeout=60)
        out = r.stdout + r.stderr
        assert r.returncode == 0 and "Warning" not in out and "ERROR" not in out, out[:2000]
        assert re.findall(r"^Layer name: (\S+)", out, re.M) == ["spot_heights", "buildings", "roads"]


def test_a_failed_write_leaves_the_old_file(tmp_path):
    path = write_layers(tmp_path / "map.gpkg", _layers(), crs="EPSG:32649")
    before = path.read_bytes()
    bad = _layers() + [VectorLayer("broken", "Point", shapely.points([[0.0, 0.0]]), {"v": np.array([1.0, 2.0])})]
    with pytest.raises(Exception):  # one value too many: the whole file stays as it was
        write_layers(path, bad, crs="EPSG:32649")
    assert path.read_bytes() == before and [p.name for p in tmp_path.iterdir()] == ["map.gpkg"]


def test_a_layer_without_crs_or_name_is_refused(tmp_path):
    with pytest.raises(ValueError, match="CRS"):
        write_layers(tmp_path / "a.gpkg", _layers(), crs=None)
    with pytest.raises(ValueError, match="name"):
        write_layers(tmp_path / "a.gpkg", [VectorLayer("", "Point", [])], crs="EPSG:32649")
    assert not any(tmp_path.iterdir())


def test_geojson_by_the_suffix_without_geopackage_options(tmp_path):
    import pyogrio

    path = write_layers(tmp_path / "lines.geojson", [VectorLayer("contours", "LineString",
                                                                 [shapely.LineString([(0, 0), (1, 1)])],
                                                                 {"elevation": np.array([5.0])})], crs="EPSG:32649")
    info = pyogrio.read_info(path)
    assert info["driver"] == "GeoJSON" and info["features"] == 1 and info["crs"] == "EPSG:32649"


def test_no_other_module_writes_vector_files():
    # every GeoPackage goes through write_layers: a direct pyogrio/geopandas/fiona write elsewhere would again
    # write GDAL's default version (1.4), without the spatial index or the atomic rename
    writes = re.compile(r"pyogrio\.raw import (.*\b)?write\b|pyogrio\.raw\.write\b|pyogrio\.write_|write_dataframe|"
                        r"write_arrow|\.to_file\(|fiona\.open\(.*['\"]w['\"]")
    found = [f"{p.relative_to(REPO)}:{n}" for pkg in ("aerotri", "lidarctl", "ortho")
             for p in (REPO / pkg).rglob("*.py") for n, line in enumerate(p.read_text().splitlines(), 1)
             if writes.search(line)]
    assert len(found) == 1 and found[0].startswith("aerotri/core/vector_files.py:"), found


def test_a_geopackage_with_a_write_ahead_log_is_not_replaced(tmp_path):
    """Reviewer 14's gp/holdwal.py: QGIS edits the file in WAL mode; a rerun renamed the new file in and SQLite
    replayed the old -wal onto it (integrity_check failed, the old tables appeared). Now exit 2 (InputError),
    the old file and its log untouched, while a program holds it; a log left by a crash (nothing holds it) is
    written into the old file first (review 15: removing it, as the message advised, lost the file's tables) and the
    file replaced; an empty -wal/-shm that nothing holds is removed and the file replaced."""
    from aerotri.core.errors import InputError, OptionError
    from aerotri.core.vector_files import refuse_foreign_layers

    path = write_layers(tmp_path / "w.gpkg", _layers(), crs="EPSG:32649")
    wal, shm = Path(f"{path}-wal"), Path(f"{path}-shm")
    held = sqlite3.connect(path)  # QGIS editing: pages in the log, not yet checkpointed
    held.execute("PRAGMA journal_mode=WAL")
    held.execute("PRAGMA wal_autocheckpoint=0")
    held.execute("CREATE TABLE scratch(a)")
    held.executemany("INSERT INTO scratch VALUES (?)", [(bytes(3000),)] * 200)
    held.commit()
    assert wal.stat().st_size > 0
    with pytest.raises(InputError, match=r"open for editing in QGIS.*save and close it"):
        write_layers(path, _layers()[:1], crs="EPSG:32649")
    with pytest.raises(OptionError, match="open for editing in QGIS") as err:
        refuse_foreign_layers(path, [layer.name for layer in _layers()], "test", option="OUT")
    assert err.value.param == "OUT"
    crashed = wal.read_bytes()  # what a killed QGIS leaves: the log, nobody holding it
    held.close()
    assert not wal.exists() and not shm.exists()  # the last connection checkpointed and removed them
    wal.write_bytes(crashed)
    write_layers(path, _layers(), crs="EPSG:32649")  # the crash's log checkpointed into the old file, then replaced
    assert not wal.exists() and not shm.exists()
    with sqlite3.connect(path) as db:
        assert db.execute("PRAGMA integrity_check").fetchone() == ("ok",)
        assert "scratch" not in {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type='table'")}
    held = sqlite3.connect(path)
    held.execute("PRAGMA journal_mode=WAL")
    held.execute("PRAGMA wal_checkpoint(TRUNCATE)")  # open, not editing: an empty log that a program holds
    held.execute("SELECT count(*) FROM sqlite_master").fetchone()
    assert wal.exists()
    with pytest.raises(InputError, match="open in another program"):
        write_layers(path, _layers()[:1], crs="EPSG:32649")
    held.close()
    wal.write_bytes(b"")  # stale and empty, and an index beside it: removed, the file replaced
    shm.write_bytes(bytes(32768))
    write_layers(path, _layers()[:1], crs="EPSG:32649")
    assert not wal.exists() and not shm.exists()
    with sqlite3.connect(path) as db:
        assert db.execute("PRAGMA integrity_check").fetchone() == ("ok",)
        tables = {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type='table'")}
    assert "spot_heights" in tables and "scratch" not in tables and "buildings" not in tables
