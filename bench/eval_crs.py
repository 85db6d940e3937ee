"""Evaluate aerotri.geom.crs: Gauss-Krueger against PROJ, parameter recovery, zone straddling, LAS throughput.

Writes ``bench/results/crs.json``. Run: ``.venv/bin/python bench/eval_crs.py`` (about a minute).
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pyproj

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from aerotri.geom.crs.definition import parse_crs  # noqa: E402
from aerotri.geom.crs.fit import fit_plane, fit_spatial  # noqa: E402
from aerotri.geom.crs.datum import PARAMETER_NAMES  # noqa: E402
from aerotri.geom.crs.gauss_kruger import GaussKruger  # noqa: E402
from aerotri.geom.crs.synthetic import TRUE_BURSA_WOLF7, TRUE_HELMERT2D, simulate_plane, simulate_spatial  # noqa: E402
from aerotri.geom.crs.transform import CrsTransformer  # noqa: E402

# Xian 1980 6-degree (2327-2337 zone-prefixed, 2338-2348 CM), Xian 1980 3-degree (2349-2369 zone,
# 2370-2390 CM), CGCS2000 6-degree (4491-4512), CGCS2000 3-degree (4513-4554), Beijing 1954 3-degree (2401-2442)
GK_CODES = [*range(2327, 2391), *range(4491, 4555), *range(2401, 2443)]


def gauss_kruger_vs_proj(n_per_zone: int = 20_000):
    worst_fwd = worst_inv = worst_rt = 0.0
    worst_code = None
    t_own = t_proj = 0.0
    n_total = 0
    names = {}
    for code in GK_CODES:
        crs = pyproj.CRS.from_epsg(code)
        names[code] = crs.name
        gk = GaussKruger.from_crs(crs)
        half = (3.0 if "3-degree" in crs.name else 6.0) / 2 + 1.0  # zone plus 1 degree overlap
        rng = np.random.default_rng(code)
        lat = rng.uniform(max(crs.area_of_use.south, 0.0) - 1, crs.area_of_use.north + 1, n_per_zone)
        lon = gk.central_meridian_deg + rng.uniform(-half, half, n_per_zone)
        fwd = pyproj.Transformer.from_crs(crs.geodetic_crs, crs, always_xy=True)
        t0 = time.perf_counter()
        E_ref, N_ref = fwd.transform(lon, lat)
        t_proj += time.perf_counter() - t0
        t0 = time.perf_counter()
        E, N = gk.forward(lat, lon)
        t_own += time.perf_counter() - t0
        n_total += n_per_zone
        e_fwd = float(np.max(np.hypot(E - E_ref, N - N_ref)))
        lat2, lon2 = gk.inverse(E_ref, N_ref)
        # inverse error expressed on the ground (metres) via the forward of the reference
        E3, N3 = fwd.transform(lon2, lat2)
        e_inv = float(np.max(np.hypot(E3 - E_ref, N3 - N_ref)))
        E2, N2 = gk.forward(*gk.inverse(E, N))
        e_rt = float(np.max(np.hypot(E2 - E, N2 - N)))
        if e_fwd > worst_fwd:
            worst_code = code
        worst_fwd, worst_inv, worst_rt = max(worst_fwd, e_fwd), max(worst_inv, e_inv), max(worst_rt, e_rt)
    return {
        "n_crs_checked": len(GK_CODES),
        "epsg_ranges": "2327-2390 (Xian 1980), 4491-4554 (CGCS2000), 2401-2442 (Beijing 1954 3-degree)",
        "points_per_crs": n_per_zone,
        "area": "zone width plus 1 degree on each side, latitudes of the CRS area of use +-1 degree",
        "forward_max_error_mm": worst_fwd * 1e3,
        "inverse_max_error_mm": worst_inv * 1e3,
        "round_trip_max_error_mm": worst_rt * 1e3,
        "worst_forward_epsg": worst_code,
        "own_forward_points_per_s": n_total / t_own,
        "proj_forward_points_per_s": n_total / t_proj,
    }


def _geocentric(crs_code, xyz):
    crs = parse_crs(crs_code)
    from aerotri.geom.crs.files import geocentric_of

    return geocentric_of(crs, xyz[:, 0], xyz[:, 1], xyz[:, 2])


def bursa_wolf_case(name, from_epsg, to_epsg, lon_range, lat_range, h_range, n, noise_m, seed):
    rng = np.random.default_rng(seed)
    lon, lat, h = rng.uniform(*lon_range, n), rng.uniform(*lat_range, n), rng.uniform(*h_range, n)
    src, dst, _ = simulate_spatial(TRUE_BURSA_WOLF7, from_epsg, to_epsg, lon_deg=lon, lat_deg=lat, h_m=h,
                                   noise_m=noise_m, seed=seed + 1)
    XYZ_s, _ = _geocentric(from_epsg, src)
    XYZ_d, ll = _geocentric(to_epsg, dst)
    res = fit_spatial("bursa-wolf7", range(n), XYZ_s, XYZ_d, dst_lat_lon_deg=ll, from_crs=f"EPSG:{from_epsg}",
                      to_crs=f"EPSG:{to_epsg}")
    t = res.transformation
    params = {}
    for k in PARAMETER_NAMES["bursa-wolf7"]:
        sd = t.std_devs[k]
        params[k] = {
            "true": TRUE_BURSA_WOLF7[k],
            "estimated": t.parameters[k],
            "std_dev": sd,
            "error_over_std_dev": (t.parameters[k] - TRUE_BURSA_WOLF7[k]) / sd if sd > 0 else None,
        }
    rms = res.rms_m
    return {
        "case": name,
        "from_epsg": from_epsg,
        "to_epsg": to_epsg,
        "n_points": n,
        "noise_m": noise_m,
        "extent_km": float(np.ptp(src[:, 0]) / 1000) if from_epsg != 4326 else None,
        "parameters": params,
        "all_within_3_sigma": bool(all(abs(p["error_over_std_dev"]) < 3 for p in params.values())),
        "sigma0_m": res.sigma0_m,
        "residual_rms_e_m": rms.e_m,
        "residual_rms_n_m": rms.n_m,
        "residual_rms_u_m": rms.u_m,
        "residual_rms_expected_m": noise_m * float(np.sqrt(res.redundancy / (3 * n))),
        "warnings": res.warnings,
    }


def bursa_wolf_calibration(runs=200, noise_m=0.03):
    """Monte Carlo: RMS over runs of (estimate - truth) / reported std dev, per parameter (ideal 1)."""
    rng = np.random.default_rng(42)
    lon, lat, h = rng.uniform(105, 115, 15), rng.uniform(30, 38, 15), rng.uniform(0, 2500, 15)
    src, _, dst_true = simulate_spatial(TRUE_BURSA_WOLF7, 4326, 4610, lon_deg=lon, lat_deg=lat, h_m=h)
    XYZ_s, _ = _geocentric(4326, src)
    XYZ_t, _ = _geocentric(4610, dst_true)
    z, s0 = [], []
    for _ in range(runs):
        res = fit_spatial("bursa-wolf7", range(15), XYZ_s, XYZ_t + rng.normal(0, noise_m, XYZ_t.shape))
        t = res.transformation
        z.append([(t.parameters[k] - TRUE_BURSA_WOLF7[k]) / t.std_devs[k] for k in PARAMETER_NAMES["bursa-wolf7"]])
        s0.append(res.sigma0_m)
    z = np.array(z)
    return {
        "runs": runs,
        "noise_m": noise_m,
        "z_score_rms": dict(zip(PARAMETER_NAMES["bursa-wolf7"], np.sqrt(np.mean(z**2, axis=0)).round(4).tolist())),
        "z_score_rms_all": float(np.sqrt(np.mean(z**2))),
        "mean_sigma0_m": float(np.mean(s0)),
    }


def helmert2d_case(noise_m, seed=7, n=25):
    rng = np.random.default_rng(seed)
    src = np.column_stack([rng.uniform(37_420_000, 37_470_000, n), rng.uniform(3_780_000, 3_830_000, n)])
    dst, _ = simulate_plane(TRUE_HELMERT2D, src, noise_m=noise_m, seed=seed + 1)
    res = fit_plane("helmert2d", range(n), src, dst, from_crs="EPSG:2361", to_crs="EPSG:4525")
    t = res.transformation
    return {
        "noise_m": noise_m,
        "n_points": n,
        "parameters": {
            k: {"true": v, "estimated": t.parameters[k], "std_dev": t.std_devs[k],
                "error_over_std_dev": (t.parameters[k] - v) / t.std_devs[k] if t.std_devs[k] > 0 else None}
            for k, v in TRUE_HELMERT2D.items()
        },
        "sigma0_m": res.sigma0_m,
        "residual_rms_horizontal_m": res.rms_m.horizontal_m,
    }


def zone_straddle():
    """Xian 1980 points 109.2..109.8 E given in zone 36 (west of 109.5) -> zone 37: max error vs direct."""
    rng = np.random.default_rng(3)
    lon, lat = rng.uniform(109.2, 109.5, 100_000), rng.uniform(34.0, 34.4, 100_000)
    gk36, gk37 = (GaussKruger.from_crs(parse_crs(c)) for c in (2360, 2361))
    E36, N36 = gk36.forward(lat, lon)
    E37, N37 = gk37.forward(lat, lon)
    X, Y, _ = CrsTransformer(2360, 2361).transform(E36, N36)
    Xo, Yo = gk37.forward(*gk36.inverse(E36, N36))
    return {
        "n_points": 100_000,
        "proj_zone_change_max_error_mm": float(np.max(np.hypot(X - E37, Y - N37)) * 1e3),
        "own_zone_change_max_error_mm": float(np.max(np.hypot(Xo - E37, Yo - N37)) * 1e3),
    }


def las_throughput(n_points=2_000_000):
    import laspy

    from aerotri.geom.crs.files import transform_las
    from aerotri.geom.crs.datum import Transformation

    rng = np.random.default_rng(0)
    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / "strip.las"
        header = laspy.LasHeader(version="1.4", point_format=6)
        header.scales = np.array([0.001, 0.001, 0.001])
        header.offsets = np.array([400_000.0, 3_780_000.0, 0.0])
        header.add_crs(pyproj.CRS.from_epsg(32649))
        las = laspy.LasData(header)
        las.x = rng.uniform(440_000, 445_000, n_points)
        las.y = rng.uniform(3_790_000, 3_795_000, n_points)
        las.z = rng.uniform(400, 600, n_points)
        las.classification = rng.integers(1, 7, n_points, dtype=np.uint8)
        las.gps_time = np.sort(rng.uniform(3e8, 3e8 + 100, n_points))
        las.write(src)
        params = Transformation("bursa-wolf7", TRUE_BURSA_WOLF7, "EPSG:32649", "EPSG:2361")
        out = {}
        for suffix in (".las", ".laz"):
            t = CrsTransformer(32649, 2361, params=params)
            t0 = time.perf_counter()
            transform_las(src, Path(tmp) / f"out{suffix}", t, chunk_size=500_000)
            dt = time.perf_counter() - t0
            out[f"bursa_wolf7_to_{suffix[1:]}_points_per_s"] = n_points / dt
        out["n_points"] = n_points
        out["chunk_size"] = 500_000
    return out


def main():
    t0 = time.perf_counter()
    results = {"gauss_kruger_vs_proj": gauss_kruger_vs_proj()}
    print("GK", json.dumps(results["gauss_kruger_vs_proj"], indent=1))
    results["bursa_wolf7_recovery"] = [
        bursa_wolf_case("national network, noise-free", 4326, 4610, (100, 120), (22, 45), (0, 3000), 30, 0.0, 1),
        bursa_wolf_case("national network, 2 cm noise", 4326, 4610, (100, 120), (22, 45), (0, 3000), 30, 0.02, 2),
        bursa_wolf_case("block 70 x 55 km UTM 49N -> GK zone 37, 2 cm noise", 32649, 2361, (109.6, 110.4),
                        (34.0, 34.5), (400, 900), 20, 0.02, 3),
    ]
    results["bursa_wolf7_calibration"] = bursa_wolf_calibration()
    results["helmert2d_recovery"] = [helmert2d_case(0.0), helmert2d_case(0.03)]
    results["zone_36_37_straddle"] = zone_straddle()
    results["las_transform"] = las_throughput()
    results["runtime_s"] = time.perf_counter() - t0
    out = REPO / "bench" / "results" / "crs.json"
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps(results, indent=2) + "\n")
    print(json.dumps({k: v for k, v in results.items() if k != "gauss_kruger_vs_proj"}, indent=1)[:6000])
    print(f"written {out}")


if __name__ == "__main__":
    main()
