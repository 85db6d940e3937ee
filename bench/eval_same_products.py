"""Same behaviour check (issue 40): the products of the demo's ``lidarctl`` and ``ortho`` commands, run once with
the code before a refactoring and once with it, compared file by file by SHA-256.

Each side is a copy of the demo project (``aerotri demo``, /work/ref/demo_chain/project) and an output folder;
the commands (run with ``PYTHONPATH`` set to the code of that side, the same command line for both):

    lidarctl classify P/lidar/strip_01.las P/lidar/strip_02.las OUT/classified --workers 1
    ortho dem P --out OUT/tp_dem.tif
    ortho rectify P --workers 1                       (P/ortho/frames)
    ortho check P --reference P/truth/ortho.tif      (refused, exit 2: the mosaic is older than the frames)
    lidarctl evaluate C/strip_02.laz --truth P/truth/lidar/strip_02.las --json OUT/evaluate.json
    lidarctl check-heights C/strip_0[1-4].laz P/truth/checkpoints.csv --json OUT/check_heights.json
    lidarctl check-heights P/truth/checkpoints.csv --dem P/lidar_out/dem.tif --json OUT/check_heights_dem.json
    lidarctl contours P/lidar_out/dem.tif OUT/contours.gpkg --interval-m 1
    lidarctl vectors C/strip_0[1-4].laz --dem P/lidar_out/dem.tif OUT/vectors.gpkg
    lidarctl check-vectors OUT/vectors.gpkg --reference OUT/vectors.gpkg --layer buildings --layer water
        --json OUT/check_vectors.json --png OUT/check_vectors.png   (the contours layer's overlap needs > 3.5 GB)

    lidarctl rasters C/strip_0[1-4].laz OUT/rasters                                 (third round of issue 40)

(C = P/lidar_out/classified), then, as ``ortho rectify`` makes the mosaic stale (``ortho check`` refuses it):

    ortho mosaic P --workers 1
    ortho check P --reference P/truth/ortho.tif
    ortho check P --points DOM_POINTS.csv --out OUT/dom_points_report   (checkpoints inside the mosaic, offset)

The third round also ran, into a second folder OUT2 (C/strip_0[1-4].laz: the four classified strips):

    lidarctl trees C/strip_01.laz C/strip_02.laz OUT2/trees
    lidarctl corners C/strip_0[1-4].laz OUT2/corners
    lidarctl check-plan C/strip_0[1-4].laz P/truth/roof_corners.csv --json OUT2/check_plan.json
    lidarctl drainage P/lidar_out/dem.tif OUT2/drainage
    lidarctl check-heights C/strip_01.laz C/strip_02.laz P/truth/checkpoints.csv --dem P/lidar_out/dem.tif
        --groups density --json OUT2/check_heights_density.json

Each side may spread its outputs over several folders (the commands ran in batches, each appending its console
lines to OUT/log.txt). This script compares what the two sides left, file by file by SHA-256:

- JSON, CSV, text and HTML with the side's folder names replaced by OUT and P;
- mosaic.json without the SHA-1 of frames/index.json (that file names the folder; it is compared itself);
- a GeoPackage by its SQL without the time each layer was written (gpkg_contents.last_change).

The console lines of all commands are compared as one sorted list (paths replaced; elapsed times, progress and
"rc=" lines left out):

    python bench/eval_same_products.py --before P_BEFORE OUT... --after P_AFTER OUT... --json RESULT.json [--what TEXT]

The fifth round of issue 40 added ``aerotri adjust P`` as the last command (at/ compared: report.json, report.txt,
report.html, eo.txt, object_points.csv, the PATB and COLMAP exports).
"""

from __future__ import annotations

import argparse
import collections
import hashlib
import json
import re
import sqlite3
from pathlib import Path

PROJECT_OUTPUTS = ("ortho/frames", "ortho/dom_report.json", "ortho/dom_report.png", "ortho/mosaic.tif",
                   "ortho/mosaic.json", "ortho/seamlines.geojson", "ortho/seams.tif",
                   "reports/summary.json",  # the QA report (bench/same_products_run.sh)
                   "at")  # aerotri adjust (its last command)
TEXT_SUFFIXES = (".json", ".txt", ".csv", ".html")
VARIES = re.compile(r"elapsed|ETA|^rc=|^== |^done$| in [0-9.]+ s|points/s|Command exited")


def _neutral(text: str, outs: list[Path], project: Path) -> str:
    for out in sorted(outs, key=lambda o: -len(str(o))):  # out_2 before out
        text = text.replace(str(out), "OUT")
    return text.replace(str(project), "P")


def _json_keys_differing(a, b) -> list[str]:
    """The top-level keys whose values differ between two JSON objects (e.g. only the wall-clock ``timings_s``);
    ``a``, ``b``: (file, the side's output folders, its project), the folder names replaced as for the digests."""
    da, db = (json.loads(_neutral(p.read_text(), outs, project)) for p, outs, project in (a, b))
    if not (isinstance(da, dict) and isinstance(db, dict)):
        return ["(not objects)"]
    return sorted(k for k in set(da) | set(db) if da.get(k, "-") != db.get(k, "-"))


def _files(outs: list[Path], project: Path, paths: dict | None = None) -> tuple[dict[str, str], list[str]]:
    """(name -> SHA-256, console lines); ``paths``, when given, gets name -> (file, ``outs``, ``project``)."""
    found, console = {}, []
    paths = {} if paths is None else paths

    def digest(p: Path) -> str:
        if p.suffix == ".gpkg":  # its SQL, without the time each layer was written (gpkg_contents.last_change)
            con = sqlite3.connect(f"file:{p}?mode=ro", uri=True)
            sql = "\n".join(con.iterdump())
            con.close()
            return hashlib.sha256(re.sub(r"'\d{4}-\d\d-\d\dT[0-9:.]+Z'", "'T'", sql).encode()).hexdigest()
        data = p.read_bytes()
        if p.suffix in TEXT_SUFFIXES:
            text = _neutral(data.decode("utf-8", "replace"), outs, project)
            # mosaic.json: the SHA-1 of frames/index.json, a file that names the project folder (compared itself)
            data = re.sub(r'"index_sha1": "[0-9a-f]+"', '"index_sha1": "-"', text).encode()
        return hashlib.sha256(data).hexdigest()

    for out in outs:
        for p in sorted(out.rglob("*")):
            # the writers' lock files and commit journals are dot files
            if not p.is_file() or p.name == "time.txt" or any(q.startswith(".") for q in p.relative_to(out).parts):
                continue
            if p.name == "log.txt":
                text = _neutral(p.read_text(errors="replace"), outs, project)
                console += [ln for ln in re.split(r"[\r\n]+", text) if ln.strip() and not VARIES.search(ln)]
                continue
            found[f"OUT/{p.relative_to(out)}"] = digest(p)
            paths[f"OUT/{p.relative_to(out)}"] = (p, outs, project)
    for rel in PROJECT_OUTPUTS:
        base = project / rel
        for p in sorted(base.rglob("*")) if base.is_dir() else [base]:
            if p.is_file() and not p.name.startswith("."):
                found[f"P/{p.relative_to(project)}"] = digest(p)
                paths[f"P/{p.relative_to(project)}"] = (p, outs, project)
    return found, sorted(console)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", nargs="+", type=Path, required=True, help="PROJECT OUT...")
    ap.add_argument("--after", nargs="+", type=Path, required=True, help="PROJECT OUT...")
    ap.add_argument("--json", type=Path)
    ap.add_argument("--what", help="what the two sides are (revisions, command lines), kept in the JSON")
    a = ap.parse_args()
    paths_before, paths_after = {}, {}
    before, console_before = _files(a.before[1:], a.before[0], paths_before)
    after, console_after = _files(a.after[1:], a.after[0], paths_after)
    names = sorted(set(before) | set(after))
    differ = [n for n in names if before.get(n) != after.get(n)]
    json_keys = {n: _json_keys_differing(paths_before[n], paths_after[n]) for n in differ
                 if n.endswith(".json") and n in paths_before and n in paths_after}
    lines_differ = sorted((collections.Counter(console_before) - collections.Counter(console_after)).elements()) + \
        sorted((collections.Counter(console_after) - collections.Counter(console_before)).elements())
    result = {**({"what": a.what} if a.what else {}), "files": len(names), "identical": len(names) - len(differ),
              "different": differ, "json_keys_differing": json_keys,
              "console_lines": len(console_after), "console_identical": console_before == console_after,
              "console_lines_differing": lines_differ,
              "sha256": {n: after.get(n) or before.get(n) for n in names}}
    print(f"{len(names)} files, {result['identical']} identical, {len(differ)} different"
          + (": " + ", ".join(differ) if differ else "")
          + f"; console lines {len(console_before)} / {len(console_after)}, "
          + ("identical" if result["console_identical"] else f"{len(lines_differ)} differ"))
    if a.json:
        a.json.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
