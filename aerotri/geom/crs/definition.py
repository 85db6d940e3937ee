"""CRSs: parsing (the one parser every command uses), labels, units, and plausibility checks of
coordinates against a CRS.

The checks catch the usual mix-ups before any arithmetic: degrees given for a projected CRS,
feet for metres, eastings without the Gauss-Krueger zone prefix, or a wrong zone.
"""

from __future__ import annotations

import concurrent.futures
import functools
import math
import re

import numpy as np
import pyproj

from aerotri.core.crs_files import is_crs_file, read_crs_file
from aerotri.core.errors import CrsError, InputError


@functools.lru_cache(maxsize=256)
def _crs_from_code(code: str) -> pyproj.CRS:
    return pyproj.CRS.from_user_input(code)


def parse_crs(value, source: str = "CRS") -> pyproj.CRS:
    """A pyproj CRS from ``4326``, ``"4326"``, ``"EPSG:4326"``, WKT, PROJ text, the path of a .wkt or .prj file
    holding WKT (``CRS_FILE_SUFFIXES``), or a pyproj CRS.

    ``CrsError`` (an ``InputError``) naming ``source`` (the option, file or key) if PROJ does not know it, or the file
    when it cannot be read.
    """
    if isinstance(value, pyproj.CRS):
        return value
    if hasattr(value, "to_wkt") and not isinstance(value, str):  # rasterio's CRS
        return _crs_from_code(value.to_wkt())
    text = str(value).strip()
    if not text:
        raise CrsError(f"{source}: empty CRS (expected e.g. EPSG:32649)")
    if is_crs_file(text):
        return _crs_from_file(text, source)
    if text.startswith("+") and _STATED_DATUM.search(text):
        return _crs_on_stated_datum(text, source)
    if text.isdigit():
        text = f"EPSG:{text}"
    try:
        return _crs_from_code(text.upper() if text.lower().startswith("epsg:") else text)
    except pyproj.exceptions.CRSError:
        raise CrsError(f"{source}: unknown CRS {value!r} (not an EPSG code, WKT or PROJ string PROJ knows)") from None


# a PROJ string's datum stated by the EPSG code of its geographic CRS (PROJ's +datum takes a few names only, none
# for CGCS2000): "+proj=tmerc +lon_0=114.5 ... +ellps=GRS80 +datum=EPSG:4490"
_STATED_DATUM = re.compile(r"\s*\+datum=(?P<code>epsg:\d+)(?=\s|$)", re.IGNORECASE)
UNKNOWN_DATUM_PREFIX = "Unknown based on "  # PROJ's datum of a definition by its ellipsoid alone (+ellps=GRS80)


def _crs_on_stated_datum(text: str, source: str) -> pyproj.CRS:
    """A PROJ string whose ``+datum=EPSG:nnnn`` states its datum (leftovers2: a local Gauss-Krueger grid, "+proj=tmerc
    +lon_0=114.5 +k=1 +x_0=500000 +ellps=GRS80", has an ellipsoid and no datum, so PROJ had only a ballpark operation
    from CGCS2000 to it): its projection on that geographic CRS, exact. Its ellipsoid, when the text gives one, must
    be the datum's; a datum stated twice (+towgs84, +nadgrids or another +datum beside it) and a 3D geographic CRS
    as the datum are refused (``CrsError`` naming them; review 44: +towgs84 dropped the stated datum, without +ellps
    ending on WGS 84). +vunits (the heights' unit) and +geoidgrids (heights above that geoid: a compound CRS) keep
    the meaning PROJ gives them (review 44: +vunits was dropped, +geoidgrids an AttributeError)."""
    m = _STATED_DATUM.search(text)
    rest = _STATED_DATUM.sub("", text).strip()
    twice = re.search(r"\+(towgs84|nadgrids|datum)=\S*", rest)
    if twice:
        raise CrsError(f"{source}: {text!r} states its datum twice, +datum={m['code']} and {twice[0]}: give one (the "
                       f"datum by the EPSG code of its geographic CRS, +datum={m['code']}, exact; or +towgs84 / "
                       "+nadgrids, the shift of an unnamed datum to WGS 84)")
    try:
        base = _crs_from_code(m["code"].upper())
        plain = _crs_from_code(rest)
    except pyproj.exceptions.CRSError:
        raise CrsError(f"{source}: unknown CRS {text!r} (a PROJ string with +datum=EPSG:nnnn, the EPSG code of a "
                       "geographic CRS, e.g. +datum=EPSG:4490 for CGCS2000)") from None
    if not base.is_geographic:
        raise CrsError(f"{source}: +datum={m['code']} is {base.name}, not a geographic CRS; give the code of the "
                       "datum's geographic CRS (e.g. EPSG:4490 for CGCS2000, EPSG:4326 for WGS 84)")
    if len(base.axis_info) == 3:
        two_d = base.to_2d().to_epsg(min_confidence=90)
        raise CrsError(f"{source}: +datum={m['code']} is {base.name}, a 3D geographic CRS (with ellipsoidal "
                       "heights); give the code of the datum's 2D geographic CRS"
                       + (f", EPSG:{two_d}" if two_d else " (e.g. EPSG:4490 for CGCS2000, EPSG:4326 for WGS 84)")
                       + " (heights: +vunits, +geoidgrids)")
    # (+geoidgrids: PROJ makes a compound CRS, the heights above the geoid its vertical part)
    horiz, vert = (plain.sub_crs_list[0], plain.sub_crs_list[1]) if plain.is_compound else (plain, None)
    if re.search(r"\+(ellps|a|rf|f|b|R)=", rest):
        e, d = horiz.ellipsoid, base.ellipsoid
        if abs(e.semi_major_metre - d.semi_major_metre) > 1e-4 or \
                abs(e.inverse_flattening - d.inverse_flattening) > 1e-9 * d.inverse_flattening:
            raise CrsError(f"{source}: the ellipsoid of {rest!r} ({e.name}: a {e.semi_major_metre} m, 1/f "
                           f"{e.inverse_flattening}) is not that of +datum={m['code']} ({base.datum.name}: {d.name}, "
                           f"a {d.semi_major_metre} m, 1/f {d.inverse_flattening}): one of them is wrong")
    three_d = len(horiz.axis_info) == 3  # (+vunits: the ellipsoidal heights' unit, a third axis)
    if horiz.is_geographic:
        if not three_d:
            h = base
        else:
            d = horiz.to_json_dict()  # its axes and units (+vunits), on the stated datum
            for k in ("datum", "datum_ensemble"):
                d.pop(k, None)
            d.update({k: v for k, v in base.to_json_dict().items() if k in ("datum", "datum_ensemble")})
            d["name"] = base.name
            h = pyproj.CRS.from_json_dict(d)
    elif not horiz.is_projected:
        raise CrsError(f"{source}: +datum=EPSG:nnnn is taken with a projection (+proj=tmerc, +proj=utm, ...) or "
                       f"+proj=longlat, not {rest!r}")
    else:
        d = horiz.to_json_dict()  # the projection, its axes and units on the stated geographic CRS
        d["base_crs"] = (base.to_3d() if three_d else base).to_json_dict()
        d["name"] = f"{base.name} / {horiz.coordinate_operation.method_name} ({rest})"
        h = pyproj.CRS.from_json_dict(d)
    if vert is None:
        return h
    return pyproj.crs.CompoundCRS(name=f"{h.name} + {vert.name}", components=[h, vert])


def unknown_datum_hint(crs: pyproj.CRS, other: pyproj.CRS) -> str | None:
    """What is missing from ``crs`` when it names an ellipsoid but no datum (a PROJ string with +ellps and neither
    +datum nor +towgs84), so that PROJ has only a ballpark operation from ``other``: its datum, and how to state it
    (the datum of ``other`` when its ellipsoid is the same: the likely one). Also for a vertical CRS whose datum is
    unknown (``VDATUM["unknown"]``: a DEM cut with Debian's gdal_translate 3.6 from one in "Lo25 WGS84 + EGM2008
    height" was refused naming EGM2008 height on both sides). None for a CRS with a datum."""
    v = vertical_crs(crs)
    if v is not None and v.datum is not None and v.datum.name.lower() == "unknown":
        ov = vertical_crs(other)
        likely = (f": if they are {ov.name} ({ov.datum.name}), as the name says, give the file its vertical datum "
                  "again (the WKT of the file it was cut from, e.g. rio edit-info --crs), and the operation is exact"
                  if ov is not None and ov.name == v.name and ov.datum is not None
                  and ov.datum.name.lower() != "unknown" else
                  ": state it (a vertical CRS by its EPSG code or WKT with its VDATUM)")
        return (f"its vertical CRS {v.name!r} names no vertical datum (VDATUM unknown; some GDAL versions write a "
                f"copied compound CRS so), so PROJ cannot know what its heights are{likely}")
    h = horizontal_crs(crs)
    if h.is_bound or h.datum is None or not h.datum.name.startswith(UNKNOWN_DATUM_PREFIX):
        return None
    e = h.ellipsoid
    words = (f"the definition names the ellipsoid {e.name} but no datum (datums share ellipsoids: GRS 1980 carries "
             "CGCS2000, ETRS89, NAD83, GDA94 ...), so PROJ cannot know the datum shift")
    o = horizontal_crs(other)
    geo = o.geodetic_crs if not o.is_geocentric else None
    code = geo.to_epsg(min_confidence=70) if geo is not None and geo.is_geographic else None
    same = (geo is not None and geo.ellipsoid is not None and abs(geo.ellipsoid.semi_major_metre - e.semi_major_metre)
            < 1e-4 and abs(geo.ellipsoid.inverse_flattening - e.inverse_flattening) < 1e-9 * e.inverse_flattening)
    if same and code:
        return (f"{words}: if it is on {geo.datum.name} (the same ellipsoid), state it, and the operation is exact: "
                f"add +datum=EPSG:{code} to the PROJ string (or give WKT with its DATUM, a .wkt/.prj file)")
    return (f"{words}: state its datum by the EPSG code of its geographic CRS, +datum=EPSG:nnnn in the PROJ string (or "
            "give WKT with its DATUM, a .wkt/.prj file)")


def _crs_from_file(name: str, source: str) -> pyproj.CRS:
    """The CRS of a .wkt or .prj file (leftovers2: `--to grid.wkt` was refused as an unknown CRS: only the WKT text
    was taken, pasted on the command line)."""
    return read_crs_file(name, source)[1]


@functools.lru_cache(maxsize=256)  # PROJ's identification takes 10-50 ms; labels ask it again and again
def epsg_code(crs: pyproj.CRS) -> int | None:
    """The EPSG code of ``crs`` when it is that code's CRS, else None: PROJ's identification at 90 % confidence, or
    a lower one (70 %: a PROJ string, "+proj=utm +zone=49 +datum=WGS84", whose datum is WGS 84 and not the WGS 84
    ensemble of EPSG:32649) and a bound CRS's base (an ODM header "+proj=utm +zone=49 +datum=WGS84
    +towgs84=0,0,0,0,0,0,0", leftovers2: named "Position Vector transformation (geog2D domain) ()" for EPSG:32649)
    when ``same_crs`` takes the two for one (a TOWGS84 moving no point by ``BOUND_SAME_M``); not for a definition by
    its ellipsoid alone (+ellps=GRS80: PROJ's 70 % names an ETRS89 grid for it)."""
    code = crs.to_epsg(min_confidence=90)
    if code:
        return code
    base = without_bound(crs)
    datum = horizontal_crs(base).datum
    if datum is None or datum.name.startswith(UNKNOWN_DATUM_PREFIX):
        return None  # a definition by its ellipsoid alone states no datum: named by what it says
    code = base.to_epsg(min_confidence=70)
    if code is None:
        return None
    try:
        return code if same_crs(crs, _crs_from_code(f"EPSG:{code}")) else None
    except (pyproj.exceptions.CRSError, CrsError):
        return None


def crs_label(crs: pyproj.CRS) -> str:
    """``EPSG:nnnn`` when the CRS has an EPSG identity (``epsg_code``), else its name; a projected CRS without a name
    (PROJ calls one given as a PROJ string "unknown") by its projection, parameters and datum."""
    code = epsg_code(crs)
    if code:
        return f"EPSG:{code}"
    base = without_bound(crs) if crs.is_bound else crs  # (a bound CRS's operation is its TOWGS84, not its projection)
    op = base.coordinate_operation
    if base.name in ("", "unknown") and op is not None:
        params = ", ".join(f"{p.name} {p.value:g}" for p in op.params if p.value)
        datum = base.datum.name if base.datum is not None else "unknown datum"
        return f"{op.method_name} ({params}), {datum}"
    return base.name


@functools.lru_cache(maxsize=64)
def epsg_wkt(code: int) -> str:
    """WKT2:2019 of EPSG ``code`` as PROJ's database defines it, the same text in any process and thread.

    Made in a new thread, so with a new PROJ context (pyproj keeps one per thread) and empty caches: the calling
    thread's context may hand out another definition of the same code. PROJ 9.5 (pyproj 3.7.2) caches a datum
    ensemble turned into a plain datum (``DatumEnsemble::asDatum``: identifying a CRS object, or writing it as PROJ
    text or WKT1) under the code the ensemble is cached under; when that context's cache does not hold the ensemble
    itself (a context renewed by ``pyproj.datadir.set_data_dir`` while CRS objects made before it live on, as
    ``parse_crs``'s cache keeps them), every CRS on that ensemble it then makes from the database has the plain
    datum: WGS 84 CRSs written with ``DATUM["World Geodetic System 1984"]`` for the ensemble (other bytes, same
    coordinates). Files that carry a CRS as text take it from here."""
    with concurrent.futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix="epsg-wkt") as pool:
        # the CRS object stays in that thread: it would outlive the context it was made in
        return pool.submit(lambda: pyproj.CRS.from_epsg(int(code)).to_wkt()).result()


def horizontal_crs(crs: pyproj.CRS) -> pyproj.CRS:
    """The horizontal part of a compound CRS, else the CRS itself."""
    crs = parse_crs(crs)
    if crs.is_compound:
        return crs.sub_crs_list[0]
    return crs


def vertical_crs(crs: pyproj.CRS) -> pyproj.CRS | None:
    """The vertical part of a compound CRS, else None (a 2D CRS's heights are not declared)."""
    crs = parse_crs(crs)
    if crs.is_compound:
        for c in crs.sub_crs_list[1:]:
            if c.is_vertical:
                return c
    return None


def without_bound(crs: pyproj.CRS) -> pyproj.CRS:
    """A "bound" CRS (WKT1 with TOWGS84, PROJ string with +towgs84: a CRS with its transformation to WGS 84 attached)
    as the CRS it is bound to (its ``source_crs``), in a compound CRS part by part; any other CRS as it is. The
    coordinates are those of the source CRS: the attached transformation only says how to reach WGS 84."""
    if crs.is_bound and crs.source_crs is not None:
        return crs.source_crs
    if crs.is_compound and any(c.is_bound for c in crs.sub_crs_list):
        return pyproj.crs.CompoundCRS(crs.name, [without_bound(c) for c in crs.sub_crs_list])
    return crs


# A bound CRS (TOWGS84) is its source CRS when PROJ's transformation from one to the other (what CrsTransformer does
# with them) moves no point of the area by more than this: RD New's usual TOWGS84 against EPSG:28992 moves none (0.000
# m), a wrong one (review 31: 593.16,26.15,...) 48.6 m, a PROJ string's +towgs84 against the EPSG CRS 45-86 m
BOUND_SAME_M = 0.1


def _axis_order_text(h: pyproj.CRS) -> str:
    """"x = easting, y = northing", or the CRS's own directions (trial-ngi: South Africa's Lo grids, EPSG:2051, are
    westing, southing), in the x, y order the toolkit reads (east-west axis first)."""
    dirs = [str(a.direction).lower() for a in h.axis_info]
    ew = next((d for d in dirs if d in ("east", "west")), "east")
    ns = next((d for d in dirs if d in ("north", "south")), "north")
    return f"x = {ew}ing, y = {ns}ing"


def same_crs(a, b) -> bool:
    """True when two CRSs are the same (axis order ignored; definitions that differ only in naming but
    carry the same EPSG identity agree); None equals only None. A bound CRS (WKT1 with TOWGS84, PROJ text with
    +towgs84) is the same as another that agrees with its source CRS only when PROJ's transformation between the two,
    which ``CrsTransformer`` applies, moves points of the area by under ``BOUND_SAME_M`` (s27-fixes: RD New with its
    usual TOWGS84 is EPSG:28992; review 31: one with another TOWGS84 is not, its points would move 48.6 m): the
    same CRS is never transformed, another never left unshifted."""
    if a is None or b is None:
        return a is None and b is None
    a, b = parse_crs(a), parse_crs(b)
    if a.equals(b, ignore_axis_order=True):
        return True
    ua, ub = without_bound(a), without_bound(b)
    if not _same_unbound(ua, ub):
        return False
    if ua is a and ub is b:
        return True
    return _bound_shift_m(horizontal_crs(a), horizontal_crs(b)) < BOUND_SAME_M


def _same_unbound(a: pyproj.CRS, b: pyproj.CRS) -> bool:
    if a.equals(b, ignore_axis_order=True):
        return True
    ea, eb = a.to_epsg(min_confidence=70), b.to_epsg(min_confidence=70)
    return ea is not None and ea == eb


@functools.lru_cache(maxsize=64)
def _bound_shift_m(a: pyproj.CRS, b: pyproj.CRS) -> float:
    """The largest horizontal move (m; inf when PROJ fails) of PROJ's transformation from ``a`` to ``b`` at the
    corners and centre of the area of use of either (else around the projection's origin), given in ``a``."""
    base = without_bound(a)
    aou = next((c.area_of_use for c in (without_bound(b), base, b, a) if c.area_of_use is not None), None)
    if aou is not None and aou.east > aou.west:
        lon = np.array([aou.west, aou.east, aou.west, aou.east, 0.5 * (aou.west + aou.east)])
        lat = np.array([aou.south, aou.south, aou.north, aou.north, 0.5 * (aou.south + aou.north)])
        # 0.1 of the way in: an area's corners may lie past a projection's domain (UTM's 84 deg N)
        lon = lon + 0.1 * (lon[4] - lon)
        lat = lat + 0.1 * (lat[4] - lat)
    else:
        op = base.coordinate_operation
        params = {p.name.lower(): p.value for p in op.params} if op is not None else {}
        lon0 = next((v for k, v in params.items() if k.startswith("longitude of")), 0.0)
        lat0 = next((v for k, v in params.items() if k.startswith("latitude of")), 0.0)
        lon = lon0 + np.array([-1.0, 1.0, -1.0, 1.0, 0.0])
        lat = np.clip(lat0 + np.array([-1.0, -1.0, 1.0, 1.0, 0.0]), -89.0, 89.0)
    try:
        with np.errstate(all="ignore"):
            x, y = pyproj.Transformer.from_crs(base.geodetic_crs, base, always_xy=True).transform(
                *greenwich_to_geodetic(base.geodetic_crs, lon, lat))
            X, Y = pyproj.Transformer.from_crs(a, b, always_xy=True).transform(x, y)
    except pyproj.exceptions.ProjError:
        return math.inf
    if base.is_geographic:
        dx = (np.asarray(X) - x) * 111_320.0 * np.cos(np.radians(lat))
        dy = (np.asarray(Y) - y) * 111_320.0
    else:
        dx = (np.asarray(X) - x) * linear_unit_m(base)
        dy = (np.asarray(Y) - y) * linear_unit_m(base)
    shift = np.hypot(dx, dy)
    return float(shift.max()) if np.all(np.isfinite(shift)) else math.inf


def same_horizontal(a, b) -> bool:
    """True when two CRSs have the same horizontal part (compound CRSs compared by their parts)."""
    return same_crs(horizontal_crs(a), horizontal_crs(b))


def other_realisation(a, b) -> tuple[str, str] | None:
    """When two horizontal CRSs are the same projection (conversion and axis units) on two datums, the datums'
    names (a's, b's: "World Geodetic System 1984 (G1762)", "... ensemble"): a datum realisation against its ensemble
    or another realisation (ETRF2000 against ETRS89), coordinates that differ by centimetres to metres; else None."""
    a, b = without_bound(horizontal_crs(a)), without_bound(horizontal_crs(b))
    if not (a.is_projected and b.is_projected) or a.datum is None or b.datum is None:
        return None
    units_a = [ax.unit_conversion_factor for ax in a.axis_info]
    units_b = [ax.unit_conversion_factor for ax in b.axis_info]
    if a.coordinate_operation != b.coordinate_operation or units_a != units_b or a.datum == b.datum:
        return None
    return a.datum.name, b.datum.name


def same_vertical(a, b) -> bool:
    """False only when both CRSs declare a vertical part and the two differ (a 2D CRS says nothing)."""
    va, vb = vertical_crs(a), vertical_crs(b)
    return va is None or vb is None or va.equals(vb)


def parse_heights(value, source: str = "[project] heights") -> pyproj.CRS | None:
    """The project's height system: ``"ellipsoidal"`` (None) or a vertical CRS (e.g. ``EPSG:3855``,
    EGM2008 height; ``EPSG:5773``, EGM96 height)."""
    text = str(value or "ellipsoidal").strip()
    if text.lower() == "ellipsoidal":
        return None
    crs = parse_crs(text, source)
    if not crs.is_vertical:
        raise CrsError(f"{source}: {crs_label(crs)} ({crs.name}) is not a vertical CRS; expected \"ellipsoidal\" or "
                       "a vertical CRS such as EPSG:3855 (EGM2008 height)")
    return crs


def height_crs(horizontal: pyproj.CRS, heights: pyproj.CRS | None) -> pyproj.CRS:
    """The 3D CRS of coordinates in ``horizontal`` with heights in ``heights`` (None: ellipsoidal)."""
    h = horizontal_crs(horizontal)
    if heights is None:
        return h.to_3d()
    # a PROJ string's CRS is called "unknown": named by its projection (s95: "unknown + EGM2008 height")
    name = h.name if h.name not in ("", "unknown") else crs_label(h)
    return pyproj.crs.CompoundCRS(f"{name} + {heights.name}", [h, heights])


def linear_unit_m(crs: pyproj.CRS) -> float:
    """Metres per unit of the first horizontal axis (1 for metre grids, 0.3048006 for US survey feet);
    ``nan`` for geographic CRSs (degrees)."""
    h = horizontal_crs(crs)
    if h.is_geographic:
        return float("nan")
    return float(h.axis_info[0].unit_conversion_factor)


def length_in_units(value_m: float, unit_m: float) -> float:
    """A length given in metres (every length option is) in a unit of ``unit_m`` metres, to 10 significant
    digits: the rounding makes 0.3048006096 m exactly 1 US survey foot and 0.6096 m exactly 2 feet, so that
    a cell size or contour interval meant in feet comes out as that whole number of feet."""
    v = value_m / unit_m
    return float(f"{v:.10g}") if math.isfinite(v) else v


def unit_name(crs: pyproj.CRS) -> str:
    """Short unit of the horizontal axes: 'deg', 'm', 'ft' or 'us-ft'."""
    h = horizontal_crs(crs)
    if h.is_geographic:
        return "deg"
    return length_unit_name(linear_unit_m(h))


# a grid whose point scale factor at the block is off 1 by more than this is no ground measure (import note, ortho
# warning): survey grids keep it within 0.1 % (UTM: 0.9996-1.001 in its zone); a web map's Pseudo-Mercator is 1.15 at
# 30 degrees latitude, 1.46 at 47
GRID_SCALE_LIMIT = 0.01


def _greenwich_degrees(geodetic: pyproj.CRS) -> tuple[float, float, float]:
    """(degrees per longitude unit, degrees per latitude unit, prime meridian's longitude east of Greenwich in
    degrees) of a geographic CRS: (1, 1, 0) for most; NTF (Paris) counts grads from Paris, MGI (Ferro) degrees from
    Ferro (review 36: their points compared with areas of use in Greenwich degrees were refused in Paris)."""
    axes = {a.direction.lower(): a.unit_conversion_factor for a in geodetic.axis_info}
    rad = 180.0 / math.pi
    pm = geodetic.prime_meridian
    return (axes.get("east", math.pi / 180.0) * rad, axes.get("north", math.pi / 180.0) * rad,
            float(pm.longitude) * pm.unit_conversion_factor * rad if pm is not None else 0.0)


def geodetic_to_greenwich(geodetic: pyproj.CRS, lon, lat):
    """(lon_deg, lat_deg) east of Greenwich of coordinates (lon, lat; always_xy order) in geographic CRS
    ``geodetic``'s own units and prime meridian; longitudes wrapped to [-180, 180)."""
    f_lon, f_lat, pm_deg = _greenwich_degrees(geodetic)
    if (f_lon, f_lat, pm_deg) == (1.0, 1.0, 0.0):
        return lon, lat
    lon_deg = (np.asarray(lon, dtype=float) * f_lon + pm_deg + 180.0) % 360.0 - 180.0
    return lon_deg, np.asarray(lat, dtype=float) * f_lat


def greenwich_to_geodetic(geodetic: pyproj.CRS, lon_deg, lat_deg):
    """The inverse of ``geodetic_to_greenwich``: (lon, lat) in ``geodetic``'s own units and prime meridian."""
    f_lon, f_lat, pm_deg = _greenwich_degrees(geodetic)
    if (f_lon, f_lat, pm_deg) == (1.0, 1.0, 0.0):
        return lon_deg, lat_deg
    return (np.asarray(lon_deg, dtype=float) - pm_deg) / f_lon, np.asarray(lat_deg, dtype=float) / f_lat


def point_scale_factor(crs, lon_deg: float, lat_deg: float) -> float:
    """The point scale factor of the projected CRS ``crs`` at (lon, lat) in degrees: the geometric mean of its
    meridional and parallel scales (1.0004 on a UTM zone's edge, 1.46 for Web Mercator at 47 degrees)."""
    # PROJ counts the longitude from the CRS's own prime meridian here (MGI (Ferro): 17.67 deg west; review 38: a
    # Ferro grid read 1.021 at Vienna for 1.0000001)
    pm_deg = _greenwich_degrees(horizontal_crs(crs).geodetic_crs)[2]
    f = pyproj.Proj(crs).get_factors(float(lon_deg) - pm_deg, float(lat_deg))
    return float(np.sqrt(f.meridional_scale * f.parallel_scale))


def utm_zone_label(lon_deg: float, lat_deg: float) -> str:
    """The WGS 84 UTM zone of (lon, lat) in degrees as an EPSG label (EPSG:326zz north, 327zz south)."""
    zone = int(((float(lon_deg) + 180.0) % 360.0) // 6.0) + 1  # 180 E is 180 W (zone 1); 32661 would be UPS North
    return f"EPSG:{32600 + zone if lat_deg >= 0 else 32700 + zone}"


_LONG_NAMES = {"deg": "degree", "m": "metre", "ft": "foot", "us-ft": "US survey foot"}


def length_unit_name(unit_m: float, long: bool = False) -> str:
    """Name of a length unit given in metres per unit: 'm', 'ft', 'us-ft' (``long``: as GDAL band unit
    types and WKT spell them: 'metre', 'foot', 'US survey foot'); other units as '<f>m' / '<f> metre'."""
    if abs(unit_m - 1.0) < 1e-12:
        short = "m"
    elif abs(unit_m - 0.3048) < 1e-9:
        short = "ft"
    elif abs(unit_m - 1200 / 3937) < 1e-9:
        short = "us-ft"
    else:
        return f"{unit_m:g} metre" if long else f"{unit_m:g}m"
    return _LONG_NAMES[short] if long else short


# metres per unit by the names files give length units in (a GeoTIFF band's unit type, a VERTICAL_UNITS tag), the
# names ``length_unit_name`` writes among them
_UNIT_M_BY_NAME = {"m": 1.0, "metre": 1.0, "meter": 1.0, "metres": 1.0, "meters": 1.0, "ft": 0.3048, "foot": 0.3048,
                   "feet": 0.3048, "international foot": 0.3048, "us-ft": 1200 / 3937, "us survey foot": 1200 / 3937,
                   "us_survey_foot": 1200 / 3937, "ftus": 1200 / 3937}


def length_unit_m(name) -> float | None:
    """Metres per unit of a length unit named as ``length_unit_name`` (and GDAL, WKT) spell them ('metre', 'ft',
    'US survey foot', ...; any case); None for another name."""
    return _UNIT_M_BY_NAME.get(str(name).strip().lower()) if name else None


def unit_long_name(crs: pyproj.CRS) -> str:
    """The horizontal axes' unit as GDAL and WKT spell it: 'degree', 'metre', 'foot', 'US survey foot'."""
    return _LONG_NAMES.get(unit_name(crs)) or length_unit_name(linear_unit_m(crs), long=True)


def height_unit_m(crs: pyproj.CRS) -> float:
    """Metres per unit of height values in ``crs``: the vertical axis's unit of a compound or 3D CRS; a 2D
    projected CRS has heights in its horizontal unit (the LAS convention, as ``transform`` reads
    z); a 2D geographic CRS in metres."""
    crs = parse_crs(crs)
    if crs.is_compound:
        v = vertical_crs(crs)
        if v is not None and v.axis_info:
            return float(v.axis_info[0].unit_conversion_factor)
    if len(crs.axis_info) >= 3:
        return float(crs.axis_info[2].unit_conversion_factor)
    f = linear_unit_m(crs)
    return 1.0 if np.isnan(f) else f


def map_axes_unit_m(crs, source: str = "CRS") -> tuple[float, float, float]:
    """Metres per unit of a map's x, y and heights (``linear_unit_m``, ``height_unit_m``): 0.3048 for a feet CRS.

    ``CrsError`` naming ``source`` (the file or key) when the CRS's map axes have no length unit: geographic
    (degrees), geocentric (X, Y, Z of the earth's centre, not map axes) or without any unit. Ground figures read
    in such a unit as metres would be silently wrong (a DOM in degrees: "RMS 0.000 m")."""
    h = horizontal_crs(parse_crs(crs, source))
    u = (linear_unit_m(h),) * 2 + (height_unit_m(h),) if h.axis_info and not h.is_geocentric else (math.nan,) * 3
    if not all(math.isfinite(x) and x > 0 for x in u):
        kind = "geographic" if h.is_geographic else "geocentric" if h.is_geocentric else "without a length unit"
        raise CrsError(f"{source}: {crs_label(h)} ({h.name}) is {kind}; expected a projected or local CRS whose "
                       "axes are in metres or feet")
    return tuple(float(x) for x in u)


def map_axis_signs(crs) -> tuple[float, float]:
    """(+1 or -1, +1 or -1): the sign that turns a step along a map's x, y (GIS order: the east-west axis first) into
    a step east and north. -1 for a south-oriented grid's westing and southing (South Africa's Lo grids, EPSG:2046
    to 2055, ``+axis=wsu``): a displacement in its units read as east and north points the other way. An axis that
    runs along a meridian (polar stereographic grids: EPSG:3413's x "south along 45°E") is not south-oriented: its
    map x, y still run right and up, so +1."""
    h = horizontal_crs(parse_crs(crs.to_wkt() if hasattr(crs, "to_wkt") else crs))
    if h.is_bound:  # a BoundCRS (+towgs84): its axes are the source CRS's (the JSON of the bound one has none)
        h = h.source_crs
    axes = h.to_json_dict().get("coordinate_system", {}).get("axis", [])
    directions = [str(a.get("direction", "")).lower() for a in axes]
    # PROJ labels a polar grid's axes by the meridian they point along ("south along 90°E"), and WKT1 / a GeoTIFF's
    # CRS drops the meridian but keeps "south, south": two axes of one direction are a polar grid's, not a southing
    if len(set(directions)) < len(directions):
        return 1.0, 1.0
    reversed_dirs = {d for d, a in zip(directions, axes) if "meridian" not in a}
    return (-1.0 if "west" in reversed_dirs else 1.0), (-1.0 if "south" in reversed_dirs else 1.0)


def check_stored_crs(requested: pyproj.CRS, stored, where: str, x, y, tolerance: float) -> None:
    """``CrsError`` naming ``where`` unless the CRS a GeoTIFF holds (``stored``: rasterio's CRS or None) is
    ``requested``. GDAL may rewrite a definition into an equivalent one (polar stereographic variant A
    as variant B): that counts as the same when datum, units and vertical part agree and the grid points
    (x, y) unproject with ``requested`` and reproject with ``stored`` to within ``tolerance`` units."""
    label = crs_label(requested) + ("" if crs_label(requested) == requested.name else f" ({requested.name})")
    why = None
    if stored is None:
        why = "GDAL wrote no CRS at all"
    else:
        got = parse_crs(stored)
        if not same_crs(requested, got):
            h_req, h_got = horizontal_crs(requested), horizontal_crs(got)
            if len(requested.axis_info) != len(got.axis_info) or requested.is_compound != got.is_compound:
                why = f"GDAL stores it as {got.type_name} {got.name!r} (with {len(got.axis_info)} axes)"
            elif requested.is_compound and not vertical_crs(requested).equals(vertical_crs(got)):
                why = f"GDAL stores its vertical part as {vertical_crs(got).name!r}"
            elif (h_req.type_name != h_got.type_name
                  or not h_req.geodetic_crs.equals(h_got.geodetic_crs, ignore_axis_order=True)
                  or h_req.is_bound and not h_req.coordinate_operation.equals(h_got.coordinate_operation)):
                why = f"GDAL stores it with another datum ({h_got.name!r}, {h_got.geodetic_crs.name!r})"
            elif h_req.is_projected and abs(linear_unit_m(h_req) - linear_unit_m(h_got)) > 1e-12:
                why = f"GDAL stores it in {unit_name(h_got)}"
            else:
                with np.errstate(all="ignore"):
                    X, Y = pyproj.Transformer.from_crs(h_req, h_got, always_xy=True).transform(
                        np.asarray(x, float), np.asarray(y, float), errcheck=False)
                err = np.hypot(np.asarray(X) - x, np.asarray(Y) - y)
                if not np.all(np.isfinite(err)) or float(np.max(err)) > tolerance:
                    why = f"GDAL stores it as {got.name!r}, which puts the grid elsewhere"
    if why:
        raise CrsError(f"{where}: {label} cannot be stored in a GeoTIFF ({why}); give the CRS in a form GeoTIFF "
                       "keeps: an EPSG code, or a 2D projected CRS (heights are then in its linear unit and the "
                       "raster says so in VERTICAL_UNITS), or a compound CRS with an EPSG vertical CRS")


def geotiff_crs(crs: pyproj.CRS, where: str, x, y, tolerance: float):
    """The rasterio CRS to write ``crs`` into a GeoTIFF (from its WKT), after a round trip through an
    in-memory GeoTIFF that ``check_stored_crs`` accepts (so a product never loses or changes its CRS)."""
    import rasterio
    from rasterio.transform import Affine
    from rasterio.crs import CRS as RioCRS
    from rasterio.io import MemoryFile

    rio = RioCRS.from_wkt(crs.to_wkt())
    # without PAM: GDAL would keep a CRS it cannot encode in an .aux.xml side file, which a copy loses
    with rasterio.Env(GDAL_PAM_ENABLED=False), MemoryFile() as mem:
        with mem.open(driver="GTiff", width=1, height=1, count=1, dtype="uint8", crs=rio,
                      transform=Affine(1.0, 0.0, 0.5, 0.0, -1.0, 0.5)):
            pass
        with mem.open() as ds:
            stored = ds.crs
    check_stored_crs(crs, stored, where, x, y, tolerance)
    return rio


def impossible_in(crs: pyproj.CRS, x, y, tolerance_m: float = 1.0) -> int | None:
    """The index of the first point of projected ``crs`` (x, y in its units) that cannot be one of its points, else
    None: its inverse projection is not finite, or projecting that back misses the point by over ``tolerance_m``
    (outside the projection's domain), or, for a transverse Mercator, it lands over 90 deg of longitude from the
    central meridian (a northing beyond the pole: PROJ takes it over the pole to the far side of the globe)."""
    h = without_bound(horizontal_crs(crs))
    if not h.is_projected:
        return None
    x, y = np.asarray(x, float), np.asarray(y, float)
    with np.errstate(all="ignore"):
        lon, lat = pyproj.Transformer.from_crs(h, h.geodetic_crs, always_xy=True).transform(x, y, errcheck=False)
        X, Y = pyproj.Transformer.from_crs(h.geodetic_crs, h, always_xy=True).transform(lon, lat, errcheck=False)
        miss_m = np.hypot(np.asarray(X) - x, np.asarray(Y) - y) * linear_unit_m(h)
    bad = ~(np.isfinite(lon) & np.isfinite(lat) & np.isfinite(miss_m)) | ~(miss_m <= tolerance_m)
    op = h.coordinate_operation
    if op is not None and "transverse mercator" in op.method_name.lower():
        lon_0 = next((p.value for p in op.params if "longitude" in p.name.lower()), None)
        if lon_0 is not None:
            with np.errstate(all="ignore"):
                bad |= np.abs((np.asarray(lon) - lon_0 + 180.0) % 360.0 - 180.0) > 90.0
    return int(np.argmax(bad)) if bad.any() else None


# ``check_coordinates(outside_area="warn")``: beyond this distance from a CRS's area of use (degrees of a great circle,
# about: the longitude gap times the cos of the latitude, and the latitude gap) a point is refused even so; grids used
# past their zone reach 1-4.5 deg beyond it (review 31), Finnmark in UTM 33 about 4 (review 35)
FAR_OUTSIDE_AREA_DEG = 10.0


def _swapped_hint(h: pyproj.CRS, x: float, y: float) -> str:
    """"; x and y swapped? ..." when (y, x) is a point of the projected CRS ``h`` (inside its area of use, a zone
    prefix carried) and (x, y) is not: the surveying order X = northing, Y = easting of Chinese (and German, Russian)
    lists read as x = easting (trial-datum: the refusal said only that the prefix was missing)."""
    try:
        check_coordinates(h, np.array([y]), np.array([x]), "", swapped_hint=False)
    except InputError:
        return ""
    if h.is_geographic:
        return (f"; x and y swapped? ({y:.6f}, {x:.6f}) is a point of it: lists with the latitude first (B, L) must "
                "name their columns lat, lon (or give x = longitude first)")
    return (f"; x and y swapped? ({y:.3f}, {x:.3f}) is a point of it: lists in the surveying order X = northing, "
            "Y = easting must name their columns easting, northing (or give x = easting first)")


def _other_zone_hint(h: pyproj.CRS, x: float, y: float) -> str:
    """"; ... is a point of EPSG:4497 (... zone 19) ..." when the easting's prefix is the zone of another Chinese
    Gauss-Krueger grid of the same datum (the other zone width first) that holds the point: 3- and 6-degree zones
    mixed up (trial-datum: a 6-degree zone 19 easting given as the 3-degree zone 37 was refused without a hint)."""
    from aerotri.geom.crs.gauss_kruger import _GK_NAME, gk_epsg

    m = _GK_NAME.match(h.name)
    if not m or not m["zone"]:
        return ""
    width = 3 if m["three"] else 6
    zone = int(math.floor(x / 1_000_000.0))
    for w in (9 - width, width):
        try:
            code = gk_epsg(m["datum"], zone, w, prefixed=True)
        except KeyError:
            continue
        other = pyproj.CRS.from_epsg(code)
        try:
            check_coordinates(other, np.array([x]), np.array([y]), "", swapped_hint=False)
        except InputError:
            continue
        why = (f"{w}-degree zones given for {width}-degree ones?" if w != width else
               "another zone of the same width (a block across a zone border: one zone per file)")
        return f"; it is a point of EPSG:{code} ({other.name}): {why}"
    return ""


def _outside_area(aou, lon, lat, margin_deg: float) -> np.ndarray:
    """Which (lon, lat) (degrees east of Greenwich, -180..180) lie outside the area of use ``aou`` widened by
    ``margin_deg`` (an area across the antimeridian taken as such); not finite: outside."""
    lon = np.asarray(lon, dtype=float)
    lat = np.asarray(lat, dtype=float)
    west, east = aou.west, aou.east
    if east < west:  # area crossing the antimeridian
        east += 360.0
        lon = np.where(lon < west - margin_deg, lon + 360.0, lon)
    return ~(np.isfinite(lon) & np.isfinite(lat) & (lon >= west - margin_deg) & (lon <= east + margin_deg)
             & (lat >= aou.south - margin_deg) & (lat <= aou.north + margin_deg))


def check_coordinates(crs: pyproj.CRS, x, y, source: str, records=None, margin_deg: float = 1.0,
                      outside_area: str = "refuse", swapped_hint: bool = True) -> str | None:
    """Raise ``InputError`` naming the first record whose coordinates cannot belong to ``crs``.

    Geographic CRSs need longitude/latitude in range; projected CRSs need points that fall, once
    unprojected, within the CRS's area of use widened by ``margin_deg``, and within that area's
    grid bounding box widened by 5 % (at least 10 km). Zone-prefixed
    Gauss-Krueger eastings must carry their zone number. ``records`` labels the points (e.g. line
    numbers or ids) in the messages; ``swapped_hint``: a refused point that is one of ``crs`` with x and y
    swapped is said to be (``_swapped_hint``).

    ``outside_area="warn"`` (``crs assign``): points outside the area of use are no refusal but the returned
    message (else None) -- national grids are used beyond their zone's area (Norway in UTM 33, all Germany in UTM 32,
    Groningen in UTM 31: 1-4.5 deg past it, review 31); only what the CRS cannot hold is refused: not finite, a
    longitude/latitude out of range, a Gauss-Krueger easting without its zone, a projected point the projection
    cannot take back (``impossible_in``).
    """
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    label = crs_label(crs)

    def where(i):
        return f"{source}: {records[i]}" if records is not None else f"{source}: point {i + 1}"

    bad = ~(np.isfinite(x) & np.isfinite(y))
    if bad.any():
        raise InputError(f"{where(int(np.argmax(bad)))}: coordinates are not finite numbers")
    h = horizontal_crs(crs)
    if h.is_geocentric:
        return None
    if h.is_geographic:
        bad = (np.abs(y) > 90.0) | (x < -180.0) | (x > 360.0)
        if bad.any():
            i = int(np.argmax(bad))
            # latitude first (the surveying B, L order) reads as a latitude beyond 90: said (trial-cn, trial-kite)
            swapped = abs(x[i]) <= 90.0 and -180.0 <= y[i] <= 360.0
            raise InputError(
                f"{where(i)}: ({x[i]:.3f}, {y[i]:.3f}) is not a longitude/latitude in degrees, which {label} "
                "expects (x = longitude, y = latitude); "
                + ("latitude first? give longitude first (x), then latitude (y)" if swapped else
                   "metres given for a geographic CRS? (mixed units)")
            )
        # its area of use too (trial-datum: latitude, longitude in the surveying B, L order at Kashgar, (39.47,
        # 75.99), passed as a longitude and latitude of CGCS2000, and went into the CM 75E grid at y = 8,720 km)
        aou = h.area_of_use
        if aou is None:
            return None
        lon, lat = geodetic_to_greenwich(h, x, y)  # NTF (Paris): grads from Paris (review 36)
        bad = _outside_area(aou, np.where(lon > 180.0, lon - 360.0, lon), lat, margin_deg)
        if not bad.any():
            return None
        i = int(np.argmax(bad))
        message = (f"{where(i)}: ({x[i]:.6f}, {y[i]:.6f}) lies outside the area of use of {label} ({h.name}, lon "
                   f"{aou.west:.1f}..{aou.east:.1f}, lat {aou.south:.1f}..{aou.north:.1f}); {label} expects x = "
                   "longitude, y = latitude in degrees" + (_swapped_hint(h, x[i], y[i]) if swapped_hint else ""))
        if outside_area == "warn":
            return message
        raise InputError(message)
    # Zone-prefixed Gauss-Krueger: the millions of the easting are the zone number.
    op = h.coordinate_operation
    fe = None
    if op is not None and "transverse mercator" in op.method_name.lower():
        params = {p.name.lower(): p.value for p in op.params}
        fe = float(params.get("false easting", 0.0))
    # a zone prefix is the zone number's millions before a 500 km false easting (3,500,000 DHDN 3; 38,500,000 CGCS2000
    # 3-degree zone 38): NZTM's 1,600,000 and Fiji's 2,000,000 false eastings are none (review 35: refused there)
    if (fe is not None and fe >= 1_000_000.0 and abs(fe % 1_000_000.0 - 500_000.0) < 1e-6
            and abs(linear_unit_m(h) - 1.0) < 1e-12):
        zone = int(fe // 1_000_000)
        bad = np.floor(x / 1_000_000.0).astype(int) != zone
        if bad.any():
            i = int(np.argmax(bad))
            raise InputError(
                f"{where(i)}: easting {x[i]:.3f} does not carry the zone prefix {zone} of {label} "
                f"(expected {zone}xxxxxx.xxx m; eastings without prefix belong to a 'CM' grid, "
                "degrees or another zone are mixed units/zones)"
                + (_swapped_hint(h, x[i], y[i]) or _other_zone_hint(h, x[i], y[i]) if swapped_hint else "")
            )
    if outside_area == "warn" or h.area_of_use is None:  # a user's own grid states no area (review 36)
        try:
            i = impossible_in(h, x, y)
        except pyproj.exceptions.ProjError as e:  # a user's own definition PROJ cannot run (a scale factor <= 0)
            raise InputError(f"{source}: {label} ({h.name}) is no projection PROJ can compute: {e}") from None
        if i is not None:
            raise InputError(
                f"{where(i)}: ({x[i]:.3f}, {y[i]:.3f}) cannot be a point of {label} ({h.name}): the projection does "
                f"not take it back to a longitude/latitude (beyond the pole, the far "
                f"side of the globe or outside its domain); wrong CRS or mixed units? {label} expects "
                f"{unit_name(h)} in {_axis_order_text(h)} order")
    aou = h.area_of_use
    if aou is None:
        return None
    to_geo = pyproj.Transformer.from_crs(h, h.geodetic_crs, always_xy=True)
    with np.errstate(all="ignore"):
        lon, lat = geodetic_to_greenwich(h.geodetic_crs, *to_geo.transform(x, y, errcheck=False))
    lon = np.asarray(lon, dtype=float)
    lat = np.asarray(lat, dtype=float)
    bad = _outside_area(aou, lon, lat, margin_deg)
    # The same area in grid coordinates, widened by 5 % (at least 10 km): catches small numbers
    # (degrees, kilometres) that unproject to somewhere near the grid's false origin.
    to_grid = pyproj.Transformer.from_crs(h.geodetic_crs, h, always_xy=True)
    try:
        (w, e), (so, no) = greenwich_to_geodetic(
            h.geodetic_crs, np.array([max(aou.west - margin_deg, -180.0), min(aou.east + margin_deg, 180.0)]),
            np.array([max(aou.south - margin_deg, -90.0), min(aou.north + margin_deg, 90.0)]))
        xmin, ymin, xmax, ymax = to_grid.transform_bounds(float(w), float(so), float(e), float(no), densify_pts=21)
    except pyproj.exceptions.ProjError:
        xmin = ymin = -np.inf
        xmax = ymax = np.inf
    if np.all(np.isfinite([xmin, ymin, xmax, ymax])):
        mx = max(0.05 * (xmax - xmin), 10_000.0 / linear_unit_m(h))
        my = max(0.05 * (ymax - ymin), 10_000.0 / linear_unit_m(h))
        bad |= (x < xmin - mx) | (x > xmax + mx) | (y < ymin - my) | (y > ymax + my)
    if outside_area == "warn":
        # national grids used past their zone reach 1-4.5 deg beyond its area (review 31); a record tens of degrees
        # away is a wrong CRS, not such a use (review 33: Autzen's Oregon feet assigned the Swiss grid, 22 deg off)
        # the longitude gap modulo 360 (areas across or ending at the antimeridian, review 35) and shortened by
        # the cos of the latitude (Finnmark in UTM 33: 11-12 deg of longitude past the zone, about 460 km at 70 N)
        width = (aou.east - aou.west) % 360.0 or 360.0
        rel = (lon - aou.west) % 360.0
        gap_lon = np.where(rel <= width, 0.0, np.minimum(rel - width, 360.0 - rel))
        gap_lat = np.maximum.reduce([aou.south - lat, lat - aou.north, np.zeros_like(lat)])
        beyond = np.hypot(gap_lon * np.cos(np.radians(np.clip(lat, -90.0, 90.0))), gap_lat)
        far = ~np.isfinite(beyond) | (beyond > FAR_OUTSIDE_AREA_DEG)
        if far.any():
            i = int(np.argmax(far))
            raise InputError(
                f"{where(i)}: ({x[i]:.3f}, {y[i]:.3f}) lies more than {FAR_OUTSIDE_AREA_DEG:g} deg outside the area "
                f"of use of {label} ({h.name}, lon {aou.west:.1f}..{aou.east:.1f}, lat {aou.south:.1f}.."
                f"{aou.north:.1f}): not a use of it beyond its zone but another CRS; {label} expects "
                f"{unit_name(h)} in {_axis_order_text(h)} order")
    if bad.any():
        i = int(np.argmax(bad))
        message = (
            f"{where(i)}: ({x[i]:.3f}, {y[i]:.3f}) lies outside the area of use of {label} ({h.name}, "
            f"lon {aou.west:.1f}..{aou.east:.1f}, lat {aou.south:.1f}..{aou.north:.1f}); wrong CRS or mixed units "
            f"(degrees, feet or metres)? {label} expects {unit_name(h)} in {_axis_order_text(h)} order"
            + (_swapped_hint(h, x[i], y[i]) if swapped_hint else "")
        )
        if outside_area == "warn":
            return message
        raise InputError(message)
    return None


def project_crs(project) -> pyproj.CRS:
    """The CRS of a project folder (``[project] crs`` of project.toml), checked."""
    return parse_crs(project.crs, f"{project.config_path} [project] crs")


def project_heights(project) -> pyproj.CRS | None:
    """The height system of a project folder (``[project] heights``; None: ellipsoidal), checked."""
    return parse_heights(project.info.heights, f"{project.config_path} [project] heights")


@functools.lru_cache(maxsize=64)
def heights_in_unit(heights: pyproj.CRS, unit_m: float, source: str = "[project] heights") -> pyproj.CRS:
    """The vertical CRS ``heights`` with its height axis in the unit of ``unit_m`` metres: the same vertical datum
    (PROJ relates the two by a unit conversion, and reaches the datum's geoid model through the original), named
    "<name> (<unit>)"; ``heights`` itself when already in that unit. A vertical CRS PROJ cannot restate (a bound
    one) in another unit is refused naming both units."""
    have_m = float(heights.axis_info[0].unit_conversion_factor)
    if abs(have_m - unit_m) <= 1e-12 * unit_m:
        return heights
    unit = length_unit_name(unit_m, long=True)
    doc = heights.to_json_dict()
    if doc.get("type") != "VerticalCRS" or len(doc.get("coordinate_system", {}).get("axis", [])) != 1:
        raise CrsError(f"{source}: {crs_label(heights)} ({heights.name}) gives heights in "
                       f"{length_unit_name(have_m, long=True)}, the project CRS's unit is {unit}: project heights are "
                       f"in the project CRS's unit; give a vertical CRS in {unit}")
    doc.pop("id", None)
    doc.pop("ids", None)
    doc["name"] = f"{heights.name} ({unit})"
    doc["coordinate_system"]["axis"][0]["unit"] = ("metre" if unit_m == 1.0 else
                                                   {"type": "LinearUnit", "name": unit, "conversion_factor": unit_m})
    return pyproj.CRS.from_json_dict(doc)


def with_heights(crs: pyproj.CRS, heights: pyproj.CRS | None) -> pyproj.CRS:
    """``crs`` with the heights ``heights``: the compound CRS for a vertical CRS, ``crs`` itself for ellipsoidal ones
    (None: the policy then takes z in the CRS's linear unit, feet in a feet grid, which ``height_crs``'s ``to_3d``
    would make metres). The CRS to transform project points from or to: ``CrsTransformer``'s ``heights`` is a
    height anomaly model, not a vertical CRS (the exports to WGS 84 passed EPSG:3855 there and stopped with an
    AttributeError).

    The heights are in ``crs``'s unit as a 2D CRS's z is (``height_unit_m``: a feet grid's in feet, a geographic
    CRS's in metres; docs/project.md: project z is "in the project CRS and its unit"), whatever the vertical CRS's
    own unit: EPSG:3855 (EGM2008, metres) beside a US-feet grid is EGM2008 in US feet (review 43: with the vertical
    CRS's metres, feet were read as metres, a point 3.28x off between two such projects)."""
    if heights is None:
        return crs
    return height_crs(crs, heights_in_unit(heights, height_unit_m(horizontal_crs(crs))))


def project_crs_3d(project) -> pyproj.CRS:
    """The CRS of a project's coordinates with their heights (``with_heights`` of ``[project] crs`` and
    ``[project] heights``: the heights in the project CRS's unit)."""
    return with_heights(project_crs(project), project_heights(project))
