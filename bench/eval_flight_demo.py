"""Flight acceptance of a simulated project (default: make demo's out/demo/project) -> bench/results/flight_demo.json.

Two rows per check: from the project as the reports see it (at/eo.txt with the adjusted camera, footprints
on lidar_out/dem.tif; ``aerotri.adjust.flight_acceptance.project_flight_acceptance``) and from the
simulator's truth (truth/eo.txt, truth/camera.toml, truth/dem.tif): the adjustment should not change the
verdicts. Limits: the project's tolerance table.

Usage: python bench/eval_flight_demo.py [PROJECT] [--results bench/results/flight_demo.json]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from aerotri.adjust.flight_acceptance import (LIMIT_KEYS, Terrain, flight_acceptance,  # noqa: E402
                                              project_flight_acceptance)
from aerotri.core.tolerances import load_table, qa_settings  # noqa: E402
from aerotri.geom.camera import read_camera  # noqa: E402
from aerotri.geom.eo import read_eo  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("project", type=Path, nargs="?", default=REPO / "out" / "demo" / "project")
    ap.add_argument("--results", type=Path, default=REPO / "bench" / "results" / "flight_demo.json")
    a = ap.parse_args(argv)
    if not (a.project / "project.toml").is_file():
        print(f"skip: {a.project} is no project folder (run make demo first)")
        return 0
    qa = qa_settings(a.project)
    tol = {k: v for k, v in load_table(qa.map_scale, qa.terrain, qa.tolerances).limits.items() if k in LIMIT_KEYS}
    runs = {"project": project_flight_acceptance(a.project, tol)}
    t = a.project / "truth"
    if (t / "eo.txt").is_file() and (t / "dem.tif").is_file():
        eo = read_eo(t / "eo.txt")
        order = np.argsort(eo.image_id)
        runs["truth"] = flight_acceptance([eo.image_id[i] for i in order], eo.centre_m[order], eo.opk_deg[order],
                                          read_camera(t / "camera.toml"), Terrain.from_dem(t / "dem.tif"), None,
                                          limits=tol)
    out = {}
    for name, fa in runs.items():
        d = dataclasses.asdict(fa)
        for f in d["frames"]:
            f.pop("footprint")
        out[name] = d
    a.results.parent.mkdir(parents=True, exist_ok=True)
    a.results.write_text(json.dumps(dict(project_folder=str(a.project), **out), indent=1) + "\n")
    names = list(runs)
    print(f"{'check':48} {'limit':>7} " + " ".join(f"{n + ' worst':>14} {'at':>9} {'':4}" for n in names))
    for k, c in enumerate(runs[names[0]].checks):
        cells = []
        for n in names:
            x = runs[n].checks[k]
            cells.append(f"{'' if x['value'] is None else x['value']:>14} {x['where']:>9} {x['verdict'] or '-':4}")
        print(f"{c['quantity']:48} {c['limit']:>7g} " + " ".join(cells))
    for n in names:
        print(f"{n}: {runs[n].source}; terrain {runs[n].terrain}")
    print(f"wrote {a.results}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
