"""The toolkit's one coordinate-operation policy: every transformation between CRSs goes through here.

``CrsTransformer(from_crs, to_crs, params=None, heights=None, allow_ballpark=False)`` is built once and
applied to arrays. It chains

1. a PROJ operation from ``from_crs`` into the parameter set's source CRS (a conversion within one
   datum: unprojecting, changing zone),
2. the fitted parameter set (``aerotri.geom.crs.datum.Transformation``, from ``aerotri crs fit``): on grid
   coordinates for the plane models, on geocentric XYZ for the spatial models,
3. a PROJ operation from the parameter set's target CRS into ``to_crs``,
4. optionally the height anomaly model (``aerotri crs fit-heights``): H = h - zeta(x, y), with h on the
   ellipsoid the model was fitted on (its ``h_crs``): taken where the chain has h on that datum (the input,
   before or after the parameter set, the output); a datum PROJ says has the same h at the cm level (an
   ensemble and its member, WGS 84 (G1762) and ITRF2014: ``compare_h_datums``) counts, with a note; a model
   recorded on a datum the operation has no h of is refused. A model file without the record takes the output's h
   (the spatial set's change said in a warning).

The policy:

- Without a parameter set, PROJ's own operation is used only when it is rigorous (it knows the datum
  shift, or there is none). When PROJ only has a "ballpark" operation (datums differ and the shift is
  ignored: errors of decimetres to hundreds of metres), the transformer refuses (``BallparkRefused``)
  unless ``allow_ballpark=True`` (``--allow-ballpark``); the remedy is a parameter set from common
  points. When the rigorous operation needs a PROJ grid (a geoid model, an NTv2 file) that is not
  installed, the refusal names the grid and how to get it.
- Compound CRSs (horizontal + vertical) are taken by their parts: PROJ transforms them as 3D CRSs.
- ``record()`` describes what was applied (each PROJ step's pipeline and accuracy, the parameter
  set, the height model) for the product's metadata and the stage report.
- ``inverse()`` is the same operation backwards (parameter sets inverted exactly, H -> h).

Heights: ``z`` is in the vertical unit of the CRS: the linear unit of a projected 2D CRS (LAS
convention: feet grids carry feet heights), metres for geographic CRSs; a compound CRS uses its
vertical axis. Ellipsoidal heights follow datum shifts; the height model converts to normal heights.
"""

from __future__ import annotations

import dataclasses
import functools
import warnings

import numpy as np
import pyproj
from pyproj.transformer import TransformerGroup

from aerotri.core.errors import CrsError
from aerotri.geom.crs.definition import (crs_label, geodetic_to_greenwich, greenwich_to_geodetic, height_unit_m,
                                         horizontal_crs, length_unit_name, linear_unit_m, parse_crs, same_horizontal,
                                         unknown_datum_hint, vertical_crs)
from aerotri.geom.crs.datum import HeightAnomalyModel, Transformation, outside_extent
from aerotri.geom.crs.ellipsoid import Ellipsoid, geocentric_to_geodetic, geodetic_to_geocentric


# A PROJ operation whose stated accuracy (EPSG's, metres) is this or coarser is named in the notes: a datum
# change of metres (EPSG:4979 -> NAD83(2011) 2 m, -> ETRS89 1 m) where a conversion within a datum states 0
COARSE_OPERATION_M = 0.5


class BallparkRefused(CrsError):
    """PROJ would ignore a datum shift; parameters from common points (or a missing grid) are needed.
    ``missing_grids``: the PROJ grids the rigorous operation needs and this machine lacks ((name, url) pairs, as
    ``grid_advice`` takes them); empty when PROJ knows no rigorous operation at all."""

    def __init__(self, message: str = "", *, param: str | None = None, missing_grids=()):
        super().__init__(message, param=param)
        self.missing_grids = tuple(missing_grids)


def z_unit_m(crs: pyproj.CRS) -> float:
    """Metres per height unit as this module reads z for ``crs`` (see module docstring)."""
    if crs.is_compound or len(crs.axis_info) >= 3:
        return 1.0  # PROJ reads z in the CRS's own vertical unit
    f = linear_unit_m(crs)
    return 1.0 if np.isnan(f) else f


def _as_3d(crs: pyproj.CRS) -> pyproj.CRS:
    if crs.is_compound or crs.is_geocentric or len(crs.axis_info) >= 3:
        return crs
    return crs.to_3d()


def datum_name(crs: pyproj.CRS) -> str:
    """The name of the geodetic datum (or datum ensemble) of ``crs``: whose ellipsoid its heights h are on."""
    crs = horizontal_crs(crs)
    datum = (crs if crs.is_geocentric or crs.geodetic_crs is None else crs.geodetic_crs).datum
    return crs.name if datum is None else datum.name  # an engineering CRS: no ellipsoid, its own name


# The ellipsoidal heights h of two different datums are taken as the same for a height model (zeta = h - H), with a
# note, only when PROJ says so: one datum a member of the other's ensemble (PROJ's datum ensembles), or PROJ's
# rigorous operation between them (between an ensemble's members) changing h by at most this much, its stated
# accuracy added, at epochs 2000 and 2030. Chosen from EPSG's own statements, not fitted: WGS 84 (G1762) -> ITRF2014
# is stated accurate to 2 cm and changes h by 5 mm at Yichang (taken), NAD83(2011) -> ITRF2014 by 2.12 m (refused);
# CGCS2000 and Xian 1980 have no rigorous operation to WGS 84 or ITRF in PROJ (refused).
SAME_H_TOLERANCE_M = 0.05
_SAME_H_EPOCHS = (2000.0, 2030.0)


@dataclasses.dataclass(frozen=True)
class HeightDatumMatch:
    """How the ellipsoidal heights of two datums compare for a height model: ``same`` (usable as one another's),
    ``exact`` (one datum), ``note`` (why they are taken as the same and by how much they may differ; "" when exact
    or not the same)."""

    same: bool
    exact: bool
    note: str = ""


def _geodetic_datum(crs: pyproj.CRS):
    return horizontal_crs(crs).datum  # not geodetic_crs.datum: pyproj drops the datum's EPSG code there


def _datum_code(datum) -> int | None:
    """The EPSG code of a datum (or datum ensemble): its own identifier, else PROJ's datum of that name."""
    ident = datum.to_json_dict().get("id") or {}
    if ident.get("authority") != "EPSG":
        try:
            ident = pyproj.crs.Datum.from_name(datum.name, auth_name="EPSG").to_json_dict().get("id") or {}
        except pyproj.exceptions.CRSError:
            return None
    return int(ident["code"]) if ident.get("authority") == "EPSG" else None


def _frames(datum) -> list:
    """(name, EPSG datum code or None) of the reference frames ``datum`` stands for: a datum ensemble's members
    (newest first), else the datum itself."""
    d = datum.to_json_dict()
    items = list(reversed(d["members"])) if d.get("members") else [d]
    out = []
    for m in items:
        ident = m.get("id") or {}
        if ident.get("authority") != "EPSG":  # a datum from WKT without its code: PROJ's of that name, if any
            try:
                ident = pyproj.crs.Datum.from_name(m["name"], auth_name="EPSG").to_json_dict().get("id") or {}
            except pyproj.exceptions.CRSError:
                ident = {}
        out.append((m["name"], int(ident["code"]) if ident.get("authority") == "EPSG" else None))
    return out


@functools.lru_cache(maxsize=64)
def _h_operation(code_a: int, code_b: int):
    """PROJ's best rigorous operation between the 3D geographic CRSs of EPSG datums ``code_a`` and ``code_b``; None
    when PROJ knows none. Made once per pair (a ``TransformerGroup`` costs tens of ms; ``_h_change`` is asked at
    each block's position)."""
    from pyproj.crs import Datum, GeographicCRS
    from pyproj.crs.coordinate_system import Ellipsoidal3DCS

    try:
        a, b = (GeographicCRS(name=f"datum {c}", datum=Datum.from_epsg(c), ellipsoidal_cs=Ellipsoidal3DCS())
                for c in (code_a, code_b))
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="Best transformation is not available", category=UserWarning)
            group = TransformerGroup(a, b, always_xy=True, allow_ballpark=False)
    # a datum PROJ cannot make a geographic CRS of, or pyproj's IndexError on some frame pairs (IGS14, IGb14,
    # SIRGAS: review 17): nothing known, so not taken as the same
    except (pyproj.exceptions.ProjError, IndexError, ValueError):
        return None
    return group.transformers[0] if group.transformers else None


@functools.lru_cache(maxsize=256)
def _h_change(code_a: int, code_b: int, lon_deg: float, lat_deg: float):
    """(largest |change of h| in m at (lon, lat) over the epochs, stated accuracy in m or None, description) of
    PROJ's best rigorous operation between the 3D geographic CRSs of EPSG datums ``code_a`` and ``code_b``; None
    when PROJ knows none."""
    t = _h_operation(code_a, code_b)
    if t is None:
        return None
    try:
        dh = [t.transform(lon_deg, lat_deg, 0.0, epoch, errcheck=False)[2] for epoch in _SAME_H_EPOCHS]
    except (pyproj.exceptions.ProjError, IndexError, ValueError):
        return None
    if not np.all(np.isfinite(dh)):
        return None
    acc = t.accuracy if t.accuracy is not None and t.accuracy >= 0 else None
    return float(np.max(np.abs(dh))), acc, t.description


def compare_h_datums(model_crs: pyproj.CRS, op_crs: pyproj.CRS, lon_deg: float = 0.0,
                     lat_deg: float = 0.0) -> HeightDatumMatch:
    """Whether a height model's h (on the datum of ``model_crs``) may be taken as the h of ``op_crs``'s datum, at
    (lon, lat): the same datum; one a member of the other's datum ensemble; or PROJ's rigorous operation between
    them (or an ensemble's member) changing h by at most ``SAME_H_TOLERANCE_M``, its stated accuracy included (see
    there; an operation of unstated accuracy is not taken). Datums are compared by what PROJ knows of them, never by a name alone (a model fitted with --h-crs
    "WGS 84 (G1762)" on a project in the WGS 84 ensemble was refused)."""
    da, db = _geodetic_datum(model_crs), _geodetic_datum(op_crs)
    if da is None or db is None:
        one = datum_name(model_crs) == datum_name(op_crs)  # an engineering CRS: no datum, its own name
        return HeightDatumMatch(one, one)
    if da.name == db.name or _datum_code(da) is not None and _datum_code(da) == _datum_code(db):
        return HeightDatumMatch(True, True)  # by code too: WKT1 names WGS 84's ensemble "World Geodetic System 1984"
    fa, fb = _frames(da), _frames(db)
    acc_of = {d.name: d.to_json_dict().get("accuracy") for d in (da, db) if d.to_json_dict().get("members")}

    def ensemble_said(name):
        acc = acc_of.get(name)
        how = "unknown, typically cm" if acc is None else f"up to {float(acc):g} m by PROJ's ensemble accuracy"
        return f"the realizations of {name} differ by {how}"

    names_a, names_b = [n for n, _ in fa], [n for n, _ in fb]
    if db.name in names_a or da.name in names_b:  # a datum and an ensemble it belongs to
        ens, member = (da, db) if db.name in names_a else (db, da)
        return HeightDatumMatch(True, False, f"h of {da.name} and of {db.name} taken as the same heights "
                                             f"({member.name} is a member of the ensemble; {ensemble_said(ens.name)})")
    common = [n for n in names_a if n in names_b]
    if common:  # two ensembles sharing a member
        return HeightDatumMatch(True, False, f"h of {da.name} and of {db.name} taken as the same heights (both hold "
                                             f"{common[0]}; {ensemble_said(da.name)})")
    lon, lat = round(float(lon_deg), 1), round(float(lat_deg), 1)
    for na, ca in fa:
        for nb, cb in fb:
            if ca is None or cb is None:
                continue
            got = _h_change(ca, cb, lon, lat)
            if got is None:
                continue
            dh, acc, _ = got
            if acc is None or dh + acc > SAME_H_TOLERANCE_M:  # an operation of unstated accuracy says nothing
                continue
            via = [f"{n} through its member {m}" for n, m, f in ((da.name, na, fa), (db.name, nb, fb)) if len(f) > 1]
            ens = [ensemble_said(n) for n in acc_of]
            return HeightDatumMatch(True, False, (
                f"h of {da.name} and of {db.name} taken as the same heights: PROJ's operation {na} -> {nb} changes h "
                f"by {dh:.3f} m at lon {lon:g}, lat {lat:g} (epochs {_SAME_H_EPOCHS[0]:g}-{_SAME_H_EPOCHS[1]:g}), "
                f"stated accurate to {acc:g} m" + "".join(f"; {t}" for t in via + ens)))
    return HeightDatumMatch(False, False)


def is_ballpark(transformer: pyproj.Transformer) -> bool:
    text = transformer.description or ""
    ops = transformer.operations or []
    return "ballpark" in text.lower() or any("ballpark" in (op.name or "").lower() for op in ops)


def _missing_grids(group: TransformerGroup) -> list:
    """Grids (short name, url) the better operations of ``group`` need but PROJ does not have."""
    out = []
    for op in group.unavailable_operations:
        for g in op.grids:
            if not g.available and g.short_name not in [m[0] for m in out]:
                out.append((g.short_name, g.url))
    return out


def _label_and_name(crs: pyproj.CRS) -> str:
    """``crs_label`` and, where it says something more, the CRS's own name ("EPSG:25832 (ETRS89 / UTM zone 32N)";
    a PROJ string's "unknown" and a label that is the name are not repeated)."""
    label = crs_label(crs)
    return label if crs.name in ("", "unknown", label) else f"{label} ({crs.name})"


def grid_advice(grids) -> str:
    """How to get the missing grids (``_missing_grids``: those of the operations PROJ could not run, which are
    alternatives to one another: one of them is enough)."""
    first = grids[0][0]
    if len(grids) == 1:
        needs = f"the PROJ grid {first}, which is not installed"
    else:  # EGM2008: us_nga_egm08_25.tif or egm08_25.gtx, not both
        names = [name for name, _ in grids[:3]]
        alternatives = ", ".join(names[:-1]) + f" or {names[-1]}"
        needs = f"one of the PROJ grids {alternatives}, none of which is installed"
    return (f"the rigorous operation needs {needs}: get it with "
            f"`pyproj sync --file {first}` (PROJ's `projsync --file {first}` works too; or set "
            f"PROJ_NETWORK=ON on a machine with internet), or put the file into "
            f"{pyproj.datadir.get_user_data_dir()}")


_TRANSFORMERS: dict[tuple[str, str, bool], pyproj.Transformer] = {}


def _transformer(s3: pyproj.CRS, d3: pyproj.CRS, key: tuple[str, str, bool]) -> pyproj.Transformer:
    """PROJ's operation from ``s3`` to ``d3`` (x, y order), made once per pair of definitions (``key``: their WKT and
    whether a ballpark operation is allowed): making one costs 5-50 ms, and a run makes a ``CrsTransformer`` per
    frame footprint, control file and check. pyproj's transformers are thread-safe (one PROJ object per thread)."""
    t = _TRANSFORMERS.get(key)
    if t is None:
        if len(_TRANSFORMERS) >= 64:
            _TRANSFORMERS.clear()
        t = _TRANSFORMERS[key] = pyproj.Transformer.from_crs(s3, d3, always_xy=True, allow_ballpark=key[2])
    return t


@functools.lru_cache(maxsize=64)
def _group(s3_wkt: str, d3_wkt: str):
    # pyproj warns "Best transformation is not available due to missing Grid": the caller names the
    # missing grid and how to get it (grid_advice), so the bare warning would only repeat it half
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Best transformation is not available", category=UserWarning)
        return TransformerGroup(pyproj.CRS.from_wkt(s3_wkt), pyproj.CRS.from_wkt(d3_wkt), always_xy=True,
                                allow_ballpark=False)


class _ProjLeg:
    """One PROJ operation between two CRSs, z converted to metres around it."""

    def __init__(self, src: pyproj.CRS, dst: pyproj.CRS, allow_ballpark: bool, purpose: str = ""):
        self.src, self.dst = src, dst
        self.identity = src == dst
        self.ballpark = False
        self.notes = []
        if self.identity:
            return
        s3, d3 = _as_3d(src), _as_3d(dst)
        self.z_in, self.z_out = z_unit_m(src), z_unit_m(dst)
        s3_wkt, d3_wkt = s3.to_wkt(), d3.to_wkt()
        try:
            group = _group(s3_wkt, d3_wkt)
        except IndexError:  # pyproj's TransformerGroup fails so on some dynamic frames (SIRGAS 2000 -> ITRF2014)
            raise CrsError(f"PROJ cannot list the operations {crs_label(src)} -> {crs_label(dst)}{purpose} (pyproj "
                           "fails on this pair of reference frames); transform in two steps through a frame PROJ "
                           "links to both, or give the parameters of the transformation (--params)") from None
        missing = _missing_grids(group)
        if not group.transformers:
            if not allow_ballpark:
                why = (grid_advice(missing) + "; or ") if missing else ("PROJ knows no rigorous transformation "
                                                                          "between these datums, only a 'ballpark' "
                                                                          "one that ignores the datum shift (errors "
                                                                          "of decimetres to hundreds of metres); ")
                # a definition by its ellipsoid alone (+ellps=GRS80): what is missing is its datum (leftovers2)
                stated = unknown_datum_hint(dst, src) or unknown_datum_hint(src, dst)
                if stated:
                    why = f"{why}{stated}; otherwise "
                raise BallparkRefused(
                    f"{_label_and_name(src)} -> {_label_and_name(dst)}{purpose}: {why}fit parameters "
                    "from common points known in both systems (aerotri crs fit ... --from/--to) and pass them with "
                    "--params (a height anomaly model with --heights), or accept the ballpark result explicitly "
                    "with --allow-ballpark", missing_grids=missing or ()
                )
            self.ballpark = True
            _refuse_ballpark_heights(src, dst, purpose)
        self.transformer = _transformer(s3, d3, (s3_wkt, d3_wkt, self.ballpark))
        acc = self.transformer.accuracy
        stated = (f" ({self.transformer.description}, stated accurate to {acc:g} m)"
                  if acc is not None and acc > 0 else "")
        if self.ballpark:
            self.notes.append(
                f"{crs_label(src)} -> {crs_label(dst)}: BALLPARK transformation accepted by the user "
                f"({self.transformer.description}); the datum shift is ignored"
            )
        elif not group.best_available and missing:
            self.notes.append(f"{crs_label(src)} -> {crs_label(dst)}: a less accurate operation{stated} is used "
                              "because " + grid_advice(missing))
        elif (acc is not None and acc >= COARSE_OPERATION_M
              and not any(op.grids for op in self.transformer.operations or [])):  # a geoid states its own
            # EPSG's null or Helmert operations between WGS 84 and a national datum (NAD83(2011): 2 m, ETRS89:
            # 1 m) are no ballpark, but a GNSS position of centimetres comes out no better than that
            self.notes.append(
                f"{crs_label(src)} -> {crs_label(dst)}: PROJ's operation{stated} changes the datum without a grid "
                "or parameters of this area: coordinates come out no better than that (for centimetres give them "
                "in the target datum, or fit parameters from common points: aerotri crs fit, aerotri crs transform "
                "--params)"
            )

    def record(self) -> dict:
        if self.identity:
            return {"step": "identity", "crs": crs_label(self.src)}
        acc = self.transformer.accuracy
        return {"step": "proj", "from": crs_label(self.src), "to": crs_label(self.dst),
                "operation": self.transformer.description, "proj_pipeline": self.transformer.definition,
                "accuracy_m": None if acc is None or acc < 0 else float(acc), "ballpark": self.ballpark}

    def __call__(self, x, y, z):
        if self.identity:
            return x, y, z
        X, Y, Z = self.transformer.transform(x, y, z * self.z_in, errcheck=False)
        X, Y, Z = (np.asarray(a, dtype=float) for a in (X, Y, Z))
        bad = ~(np.isfinite(X) & np.isfinite(Y) & np.isfinite(Z))
        if bad.any():
            i = int(np.argmax(bad))
            raise CrsError(
                f"{crs_label(self.src)} -> {crs_label(self.dst)}: point {i + 1} ({x[i]:.3f}, {y[i]:.3f}) could not be "
                "transformed rigorously (outside the area of the available operations, or not a valid coordinate)"
            )
        return X, Y, Z / self.z_out


def _refuse_ballpark_heights(src, dst, purpose: str) -> None:
    """``BallparkRefused`` for a ballpark between ellipsoidal heights and a vertical datum's (one side compound),
    whatever ``--allow-ballpark`` says: PROJ's ballpark copies the heights unchanged, and the height anomaly (-12 m
    near Wuhan, up to 100 m elsewhere) went into a file labelled Yellow Sea 1985 height under exit 0 (trial s96
    F1). --allow-ballpark is taken for the horizontal datum shift it names; the heights need a model (--heights,
    whose ``CrsTransformer._leg`` then takes the horizontal parts) or a geoid grid."""
    v_src, v_dst = vertical_crs(src), vertical_crs(dst)
    if (v_src is None) == (v_dst is None):
        return
    vert, ell = (v_dst, src) if v_dst is not None else (v_src, dst)
    raise BallparkRefused(
        f"{_label_and_name(src)} -> {_label_and_name(dst)}{purpose}: PROJ has only a ballpark operation for the "
        f"heights: it would take the ellipsoidal heights of {crs_label(horizontal_crs(ell))} as {vert.name} "
        f"({crs_label(vert)}) unchanged, ignoring the height anomaly (geoid undulation) between them, metres to tens of metres; "
        "--allow-ballpark accepts an ignored horizontal datum shift, not that: give a height anomaly model with "
        "--heights (aerotri crs fit-heights from levelled points), install the geoid grid PROJ names for it, or "
        f"transform into the horizontal CRS alone ({crs_label(horizontal_crs(dst))}, ellipsoidal heights kept)")


@dataclasses.dataclass(frozen=True)
class OperationSpec:
    """A coordinate operation as plain data (picklable for Dask tasks, storable in JSON): CRSs as WKT or
    codes, the parameter set and height model as their file dicts. ``build()`` makes the transformer."""

    from_crs: str
    to_crs: str
    params: dict | None = None
    heights: dict | None = None
    allow_ballpark: bool = False
    heights_inverse: bool = False

    def build(self) -> "CrsTransformer":
        return _build(self)


@functools.lru_cache(maxsize=16)
def _build_cached(spec_json: str) -> "CrsTransformer":
    import json

    d = json.loads(spec_json)
    params = Transformation.from_dict(d["params"], "operation parameters") if d["params"] else None
    heights = HeightAnomalyModel.from_dict(d["heights"], "operation height model") if d["heights"] else None
    return CrsTransformer(d["from_crs"], d["to_crs"], params, heights, d["allow_ballpark"],
                          heights_inverse=d["heights_inverse"])


def _build(spec: OperationSpec) -> "CrsTransformer":
    import json

    return _build_cached(json.dumps(dataclasses.asdict(spec), sort_keys=True))


def _same_datum(a, b) -> bool:
    """Whether two CRSs' horizontal parts lie on one geodetic datum (a datum ensemble and its name; False when either
    has none, e.g. a local engineering grid)."""
    from aerotri.geom.crs.definition import horizontal_crs, without_bound

    da, db = (without_bound(horizontal_crs(c)).datum for c in (a, b))
    return da is not None and db is not None and da == db


class CrsTransformer:
    """Build once, call ``transform(x, y, z)`` on arrays (see the module docstring)."""

    def __init__(self, from_crs, to_crs, params: Transformation | None = None,
                 heights: HeightAnomalyModel | None = None, allow_ballpark: bool = False,
                 heights_inverse: bool = False):
        self.src = parse_crs(from_crs, "--from")
        self.dst = parse_crs(to_crs, "--to")
        self.params = params
        self.heights = heights
        self.allow_ballpark = allow_ballpark
        self.heights_inverse = heights_inverse  # h = H + zeta (the inverse of a normal-height operation)
        self.n_outside_fit_extent = 0
        self.n_points = 0
        # points where the height model is extrapolated beyond its levelling points' hull (and the farthest, m)
        self.n_beyond_heights_hull = 0
        self.beyond_heights_hull_m = 0.0
        # the spatial set's change of the ellipsoidal heights (sum, count), said beside a height model
        self._dh_sum_m, self._dh_n = 0.0, 0
        self._vertical_by_model = None  # a compound CRS's vertical datum whose heights the height model gives
        legs = []
        if params is None:
            legs.append(self._leg(self.src, self.dst, allow_ballpark))
        else:
            p_from = parse_crs(params.from_crs_def, "parameter file from_crs")
            p_to = parse_crs(params.to_crs_def, "parameter file to_crs")
            if not same_horizontal(p_from, self.src) and (
                    same_horizontal(p_to, self.src)
                    or (_same_datum(self.src, p_to) and not _same_datum(self.src, p_from))):
                # a parameter set fitted the other way round: one file serves both directions. The input in the set's
                # target system (or another grid on its datum) goes back through the set, whatever the output (trial-cn:
                # EPSG:4547 -> EPSG:4326 with a set 32650 -> 4547 was refused, and with --allow-ballpark applied forward,
                # 274 m off)
                params = self.params = params.inverse()
                p_from, p_to = p_to, p_from
            self._p_from, self._p_to = p_from, p_to
            why = " (into the parameter set's source system)"
            if params.spatial:
                self._ell_from = Ellipsoid.from_crs(p_from)
                self._ell_to = Ellipsoid.from_crs(p_to)
                self._geo_from = p_from if p_from.is_geocentric else p_from.geodetic_crs
                self._geo_to = p_to if p_to.is_geocentric else p_to.geodetic_crs
                self._pre_plane = self._leg(self.src, p_from, allow_ballpark, why) if not p_from.is_geocentric else None
                legs.append(self._leg(self.src, self._geo_from, allow_ballpark, why))
                legs.append(self._leg(self._geo_to, self.dst, allow_ballpark, " (from the parameter set's target)"))
            else:
                for c, role in ((p_from, "from_crs"), (p_to, "to_crs")):
                    h = horizontal_crs(c)
                    if not (h.is_projected or h.is_engineering) or abs(linear_unit_m(c) - 1.0) > 1e-12:
                        raise CrsError(f"parameter file {role} {crs_label(c)}: plane models need a metre grid")
                legs.append(self._leg(self.src, p_from, allow_ballpark, why))
                legs.append(self._leg(p_to, self.dst, allow_ballpark, " (from the parameter set's target)"))
        self._legs = legs
        self.notes = []
        if self._vertical_by_model is not None:
            self.notes.append(f"heights: {self._vertical_by_model} taken as the height model's normal heights "
                              "(H = h - zeta; PROJ knows no operation into or out of it)")
        self._height_leg = None
        self._height_leg_from_src = False
        if heights is not None and heights.crs:
            hcrs = parse_crs(heights.crs, "height model crs")
            # (x, y alone: the model is evaluated on its grid's plane; a compound output's vertical part has no
            # operation to the grid's ellipsoidal heights: --to EPSG:2383+5737 with a model in EPSG:2383 was refused
            # as "on neither datum", trial s96 F4)
            h_dst, h_src, h_grid = horizontal_crs(self.dst), horizontal_crs(self.src), horizontal_crs(hcrs)
            if h_grid != h_dst and h_grid != h_src:
                try:
                    self._height_leg = _ProjLeg(h_dst, h_grid, allow_ballpark=False, purpose=" (height model)")
                except BallparkRefused as exc:
                    # the model's grid on the input's datum (levelling in CGCS2000 zone 37, a cloud in CGCS2000 CM
                    # 111E into Xian 1980 with --params): reached from the input by a conversion (trial-datum: refused,
                    # "pass --params", which was given)
                    try:
                        self._height_leg = _ProjLeg(h_src, h_grid, allow_ballpark=False, purpose=" (height model)")
                        self._height_leg_from_src = True
                    except BallparkRefused:
                        raise BallparkRefused(
                            f"height model: its grid {crs_label(hcrs)} ({hcrs.name}) is on neither the datum of "
                            f"{crs_label(self.src)} nor that of {crs_label(self.dst)}, and PROJ knows no rigorous "
                            f"operation to it from either ({exc}); fit the height model in a grid of the input's or "
                            "the output's datum (crs fit-heights --epsg)", missing_grids=exc.missing_grids) from None
            self._heights_crs = hcrs
        else:
            self._heights_crs = self.dst
        self.ballpark = any(leg.ballpark for leg in legs)
        self.notes += [n for leg in legs for n in leg.notes]
        self._h_stage = self._height_stage() if heights is not None and heights.h_crs else None

    def _leg(self, a, b, allow_ballpark: bool, purpose: str = "") -> "_ProjLeg":
        """The PROJ leg a -> b; with a height model (recording its h) whose normal heights are a compound CRS's
        vertical part that PROJ cannot reach (Yellow Sea 1985 height, EPSG:5737: no geoid in PROJ), the leg between the
        horizontal parts: the model gives those heights, the chain's own height arithmetic does the rest
        (trial-datum: --to EPSG:2361+5737 --heights zeta.json was refused as ballpark, "pass --heights")."""
        try:
            return _ProjLeg(a, b, allow_ballpark, purpose)
        except BallparkRefused:
            vert = vertical_crs(b) if vertical_crs(b) is not None else vertical_crs(a)
            if (self.heights is None or not self.heights.h_crs or vert is None
                    or abs(height_unit_m(b if vertical_crs(b) is not None else a) - 1.0) > 1e-12):
                raise
            leg = _ProjLeg(horizontal_crs(a), horizontal_crs(b), allow_ballpark, purpose)
            self._vertical_by_model = vert.name
            return leg

    def _height_stage(self) -> str:
        """Where the chain has ellipsoidal heights on the datum of the height model's h: ``in`` (the input),
        ``from``/``to`` (before/after the parameter set), ``out`` (the output); CrsError when nowhere."""
        model_crs = parse_crs(self.heights.h_crs, "height model h_crs")
        model_datum = datum_name(model_crs)
        if self.params is None:
            stages = [("in", self.src), ("out", self.dst)]
        elif self.params.spatial:
            stages = [("in", self.src), ("from", self._p_from), ("to", self._p_to), ("out", self.dst)]
        elif self.heights_inverse:  # a plane set leaves h alone: they are the (ellipsoidal) output side's
            stages = [("to", self._p_to), ("out", self.dst)]
        else:
            stages = [("in", self.src), ("from", self._p_from)]
        stages = [(name, c) for name, c in stages if vertical_crs(c) is None]  # heights above a geoid are no h
        for name, c in stages:
            if datum_name(c) == model_datum:
                return name
        lon, lat = self._model_lon_lat()
        for name, c in stages:  # another datum whose h PROJ says are the same at the cm level (compare_h_datums)
            match = compare_h_datums(model_crs, c, lon, lat)
            if match.same:
                self.notes.append(f"height model (h_crs {self.heights.h_crs}) on {crs_label(c)}: "
                                  + (match.note or f"taken as the same ellipsoidal heights ({model_datum} and "
                                                   f"{datum_name(c)})"))
                return name
        have = list(dict.fromkeys(datum_name(c) for _, c in stages))
        why = ""
        if self.params is not None and not self.params.spatial:
            why = (f" (a plane set, {self.params.model}, leaves them unchanged; a spatial set, bursa-wolf7 or "
                   "translation3, has them on both datums)")
        raise CrsError(
            f"height model: fitted on ellipsoidal heights of {model_datum} (h_crs {self.heights.h_crs}), but "
            f"{crs_label(self.src)} -> {crs_label(self.dst)} has ellipsoidal heights only on {' and '.join(have)}"
            f"{why}; if the model's h are of another datum, fit it again with --h-crs naming it (crs fit-heights)")

    def _model_lon_lat(self) -> tuple[float, float]:
        """Where the height model is (its origin, degrees on its CRS's own datum), else the centre of the output
        CRS's area of use: where a change of datum is told in metres of h."""
        try:
            if self.heights.crs:
                hcrs = horizontal_crs(parse_crs(self.heights.crs, "height model crs"))
                lon, lat, _ = to_own_geodetic(hcrs, np.array([self.heights.origin_m[0]]),
                                              np.array([self.heights.origin_m[1]]), np.zeros(1))
                return float(lon[0]), float(lat[0])
        except CrsError:
            pass
        area = horizontal_crs(self.dst).area_of_use
        if area is None:
            return 0.0, 0.0
        east = area.east + 360.0 if area.east < area.west else area.east  # an area across the antimeridian
        return ((area.west + east) / 2.0 + 180.0) % 360.0 - 180.0, (area.south + area.north) / 2.0

    @property
    def identity(self) -> bool:
        return self.params is None and self.heights is None and self.src == self.dst

    @property
    def description(self) -> str:
        parts = [f"{crs_label(self.src)} -> {crs_label(self.dst)}"]
        if self.params is not None:
            way = " applied inversely" if self.params.inverted else ""
            parts.append(f"via {self.params.model}{way} ({self.params.from_crs} -> {self.params.to_crs})")
            if not self.params.spatial and self.heights is None:  # a 4-parameter user may expect new heights
                parts.append("heights unchanged (a plane model)")
        if self.heights is not None:
            kind = "ellipsoidal heights from" if self.heights_inverse else "normal heights by"
            parts.append(f"{kind} {self.heights.model} height anomaly model")
        return ", ".join(parts)

    def inverse(self) -> "CrsTransformer":
        """The same operation from ``to_crs`` back to ``from_crs``."""
        heights = self.heights
        if heights is not None and not heights.crs:
            heights = dataclasses.replace(heights, crs=self.dst.to_wkt())  # it was evaluated on the output x, y
        return CrsTransformer(self.dst, self.src, self.params.inverse() if self.params is not None else None,
                              heights, self.allow_ballpark, heights_inverse=not self.heights_inverse)

    def spec(self) -> OperationSpec:
        """This operation as plain data (for Dask tasks and JSON)."""
        return OperationSpec(self.src.to_wkt(), self.dst.to_wkt(),
                             self.params.to_dict() if self.params is not None else None,
                             self.heights.to_dict() if self.heights is not None else None,
                             self.allow_ballpark, self.heights_inverse)

    def record(self) -> dict:
        """What this operation applies, for product metadata and stage reports: the CRSs, every PROJ step
        with its pipeline and stated accuracy, the parameter set and the height model."""
        steps = [leg.record() for leg in self._legs]
        if self.params is not None:
            steps.insert(1, {"step": "parameters", "model": self.params.model,
                             "applied": "inverse" if self.params.inverted else "forward",
                             "from": self.params.from_crs, "to": self.params.to_crs,
                             "parameters": {k: float(v) for k, v in self.params.parameters.items()}})
        if self.heights is not None:
            steps.append({"step": "height anomaly", "model": self.heights.model,
                          "formula": "h = H + zeta(x, y)" if self.heights_inverse else "H = h - zeta(x, y)",
                          "h_crs": self.heights.h_crs, "h_taken": {None: "output (h_crs not recorded)",
                                                                   "in": "input", "from": "before the parameters",
                                                                   "to": "after the parameters",
                                                                   "out": "output"}[self._h_stage]})
        # heights go in and out in these units (a 2D foot grid's heights are feet, whatever the PROJ
        # pipeline's own z unit says: the legs scale z around it)
        z_units = {"from": length_unit_name(height_unit_m(self.src), long=True),
                   "to": length_unit_name(height_unit_m(self.dst), long=True)}
        return {"from_crs": crs_label(self.src), "to_crs": crs_label(self.dst), "description": self.description,
                "ballpark": self.ballpark, "z_units": z_units, "steps": steps, "warnings": self.warnings}

    def transform(self, x, y, z=None):
        """Arrays in ``from_crs`` (x = easting/longitude) -> arrays in ``to_crs``; z defaults to 0."""
        x = np.atleast_1d(np.asarray(x, dtype=float))
        y = np.atleast_1d(np.asarray(y, dtype=float))
        z = np.zeros_like(x) if z is None else np.atleast_1d(np.asarray(z, dtype=float))
        x_in, y_in = x, y
        self.n_points += len(x)
        h_m = {"in": z * z_unit_m(self.src)}  # the ellipsoidal heights along the chain, metres, by stage
        if self.params is None:
            X, Y, Z = self._legs[0](x, y, z)
        elif not self.params.spatial:
            a, b, c = self._legs[0](x, y, z)
            h_m["from"] = h_m["to"] = c
            self._count_outside(a, b)
            ab = self.params.apply(np.column_stack([a, b]))
            X, Y, Z = self._legs[1](ab[:, 0], ab[:, 1], c)
        else:
            if self.params.fit_extent is not None and self._pre_plane is not None:
                a, b, _ = self._pre_plane(x, y, z)
                self._count_outside(a, b)
            if self._p_from.is_geocentric:
                XYZ = np.column_stack(self._legs[0](x, y, z))
                if self._h_stage == "from":
                    h_m["from"] = geocentric_to_geodetic(XYZ[:, 0], XYZ[:, 1], XYZ[:, 2], self._ell_from)[2]
            else:
                lon, lat, h = self._legs[0](x, y, z)
                lon, lat = geodetic_to_greenwich(self._geo_from, lon, lat)
                h_m["from"] = h
                XYZ = np.column_stack(geodetic_to_geocentric(lat, lon, h, self._ell_from))
            XYZ = self.params.apply(XYZ)
            if self._p_to.is_geocentric:
                if self._h_stage == "to":
                    h_m["to"] = geocentric_to_geodetic(XYZ[:, 0], XYZ[:, 1], XYZ[:, 2], self._ell_to)[2]
                X, Y, Z = self._legs[1](XYZ[:, 0], XYZ[:, 1], XYZ[:, 2])
            else:
                lat, lon, h = geocentric_to_geodetic(XYZ[:, 0], XYZ[:, 1], XYZ[:, 2], self._ell_to)
                h_m["to"] = h
                if self.heights is not None and self._h_stage is None and not self._p_from.is_geocentric:
                    dh = h - self._legs[0](x, y, z)[2]
                    self._dh_sum_m += float(np.sum(dh[np.isfinite(dh)]))
                    self._dh_n += int(np.count_nonzero(np.isfinite(dh)))
                X, Y, Z = self._legs[1](*greenwich_to_geodetic(self._geo_to, lon, lat), h)
        if self.heights is not None:
            if self._height_leg is not None and self._height_leg_from_src:
                hx, hy, _ = self._height_leg(x_in, y_in, np.zeros_like(x_in))
            elif self._height_leg is not None:
                hx, hy, _ = self._height_leg(X, Y, np.zeros_like(X))
            elif self._heights_crs == self.src and self._heights_crs != self.dst:
                hx, hy = x_in, y_in
            else:
                hx, hy = X, Y
            zeta = self.heights.zeta_m(hx, hy) / z_unit_m(self.dst)
            beyond = self.heights.beyond_hull_m(hx, hy)
            if beyond is not None:
                far = beyond > self.heights.hull_margin_m()
                self.n_beyond_heights_hull += int(far.sum())
                if far.any():
                    self.beyond_heights_hull_m = max(self.beyond_heights_hull_m, float(beyond.max()))
            if self._h_stage is None:  # a model file without h_crs: on the output's h (the trial's 118.8 m)
                Z = Z + zeta if self.heights_inverse else Z - zeta
            else:
                u = z_unit_m(self.dst)
                h_m["out"] = Z * u
                if self.heights_inverse:
                    # the normal heights went through the chain as if they were h; each step moved them by its
                    # change of h (independent of h to 1e-5 of zeta): h = H + zeta on the model's datum, then on
                    # by the steps after that stage
                    Z = Z + (h_m["in"] - h_m[self._h_stage]) / u + zeta
                else:
                    Z = h_m[self._h_stage] / u - zeta
        return X, Y, Z

    def _count_outside(self, a, b):
        if self.params is not None and self.params.fit_extent is not None:
            self.n_outside_fit_extent += int(outside_extent(self.params.fit_extent, np.column_stack([a, b])).sum())

    @property
    def warnings(self) -> list:
        out = list(self.notes)
        if self._dh_n:
            # The same GNSS-levelling model gave right normal heights through a 4-parameter set and 118.8 m wrong
            # ones through a 7-parameter set (WGS 84 -> Xian 1980 at Yichang, trial-lidar), without a word.
            dh = self._dh_sum_m / self._dh_n
            normal = self._p_from if self.heights_inverse else self._p_to  # the side whose heights are normal
            other = self._p_to if self.heights_inverse else self._p_from
            out.append(
                f"heights: the {self.params.model} set changed the ellipsoidal heights by {dh:+.3f} m (mean over "
                f"{self._dh_n} points); the height model's zeta = h - H is taken with h on the ellipsoid of "
                f"{normal.datum.name}: a model fitted from h on {other.datum.name} puts the heights {abs(dh):.3f} m "
                "off (docs/datums.md)")
        w = self.heights_extrapolation_warning()
        if w:
            out.append(w)
        if self.n_outside_fit_extent:
            out.append(
                f"{self.n_outside_fit_extent} of {self.n_points} points lie outside the area of the common points "
                "used for the parameters (extrapolation; accuracy unknown there)"
            )
        return out

    def heights_extrapolation_warning(self) -> str | None:
        """Said when the height model was evaluated past its levelling points' hull (by more than
        ``HeightAnomalyModel.hull_margin_m``; trial-datum: 40 km outside, or x, y swapped, said nothing)."""
        if not self.n_beyond_heights_hull:
            return None
        return (f"height model extrapolated: {self.n_beyond_heights_hull} of {self.n_points} points lie outside the "
                f"area of its levelling points (convex hull), up to {self.beyond_heights_hull_m / 1000.0:.3f} km "
                f"beyond it; its {self.heights.model} zeta there is unchecked (accuracy unknown): add levelled "
                "points there, or check that the model's x, y are easting, northing of the grid it records")


def transform_points(x, y, z=None, *, from_crs, to_crs, params=None, heights=None, allow_ballpark=False):
    """One-shot convenience: ``CrsTransformer(...).transform(x, y, z)``."""
    return CrsTransformer(from_crs, to_crs, params, heights, allow_ballpark).transform(x, y, z)


def to_own_geodetic(crs: pyproj.CRS, x, y, z):
    """(lon_deg, lat_deg, h) of coordinates in ``crs`` on its own geodetic CRS: a conversion, never a datum shift
    (degrees east of Greenwich whatever the CRS counts: NTF (Paris)'s grads from Paris too; h in metres; z in the
    height unit of ``crs``, see the module docstring)."""
    lon, lat, h = _ProjLeg(crs, crs.geodetic_crs, allow_ballpark=False)(x, y, z)
    lon, lat = geodetic_to_greenwich(horizontal_crs(crs).geodetic_crs, lon, lat)
    return lon, lat, h


def from_own_geodetic(crs: pyproj.CRS, lon_deg, lat_deg, h_m):
    """Coordinates in ``crs`` of points given on its own geodetic CRS in degrees east of Greenwich (the inverse of
    ``to_own_geodetic``)."""
    lon, lat = greenwich_to_geodetic(horizontal_crs(crs).geodetic_crs, lon_deg, lat_deg)
    return _ProjLeg(crs.geodetic_crs, crs, allow_ballpark=False)(lon, lat, h_m)


def same_datum_geocentric(crs: pyproj.CRS) -> pyproj.CRS:
    """The geocentric CRS of ``crs``'s own datum (the conversion to it never shifts a datum)."""
    geod = horizontal_crs(crs).geodetic_crs
    return pyproj.CRS.from_json_dict({
        "$schema": "https://proj.org/schemas/v0.7/projjson.schema.json", "type": "GeodeticCRS",
        "name": f"{geod.name} (geocentric)", "datum" if geod.datum.type_name != "Datum Ensemble" else
        "datum_ensemble": geod.datum.to_json_dict(),
        "coordinate_system": {"subtype": "Cartesian", "axis": [
            {"name": "Geocentric X", "abbreviation": "X", "direction": "geocentricX", "unit": "metre"},
            {"name": "Geocentric Y", "abbreviation": "Y", "direction": "geocentricY", "unit": "metre"},
            {"name": "Geocentric Z", "abbreviation": "Z", "direction": "geocentricZ", "unit": "metre"}]}})
