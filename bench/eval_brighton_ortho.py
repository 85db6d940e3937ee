"""Brighton Beach orthos (issue 42): the mosaic's saturated share against its frames' after the gain limit, and the
frame orthos with a DEM that covers part of the block -> bench/results/brighton_ortho.json.

Data: ../shared/data/brighton_beach (18 DJI FC300S frames, EXIF GNSS, ODM point cloud ``model.laz``; read only).
The commands a user runs (``bench/eval_real_blocks.py``'s Brighton chain, through the same ``Runner``):

1. ``aerotri init`` / ``import --format exif`` / ``match``; ``lidarctl classify model.laz`` and ``lidarctl rasters
   --res-m 0.5`` (the DEM of the ODM cloud, which covers the middle of the block only); ``aerotri adjust --self-cal
   focal,pp,radial --dem --ndsm`` (the DEM as surface control, as in docs/real-blocks.md);
2. ``full``: ``ortho dem`` (the tie points' DEM, to the frames' edges), ``ortho rectify --dem at/dem.tif``, ``ortho
   mosaic`` (the run of issue 42's 4.6 %);
3. ``partial``: ``ortho rectify --dem <the cloud's DEM>`` (covers part of every frame; frames whose ground it misses
   entirely are refused, exit 2, and left out with ``--frames``), ``ortho mosaic``;
4. ``cropped``: the cloud's DEM cut to its western half (``cropped_dem.tif``), the same.

Measured per run: the share of saturated pixels (any of the 3 bands at 255) among the valid pixels of every frame
ortho and of the mosaic (the issue: 4.6 % in the mosaic against at most 0.3 % per frame), the gains the mosaic
lowered (its warnings), each frame's ``height_covered_share`` and valid fraction (index.json), the warnings and exit
codes of rectify. The "before" figures of the issue are quoted, not re-measured here.

Usage: python bench/eval_brighton_ortho.py [--data $AEROTRI_SHARED_DATA or ../shared/data] [--work DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))

from eval_real_blocks import Runner, _flight_height_from_import  # noqa: E402


def saturated_share(path: Path, block_px: int = 2048) -> dict:
    """Valid pixels of a GeoTIFF with any of its first 3 bands at the type's maximum, by blocks."""
    import rasterio
    from rasterio.windows import Window

    sat = valid = 0
    with rasterio.open(path) as ds:
        top = np.iinfo(np.dtype(ds.dtypes[0])).max
        for r0 in range(0, ds.height, block_px):
            for c0 in range(0, ds.width, block_px):
                w = Window(c0, r0, min(block_px, ds.width - c0), min(block_px, ds.height - r0))
                ok = ds.read_masks(1, window=w) > 0
                a = ds.read([1, 2, 3], window=w)
                sat += int(((a == top).any(axis=0) & ok).sum())
                valid += int(ok.sum())
    return {"valid_px": valid, "saturated_px": sat, "saturated_pct": round(100.0 * sat / valid, 3) if valid else None}


def crop_west_half(src: Path, dst: Path) -> dict:
    """The western half of a DEM's columns, as a GeoTIFF of its own."""
    import rasterio
    from rasterio.windows import Window

    with rasterio.open(src) as ds:
        w = Window(0, 0, ds.width // 2, ds.height)
        prof = ds.profile | {"width": w.width, "height": w.height, "transform": ds.window_transform(w)}
        a = ds.read(1, window=w)
        with rasterio.open(dst, "w", **prof) as out:
            out.write(a, 1)
        return {"from": src.name, "columns": [0, int(w.width)], "of": ds.width}


def _messages(r: Runner, out: str) -> list[str]:
    """The warnings and errors of a command's output (at most 40 lines)."""
    return [r._show(ln) for ln in out.splitlines() if re.match(r"\s*(warning|error)", ln, re.I)][:40]


def ortho_run(r: Runner, P: Path, dem: Path, name: str) -> dict:
    """rectify on ``dem`` (again with --frames when frames are refused), mosaic; the figures of both."""
    code, out = r.run("ortho", "rectify", P, "--dem", dem)
    res = {"dem": str(dem.relative_to(r.work)), "rectify_exit": code,
           "rectify_messages": _messages(r, out)}
    if code == 2:
        from aerotri.geom.eo import read_eo

        m = re.search(r"covers none of frame (\S+)", out)
        ids = list(read_eo(P / "at" / "eo.txt").image_id)
        # rectify names the first frame it refuses; all of them at once from the coverage rectify computes
        refused = uncovered_frames(P, dem)
        res["refused_frames"] = refused
        res["first_refusal"] = m.group(0) if m else None
        keep = [i for i in ids if i not in refused]
        code, out = r.run("ortho", "rectify", P, "--dem", dem, "--frames", ",".join(keep))
        res["rectify_exit_with_frames"] = code
        res["rectify_messages"] += _messages(r, out)
    index = json.loads((P / "ortho" / "frames" / "index.json").read_text())
    res["frames"] = {e["image_id"]: {"height_covered_share": e.get("height_covered_share"),
                                     "valid_fraction": round(e["valid_fraction"], 4),
                                     **saturated_share(P / "ortho" / "frames" / e["file"])}
                     for e in index["frames"]}
    code, out = r.run("ortho", "mosaic", P)
    res["mosaic_exit"] = code
    res["mosaic_gain_warnings"] = [r._show(ln) for ln in out.splitlines() if "lowered" in ln]
    res["mosaic"] = saturated_share(P / "ortho" / "mosaic.tif")
    summary = json.loads((P / "ortho" / "mosaic.json").read_text())
    res["mosaic"].update({k: summary[k] for k in ("cells_seen_by_no_frame", "share_seen_by_no_frame") if k in summary})
    pct = [f["saturated_pct"] for f in res["frames"].values() if f["saturated_pct"] is not None]
    res["frames_saturated_pct_max"] = max(pct) if pct else None
    print(name, json.dumps({k: v for k, v in res.items() if k != "frames"}, indent=1), flush=True)
    return res


def uncovered_frames(P: Path, dem: Path) -> list[str]:
    """The frames whose ground the DEM covers none of (``ortho.rectify.covered_share`` = 0), as rectify finds them."""
    from pyproj import CRS

    from ortho.block import load_block
    from ortho.dem import read_height_raster
    from ortho.rectify import covered_share

    b = load_block(P)
    heights = read_height_raster(dem, CRS(b.project_crs), "DEM")
    return [iid for i, iid in enumerate(b.eo.image_id) if iid in b.images
            and covered_share(b.camera, b.eo.centre_m[i], b.eo.rotation(i), heights) == 0.0]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    default = Path(os.environ.get("AEROTRI_SHARED_DATA", "/work/shared/data"))
    ap.add_argument("--data", type=Path, default=default)
    ap.add_argument("--work", type=Path, default=REPO / "out" / "brighton_ortho")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "brighton_ortho.json")
    ap.add_argument("--reuse", action="store_true", help="keep the adjusted project of an earlier run in --work (the "
                                                          "orthos only; its commands are not recorded again)")
    args = ap.parse_args()
    D = args.data / "brighton_beach"
    P = args.work / "brighton"
    lidar = args.work / "brighton_lidar"
    r = Runner(args.work, D)
    reused = args.reuse and (P / "at" / "eo.txt").is_file() and (lidar / "dem.tif").is_file()
    if not reused:
        if args.work.exists():
            shutil.rmtree(args.work)
        args.work.mkdir(parents=True)
        adjust(r, P, D, lidar)
    else:
        shutil.rmtree(args.work / "ortho_full", ignore_errors=True)
    out = {"data": "brighton_beach", "reused_adjustment": reused,
           "before_issue_42": {"mosaic_saturated_pct": 4.6, "frames_saturated_pct_max": 0.3,
                               "partial_dem": "every frame refused (ortho rectify exit 2)"}}
    r.run("ortho", "dem", P)
    out["full"] = ortho_run(r, P, P / "at" / "dem.tif", "full")
    full_ortho = args.work / "ortho_full"
    shutil.copytree(P / "ortho", full_ortho)
    out["partial"] = ortho_run(r, P, lidar / "dem.tif", "partial")
    cropped = args.work / "cropped_dem.tif"
    out["cropped_dem"] = crop_west_half(lidar / "dem.tif", cropped)
    out["cropped"] = ortho_run(r, P, cropped, "cropped")
    out["commands"] = r.summary()
    out["load_avg"] = [round(v, 2) for v in os.getloadavg()]
    out["commit"] = subprocess.run(["git", "-C", str(REPO), "rev-parse", "HEAD"], capture_output=True,
                                   text=True).stdout.strip()
    from aerotri.core.atomic import write_text_atomic

    write_text_atomic(args.out, json.dumps(out, indent=1) + "\n")
    print(f"wrote {args.out}")


def adjust(r: Runner, P: Path, D: Path, lidar: Path) -> None:
    """The block adjusted with the cloud's DEM as surface control (docs/real-blocks.md), from the data folder."""
    r.run("aerotri", "init", P, "--images", D / "images", "--crs", "EPSG:32615")
    _, out = r.run("aerotri", "import", P, "--format", "exif", P / "images")
    _flight_height_from_import(r, P, out)
    r.run("aerotri", "match", P)
    r.run("lidarctl", "classify", D / "model.laz", lidar / "model_classified.laz")
    r.run("lidarctl", "rasters", lidar / "model_classified.laz", lidar, "--res-m", "0.5")
    r.run("aerotri", "adjust", P, "--self-cal", "focal,pp,radial", "--dem", lidar / "dem.tif", "--ndsm",
          lidar / "ndsm.tif")


if __name__ == "__main__":
    main()
