"""Rows of docs/true-ortho.md's tables from a key of bench/results/true_ortho_fill.json: per block and DSM spec the
fill, ghosts, frame-by-frame masks, roofs and misses by cause. Usage: python bench/crowns_table.py [KEY]"""

import json
import sys
from pathlib import Path

key = sys.argv[1] if len(sys.argv) > 1 else "crowns8"
d = json.loads((Path(__file__).parent / "results" / "true_ortho_fill.json").read_text())[key]
for block, b in d["blocks"].items():
    for spec, s in b["dsm"].items():
        f, g, r = s["fill"], s["ghosts"], s["roofs"]
        m = s["misses_by_what_the_2_5d_surface_puts_in_the_line_of_sight"]["miss"]
        cw = s.get("crowns_within_cells") or {}
        print(f"| {block} | {spec} | {100 * f['fill_share']:.2f} % ({f['filled_from_a_frame_that_sees']:,} of "
              f"{f['seen_by_another_frame']:,}) | {g['building']:,} / {g['tree']:,} ({g['building_beyond_1m_of_a_roof']:,}) | "
              f"{f['masks']['hidden_but_valid']:,} / {f['masks']['seen_but_masked']:,} | {r['rms_gsd']:.2f} / "
              f"{r['median_gsd']:.2f} ({r['measured']:,}) | {m['a_seeing_frame_clears_the_2_5d_surface']:,} / "
              f"{m['eave_overhang']:,} / {m['tree_crown']:,} | {s['rectify'].get('cpu_s_per_mp', '')} |"
              + (f" trees {cw.get('trees')}" if cw.get("trees") else ""))
