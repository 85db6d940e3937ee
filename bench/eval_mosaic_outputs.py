"""Whether two runs of ``ortho mosaic`` (e.g. main's code and a branch's, each on its own copy of the same project)
wrote the same outputs: sha256 of mosaic.tif, seams.tif, seamlines.geojson and seamlines_preview.png; seamlines.gpkg by
content (its layer's CRS, fields, geometries as WKB and attribute values: the file's bytes hold the time it was
written); mosaic.json but its ``path`` and the nDSM path under ``settings`` (the projects' folders differ).

Usage: python bench/eval_mosaic_outputs.py PROJECT_A PROJECT_B [--out FILE] [--entry KEY] [--label KEY]
(with --out the result goes under ``--label`` (default "same_outputs") of the ``--entry`` key (default "i41_mosaic5") of
that JSON file, whose other keys are kept); exit code 1 when any output differs.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from pathlib import Path

import numpy as np

FILES = ("mosaic.tif", "seams.tif", "seamlines.geojson", "seamlines_preview.png")


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def gpkg_content_equal(a: Path, b: Path) -> bool:
    import pyogrio.raw

    ra, rb = pyogrio.raw.read(a), pyogrio.raw.read(b)
    return (ra[0]["crs"] == rb[0]["crs"] and list(ra[0]["fields"]) == list(rb[0]["fields"])
            and len(ra[2]) == len(rb[2]) and all(x == y for x, y in zip(ra[2], rb[2]))
            and all(np.array_equal(x, y) for x, y in zip(ra[3], rb[3])))


def summary_without_paths(path: Path) -> dict:
    s = json.loads(path.read_text())
    s.pop("path", None)
    if isinstance(s.get("settings"), dict) and isinstance(s["settings"].get("ndsm"), dict):
        s["settings"]["ndsm"].pop("value", None)
    return s


def compare(a: Path, b: Path) -> dict:
    oa, ob = a / "ortho", b / "ortho"
    out = {}
    for name in FILES:
        ha, hb = sha256(oa / name), sha256(ob / name)
        out[name] = {"same_bytes": ha == hb, "sha256_a": ha, "sha256_b": hb}
    out["seamlines.gpkg"] = {"same_content": gpkg_content_equal(oa / "seamlines.gpkg", ob / "seamlines.gpkg")}
    same_summary = summary_without_paths(oa / "mosaic.json") == summary_without_paths(ob / "mosaic.json")
    out["mosaic.json"] = {"same_but_paths": same_summary}
    out["all_same"] = all(v.get("same_bytes", v.get("same_content", v.get("same_but_paths"))) for v in out.values())
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("a", type=Path)
    ap.add_argument("b", type=Path)
    ap.add_argument("--out", type=Path)
    ap.add_argument("--entry", default="i41_mosaic5", help="key of the --out file the result goes under")
    ap.add_argument("--label", default="same_outputs")
    a = ap.parse_args()
    result = compare(a.a, a.b)
    for k, v in result.items():
        print(k, v)
    if a.out:
        doc = json.loads(a.out.read_text()) if a.out.exists() else {}
        doc.setdefault(a.entry, {})[a.label] = {"a": str(a.a), "b": str(a.b), **result}
        a.out.write_text(json.dumps(doc, indent=1) + "\n")
    sys.exit(0 if result["all_same"] else 1)


if __name__ == "__main__":
    main()
