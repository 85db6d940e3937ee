"""The simulated town: terrain, roads, ponds, buildings, trees and ground targets.

Everything is built in a local metric frame (x east, y north, z up, metres) whose origin is the
lower-left corner of the scene; ``Scene.origin_m`` shifts it into the project CRS. Geometry is
explicit and exact: terrain is a triangulated height field, buildings are closed sets of triangles
(roof faces, fascia under the eaves, walls), tree crowns are spheroids. The renderer and the LiDAR
scanner ray-cast the same geometry, so every truth product is consistent with the data.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import shapely
from shapely.geometry import LineString, Point, Polygon
from shapely.ops import unary_union

from aerotri.sim.config import PresetScene

# Material codes for the ground texture (also used for truth classes and LiDAR intensity).
GRASS, SOIL, ROAD, MARKING, WATER, TARGET, TARGET_RING = 0, 1, 2, 3, 4, 5, 6
# Surface kinds returned by the ray caster.
KIND_NONE, KIND_TERRAIN, KIND_ROOF, KIND_WALL, KIND_TREE = 0, 1, 2, 3, 4

ROOF_TYPES = ("flat", "gable", "hip")
FASCIA_M = 0.3  # depth of the roof slab edge below the eave line


@dataclasses.dataclass
class Building:
    building_id: int
    footprint: Polygon  # wall line (local metres)
    outline: Polygon  # roof (eave) outline = footprint grown by the eave overhang
    shape: str  # rectangle | L | courtyard
    roof: str  # flat | gable | hip
    base_z_m: float
    eave_z_m: float
    ridge_z_m: float
    eave_m: float
    size_m: tuple[float, float]  # (length, width) of the minimum rotated rectangle of the footprint


@dataclasses.dataclass
class Scene:
    """Scene geometry in local metres; arrays are numba-ready."""

    width_m: float
    height_m: float
    origin_m: np.ndarray  # (3,) project-CRS coordinates of the local origin (E, N, h)
    terrain_res_m: float
    terrain_z: np.ndarray  # (ny+1, nx+1) node heights, node (i, j) at (j*res, i*res)
    tri_v: np.ndarray  # (T, 3, 3) building triangles
    tri_kind: np.ndarray  # (T,) KIND_ROOF or KIND_WALL
    tri_obj: np.ndarray  # (T,) building id
    tree_c: np.ndarray  # (K, 3) crown centres
    tree_ac: np.ndarray  # (K, 2) horizontal and vertical semi-axes
    roads: np.ndarray  # (R, 5) x0 y0 x1 y1 width
    ponds: np.ndarray  # (P, 6) cx cy a b angle_rad water_z
    targets: np.ndarray  # (C, 3) painted check targets: x y radius
    target_z: np.ndarray  # (C,)
    buildings: list[Building]
    roof_albedo: np.ndarray  # (B, 3) per building roof colour
    seed: int
    steep_band_y_m: tuple[float, float]

    def terrain_height(self, x, y):
        """Height of the triangulated terrain at local (x, y) (arrays), same split as the ray caster."""
        res = self.terrain_res_m
        ny, nx = self.terrain_z.shape
        fx = np.clip(np.asarray(x, dtype=float) / res, 0, nx - 1 - 1e-9)
        fy = np.clip(np.asarray(y, dtype=float) / res, 0, ny - 1 - 1e-9)
        j = np.floor(fx).astype(int)
        i = np.floor(fy).astype(int)
        u = fx - j
        v = fy - i
        h = self.terrain_z
        h00, h10, h01, h11 = h[i, j], h[i, j + 1], h[i + 1, j], h[i + 1, j + 1]
        # Diagonal from node (i, j) to (i+1, j+1): lower triangle u >= v.
        lower = u >= v
        return np.where(lower, h00 + u * (h10 - h00) + v * (h11 - h10), h00 + v * (h01 - h00) + u * (h11 - h01))

    def roof_corners(self) -> list[dict]:
        """Every roof (eave outline) corner: local x y z, roof type, building id, corner angle."""
        rows = []
        for b in self.buildings:
            rings = [b.outline.exterior] + list(b.outline.interiors)
            for ring in rings:
                pts = np.asarray(ring.coords)[:-1]
                n = len(pts)
                for k in range(n):
                    p, a, c = pts[k], pts[k - 1], pts[(k + 1) % n]
                    e1, e2 = a - p, c - p
                    ang = math.degrees(math.acos(np.clip(e1 @ e2 / (np.linalg.norm(e1) * np.linalg.norm(e2)), -1, 1)))
                    rows.append(
                        dict(
                            x=p[0], y=p[1], z=b.eave_z_m, roof=b.roof, building_id=b.building_id,
                            shape=b.shape, angle_deg=ang, length_m=b.size_m[0], width_m=b.size_m[1],
                        )
                    )
        return rows


# ----------------------------------------------------------------------------------------------
# Terrain


def _smooth_noise(rng, shape, scale_px):
    """Band-limited Gaussian noise (unit variance) by Fourier filtering."""
    ny, nx = shape
    white = rng.standard_normal(shape)
    ky = np.fft.fftfreq(ny)[:, None]
    kx = np.fft.rfftfreq(nx)[None, :]
    filt = np.exp(-0.5 * (kx**2 + ky**2) * (2 * np.pi * scale_px) ** 2)
    out = np.fft.irfft2(np.fft.rfft2(white) * filt, s=shape)
    return out / (out.std() + 1e-12)


def build_terrain(cfg: PresetScene, width_m: float, height_m: float, rng) -> tuple[np.ndarray, tuple[float, float]]:
    """Heights of the terrain nodes: flat urban ground, gentle hills and a steep valley side.

    The steep band runs along the northern part of the scene: a ramp of ``steep_slope_deg`` over
    ``steep_band_m`` ending in a hilly plateau, like the side of a mountain reservoir valley.
    """
    res = cfg.terrain_res_m
    nx = int(math.ceil(width_m / res)) + 1
    ny = int(math.ceil(height_m / res)) + 1
    y = np.arange(ny) * res
    hills = cfg.hill_amplitude_m * _smooth_noise(rng, (ny, nx), cfg.hill_scale_m / res)
    rough = 0.15 * _smooth_noise(rng, (ny, nx), 6.0 / res)
    z = hills + rough
    y0 = height_m * cfg.steep_start_frac
    band = cfg.steep_band_m
    rise = band * math.tan(math.radians(cfg.steep_slope_deg))
    s = np.clip((y - y0) / band, 0.0, 1.0)
    # Smoothed ramp: constant slope in the middle, rounded toe and crest over ~10 % of the band.
    ramp = rise * _smooth_ramp(s)
    z = z + ramp[:, None]
    # Mountain side relief: ridges and gullies on the slope and plateau.
    slope_mask = np.clip((y - y0) / (0.3 * band), 0.0, 1.0)[:, None]
    z = z + slope_mask * cfg.mountain_relief_m * _smooth_noise(rng, (ny, nx), 40.0 / res)
    return z, (y0, y0 + band)


def _smooth_ramp(s):
    # Quadratic toe and crest (10 % each) joined by a straight constant slope, normalised to 0..1.
    a = 0.1
    out = np.where(
        s < a,
        s**2 / (2 * a),
        np.where(s > 1 - a, 1 - a - (1 - s) ** 2 / (2 * a) + a / 2, s - a / 2),
    )
    return out / (1 - a)


# ----------------------------------------------------------------------------------------------
# Roads, ponds, buildings, trees


def build_roads(cfg: PresetScene, urban: Polygon, rng) -> np.ndarray:
    """A rotated grid of straight roads clipped to the urban area."""
    ang = math.radians(cfg.road_angle_deg)
    u = np.array([math.cos(ang), math.sin(ang)])
    v = np.array([-u[1], u[0]])
    cx, cy = urban.centroid.x, urban.centroid.y
    half = math.hypot(*np.ptp(np.asarray(urban.exterior.coords), axis=0))
    roads = []
    for direction, normal in ((u, v), (v, u)):
        spacing = cfg.road_spacing_m
        offsets = np.arange(-half, half, spacing) + rng.uniform(0, spacing)
        for off in offsets:
            c = np.array([cx, cy]) + normal * off
            line = LineString([c - direction * half, c + direction * half]).intersection(urban)
            if line.is_empty or line.length < 50:
                continue
            for seg in getattr(line, "geoms", [line]):
                (x0, y0), (x1, y1) = seg.coords[0], seg.coords[-1]
                w = rng.uniform(*cfg.road_width_m)
                roads.append((x0, y0, x1, y1, w))
    return np.array(roads, dtype=float).reshape(-1, 5)


def _footprint(shape: str, L: float, W: float, rng) -> Polygon:
    """Footprint in a local frame centred at 0 with its long axis along x."""
    if shape == "rectangle":
        return Polygon([(-L / 2, -W / 2), (L / 2, -W / 2), (L / 2, W / 2), (-L / 2, W / 2)])
    if shape == "L":
        a = rng.uniform(0.4, 0.6) * L
        b = rng.uniform(0.45, 0.6) * W
        return Polygon([(-L / 2, -W / 2), (L / 2, -W / 2), (L / 2, -W / 2 + b), (-L / 2 + a, -W / 2 + b),
                        (-L / 2 + a, W / 2), (-L / 2, W / 2)])
    if shape == "courtyard":
        t = rng.uniform(0.28, 0.34) * min(L, W)
        outer = [(-L / 2, -W / 2), (L / 2, -W / 2), (L / 2, W / 2), (-L / 2, W / 2)]
        inner = [(-L / 2 + t, -W / 2 + t), (-L / 2 + t, W / 2 - t), (L / 2 - t, W / 2 - t), (L / 2 - t, -W / 2 + t)]
        return Polygon(outer, [inner])
    raise ValueError(shape)


def _place(poly: Polygon, angle_rad: float, cx: float, cy: float) -> Polygon:
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return shapely.affinity.affine_transform(poly, [c, -s, s, c, cx, cy])


def _quad(a, b, c, d):
    return [(a, b, c), (a, c, d)]


def _building_triangles(b: Building, angle_rad: float, centre: tuple[float, float], pitch_deg: float):
    """Triangles (list of 3x3 arrays) and their kinds for one building."""
    tris, kinds = [], []
    base = b.base_z_m - 1.0  # walls reach below the terrain: no gaps on uneven ground
    wall_top = b.eave_z_m - FASCIA_M

    def add(vs, kind):
        for t in vs:
            tris.append(np.array(t, dtype=float))
            kinds.append(kind)

    for ring in [b.footprint.exterior] + list(b.footprint.interiors):
        pts = np.asarray(ring.coords)
        for p, q in zip(pts[:-1], pts[1:]):
            add(_quad((*p, base), (*q, base), (*q, wall_top), (*p, wall_top)), KIND_WALL)
    for ring in [b.outline.exterior] + list(b.outline.interiors):
        pts = np.asarray(ring.coords)
        for p, q in zip(pts[:-1], pts[1:]):
            add(_quad((*p, wall_top), (*q, wall_top), (*q, b.eave_z_m), (*p, b.eave_z_m)), KIND_WALL)
    if b.roof == "flat":
        for t in shapely.constrained_delaunay_triangles(b.outline).geoms:
            c = np.asarray(t.exterior.coords)[:3]
            add([[(x, y, b.eave_z_m) for x, y in c]], KIND_ROOF)
        # Underside of the overhang, so that no ray slips between fascia and wall.
        ring_area = b.outline.difference(b.footprint)
        for t in shapely.constrained_delaunay_triangles(ring_area).geoms:
            c = np.asarray(t.exterior.coords)[:3]
            add([[(x, y, wall_top) for x, y in c]], KIND_WALL)
        return tris, kinds
    # Pitched roofs on rectangles: local frame u along the ridge (long axis), v across.
    ca, sa = math.cos(angle_rad), math.sin(angle_rad)
    cx, cy = centre

    def P(u, v, z):
        return (cx + ca * u - sa * v, cy + sa * u + ca * v, z)

    Lo, Wo = b.size_m[0] / 2 + b.eave_m, b.size_m[1] / 2 + b.eave_m
    ze, zr = b.eave_z_m, b.ridge_z_m
    if b.roof == "gable":
        add(_quad(P(-Lo, -Wo, ze), P(Lo, -Wo, ze), P(Lo, 0, zr), P(-Lo, 0, zr)), KIND_ROOF)
        add(_quad(P(Lo, Wo, ze), P(-Lo, Wo, ze), P(-Lo, 0, zr), P(Lo, 0, zr)), KIND_ROOF)
        add([(P(Lo, -Wo, ze), P(Lo, Wo, ze), P(Lo, 0, zr))], KIND_WALL)
        add([(P(-Lo, Wo, ze), P(-Lo, -Wo, ze), P(-Lo, 0, zr))], KIND_WALL)
    else:  # hip
        r = Lo - Wo
        add(_quad(P(-Lo, -Wo, ze), P(Lo, -Wo, ze), P(r, 0, zr), P(-r, 0, zr)), KIND_ROOF)
        add(_quad(P(Lo, Wo, ze), P(-Lo, Wo, ze), P(-r, 0, zr), P(r, 0, zr)), KIND_ROOF)
        add([(P(Lo, -Wo, ze), P(Lo, Wo, ze), P(r, 0, zr))], KIND_ROOF)
        add([(P(-Lo, Wo, ze), P(-Lo, -Wo, ze), P(-r, 0, zr))], KIND_ROOF)
    ring_area = b.outline.difference(b.footprint)
    for t in shapely.constrained_delaunay_triangles(ring_area).geoms:
        c = np.asarray(t.exterior.coords)[:3]
        add([[(x, y, wall_top) for x, y in c]], KIND_WALL)
    return tris, kinds


def _building_height(cfg, rng) -> float:
    lo, hi = cfg.building_height_m
    # Mostly low-rise with some towers up to the top of the range.
    r = rng.random()
    if r < 0.7:
        return rng.uniform(lo, min(hi, 20.0))
    if r < 0.9:
        return rng.uniform(min(hi, 20.0), min(hi, 35.0))
    return rng.uniform(min(hi, 35.0), hi)


def _ponds(cfg: PresetScene, z: np.ndarray, res: float, width_m: float, steep: tuple[float, float], rng):
    """Flat water surfaces set into the terrain of the urban/rural flats: (P, 6) ponds, the terrain with the
    ponds and their banks (``z`` changed in place), the pond outlines."""
    margin = cfg.urban_margin_m
    ponds = []
    for _ in range(cfg.ponds):
        a, b = rng.uniform(*cfg.pond_size_m), rng.uniform(*cfg.pond_size_m)
        cx = rng.uniform(margin + a, width_m - margin - a)
        cy = rng.uniform(margin + a, max(margin + a + 1, steep[0] - a))
        ang = rng.uniform(0, math.pi)
        ponds.append([cx, cy, a, b, ang, 0.0])
    ponds = np.array(ponds, dtype=float).reshape(-1, 6)
    ny, nx = z.shape
    for p in ponds:
        cx, cy, a, b, ang = p[:5]
        # Only nodes within the banks change: work on the box that holds the ellipse grown by the 8 m bank.
        # (The whole-grid blend this replaces also rounded far nodes by at most an ulp, min(z, level + (z -
        # level)); leaving them alone gives byte-identical demo and tiny projects and costs nothing per pond.)
        reach = max(a, b) * (1.0 + 8.0 / min(a, b)) + 2.0 * res
        i0, i1 = max(0, int((cy - reach) / res)), min(ny, int((cy + reach) / res) + 2)
        j0, j1 = max(0, int((cx - reach) / res)), min(nx, int((cx + reach) / res) + 2)
        yy, xx = np.mgrid[i0:i1, j0:j1] * res
        zz = z[i0:i1, j0:j1]
        dx, dy = xx - cx, yy - cy
        u = (dx * math.cos(ang) + dy * math.sin(ang)) / a
        v = (-dx * math.sin(ang) + dy * math.cos(ang)) / b
        inside = u * u + v * v <= 1.0
        level = np.percentile(zz[inside], 20) - 0.3
        p[5] = level
        # Banks: blend the terrain down to the water level over 8 m outside the shore.
        d = np.sqrt(u * u + v * v)
        shore = np.clip((d - 1.0) * min(a, b) / 8.0, 0.0, 1.0)
        box = np.where(inside, level, np.minimum(zz, level + shore * (zz - level) + 0.0))
        z[i0:i1, j0:j1] = box
    pond_polys = [
        shapely.affinity.rotate(shapely.affinity.scale(Point(p[0], p[1]).buffer(1.0, 32), p[2], p[3]),
                                p[4], origin=(p[0], p[1]), use_radians=True)
        for p in ponds
    ]
    return ponds, z, pond_polys


@dataclasses.dataclass
class _Buildings:
    buildings: list[Building]
    footprints: list[Polygon]
    tris: list  # (3, 3) triangles of all buildings
    kinds: list  # KIND_ROOF or KIND_WALL per triangle
    objs: list  # building id per triangle


def _place_buildings(cfg: PresetScene, ground: Scene, urban: Polygon, blocked, rng) -> _Buildings:
    """Footprints aligned with the road grid, kept off roads, ponds (``blocked``) and each other, on ground
    flat enough; their roofs and triangles."""
    angle = math.radians(cfg.road_angle_deg)
    out = _Buildings([], [], [], [], [])
    attempts = 0
    n_target = cfg.buildings
    shapes = ("rectangle", "L", "courtyard")
    shapely.prepare(blocked)
    # placed footprints by 100 m cell: the gap test looks at the footprints whose box meets the candidate's
    # (the same decisions as testing every footprint)
    cells: dict[tuple[int, int], list[int]] = {}
    cell = 100.0

    def near(bounds):
        seen = set()
        for i in range(int(bounds[1] // cell), int(bounds[3] // cell) + 1):
            for j in range(int(bounds[0] // cell), int(bounds[2] // cell) + 1):
                for k in cells.get((i, j), ()):
                    if k not in seen:
                        seen.add(k)
                        yield k
    while len(out.buildings) < n_target and attempts < n_target * 60:
        attempts += 1
        shape = shapes[rng.choice(3, p=cfg.shape_weights)]
        L = rng.uniform(*cfg.building_length_m)
        W = rng.uniform(cfg.building_width_m[0], min(cfg.building_width_m[1], L))
        if shape == "courtyard":
            L, W = max(L, 24.0), max(W, 22.0)
        if shape == "L":
            W = max(W, 16.0)
        fp0 = _footprint(shape, L, W, rng)
        cx = rng.uniform(urban.bounds[0] + 10, urban.bounds[2] - 10)
        cy = rng.uniform(urban.bounds[1] + 10, urban.bounds[3] - 10)
        rot = angle + rng.choice([0.0, math.pi / 2]) + math.radians(rng.normal(0, cfg.building_angle_jitter_deg))
        fp = _place(fp0, rot, cx, cy)
        if not urban.contains(fp.buffer(3.0)) or fp.buffer(2.0).intersects(blocked):
            continue
        grown = fp.buffer(cfg.building_gap_m)
        if any(grown.intersects(out.footprints[k]) for k in sorted(near(grown.bounds))):
            continue
        roof = "flat"
        if shape == "rectangle" and rng.random() < cfg.pitched_fraction:
            roof = "gable" if rng.random() < 0.5 else "hip"
        eave = rng.uniform(*cfg.eave_m)
        outline = fp.buffer(eave, join_style="mitre")
        verts = np.asarray(outline.exterior.coords)
        zt = ground.terrain_height(verts[:, 0], verts[:, 1])
        base = float(zt.min())
        if zt.max() - zt.min() > 4.0:
            continue
        height = _building_height(cfg, rng) if roof == "flat" else rng.uniform(cfg.building_height_m[0], 14.0)
        eave_z = base + height
        pitch = rng.uniform(25.0, 40.0)
        ridge_z = eave_z + (W / 2 + eave) * math.tan(math.radians(pitch)) if roof != "flat" else eave_z
        b = Building(len(out.buildings) + 1, fp, outline, shape, roof, base, eave_z, ridge_z, eave, (L, W))
        t, k = _building_triangles(b, rot, (cx, cy), pitch)
        out.buildings.append(b)
        x0, y0, x1, y1 = fp.bounds
        for i in range(int(y0 // cell), int(y1 // cell) + 1):
            for j in range(int(x0 // cell), int(x1 // cell) + 1):
                cells.setdefault((i, j), []).append(len(out.footprints))
        out.footprints.append(fp)
        out.tris.extend(t)
        out.kinds.extend(k)
        out.objs.extend([b.building_id] * len(t))
    return out


def _plant_trees(cfg: PresetScene, ground: Scene, no_tree, steep: tuple[float, float], rng) -> tuple[np.ndarray, np.ndarray]:
    """Single trees, clusters (groves), forest on the steep slope and bushes, never where ``no_tree`` (roofs,
    roads, water): crown centres (K, 3) and semi-axes (K, 2)."""
    width_m, height_m = ground.width_m, ground.height_m
    centres, axes = [], []
    shapely.prepare(no_tree)

    def try_tree(x, y, crown_r, height):
        if not (2 <= x <= width_m - 2 and 2 <= y <= height_m - 2):
            return
        if no_tree.intersects(Point(x, y).buffer(crown_r)):
            return
        zg = float(ground.terrain_height(x, y))
        c = crown_r * rng.uniform(0.8, 1.3)  # vertical semi-axis
        centres.append((x, y, zg + height - c))
        axes.append((crown_r, c))

    for _ in range(cfg.single_trees):
        try_tree(rng.uniform(0, width_m), rng.uniform(0, steep[0]), rng.uniform(*cfg.crown_radius_m),
                 rng.uniform(*cfg.tree_height_m))
    for _ in range(cfg.tree_clusters):
        gx, gy = rng.uniform(0, width_m), rng.uniform(0, height_m)
        n = rng.integers(8, 25)
        for _ in range(n):
            try_tree(gx + rng.normal(0, 12), gy + rng.normal(0, 12), rng.uniform(*cfg.crown_radius_m),
                     rng.uniform(*cfg.tree_height_m))
    for _ in range(cfg.slope_trees):
        try_tree(rng.uniform(0, width_m), rng.uniform(steep[0], height_m), rng.uniform(*cfg.crown_radius_m),
                 rng.uniform(*cfg.tree_height_m))
    for _ in range(cfg.bushes):
        try_tree(rng.uniform(0, width_m), rng.uniform(0, steep[0]), rng.uniform(0.6, 1.2), rng.uniform(0.8, 1.8))
    return np.array(centres, dtype=float).reshape(-1, 3), np.array(axes, dtype=float).reshape(-1, 2)


def _place_targets(cfg: PresetScene, ground: Scene, clutter, rng) -> tuple[np.ndarray, np.ndarray]:
    """Painted check targets on open, flat-ish ground at least 40 m apart, clear of ``clutter``: (C, 3)
    x y radius and their terrain heights (C,)."""
    width_m, height_m = ground.width_m, ground.height_m
    targets, tz = [], []
    radius = cfg.target_radius_m
    shapely.prepare(clutter)
    tries = 0
    while len(targets) < cfg.check_targets and tries < 20000:
        tries += 1
        x = rng.uniform(cfg.urban_margin_m, width_m - cfg.urban_margin_m)
        y = rng.uniform(cfg.urban_margin_m, height_m - cfg.urban_margin_m)
        if clutter.intersects(Point(x, y).buffer(radius)):
            continue
        if any(math.hypot(x - t[0], y - t[1]) < 40.0 for t in targets):
            continue
        ring = np.array([(x + radius * math.cos(a), y + radius * math.sin(a)) for a in np.linspace(0, 2 * math.pi, 8)])
        hz = ground.terrain_height(ring[:, 0], ring[:, 1])
        if np.ptp(hz) > 0.5 * radius:  # too steep to paint a target on
            continue
        targets.append((x, y, radius))
        tz.append(float(ground.terrain_height(x, y)))
    return np.array(targets, dtype=float).reshape(-1, 3), np.array(tz)


COUNT_KEYS = ("ponds", "buildings", "single_trees", "tree_clusters", "bushes", "check_targets")


def scene_counts(cfg: PresetScene, width_m: float, height_m: float) -> PresetScene:
    """The ``[scene]`` table with its object counts for a scene of this size.

    With ``counts_for_m = [width, height]`` the counts (ponds, buildings, trees, bushes, targets) are those of
    a scene of that size and scale with the area of this one, the slope trees with its width (the valley
    side runs across the scene): a flight made larger with ``--set`` flies over a larger town, not over the
    same town spread thin. Without it (or for that very size) the counts are used as they are.
    """
    ref = cfg.counts_for_m
    if not ref:
        return cfg
    area = (width_m * height_m) / (float(ref[0]) * float(ref[1]))
    width = width_m / float(ref[0])
    if abs(area - 1.0) < 1e-9 and abs(width - 1.0) < 1e-9:
        return cfg
    return dataclasses.replace(cfg, **{key: int(round(getattr(cfg, key) * area)) for key in COUNT_KEYS},
                               slope_trees=int(round(cfg.slope_trees * width)))


def build_scene(cfg: PresetScene, width_m: float, height_m: float, origin_m, seed: int) -> Scene:
    """Generate the whole scene from the ``[scene]`` preset table (counts by ``scene_counts``).

    One random stream, drawn in a fixed order (terrain, ponds, roads, buildings, trees, targets, roof
    colours): the same seed gives the same scene.
    """
    cfg = scene_counts(cfg, width_m, height_m)
    rng = np.random.default_rng(seed)
    res = cfg.terrain_res_m
    z, steep = build_terrain(cfg, width_m, height_m, rng)
    margin = cfg.urban_margin_m
    urban = Polygon([(margin, margin), (width_m - margin, margin), (width_m - margin, steep[0] - 20.0),
                     (margin, steep[0] - 20.0)])
    ponds, z, pond_polys = _ponds(cfg, z, res, width_m, steep, rng)
    roads = build_roads(cfg, urban, rng)
    road_area = unary_union([LineString([(r[0], r[1]), (r[2], r[3])]).buffer(r[4] / 2, cap_style="flat")
                             for r in roads]) if len(roads) else Polygon()

    # The terrain, roads and ponds first: buildings, trees and targets are placed on it.
    scene = Scene(width_m, height_m, np.asarray(origin_m, float), res, z, np.zeros((0, 3, 3)),
                  np.zeros(0, np.int32), np.zeros(0, np.int32), np.zeros((0, 3)), np.zeros((0, 2)),
                  roads, ponds, np.zeros((0, 3)), np.zeros(0), [], np.zeros((0, 3)), seed, steep)
    blocked = unary_union([road_area.buffer(3.0)] + [p.buffer(6.0) for p in pond_polys])
    bld = _place_buildings(cfg, scene, urban, blocked, rng)
    no_tree = unary_union([road_area] + [p.buffer(2.0) for p in pond_polys] + [fp.buffer(3.0) for fp in bld.footprints])
    tree_c, tree_ac = _plant_trees(cfg, scene, no_tree, steep, rng)
    # Check targets on open ground and roads: clear of buildings, trees and water.
    clutter = unary_union([fp.buffer(12.0) for fp in bld.footprints] + [p.buffer(4.0) for p in pond_polys]
                          + [Point(c[0], c[1]).buffer(a[0] + 6.0) for c, a in zip(tree_c, tree_ac)])
    targets, tz = _place_targets(cfg, scene, clutter, rng)

    palette = np.array([[0.55, 0.25, 0.2], [0.5, 0.5, 0.52], [0.3, 0.3, 0.33], [0.7, 0.68, 0.62],
                        [0.45, 0.35, 0.3], [0.25, 0.38, 0.42], [0.62, 0.55, 0.45]])
    nb = len(bld.buildings) + 1
    roof_albedo = palette[rng.integers(0, len(palette), nb)] * rng.uniform(0.85, 1.15, (nb, 1))

    scene.tri_v = np.array(bld.tris, dtype=float).reshape(-1, 3, 3)
    scene.tri_kind = np.array(bld.kinds, dtype=np.int32)
    scene.tri_obj = np.array(bld.objs, dtype=np.int32)
    scene.tree_c = tree_c
    scene.tree_ac = tree_ac
    scene.targets = targets
    scene.target_z = tz
    scene.buildings = bld.buildings
    scene.roof_albedo = np.clip(roof_albedo, 0, 1)
    return scene
