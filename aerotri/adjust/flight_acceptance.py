"""Flight acceptance: the checks of an aerial-photography flight against the specification limits.

Per frame: the tilt of the camera axis from the vertical, the kappa deviation (the angle between the
image's sides and the base direction to the neighbouring frames, reduced modulo 90 deg so that a
camera mounted with its long side along or across track reads the same), the flying height and its
change from the previous frame, the forward overlap with the next frame of the strip and the side
overlap with the neighbouring strip, both from the frames' footprints draped on the DEM (or on the
mean terrain height when there is no DEM). Per strip: the curvature (the largest distance of a
projection centre from the line joining the strip's first and last centres, in percent of that
line's length) and the range of the flying heights.

Limits (``LIMIT_KEYS``) by platform: a manned aerial block is held to the aerial photography flight
specification (``aerotri/core/tolerance_tables/flight_cn_aerial.toml``: tilt 2 deg, kappa 7 deg, strip
curvature 3 %, adjacent flying heights within 30 m, a strip's highest and lowest within 50 m, forward
overlap at least 56 %, side overlap at least 13 %; the thesis's section 4.1), a low-altitude (UAS) block to
none (its tolerance table says ``flight_limits_apply = False``): its values are reported, not judged, and
``spec`` says why. Works from adjusted orientations (``at/eo.txt``) or,
before the adjustment, from GNSS positions with a nominal attitude (level, image top looking forward:
tilt and kappa are then not measured). Overlaps are areas: overlap / footprint area of the frame.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from pathlib import Path

import numpy as np

from aerotri.core.errors import InputError
from aerotri.core.records import to_record
from aerotri.core.tolerances import NO_FLIGHT_SPEC, FlightLimits, manned_flight_limits
from aerotri.geom.block_scale import planned_terrain_height
from aerotri.geom.rotation import rotation_matrix_opk
from aerotri.geom.strips import strips_from_track

# tolerance-table key (a field of FlightLimits) -> (quantity, unit, "max" or "min")
LIMIT_KEYS = {
    "flight_tilt_max_deg": ("tilt", "deg", "max"),
    "flight_kappa_max_deg": ("kappa deviation", "deg", "max"),
    "flight_curvature_max_pct": ("strip curvature", "%", "max"),
    "flight_height_step_max_m": ("flying-height change between adjacent frames", "m", "max"),
    "flight_height_range_max_m": ("flying-height range in a strip", "m", "max"),
    "flight_forward_overlap_min_pct": ("forward overlap", "%", "min"),
    "flight_side_overlap_min_pct": ("side overlap", "%", "min"),
}
log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

DEFAULT_LIMITS = manned_flight_limits()  # the manned aerial photography specification
DEFAULT_SPEC = "manned aerial photography flight specification (flight_cn_aerial.toml)"
BORDER_SAMPLES = 8  # points per image side of a draped footprint


@dataclasses.dataclass
class Terrain:
    """Ground heights for draping footprints: a DEM (bilinear, NaN outside) or one mean height."""

    mean_height_m: float
    dem: np.ndarray | None = None  # (rows, cols) heights
    transform: tuple | None = None  # affine (a, b, c, d, e, f) of the DEM: x = a col + b row + c, y = d col + e row + f
    source: str = "mean terrain height"

    @classmethod
    def from_dem(cls, path, mean_height_m: float | None = None, max_side_px: int = 2000,
                 source: str | None = None) -> "Terrain":
        """The DEM of ``path``, read averaged down to at most ``max_side_px`` cells a side (a footprint
        corner needs the terrain height, not its detail; memory stays bounded on a large DEM). ``source``:
        how reports name it (default the path)."""
        import rasterio
        from rasterio.enums import Resampling

        path = Path(path)
        with rasterio.open(path) as ds:
            f = max(1.0, max(ds.width, ds.height) / max_side_px)
            shape = (max(1, round(ds.height / f)), max(1, round(ds.width / f)))
            z = ds.read(1, masked=True, out_shape=shape, resampling=Resampling.average).astype(float).filled(np.nan)
            tr = ds.transform @ ds.transform.scale(ds.width / shape[1], ds.height / shape[0])
        if not np.isfinite(z).any():
            raise InputError(f"{path}: the DEM holds no valid height")
        mean = float(np.nanmean(z)) if mean_height_m is None else float(mean_height_m)
        return cls(mean, z, (tr.a, tr.b, tr.c, tr.d, tr.e, tr.f), source=source or str(path))

    def height(self, x, y) -> np.ndarray:
        """Ground height at map positions; the mean height where the DEM has none."""
        x, y = np.asarray(x, float), np.asarray(y, float)
        if self.dem is None:
            return np.full(x.shape, self.mean_height_m)
        a, b, c, d, e, f = self.transform
        det = a * e - b * d
        col = (e * (x - c) - b * (y - f)) / det - 0.5  # pixel centres at integer positions
        row = (-d * (x - c) + a * (y - f)) / det - 0.5
        r0, c0 = np.floor(row).astype(int), np.floor(col).astype(int)
        fr, fc = row - r0, col - c0
        n_r, n_c = self.dem.shape
        out = np.full(x.shape, np.nan)
        ok = (r0 >= 0) & (c0 >= 0) & (r0 + 1 < n_r) & (c0 + 1 < n_c)
        r, cc, fr, fc = r0[ok], c0[ok], fr[ok], fc[ok]
        z = self.dem
        out[ok] = ((1 - fr) * ((1 - fc) * z[r, cc] + fc * z[r, cc + 1])
                   + fr * ((1 - fc) * z[r + 1, cc] + fc * z[r + 1, cc + 1]))
        return np.where(np.isfinite(out), out, self.mean_height_m)


def drape_rays(centre_m, dirs, terrain: Terrain, iterations: int = 12) -> np.ndarray:
    """Ground points (K, 3) of rays from ``centre_m`` (3,) along unit ``dirs`` (K, 3) on the terrain:
    fixed-point iteration on the height (converges for rays steeper than the terrain slope)."""
    z = np.full(len(dirs), terrain.mean_height_m)
    dz = np.where(np.abs(dirs[:, 2]) > 1e-6, dirs[:, 2], -1e-6)
    for _ in range(iterations):
        s = (z - centre_m[2]) / dz
        p = centre_m[:2] + s[:, None] * dirs[:, :2]
        z = terrain.height(p[:, 0], p[:, 1])
    s = (z - centre_m[2]) / dz
    return np.column_stack([centre_m[:2] + s[:, None] * dirs[:, :2], z])


def footprint(camera, centre_m, R, terrain: Terrain):
    """The frame's ground footprint (a shapely Polygon, map units) draped on the terrain."""
    import shapely

    w, h = camera.width - 0.5, camera.height - 0.5
    t = np.linspace(0.0, 1.0, BORDER_SAMPLES, endpoint=False)
    x = np.concatenate([-0.5 + t * (w + 0.5), np.full_like(t, w), w - t * (w + 0.5), np.full_like(t, -0.5)])
    y = np.concatenate([np.full_like(t, -0.5), -0.5 + t * (h + 0.5), np.full_like(t, h), h - t * (h + 0.5)])
    g = drape_rays(np.asarray(centre_m, float), camera.rays(x, y, R), terrain)
    poly = shapely.Polygon(g[:, :2])
    return poly if poly.is_valid else shapely.make_valid(poly).convex_hull


@dataclasses.dataclass
class FlightAcceptance:
    """Per-frame and per-strip values (JSON-ready via ``dataclasses.asdict``) and the limits they were held to."""

    frames: list[dict]
    strips: list[dict]
    limits: dict  # the FlightLimits that apply, as the report writes them (key -> limit; none for a UAS block)
    source: str  # "exterior orientations" or "GNSS positions, nominal attitude ..."
    terrain: str
    checks: list[dict]  # quantity, worst value, limit, unit, verdict, where
    spec: str = DEFAULT_SPEC  # the flight specification the limits come from, or why none applies

    @property
    def failed(self) -> list[dict]:
        return [c for c in self.checks if c["verdict"] == "fail"]


def _r(x, nd=2):
    return None if x is None or not math.isfinite(float(x)) else round(float(x), nd)


def nominal_attitude(centre_m, strip) -> np.ndarray:
    """Omega, phi, kappa (deg) of a level camera whose image top looks along the flight direction
    (the long side of a DMC frame across track, as the simulator flies): kappa = heading - 90 deg,
    with the heading counted from the x axis towards y."""
    c = np.asarray(centre_m, float)
    opk = np.zeros((len(c), 3))
    for s in np.unique(strip):
        idx = np.flatnonzero(strip == s)
        for n, i in enumerate(idx):
            a, b = idx[max(n - 1, 0)], idx[min(n + 1, len(idx) - 1)]
            d = c[b, :2] - c[a, :2]
            opk[i, 2] = (math.degrees(math.atan2(d[1], d[0])) - 90.0 + 180.0) % 360.0 - 180.0 if a != b else 0.0
    return opk


def in_flight_order(image_id, centre_m, opk_deg, extra_id=(), extra_centre_m=None):
    """Frames with orientations and ``extra_id`` frames with positions alone (the adjustment left them out, or
    before it), in image-id order (the flight order, as the adjustment's strips): ids, centres, omega phi kappa
    (deg; the extra frames' nominal, ``nominal_attitude``), attitude measured per frame, strip (from 0)."""
    ids = list(image_id) + list(extra_id)
    c = np.asarray(centre_m, float).reshape(-1, 3)
    if len(extra_id):
        c = np.vstack([c, np.asarray(extra_centre_m, float).reshape(-1, 3)])
    order = np.argsort(np.asarray(ids, dtype=object), kind="stable")
    ids, c = [ids[i] for i in order], c[order]
    measured = order < len(image_id)
    strip = strips_from_track(c)
    opk = np.vstack([np.asarray(opk_deg, float).reshape(-1, 3), np.zeros((len(extra_id), 3))])[order]
    return ids, c, np.where(measured[:, None], opk, nominal_attitude(c, strip)), measured, strip


CROSS_STRIP_DEG = 45.0  # a strip turned further than this from the block's direction is a cross strip


def _strip_heading_deg(centre_m, idx) -> float | None:
    """The direction of a strip (its first to its last centre), degrees modulo 180; None for one frame."""
    if len(idx) < 2:
        return None
    d = centre_m[idx[-1], :2] - centre_m[idx[0], :2]
    return math.degrees(math.atan2(d[1], d[0])) % 180.0 if np.any(d) else None


def _strip_order(centre_m, strip) -> tuple[list, list]:
    """(the parallel strips sorted across track, the cross strips). The block's direction is the mean of the strips'
    directions as axes (doubled angles), weighted by their frames; a strip more than ``CROSS_STRIP_DEG`` from it is a
    cross strip, which has no neighbour across track (sorted in among the parallel strips, a cross strip at the west
    end of an east-west block was "side overlap 11.7 %, fail" and made its neighbour's 53.9 % of a true 40.4 %,
    trial-ew)."""
    ids = list(np.unique(strip))
    heading = {s: _strip_heading_deg(centre_m, np.flatnonzero(strip == s)) for s in ids}
    weight = {s: int(np.sum(strip == s)) for s in ids}
    known = [s for s in ids if heading[s] is not None]
    if known:
        a = np.radians([2.0 * heading[s] for s in known])
        w = np.array([weight[s] for s in known], float)
        main = 0.5 * math.degrees(math.atan2(float(w @ np.sin(a)), float(w @ np.cos(a))))
    else:
        main = 0.0
    cross = [s for s in known if abs((heading[s] - main + 90.0) % 180.0 - 90.0) > CROSS_STRIP_DEG]
    u = np.array([math.cos(math.radians(main)), math.sin(math.radians(main))])
    w_across = np.array([-u[1], u[0]])
    parallel = sorted((s for s in ids if s not in cross),
                      key=lambda s: float(np.mean(centre_m[strip == s, :2] @ w_across)))
    return parallel, cross


def _beyond(value, key, limits: FlightLimits) -> bool:
    """True when ``value`` breaks the limit ``key`` (a max or a min limit); False without either."""
    limit = getattr(limits, key)
    if value is None or limit is None:
        return False
    return value > limit if LIMIT_KEYS[key][2] == "max" else value < limit


def _check(quantity, values, where, key, limits: FlightLimits) -> dict:
    unit, kind = LIMIT_KEYS[key][1], LIMIT_KEYS[key][2]
    limit = getattr(limits, key)
    pairs = [(v, w) for v, w in zip(values, where) if v is not None and math.isfinite(v)]
    if not pairs:
        return dict(quantity=quantity, value=None, limit=limit, unit=unit, verdict=None, where="", key=key,
                    n=0, n_fail=0)
    v, w = (max if kind == "max" else min)(pairs, key=lambda p: p[0])
    bad = [p for p in pairs if _beyond(p[0], key, limits)]
    # measured but held to no limit (a UAS block): say so rather than leave the verdict empty
    verdict = "not judged" if limit is None else ("fail" if bad else "pass")
    return dict(quantity=quantity, value=_r(v), limit=limit, unit=unit, verdict=verdict, where=w, key=key,
                n=len(pairs), n_fail=len(bad))


def flight_acceptance(image_id, centre_m, opk_deg, camera, terrain: Terrain, strip=None, *, limits: dict | None = None,
                      attitude_measured=True, unit_m=(1.0, 1.0, 1.0)) -> FlightAcceptance:
    """The flight acceptance of frames in flight order (``image_id`` order is the track order when
    ``strip`` is None: ``strips_from_track`` splits it). ``opk_deg`` in the photogrammetric
    convention; ``attitude_measured`` False for a nominal attitude (tilt and kappa not reported), one
    bool for all frames or one per frame. ``centre_m`` and the footprints are in the CRS's units (``x_m``, ``y_m``,
    ``z_m``, ``mean_z_m`` stay coordinates); ``unit_m``: metres per unit of x, y, z (``map_unit_m``), so that heights
    above ground, height steps and ranges and strip lengths are metres, as the limits are (trial s102 txt2 H1: a feet
    block's 13.15 ft step judged against 30 m)."""
    import shapely

    c = np.asarray(centre_m, float)
    opk = np.asarray(opk_deg, float)
    n = len(c)
    measured = np.broadcast_to(np.asarray(attitude_measured, bool), (n,))
    strip = strips_from_track(c) + 1 if strip is None else np.asarray(strip)
    limits = limits or {}
    if limits.get("flight_limits_apply", True):
        lim = dataclasses.replace(DEFAULT_LIMITS, **{k: v for k, v in limits.items() if k in LIMIT_KEYS})
        spec = limits.get("flight_spec") or DEFAULT_SPEC
    else:  # a UAS block: no manned flight specification judges it
        lim, spec = FlightLimits(), limits.get("flight_spec") or NO_FLIGHT_SPEC
    R = rotation_matrix_opk(opk[:, 0], opk[:, 1], opk[:, 2])
    polys = [footprint(camera, c[i], R[i], terrain) for i in range(n)]
    ground = terrain.height(c[:, 0], c[:, 1])
    uxy, uz = float(unit_m[0]), float(unit_m[2])
    frames = [dict(image_id=str(image_id[i]), strip=int(strip[i]), x_m=_r(c[i, 0], 3), y_m=_r(c[i, 1], 3),
                   z_m=_r(c[i, 2], 3), height_above_ground_m=_r((c[i, 2] - ground[i]) * uz, 2), tilt_deg=None,
                   kappa_deviation_deg=None, height_step_m=None, forward_overlap_pct=None, side_overlap_pct=None,
                   footprint=[[_r(x, 2), _r(y, 2)] for x, y in polys[i].exterior.coords])
              for i in range(n)]
    order, cross = _strip_order(c, strip)
    strips = []
    for k, s in enumerate(order + cross):
        idx = np.flatnonzero(strip == s)
        for m, i in enumerate(idx):
            if measured[i]:
                # angle between the camera axis (third column of R) and the vertical
                frames[i]["tilt_deg"] = _r(math.degrees(math.acos(min(1.0, abs(R[i][2, 2])))), 3)
            if len(idx) > 1:
                a, b = idx[max(m - 1, 0)], idx[min(m + 1, len(idx) - 1)]
                base = c[b, :2] - c[a, :2]
                # image x axis in the ground plane vs the base direction, modulo 90 deg
                ax = R[i][:2, 0]
                ang = math.degrees(math.atan2(ax[1], ax[0]) - math.atan2(base[1], base[0]))
                if measured[i]:
                    frames[i]["kappa_deviation_deg"] = _r(abs((ang + 45.0) % 90.0 - 45.0), 3)
            if m > 0:
                frames[i]["height_step_m"] = _r(abs(c[i, 2] - c[idx[m - 1], 2]) * uz, 2)
            if m + 1 < len(idx):
                p, q = polys[i], polys[idx[m + 1]]
                frames[i]["forward_overlap_pct"] = _r(100.0 * p.intersection(q).area / p.area, 2)
        # side overlap: each frame's share covered by the neighbouring strip(s) across track (the
        # smaller of the two for an inner strip: the weaker side decides)
        neighbours = [order[j] for j in (k - 1, k + 1) if 0 <= j < len(order)] if s not in cross else []
        unions = [shapely.union_all([polys[j] for j in np.flatnonzero(strip == t)]) for t in neighbours]
        for i in idx:
            if unions:
                frames[i]["side_overlap_pct"] = _r(min(100.0 * polys[i].intersection(u).area / polys[i].area
                                                       for u in unions), 2)
        ends = c[idx[-1], :2] - c[idx[0], :2]
        length = float(np.linalg.norm(ends))
        if len(idx) > 2 and length > 0:
            u = ends / length
            off = np.abs((c[idx, 0] - c[idx[0], 0]) * u[1] - (c[idx, 1] - c[idx[0], 1]) * u[0])
            curvature = 100.0 * float(off.max()) / length
        else:
            curvature = None  # two frames always lie on a line
        side = [frames[i]["side_overlap_pct"] for i in idx if frames[i]["side_overlap_pct"] is not None]
        fwd = [frames[i]["forward_overlap_pct"] for i in idx if frames[i]["forward_overlap_pct"] is not None]
        strips.append(dict(strip=int(s), frames=len(idx), first=str(image_id[idx[0]]), last=str(image_id[idx[-1]]),
                           cross_strip=s in cross,
                           length_m=_r(length * uxy, 2), curvature_pct=_r(curvature, 3),
                           height_range_m=_r(float(np.ptp(c[idx, 2])) * uz, 2), mean_z_m=_r(float(c[idx, 2].mean()), 2),
                           mean_height_above_ground_m=_r(float(np.mean(c[idx, 2] - ground[idx])) * uz, 2),
                           forward_overlap_min_pct=min(fwd) if fwd else None,
                           forward_overlap_mean_pct=_r(np.mean(fwd), 2) if fwd else None,
                           side_overlap_median_pct=_r(np.median(side), 2) if side else None,
                           max_tilt_deg=max((frames[i]["tilt_deg"] for i in idx if frames[i]["tilt_deg"] is not None),
                                            default=None),
                           max_kappa_deviation_deg=max((frames[i]["kappa_deviation_deg"] for i in idx
                                                        if frames[i]["kappa_deviation_deg"] is not None), default=None)))
    frame_keys = {"tilt_deg": "flight_tilt_max_deg", "kappa_deviation_deg": "flight_kappa_max_deg",
                  "height_step_m": "flight_height_step_max_m", "forward_overlap_pct": "flight_forward_overlap_min_pct",
                  "side_overlap_pct": "flight_side_overlap_min_pct"}
    strip_keys = {"curvature_pct": "flight_curvature_max_pct", "height_range_m": "flight_height_range_max_m",
                  "side_overlap_median_pct": "flight_side_overlap_min_pct"}
    for rows, keys in ((frames, frame_keys), (strips, strip_keys)):
        for row in rows:
            row["fails"] = [k for f, k in keys.items() if _beyond(row[f], k, lim)]
    fid = [f["image_id"] for f in frames]
    sid = [f"strip {st['strip']}" for st in strips]
    checks = [
        _check("tilt of the camera axis", [f["tilt_deg"] for f in frames], fid, "flight_tilt_max_deg", lim),
        _check("kappa deviation from the base direction", [f["kappa_deviation_deg"] for f in frames], fid,
               "flight_kappa_max_deg", lim),
        _check("strip curvature", [st["curvature_pct"] for st in strips], sid, "flight_curvature_max_pct", lim),
        _check("flying-height change between adjacent frames", [f["height_step_m"] for f in frames], fid,
               "flight_height_step_max_m", lim),
        _check("flying-height range in a strip", [st["height_range_m"] for st in strips], sid,
               "flight_height_range_max_m", lim),
        _check("forward overlap (footprints on the terrain)", [f["forward_overlap_pct"] for f in frames], fid,
               "flight_forward_overlap_min_pct", lim),
        # the side overlap of a strip pair is the median over its frames: strip ends reach past the
        # neighbouring strip's ends without being a gap in the cover
        _check("side overlap (median over a strip's frames)", [st["side_overlap_median_pct"] for st in strips], sid,
               "flight_side_overlap_min_pct", lim),
    ]
    if measured.all():
        source = "exterior orientations"
    elif not measured.any():
        source = "GNSS positions, nominal attitude (tilt and kappa not measured)"
    else:
        nominal = [str(image_id[i]) for i in np.flatnonzero(~measured)]
        source = (f"exterior orientations; {len(nominal)} frames the adjustment left out from GNSS positions, nominal "
                  f"attitude (tilt and kappa not measured: {', '.join(nominal[:10])}{' ...' if len(nominal) > 10 else ''})")
    return FlightAcceptance(frames, strips, to_record(lim, drop_none=True), source, terrain.source, checks, spec)


def project_terrain(project, *, dem: Path | None = None) -> Terrain | None:
    """The project's terrain for the footprints: ``dem`` (the adjustment's surface-control DEM) when given,
    else ``lidar_out/dem.tif``, else ``[flight] mean_terrain_height_m`` of project.toml, else None."""
    mean_h = planned_terrain_height(project)
    if dem is not None and Path(dem).is_file():
        dem = Path(dem).resolve()
        root = Path(project.root).resolve()
        return Terrain.from_dem(dem, mean_h, source=str(dem.relative_to(root)) if dem.is_relative_to(root) else str(dem))
    # named relative to the project folder: the same project elsewhere reports the same
    if project.dem_path.is_file():
        return Terrain.from_dem(project.dem_path, mean_h, source=str(project.dem_path.relative_to(project.root)))
    if mean_h is not None:
        return Terrain(float(mean_h), source="project.toml [flight] mean_terrain_height_m")
    return None


def project_flight_acceptance(root, limits: dict | None = None, *,
                              terrain: Terrain | None = None) -> FlightAcceptance | None:
    """The flight acceptance of a project folder: ``at/eo.txt`` (with the adjusted camera) when the block
    is adjusted, else ``gnss.txt`` with the nominal attitude; footprints on ``terrain`` when given, else on
    ``lidar_out/dem.tif`` when present, else on ``[flight] mean_terrain_height_m``. None when there is
    neither EO nor GNSS, or no terrain."""
    from aerotri.core.project import Project
    from aerotri.geom.camera import oriented_camera
    from aerotri.geom.crs.definition import parse_crs
    from aerotri.geom.eo import read_eo, read_gnss

    project = Project.open(root)
    terrain = terrain if terrain is not None else project_terrain(project)
    camera, _ = oriented_camera(project)
    crs = parse_crs(project.crs)
    g = read_gnss(project.gnss_path, crs) if project.gnss_path.is_file() else None
    if project.eo_path.is_file():
        eo = read_eo(project.eo_path, crs)
        # trial-relief F1: frames the adjustment left out (a block split over the mountain) were missing from
        # the flight checks, which then passed the overlaps that had failed; they come from GNSS
        have = set(eo.image_id)
        extra = [i for i, k in enumerate(g.image_id) if k not in have] if g is not None else []
        ids, c, opk, measured, strip = in_flight_order(eo.image_id, eo.centre_m, eo.opk_deg,
                                                       [g.image_id[i] for i in extra],
                                                       np.asarray(g.position_m)[extra] if extra else None)
    elif g is not None:
        ids, c, opk, measured, strip = in_flight_order([], np.zeros((0, 3)), np.zeros((0, 3)), g.image_id,
                                                       g.position_m)
    else:
        return None
    if terrain is None:
        return None  # the footprints need a terrain: the caller says the checks were not made
    from aerotri.adjust.report_record import map_unit_m

    return flight_acceptance(ids, c, opk, camera, terrain, strip + 1, limits=limits, attitude_measured=measured,
                             unit_m=map_unit_m(crs, f"{project.config_path} [project] crs"))


def overlap_shortfall(root) -> str:
    """"the flight's side overlap ... is 3.2 % at strip 1 against the specification's 13 % (...)": the overlaps of
    the flight acceptance that fail (footprints on the LiDAR DEM, else the planned terrain height), the usual reason
    a block falls apart into parts no tie point connects (trial-relief F3: a side overlap of 6 % over a mountain, and
    the split block's warning sent the user to the terrain height). Empty when they pass or cannot be measured."""
    try:
        fa = project_flight_acceptance(root)
    except (InputError, OSError) as e:  # a hint only: the split itself is what the warning is about
        return f"(the flight's overlaps not measured: {e})"
    if fa is None:
        return ""
    failed = [c for c in fa.failed if c["key"] in ("flight_side_overlap_min_pct", "flight_forward_overlap_min_pct")]
    return "; ".join(f"the flight's {c['quantity']} is {c['value']} % at {c['where']} against the specification's "
                     f"{c['limit']:g} % ({fa.terrain})" for c in failed)


def say_split_block(root, components: int) -> None:
    """After matching: when the block fell apart, the overlaps that fail the specification, as a warning (the match
    stage cannot measure them itself: its layer does not reach the flight acceptance)."""
    if components > 1 and (text := overlap_shortfall(root)):
        log.warning(f"{root}: the block falls apart into {components} parts: {text}")
