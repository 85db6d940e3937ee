"""An 8-bit DOM from a 16-bit block when asked (dom-8bit, issue 42): per block, ``ortho mosaic`` with the default
(the frames' own type), with ``--output-bits 8`` and with ``--output-range percentiles``; the 8-bit DOM against the 16-bit DOM mapped by mosaic.json's
recorded mapping, the masks, the shares at 255 (at white before the mapping, and what the mapping clipped), sizes and
CPU -> bench/results/dom_8bit.json. The default DOM's sha256 is the byte-identity check against another commit's run
(``--code DIR``: run the same with ``ortho`` imported from DIR first on the path, e.g. ``git archive COMMIT ortho``
unpacked there; that run writes no 8-bit DOM).

Blocks are copies of rectified projects (frame orthos, index, project.toml, lidar_out/ndsm.tif; their ortho/ outputs are
rewritten and left as the default DOM). As measured: the demo (8-bit frames) and the demo's images x 4095 / 255 in
uint16 (12-bit data in 16-bit frames, no NBITS tag) rectified as the demo's true ortho.

Usage: python bench/dom_8bit.py NAME=PROJECT [NAME=PROJECT ...] [--tag TAG] [--code DIR]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shutil
import sys
import time
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("blocks", nargs="+", help="NAME=PROJECT (a copy: its ortho/ outputs are rewritten)")
    ap.add_argument("--tag", default="now")
    ap.add_argument("--code", type=Path, help="import ortho from this folder (another commit's run: default DOM only)")
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "dom_8bit.json")
    a = ap.parse_args()
    if a.code is not None:
        sys.path.insert(0, str(a.code))
    import numpy as np
    import rasterio
    from click.testing import CliRunner

    import ortho.mosaic
    from ortho.cli import main as ortho_main

    def run(root, *args) -> float:
        t0 = time.process_time()
        r = CliRunner().invoke(ortho_main, ["mosaic", str(root), *args])
        if r.exit_code != 0:
            raise SystemExit(r.output)
        return round(time.process_time() - t0, 2)

    out = {"code": str(Path(ortho.mosaic.__file__).parent.parent), "blocks": {}}
    for spec in a.blocks:
        name, root = spec.split("=", 1)
        root = Path(root)
        rec = out["blocks"][name] = {"project": str(root), "cpu_s": run(root)}
        dom = root / "ortho" / "mosaic.tif"
        rec["sha256"] = hashlib.sha256(dom.read_bytes()).hexdigest()
        if a.code is not None:
            continue
        keep = root / "work" / "dom16.tif"
        keep.parent.mkdir(exist_ok=True)
        shutil.copy(dom, keep)
        cpu8 = run(root, "--output-bits", "8")
        s = json.loads((root / "ortho" / "mosaic.json").read_text())["output"]
        m = s["mapping"]
        with rasterio.open(keep) as ds:
            a16, ok16 = ds.read(), ds.read_masks(1) > 0
        with rasterio.open(dom) as ds:
            a8, ok8, tags = ds.read(), ds.read_masks(1) > 0, ds.tags()
        mapped = np.clip(np.rint((a16.astype(np.float64) - m["low_dn"]) * 255 / (m["high_dn"] - m["low_dn"])), 0, 255)
        rec["output_bits_8"] = {
            "cpu_s": cpu8, "mapping": m, "tag": tags.get("DOM_SAMPLE_MAPPING"),
            "max_abs_diff_to_mapped_16": float(np.abs(a8[:, ok8] - mapped[:, ok8]).max()),
            "mask_equal": bool(np.array_equal(ok8, ok16)), "dtype": str(a8.dtype),
            "share_at_white_16": float((a16 >= int(m["high_dn"])).any(axis=0)[ok16].mean()),
            "report": {k: v for k, v in s.items() if k != "mapping"},
            "bytes_16": keep.stat().st_size, "bytes_8": dom.stat().st_size}
        cpu_p = run(root, "--output-bits", "8", "--output-range", "percentiles")
        s = json.loads((root / "ortho" / "mosaic.json").read_text())["output"]
        m = s["mapping"]
        with rasterio.open(dom) as ds:
            a8, ok8 = ds.read(), ds.read_masks(1) > 0
        mapped = np.clip(np.rint((a16.astype(np.float64) - m["low_dn"]) * 255 / (m["high_dn"] - m["low_dn"])), 0, 255)
        rec["output_bits_8_percentiles"] = {
            "cpu_s": cpu_p, "mapping": m, "dom_16_percentiles_0.1_99.9": [float(v) for v in np.percentile(
                a16[:, ok16], [0.1, 99.9])],
            "max_abs_diff_to_mapped_16": float(np.abs(a8[:, ok8] - mapped[:, ok8]).max()),
            "mask_equal": bool(np.array_equal(ok8, ok16)), "report": {k: v for k, v in s.items() if k != "mapping"},
            "bytes_8": dom.stat().st_size}
        shutil.copy(keep, dom)
        run(root)  # leave the default DOM and its mosaic.json
    print(json.dumps(out, indent=1))
    doc = json.loads(a.out.read_text()) if a.out.is_file() else {}
    doc[a.tag] = out
    a.out.write_text(json.dumps(doc, indent=1) + "\n")


if __name__ == "__main__":
    main()
