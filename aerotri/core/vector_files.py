"""The one writer of vector files: every GeoPackage the toolkit writes goes through ``write_layers`` (and the
GeoJSON and KML files of the commands that offer them), so that each one is

- GeoPackage 1.2 (``application_id`` 'GPKG', ``user_version`` 10200 in the SQLite header), the version every
  reader knows: the GDAL of the wheels writes 1.4 by default, which GDAL 3.6 (QGIS 3.28 LTR, Debian 12's
  gdal-bin) opens with "Warning 1: This version of GeoPackage user_version=0x000028A0 (10400, v1.4.0) ... may
  only be partially supported";
- in a CRS (every layer the same; a layer without one is refused), each layer under an explicit name, with a
  spatial index (an R-tree: QGIS pans a large layer without reading it whole);
- atomic: written under a temporary name next to the output and renamed onto it (``atomic_path``): the layers
  of one file are all new or all old;
- refused while the GeoPackage it replaces has a non-empty SQLite write-ahead log beside it (``<file>-wal``:
  open for editing in QGIS, or left by a crash): SQLite replays a ``-wal`` onto whatever file bears the name,
  so the new file would take the old one's pages (``refuse_open_geopackage``);
- marked as ours (each layer's description in gpkg_contents starts with ``MARK``; QGIS shows it as the
  layer's abstract): a rerun replaces a file it wrote, and warns before replacing one that merely has layers of
  our names (``refuse_foreign_layers``); the ``layer_styles`` table QGIS saves styles in is carried over.

The driver follows the suffix (``DRIVERS``); the GeoPackage options apply to .gpkg only.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import sqlite3
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from aerotri.core.atomic import atomic_path
from aerotri.core.errors import InputError, OptionError


GPKG_VERSION = "1.2"  # the driver's VERSION creation option (AUTO, 1.0 ... 1.4)
GPKG_APPLICATION_ID = 0x47504B47  # b"GPKG", the SQLite header's application_id of GeoPackage >= 1.2
GPKG_USER_VERSION = 10200  # the SQLite header's user_version of GeoPackage 1.2.0
DRIVERS = {".gpkg": "GPKG", ".geojson": "GeoJSON", ".json": "GeoJSON", ".kml": "KML"}
# the marker of our GeoPackages, in gpkg_contents.description (GDAL's dataset metadata would add a time stamp and
# a .aux.xml beside the file)
MARK = "written by aerotri"
QGIS_STYLES = "layer_styles"  # the attributes table QGIS saves layer styles in ("Save style ... in database")

log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True)
class VectorLayer:
    """One layer: its ``name``, the OGR ``geometry_type`` of all its features ("Point", "LineString",
    "MultiPolygon", "Point Z", ...), the ``geometries`` (shapely; a Polygon in a Multi* layer is written as a
    MultiPolygon of one) and the ``fields`` (name -> one value per geometry, in the order given; a layer without
    features keeps its fields)."""

    name: str
    geometry_type: str
    geometries: Sequence
    fields: Mapping[str, np.ndarray] = dataclasses.field(default_factory=dict)
    # more of the layer's description after ``MARK`` ("written by aerotri; <note>"): what its fields hold, for a
    # reader to tell file versions apart (QGIS shows it as the abstract); "": the mark alone
    note: str = ""


def layer_description(note: str = "") -> str:
    """A layer's description in gpkg_contents: ``MARK``, then ``note`` after "; " when there is one."""
    return f"{MARK}; {note}" if note else MARK


def write_layers(path, layers: Sequence[VectorLayer], *, crs, timestamp: str | None = None) -> Path:
    """Write ``layers`` (in this order) into the new file ``path`` (replacing it; the driver by the suffix,
    ``DRIVERS``), all in ``crs`` (WKT, an authority code such as "EPSG:32649", or a pyproj CRS), atomically.
    ``timestamp``: the time GDAL stamps into a GeoPackage (ISO 8601, e.g. "2000-01-01T00:00:00.000Z", so that
    the same data gives the same bytes); None: the time of writing. Returns ``path``."""
    import pyogrio
    import shapely
    from pyogrio.raw import write

    path = Path(path)
    driver = DRIVERS.get(path.suffix.lower())
    if driver is None:
        raise ValueError(f"{path}: a vector file ends in {', '.join(DRIVERS)}")
    if crs is None or (isinstance(crs, str) and not crs.strip()):
        raise ValueError(f"{path}: a vector file is written with its CRS")
    crs = crs if isinstance(crs, str) else crs.to_wkt()
    if driver == "GeoJSON":
        refuse_geojson_without_code(path, crs)
    if not layers or any(not layer.name for layer in layers):
        raise ValueError(f"{path}: every layer needs a name (got {[layer.name for layer in layers]})")
    gpkg = driver == "GPKG"
    if gpkg:
        refuse_open_geopackage(path)
    with _gdal_timestamp(pyogrio, timestamp), atomic_path(path) as tmp:
        tmp.unlink(missing_ok=True)  # a new file, not the empty temporary
        for i, layer in enumerate(layers):
            wkb = shapely.to_wkb(np.asarray(list(layer.geometries), dtype=object))
            write(str(tmp), np.asarray(wkb, dtype=object), field_data=[np.asarray(v) for v in layer.fields.values()],
                  fields=list(layer.fields), layer=layer.name, driver=driver, crs=crs,
                  geometry_type=layer.geometry_type, promote_to_multi=layer.geometry_type.startswith("Multi"),
                  append=i > 0, dataset_options={"VERSION": GPKG_VERSION} if gpkg else None,
                  layer_options={"SPATIAL_INDEX": "YES", "DESCRIPTION": layer_description(layer.note)}
                  if gpkg else None)
        if gpkg and path.is_file():
            _keep_qgis_styles(path, tmp)
            # the read-only look at a file in WAL mode leaves an empty -wal/-shm (only a writer removes them):
            # removed here, or they would sit beside the new file
            refuse_open_geopackage(path)
    return path


def refuse_geojson_without_code(path, crs) -> None:
    """A GeoJSON file names its CRS only by an authority code (GDAL's legacy ``crs`` member; RFC 7946 GeoJSON is WGS 84
    lon/lat): a CRS without one would be written without it and read back as WGS 84 (trial-hydro: Autzen's contours in
    Oregon Lambert feet, read by QGIS and by hydro-flatten as EPSG:4326). OptionError naming the output."""
    import pyproj

    c = pyproj.CRS.from_user_input(crs)
    if c.to_authority(min_confidence=100) is None:   # what GDAL writes: the definition's own code, none guessed
        near = c.to_authority(min_confidence=70)
        raise OptionError(f"{path}: GeoJSON names a CRS only by an authority code, and {c.name} carries none"
                          + (f" (it resembles {':'.join(near)})" if near else "")
                          + ": the file would be read as WGS 84 longitude/latitude; write a GeoPackage (.gpkg), which "
                          "keeps the CRS", param="OUT")


def _keep_qgis_styles(old, new) -> None:
    """Copy QGIS's ``layer_styles`` table (and its gpkg_contents row) from the GeoPackage ``old`` being replaced
    into ``new``: a user's saved styles of our layers survive a rerun. Nothing when ``old`` has none or is not
    SQLite; a table that cannot be copied goes with the old file, with a warning."""
    try:
        with contextlib.closing(sqlite3.connect(Path(old).resolve().as_uri() + "?mode=ro", uri=True)) as src:
            row = src.execute("SELECT sql FROM sqlite_master WHERE type='table' AND name=?", (QGIS_STYLES,)).fetchone()
    except sqlite3.Error:
        return
    if row is None:
        return
    try:
        with contextlib.closing(sqlite3.connect(new)) as dst:
            dst.execute("ATTACH DATABASE ? AS old", (str(old),))
            dst.execute(row[0])
            dst.execute(f"INSERT INTO main.{QGIS_STYLES} SELECT * FROM old.{QGIS_STYLES}")
            dst.execute("INSERT INTO main.gpkg_contents (table_name, data_type, identifier, description, last_change) "
                        "SELECT table_name, data_type, identifier, description, last_change FROM old.gpkg_contents "
                        "WHERE table_name=?", (QGIS_STYLES,))
            dst.commit()
    except sqlite3.Error as exc:
        log.warning(f"{old}: QGIS's saved styles ({QGIS_STYLES}) could not be kept in the new file ({exc}); "
                    "set the layers' styles again")


def refuse_foreign_layers(path, layer_names, what: str, option: str = "OUT", owned: bool = False) -> None:
    """``OptionError`` when the GeoPackage ``path`` exists and holds a layer not in ``layer_names`` (what
    ``what``, e.g. "lidarctl contours", writes there; QGIS's ``layer_styles`` is kept, ``write_layers``), or
    is not a GeoPackage GDAL reads: ``write_layers`` replaces the whole file, so a user's other layers would go
    without a word. A file without our marker (``MARK``: a user's file with layers of our names, or written before
    the marker, 2026-12-01) is refused too, naming its layers (trial s94: a copy of the BGT reference, whose one
    layer ``buildings`` check-vectors asks for, given as ``lidarctl vectors``' OUT went with a warning); ``owned``:
    the path is a project's own output (the chain's), whose unmarked file is an earlier version's and is replaced.
    Other formats hold one layer and are replaced as before."""
    import pyogrio

    path = Path(path)
    if DRIVERS.get(path.suffix.lower()) != "GPKG":
        return
    refuse_open_geopackage(path, option)
    if not path.exists():
        return
    try:
        present = [str(name) for name, _ in pyogrio.list_layers(path)]
        with contextlib.closing(sqlite3.connect(path.resolve().as_uri() + "?mode=ro", uri=True)) as db:
            marked = {r[0] for r in db.execute("SELECT table_name FROM gpkg_contents WHERE description = ? "
                                               "OR description LIKE ?", (MARK, layer_description("%")))}
    except Exception:  # pyogrio's DataSourceError and kin: not a GeoPackage
        raise OptionError(f"{path}: exists and is not a GeoPackage GDAL can read; it would be replaced as a "
                          "whole: move it (or remove it), or give another file name", param=option) from None
    refuse_open_geopackage(path, option)  # the empty -wal/-shm the read-only looks leave at a file in WAL mode
    foreign = [name for name in present if name not in layer_names and name != QGIS_STYLES]
    if foreign:
        raise OptionError(f"{path}: the file is replaced as a whole, and it holds the layer(s) {', '.join(foreign)}, "
                          f"which {what} does not write: move the file (or remove it), or give another file name",
                          param=option)
    unmarked = [name for name in present if name != QGIS_STYLES and name not in marked]
    if unmarked and not owned:
        raise OptionError(f"{path}: the file is replaced as a whole, and its layer(s) {', '.join(unmarked)} have the "
                          f"names {what} writes but not the mark of its outputs (a file of yours, such as a "
                          "reference, or an output of a version before 2026-12-01): move the file (or remove it), or "
                          "give another file name", param=option)


def refuse_open_geopackage(path, option: str | None = None) -> None:
    """``InputError`` (``OptionError`` naming ``option`` when given) when the GeoPackage ``path`` has a
    non-empty write-ahead log beside it (``<path>-wal``: open for editing in QGIS, or left by a crash), or
    an empty ``-wal``/``-shm`` that another program still holds. SQLite replays a ``-wal`` onto whatever file
    bears the name, so a file renamed in over the old one would take the old one's pages (``pragma
    integrity_check`` fails, the old tables reappear). A log nothing holds (empty, or left by a crash) is written
    into the file and removed with its ``-shm`` (SQLite checkpoints and removes both when the last connection
    closes: we open and close one; removing a crash's log instead would lose what it holds, review 15)."""
    path = Path(path)
    wal, shm = Path(f"{path}-wal"), Path(f"{path}-shm")
    if not wal.exists() and not shm.exists():
        return
    error = OptionError if option else InputError
    advice = "save and close it in the program that holds it, then run again"
    if path.is_file():
        # the last connection to close checkpoints the (empty) log and removes -wal and -shm; a program that
        # holds the file keeps them (and would write its log over the new file)
        with contextlib.suppress(sqlite3.Error), contextlib.closing(sqlite3.connect(path)) as db:
            db.execute("SELECT count(*) FROM sqlite_master").fetchone()
    else:  # no database: the log and index of a file that is gone
        with contextlib.suppress(OSError):
            wal.unlink(missing_ok=True)
    if not wal.exists():  # an index without a log: nothing in WAL mode holds the file
        with contextlib.suppress(OSError):
            shm.unlink(missing_ok=True)
    if wal.exists() and wal.stat().st_size > 0:
        raise error(f"{path}: open for editing in QGIS (another program holds it): its SQLite write-ahead log "
                    f"{wal.name} holds changes that SQLite would replay onto the new file: {advice}", param=option)
    if wal.exists():
        raise error(f"{path}: open in another program (QGIS?): its SQLite log {wal.name} is held, and SQLite "
                    f"would apply it to the new file: {advice}", param=option)


@contextlib.contextmanager
def _gdal_timestamp(pyogrio, timestamp: str | None):
    """GDAL's OGR_CURRENT_DATE set to ``timestamp`` for the block (a process-wide option: the writers that fix
    it, the simulator's, run in one thread)."""
    if timestamp is None:
        yield
        return
    before = pyogrio.get_gdal_config_option("OGR_CURRENT_DATE")
    pyogrio.set_gdal_config_options({"OGR_CURRENT_DATE": timestamp})
    try:
        yield
    finally:
        pyogrio.set_gdal_config_options({"OGR_CURRENT_DATE": before})
