#!/bin/bash
# The commands of bench/eval_same_products.py on one side: CODE (a folder holding that side's aerotri, lidarctl and
# ortho packages, e.g. `git archive REV aerotri lidarctl ortho | tar -x -C CODE`), P (a copy of the demo project,
# `aerotri demo`), OUT and OUT2 (new folders). Console lines go to OUT/log.txt. Run both sides with the same python:
#
#   bench/same_products_run.sh PYTHON CODE P OUT OUT2
#
# then python bench/eval_same_products.py --before P1 OUT1 OUT1B --after P2 OUT2 OUT2B --json RESULT.json
set -u
PY=$1; CODE=$(realpath "$2"); P=$(realpath "$3"); OUT=$4; OUT2=$5
mkdir -p "$OUT" "$OUT2"; OUT=$(realpath "$OUT"); OUT2=$(realpath "$OUT2")
C=$P/lidar_out/classified
LOG=$OUT/log.txt
run() {  # run PROGRAM ARGS...: one command of the side, its console lines appended to the log
    local prog=$1; shift
    local entry=$prog.cli  # the console script's module (pyproject [project.scripts]); lidarctl's is cli/main.py
    [ "$prog" = lidarctl ] && entry=lidarctl.cli.main
    echo "\$ $prog $*" >> "$LOG"
    PYTHONPATH=$CODE "$PY" -P -c "import sys; from $entry import main; sys.argv[0] = '$prog'; main()" "$@" \
        >> "$LOG" 2>&1
    echo "rc=$?" >> "$LOG"
}
: > "$LOG"
PYTHONPATH=$CODE "$PY" -P -c "import aerotri, lidarctl, ortho; print(aerotri.__file__, lidarctl.__file__, ortho.__file__)" \
    > "$OUT.code.txt"  # beside OUT: which code ran (not a product)
run lidarctl classify "$P/lidar/strip_01.las" "$P/lidar/strip_02.las" "$OUT/classified" --workers 1
run ortho dem "$P" --out "$OUT/tp_dem.tif"
run ortho rectify "$P" --workers 1
run ortho check "$P" --reference "$P/truth/ortho.tif"
run lidarctl evaluate "$C/strip_02.laz" --truth "$P/truth/lidar/strip_02.las" --json "$OUT/evaluate.json"
run lidarctl check-heights "$C"/strip_0[1-4].laz "$P/truth/checkpoints.csv" --json "$OUT/check_heights.json"
run lidarctl check-heights "$P/truth/checkpoints.csv" --dem "$P/lidar_out/dem.tif" --json "$OUT/check_heights_dem.json"
run lidarctl contours "$P/lidar_out/dem.tif" "$OUT/contours.gpkg" --interval-m 1
run lidarctl vectors "$C"/strip_0[1-4].laz --dem "$P/lidar_out/dem.tif" "$OUT/vectors.gpkg"
run lidarctl check-vectors "$OUT/vectors.gpkg" --reference "$OUT/vectors.gpkg" --layer buildings --layer water \
    --json "$OUT/check_vectors.json" --png "$OUT/check_vectors.png"
run lidarctl rasters "$C"/strip_0[1-4].laz "$OUT/rasters" --res-m 1.0
run lidarctl strips check "$C"/strip_0[1-4].laz "$OUT/strips"
run ortho mosaic "$P" --workers 1
run ortho check "$P" --reference "$P/truth/ortho.tif"
# checkpoints inside the mosaic, "measured" in the DOM 0.3 m east and 0.2 m south of their surveyed position
PYTHONPATH=$CODE "$PY" -P - "$P" "$OUT/dom_points.csv" <<'EOF'
import csv, sys
import rasterio
p, out = sys.argv[1], sys.argv[2]
with rasterio.open(f"{p}/ortho/mosaic.tif") as ds:
    b = ds.bounds
rows = [r for r in csv.DictReader(open(f"{p}/truth/checkpoints.csv"))
        if b.left + 5 < float(r["x"]) < b.right - 5 and b.bottom + 5 < float(r["y"]) < b.top - 5]
with open(out, "w") as f:
    f.write("id,x,y,x_dom,y_dom\n")
    for r in rows:
        x, y = float(r["x"]), float(r["y"])
        f.write(f"{r['id']},{x:.3f},{y:.3f},{x + 0.3:.3f},{y - 0.2:.3f}\n")
EOF
run ortho check "$P" --points "$OUT/dom_points.csv" --out "$OUT/dom_points_report"
run lidarctl trees "$C/strip_01.laz" "$C/strip_02.laz" "$OUT2/trees"
run lidarctl corners "$C"/strip_0[1-4].laz "$OUT2/corners"
run lidarctl check-plan "$C"/strip_0[1-4].laz "$P/truth/roof_corners.csv" --json "$OUT2/check_plan.json"
run lidarctl drainage "$P/lidar_out/dem.tif" "$OUT2/drainage"
run lidarctl check-heights "$C/strip_01.laz" "$C/strip_02.laz" "$P/truth/checkpoints.csv" --dem "$P/lidar_out/dem.tif" \
    --groups density --json "$OUT2/check_heights_density.json"
run aerotri report "$P"
run aerotri adjust "$P"
